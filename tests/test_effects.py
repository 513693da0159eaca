"""Tests for anra_torch.effects: each hidden effect against an analytic or independent expectation,
combinations, time convergence, errors, and the random ground-truth videos."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
import torch

from anra_torch.effects import (
    EFFECTS,
    Effect,
    ExtendedHeatRHS,
    Geometry,
    Grid,
    HiddenEffectVideo,
    effects_from_json,
    effects_to_json,
    hidden_effect_video,
    simulate_effects,
)
from anra_torch.simulation import HeatRHS, gaussian_blob, simulate_heat
from anra_torch.video import load_video

F64 = torch.float64

PARAMS = {
    "linear_loss": ["b", "T_ref"],
    "source": ["x0", "y0", "x1", "y1", "rate", "width"],
    "advection": ["vx", "vy"],
    "anisotropy": ["a_x", "a_y", "a_xy"],
    "heterogeneity": ["x", "y", "radius", "a_inside", "a_outside"],
    "nonlinear_diffusion": ["a0", "beta", "T_ref"],
    "periodic_source": ["x", "y", "width", "rate", "frequency", "phase"],
    "depth_conduction": ["strength", "t_heat", "depth_time", "T_ref"],
    "delamination": ["x", "y", "radius", "strength", "depth_time", "t_heat", "plate_time", "T_ref"],
}
"""The fixed names of the truth records (a later JSON relies on them)."""

EXAMPLES = {
    "linear_loss": {"b": 0.3, "T_ref": 29.0},
    "source": {"x0": 6.0, "y0": 7.0, "x1": 9.0, "y1": 5.0, "rate": 4.0, "width": 1.2},
    "advection": {"vx": 0.8, "vy": -0.5},
    "anisotropy": {"a_x": 0.2, "a_y": 0.08, "a_xy": 0.06},
    "heterogeneity": {"x": 8.0, "y": 8.0, "radius": 4.0, "a_inside": 0.3, "a_outside": 0.1},
    "nonlinear_diffusion": {"a0": 0.1, "beta": 0.05, "T_ref": 30.0},
    "periodic_source": {"x": 8.0, "y": 7.0, "width": 1.2, "rate": 4.0, "frequency": 0.5, "phase": 1.0},
    "depth_conduction": {"strength": 1.0, "t_heat": -0.2, "depth_time": 3.0, "T_ref": 29.0},
    "delamination": {
        "x": 8.0,
        "y": 7.0,
        "radius": 3.0,
        "strength": 1.0,
        "depth_time": 0.4,
        "t_heat": -0.2,
        "plate_time": 3.0,
        "T_ref": 29.0,
    },
}


def centres(n: int, dx: float) -> torch.Tensor:
    return (torch.arange(n, dtype=F64) + 0.5) * dx


def moments(u: torch.Tensor, dx: float) -> dict[str, torch.Tensor]:
    """Mass, centroid (mm) and covariance (mm^2) of a field ``(..., H, W)`` (x along W, y along H)."""
    x, y = centres(u.shape[-1], dx), centres(u.shape[-2], dx)[:, None]
    mass = u.sum((-2, -1))
    mx = (u * x).sum((-2, -1)) / mass
    my = (u * y).sum((-2, -1)) / mass
    dx_, dy_ = x - mx[..., None, None], y - my[..., None, None]
    return {
        "mass": mass,
        "x": mx,
        "y": my,
        "xx": (u * dx_**2).sum((-2, -1)) / mass,
        "yy": (u * dy_**2).sum((-2, -1)) / mass,
        "xy": (u * dx_ * dy_).sum((-2, -1)) / mass,
    }


def blob(
    n: int = 64, dx: float = 0.25, sigma: float = 1.5, centre: tuple[float, float] | None = None
) -> torch.Tensor:
    return gaussian_blob([0.0], shape=(n, n), dx=dx, a=0.0, peak=1.0, sigma=sigma, centre=centre)[0]


def rough(n: int = 20) -> torch.Tensor:
    """Random pixels with a hot pixel on an edge: boundaries matter."""
    u = 30.0 + torch.rand(n, n, dtype=F64)
    u[0, n // 2] = 40.0
    return u


# --------------------------------------------------------------------------------------- registry
def test_registry_names_and_parameter_names_are_fixed() -> None:
    assert list(EFFECTS) == list(PARAMS)
    for name, keys in PARAMS.items():
        assert list(EFFECTS[name].params) == keys
        assert all(isinstance(unit, str) and unit for unit in EFFECTS[name].params.values())
    assert [n for n, s in EFFECTS.items() if s.replaces_diffusion] == [
        "anisotropy",
        "heterogeneity",
        "nonlinear_diffusion",
    ]


@pytest.mark.parametrize("name", list(EFFECTS))
def test_term_shapes_and_dtype(name: str, dtype: torch.dtype) -> None:
    grid = Grid((12, 16), 1.0, duration=2.0)
    effect = Effect(name, EXAMPLES[name])
    u = 30.0 + torch.rand(3, 12, 16, dtype=dtype)
    out = effect.term(u, 0.5, grid)
    assert out.shape == (3, 12, 16) and out.dtype == dtype and bool(out.isfinite().all())
    assert effect.term(u[0], torch.tensor(0.5), grid).shape == (12, 16)


# ------------------------------------------------------------------------------------ linear_loss
def test_linear_loss_uniform_field_decays_exactly(dtype: torch.dtype) -> None:
    u0 = torch.full((2, 8, 8), 40.0, dtype=dtype)
    u0[1] = 20.0  # below T_ref: warms up towards it
    loss = Effect("linear_loss", {"b": 0.4, "T_ref": 30.0})
    video = simulate_effects(u0, a=0.2, dx=0.5, dt=0.1, n_frames=31, effects=[loss])
    t = torch.arange(31, dtype=F64) * 0.1
    z = -0.4 * 0.1  # one RK4 step (one substep per frame here) multiplies the excess by R(z)
    step = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
    tol = 1e-12 if dtype == F64 else 1e-5
    for k, t0 in enumerate((40.0, 20.0)):
        discrete = 30.0 + (t0 - 30.0) * step ** torch.arange(31, dtype=F64)
        torch.testing.assert_close(video[k, :, 3, 5].double(), discrete, rtol=tol, atol=0)
        continuous = 30.0 + (t0 - 30.0) * torch.exp(-0.4 * t)
        torch.testing.assert_close(video[k, :, 3, 5].double(), continuous, rtol=0, atol=1e3 * tol + 1e-7)
        assert float((video[k] - video[k, :, :1, :1]).abs().max()) <= tol * 40  # stays uniform


def test_linear_loss_gaussian_is_diffusion_times_decay() -> None:
    u0 = blob()
    b, a, dt = 0.5, 0.1, 0.1
    loss = Effect("linear_loss", {"b": b, "T_ref": 0.0})
    video = simulate_effects(u0, a=a, dx=0.25, dt=dt, n_frames=21, effects=[loss])
    t = torch.arange(21, dtype=F64) * dt
    decay = torch.exp(-b * t)[:, None, None]
    # The loss commutes with the Laplacian: the semi-discrete solution is the heat solution times
    # exp(-b t) (up to RK4's O(ds^4) time error).
    heat = simulate_heat(u0, a=a, dx=0.25, dt=dt, n_frames=21)
    torch.testing.assert_close(video, heat * decay, rtol=0, atol=1e-7)
    exact = gaussian_blob(t, shape=(64, 64), dx=0.25, a=a, peak=1.0, sigma=1.5) * decay
    assert float((video - exact).abs().max()) < 2e-3  # the 5-point Laplacian's O(dx^2)


# -------------------------------------------------------------------------------------- advection
def test_advection_moves_the_centroid_by_vt_and_spreads_by_2at() -> None:
    n, dx, a, dt, sigma, c = 96, 0.25, 0.1, 0.1, 1.5, (11.0, 13.0)
    v = (0.6, -0.4)
    u0 = blob(n, dx, sigma, c)
    flow = Effect("advection", {"vx": v[0], "vy": v[1]})
    video = simulate_effects(u0, a=a, dx=dx, dt=dt, n_frames=21, effects=[flow])
    t = torch.arange(21, dtype=F64) * dt
    m = moments(video, dx)
    # Central differences and the 5-point Laplacian are exact on quadratics: the moments evolve exactly.
    torch.testing.assert_close(m["x"], c[0] + v[0] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["y"], c[1] + v[1] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["xx"], sigma**2 + 2 * a * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["yy"], sigma**2 + 2 * a * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["xy"], torch.zeros_like(t), rtol=0, atol=1e-8)
    # The field is the analytic Gaussian carried along by v (translation commutes with diffusion).
    exact = torch.stack(
        [
            gaussian_blob(
                [s],
                shape=(n, n),
                dx=dx,
                a=a,
                peak=1.0,
                sigma=sigma,
                centre=(c[0] + v[0] * s, c[1] + v[1] * s),
            )[0]
            for s in t.tolist()
        ]
    )
    assert float((video - exact).abs().max()) < 1e-2  # central differences' dispersion, O(dx^2)


# ------------------------------------------------------------------------------------- anisotropy
def test_anisotropy_covariance_grows_as_sigma0_plus_2At() -> None:
    n, dx, dt, sigma, c = 96, 0.25, 0.1, 1.5, (12.0, 12.0)
    p = {"a_x": 0.2, "a_y": 0.08, "a_xy": 0.06}
    video = simulate_effects(
        blob(n, dx, sigma, c), a=0.0, dx=dx, dt=dt, n_frames=21, effects=[Effect("anisotropy", p)]
    )
    t = torch.arange(21, dtype=F64) * dt
    m = moments(video, dx)
    torch.testing.assert_close(m["xx"], sigma**2 + 2 * p["a_x"] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["yy"], sigma**2 + 2 * p["a_y"] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["xy"], 2 * p["a_xy"] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["x"], torch.full_like(t, c[0]), rtol=0, atol=1e-8)
    # The field: sigma0^2 / sqrt(det S) exp(-r' S^-1 r / 2) with S = sigma0^2 I + 2 A t.
    A = np.array([[p["a_x"], p["a_xy"]], [p["a_xy"], p["a_y"]]])
    x, y = centres(n, dx)[None, :] - c[0], centres(n, dx)[:, None] - c[1]
    for k in (5, 20):
        S = sigma**2 * np.eye(2) + 2 * A * float(t[k])
        Si = np.linalg.inv(S)
        q = Si[0, 0] * x**2 + 2 * Si[0, 1] * x * y + Si[1, 1] * y**2
        exact = sigma**2 / math.sqrt(np.linalg.det(S)) * torch.exp(-0.5 * q)
        assert float((video[k] - exact).abs().max()) < 2e-3


def test_anisotropy_derived_angle_and_ratio_match_the_eigenvectors() -> None:
    for p in (
        {"a_x": 0.2, "a_y": 0.08, "a_xy": 0.06},
        {"a_x": 0.1, "a_y": 0.3, "a_xy": -0.05},
        {"a_x": 0.1, "a_y": 0.1, "a_xy": 0.0},
    ):
        derived = Effect("anisotropy", p).derived()
        values, vectors = np.linalg.eigh(np.array([[p["a_x"], p["a_xy"]], [p["a_xy"], p["a_y"]]]))
        assert derived["ratio"] == pytest.approx(values[1] / values[0], rel=1e-12)
        assert -90.0 < derived["angle_deg"] <= 90.0
        if values[1] > values[0]:  # the larger eigenvalue's axis (undefined when isotropic)
            angle = math.radians(derived["angle_deg"])
            axis = [math.cos(angle), math.sin(angle)]
            assert abs(np.dot(vectors[:, 1], axis)) == pytest.approx(1.0, abs=1e-12)


DEGENERATE = {
    "anisotropy": {"a_x": 0.15, "a_y": 0.15, "a_xy": 0.0},
    "heterogeneity": {"x": 5.0, "y": 5.0, "radius": 3.0, "a_inside": 0.15, "a_outside": 0.15},
    "nonlinear_diffusion": {"a0": 0.15, "beta": 0.0, "T_ref": 12.0},
}
"""Diffusion-replacing effects that reduce to ``0.15 Lap T``."""


@pytest.mark.parametrize("boundary", ["neumann", "periodic", "dirichlet"])
@pytest.mark.parametrize("name", list(DEGENERATE))
def test_degenerate_diffusion_effects_equal_simulate_heat(name: str, boundary: str) -> None:
    u0 = rough()
    value = 25.0 if boundary == "dirichlet" else 0.0
    effect = Effect(name, DEGENERATE[name])
    # a = 0.7 is replaced by the effect's own diffusivity (and so is the step count).
    kw = {"dx": 0.5, "dt": 0.2, "n_frames": 8, "boundary": boundary, "boundary_value": value}
    video = simulate_effects(u0, a=0.7, effects=[effect], **kw)
    torch.testing.assert_close(video, simulate_heat(u0, a=0.15, **kw), rtol=0, atol=1e-11)


@pytest.mark.parametrize("boundary", ["neumann", "periodic"])
def test_anisotropy_conserves_heat_with_a_mixed_term(boundary: str) -> None:
    p = {"a_x": 0.1, "a_y": 0.3, "a_xy": -0.12}
    video = simulate_effects(
        rough(), a=0.0, dx=0.5, dt=0.2, n_frames=20, effects=[Effect("anisotropy", p)], boundary=boundary
    )
    total = video.sum((-2, -1))
    torch.testing.assert_close(total, total[:1].expand_as(total), rtol=1e-13, atol=0)


# ---------------------------------------------------------------------------------- heterogeneity
def test_heterogeneity_map_has_a_one_pixel_tanh_edge() -> None:
    p = {"x": 10.0, "y": 8.0, "radius": 4.0, "a_inside": 0.3, "a_outside": 0.1}
    grid = Grid((40, 48), 0.5)
    a_map = EFFECTS["heterogeneity"].diffusivity_map(p, grid)
    assert a_map.shape == (40, 48)
    assert float(a_map[16, 20]) == pytest.approx(0.3, abs=1e-6)  # pixel centre (10.25, 8.25) mm
    assert float(a_map[0, 0]) == pytest.approx(0.1, abs=1e-12)
    r = torch.sqrt((centres(48, 0.5)[None, :] - 10.0) ** 2 + (centres(40, 0.5)[:, None] - 8.0) ** 2)
    middle = a_map[(r - 4.0).abs() < 0.05]
    assert middle.numel() and bool(((middle - 0.2).abs() < 0.02).all())  # halfway on the circle
    assert bool((a_map[(r - 4.0) > 1.5] < 0.1 + 0.2 * 0.01).all())  # 3 px out: < 1 % of the step


def test_heterogeneity_conserves_heat_and_changes_the_spreading_inside() -> None:
    n, dx, dt, sigma, c = 64, 0.25, 0.05, 0.75, (8.0, 8.0)
    u0 = blob(n, dx, sigma, c)
    t = torch.arange(11, dtype=F64) * dt
    rates = {}
    for a_in in (0.05, 0.1, 0.25):
        disc = Effect(
            "heterogeneity", {"x": 8.0, "y": 8.0, "radius": 5.0, "a_inside": a_in, "a_outside": 0.1}
        )
        video = simulate_effects(u0, a=0.1, dx=dx, dt=dt, n_frames=11, effects=[disc])
        m = moments(video, dx)
        torch.testing.assert_close(m["mass"], m["mass"][:1].expand(11), rtol=1e-13, atol=0)
        # d/dt (xx + yy) = 4 a for heat that stays inside the disc (the blob is 6.7 sd inside its edge).
        rates[a_in] = float(((m["xx"] + m["yy"])[-1] - (m["xx"] + m["yy"])[0]) / (4 * t[-1]))
    assert rates[0.05] == pytest.approx(0.05, rel=1e-3)
    assert rates[0.1] == pytest.approx(0.1, rel=1e-3)
    assert rates[0.25] == pytest.approx(0.25, rel=1e-3)


# ---------------------------------------------------------------------------- nonlinear_diffusion
def _flux_form_reference(u: np.ndarray, p: dict[str, float], dx: float) -> np.ndarray:
    """div(a(T) grad T) with a(T) at pixels, face diffusivity their mean, zero flux on the frame edge."""
    a = p["a0"] * (1 + p["beta"] * (u - p["T_ref"]))
    out = np.zeros_like(u)
    rows, cols = u.shape
    for i in range(rows):
        for j in range(cols):
            for di, dj in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                k, m = i + di, j + dj
                if 0 <= k < rows and 0 <= m < cols:
                    out[i, j] += 0.5 * (a[i, j] + a[k, m]) * (u[k, m] - u[i, j])
    return out / dx**2


def test_nonlinear_rhs_is_the_conservative_flux_form() -> None:
    u = rough(12)
    p = {"a0": 0.1, "beta": 0.08, "T_ref": 29.0}
    out = Effect("nonlinear_diffusion", p).term(u, 0.0, Grid((12, 12), 0.5))
    np.testing.assert_allclose(out.numpy(), _flux_form_reference(u.numpy(), p, 0.5), rtol=0, atol=1e-11)


def test_nonlinear_conserves_heat_and_hot_regions_spread_faster() -> None:
    n, dx, dt = 64, 0.25, 0.1
    u0 = 30.0 + 10.0 * blob(n, dx, 1.0, (8.0, 8.0))
    runs = {}
    for beta in (0.0, 0.05, 0.1):
        law = Effect("nonlinear_diffusion", {"a0": 0.1, "beta": beta, "T_ref": 30.0})
        video = simulate_effects(u0, a=0.1, dx=dx, dt=dt, n_frames=21, effects=[law])
        total = video.sum((-2, -1))
        torch.testing.assert_close(total, total[:1].expand(21), rtol=1e-14, atol=0)
        runs[beta] = moments(video - 30.0, dx)
    spread = {beta: float(m["xx"][-1] - m["xx"][0]) for beta, m in runs.items()}
    assert spread[0.0] == pytest.approx(2 * 0.1 * 2.0, rel=1e-6)
    # a ranges over 0.1 .. 0.1 (1 + 10 beta): 1.5x and 2x at the peak.
    assert spread[0.0] * 1.1 < spread[0.05] < spread[0.1] < spread[0.0] * 2.0
    assert float(runs[0.1]["x"][-1]) == pytest.approx(8.0, abs=1e-9)  # symmetric: no drift


# ---------------------------------------------------------------------------------------- source
def test_static_source_on_zero_field_accumulates_rate_t() -> None:
    p = {"x0": 5.25, "y0": 4.75, "x1": 5.25, "y1": 4.75, "rate": 2.0, "width": 1.0}
    n, dx, dt = 24, 0.5, 0.25
    video = simulate_effects(
        torch.zeros(n, n, dtype=F64), a=0.0, dx=dx, dt=dt, n_frames=9, effects=[Effect("source", p)]
    )
    t = torch.arange(9, dtype=F64) * dt
    torch.testing.assert_close(video[:, 9, 10], 2.0 * t, rtol=1e-14, atol=1e-14)  # the centre pixel
    shape = torch.exp(-((centres(n, dx)[None, :] - 5.25) ** 2 + (centres(n, dx)[:, None] - 4.75) ** 2) / 2.0)
    torch.testing.assert_close(video, 2.0 * t[:, None, None] * shape, rtol=1e-13, atol=1e-15)


def _swept_gaussian(p: dict[str, float], t: float, duration: float, n: int, dx: float) -> np.ndarray:
    """Independent quadrature of the integral over [0, t] of rate exp(-|r - c(s)|^2 / (2 width^2)) ds."""
    nodes, weights = np.polynomial.legendre.leggauss(40)
    s = 0.5 * t * (nodes + 1)
    x = (np.arange(n) + 0.5) * dx
    cx = p["x0"] + (p["x1"] - p["x0"]) * s / duration
    cy = p["y0"] + (p["y1"] - p["y0"]) * s / duration
    gx = np.exp(-((x[None, :] - cx[:, None]) ** 2) / (2 * p["width"] ** 2))
    gy = np.exp(-((x[None, :] - cy[:, None]) ** 2) / (2 * p["width"] ** 2))
    return 0.5 * t * p["rate"] * np.einsum("k,ki,kj->ij", weights, gy, gx)


def test_moving_source_follows_its_path() -> None:
    p = {"x0": 6.0, "y0": 12.0, "x1": 13.0, "y1": 8.0, "rate": 3.0, "width": 1.0}  # >= 6 widths inside
    n, dx, dt, frames = 40, 0.5, 0.2, 11
    duration = (frames - 1) * dt
    moving = Effect("source", p)
    zero = torch.zeros(n, n, dtype=F64)
    # The centre moves 4 mm/s past a 1 mm wide source: RK4's time error needs small steps here.
    errors = []
    for substeps in (4, 8):
        video = simulate_effects(
            zero, a=0.0, dx=dx, dt=dt, n_frames=frames, effects=[moving], substeps=substeps
        )
        errors.append(
            max(
                float(np.abs(video[k].numpy() - _swept_gaussian(p, k * dt, duration, n, dx)).max())
                for k in (3, 10)
            )
        )
    assert errors[1] < 1e-6 and 12.0 < errors[0] / errors[1] < 20.0
    # The accumulated heat's centroid is the path's mean position so far: c0 + (c1 - c0) t / (2 duration),
    # with or without diffusion (diffusion moves no centroid).
    t = torch.arange(1, frames, dtype=F64) * dt
    for a in (0.0, 0.2):
        run = simulate_effects(zero, a=a, dx=dx, dt=dt, n_frames=frames, effects=[moving], substeps=8)
        m = moments(run[1:], dx)
        torch.testing.assert_close(
            m["x"], p["x0"] + (p["x1"] - p["x0"]) * t / (2 * duration), rtol=0, atol=1e-6
        )
        torch.testing.assert_close(
            m["y"], p["y0"] + (p["y1"] - p["y0"]) * t / (2 * duration), rtol=0, atol=1e-6
        )
        torch.testing.assert_close(m["mass"], 3.0 * t * 2 * math.pi / dx**2, rtol=1e-6, atol=0)


def test_source_with_loss_saturates_analytically() -> None:
    p = {"x0": 6.25, "y0": 6.25, "x1": 6.25, "y1": 6.25, "rate": 2.0, "width": 1.5}
    b = 0.8
    effects = [Effect("source", p), Effect("linear_loss", {"b": b, "T_ref": 0.0})]
    zero = torch.zeros(25, 25, dtype=F64)
    video = simulate_effects(zero, a=0.0, dx=0.5, dt=0.25, n_frames=17, effects=effects, substeps=10)
    t = torch.arange(17, dtype=F64) * 0.25
    torch.testing.assert_close(video[:, 12, 12], 2.0 * (1 - torch.exp(-b * t)) / b, rtol=1e-8, atol=1e-12)


# ---------------------------------------------------------------------------- time stepping, RHS
def test_rk4_error_drops_16x_when_dt_halves() -> None:
    n, dx, dt, frames = 32, 0.5, 0.5, 5
    u0 = 30.0 + 8.0 * blob(n, dx, 2.0, (7.0, 8.0))
    effects = [
        Effect("linear_loss", {"b": 0.6, "T_ref": 29.0}),
        Effect("source", {"x0": 5.0, "y0": 5.0, "x1": 11.0, "y1": 9.0, "rate": 6.0, "width": 1.5}),
        Effect("advection", {"vx": 0.9, "vy": 0.6}),
        Effect("anisotropy", {"a_x": 0.2, "a_y": 0.1, "a_xy": 0.05}),
    ]
    runs = {
        s: simulate_effects(u0, a=0.0, dx=dx, dt=dt, n_frames=frames, effects=effects, substeps=s)
        for s in (2, 4, 8, 64)
    }
    errors = [float((runs[s] - runs[64]).abs().max()) for s in (2, 4, 8)]
    assert errors[0] > 1e-6  # far above rounding: the ratios measure the method
    for coarse, fine in zip(errors, errors[1:], strict=False):
        assert 12.0 < coarse / fine < 20.0


def test_automatic_substeps_are_stable_for_fast_advection_and_loss() -> None:
    u0 = 30.0 + 8.0 * blob(32, 0.5, 2.0, (8.0, 8.0))
    effects = [
        Effect("advection", {"vx": 6.0, "vy": -4.0}),
        Effect("linear_loss", {"b": 20.0, "T_ref": 30.0}),
    ]
    video = simulate_effects(u0, a=0.1, dx=0.5, dt=0.5, n_frames=6, effects=effects)
    assert bool(video.isfinite().all()) and float(video.max()) <= 38.0 + 1e-9 and float(video.min()) > 29.0
    with pytest.raises(ValueError, match=r"substeps=1 is unstable for RK4 .* need at least \d+"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.5, n_frames=6, effects=effects, substeps=1)


def test_without_effects_equals_simulate_heat_and_batches(dtype: torch.dtype) -> None:
    u0 = torch.stack([rough(), rough().flip(-1)]).to(dtype)
    video = simulate_effects(u0, a=0.3, dx=0.5, dt=0.5, n_frames=6)
    assert video.shape == (2, 6, 20, 20) and video.dtype == dtype
    torch.testing.assert_close(video, simulate_heat(u0, a=0.3, dx=0.5, dt=0.5, n_frames=6), rtol=0, atol=0)
    torch.testing.assert_close(video[:, 0], u0, rtol=0, atol=0)
    effects = [Effect("advection", EXAMPLES["advection"]), Effect("source", EXAMPLES["source"])]
    batch = simulate_effects(u0, a=0.3, dx=0.5, dt=0.5, n_frames=6, effects=effects)
    single = simulate_effects(u0[1], a=0.3, dx=0.5, dt=0.5, n_frames=6, effects=effects)
    torch.testing.assert_close(batch[1], single, rtol=0, atol=0)


def test_extended_rhs_sums_the_terms() -> None:
    grid = Grid((10, 12), 0.5, duration=2.0)
    effects = [
        Effect(name, EXAMPLES[name]) for name in ("linear_loss", "source", "advection", "heterogeneity")
    ]
    rhs = ExtendedHeatRHS(0.2, grid=grid, effects=effects, time_scale=0.5)
    u = 30.0 + torch.rand(10, 12, dtype=F64)
    t = torch.tensor(2.0, dtype=F64)  # solver time: 1 s
    expected = sum(e.term(u, 1.0, grid) for e in effects) * 0.5
    torch.testing.assert_close(rhs(t, u), expected, rtol=1e-14, atol=1e-14)
    plain = ExtendedHeatRHS(0.2, grid=grid, effects=effects[:3])
    expected = HeatRHS(0.2, dx=0.5)(t, u)[0] + sum(e.term(u, 2.0, grid) for e in effects[:3])
    torch.testing.assert_close(plain(t, u), expected, rtol=1e-14, atol=1e-14)
    assert "effects=(linear_loss, source, advection)" in repr(plain) and "boundary='neumann'" in repr(plain)


@pytest.mark.parametrize("diffusion", [None, "anisotropy", "heterogeneity", "nonlinear_diffusion"])
def test_combinations_run_and_stay_bounded(diffusion: str | None) -> None:
    names = ["linear_loss", "source", "advection"] + ([diffusion] if diffusion else [])
    u0 = 30.0 + 8.0 * blob(32, 0.5, 2.0, (8.0, 8.0))
    effects = [Effect(name, EXAMPLES[name]) for name in names]
    video = simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=21, effects=effects)
    assert video.shape == (21, 32, 32) and bool(video.isfinite().all())
    # Above: at most the initial peak plus rate * duration; below: the loss pulls towards T_ref = 29.
    assert float(video.max()) <= 38.0 + 4.0 * 2.0 and float(video.min()) >= 29.0 - 1e-6
    without = simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=21, effects=effects[:-1])
    assert float((video - without).abs().max()) > 1e-3  # every effect matters


# ------------------------------------------------------------------------------------------ errors
def one_line(err: pytest.ExceptionInfo[BaseException]) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: Effect("perfusion", {}),
            "unknown effect 'perfusion'; expected one of: linear_loss, source, advection, anisotropy, "
            "heterogeneity, nonlinear_diffusion",
        ),
        (
            lambda: Effect("advection", {"vx": 1.0}),
            "effect 'advection' is missing vy; expected: vx (mm/s), vy (mm/s)",
        ),
        (
            lambda: Effect("advection", {"vx": 1.0, "vy": 0.0, "vz": 1.0}),
            "effect 'advection' has no parameter 'vz'",
        ),
        (
            lambda: Effect("anisotropy", {"a_x": 0.1, "a_y": 0.1, "a_xy": 0.1, "ratio": 2.0}),
            "has no parameter 'ratio' (derived, set from the others)",
        ),
        (
            lambda: Effect("advection", {"vx": math.nan, "vy": 0.0}),
            "advection.vx must be a finite number in mm/s",
        ),
        (
            lambda: Effect("source", {**EXAMPLES["source"], "width": 0.0}),
            "source.width must be positive in mm, got 0.0",
        ),
        (lambda: Effect("linear_loss", {"b": -1.0, "T_ref": 0.0}), "linear_loss.b must be non-negative"),
        (
            lambda: Effect("heterogeneity", {**EXAMPLES["heterogeneity"], "radius": -1.0}),
            "heterogeneity.radius must be positive",
        ),
        (
            lambda: Effect("nonlinear_diffusion", {"a0": 0.0, "beta": 0.1, "T_ref": 0.0}),
            "nonlinear_diffusion.a0 must be positive",
        ),
        (
            lambda: Effect("anisotropy", {"a_x": 0.1, "a_y": 0.1, "a_xy": 0.2}),
            "anisotropy tensor [[a_x, a_xy], [a_xy, a_y]] must be positive definite",
        ),
        (lambda: Effect("anisotropy", {"a_x": -0.1, "a_y": -0.1, "a_xy": 0.0}), "must be positive definite"),
    ],
)
def test_invalid_effects_give_one_line_value_errors(build, message: str) -> None:  # noqa: ANN001
    with pytest.raises(ValueError, match=re.escape(message)) as err:
        build()
    one_line(err)


def test_model_level_errors() -> None:
    u0 = torch.zeros(8, 8, dtype=F64)
    two = [Effect("anisotropy", EXAMPLES["anisotropy"]), Effect("heterogeneity", EXAMPLES["heterogeneity"])]
    with pytest.raises(
        ValueError,
        match=r"effects anisotropy and heterogeneity both replace the diffusion term; "
        r"a model may hold at most one of anisotropy, heterogeneity, nonlinear_diffusion",
    ) as err:
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, effects=two)
    one_line(err)
    loss = Effect("linear_loss", EXAMPLES["linear_loss"])
    with pytest.raises(ValueError, match="effect 'linear_loss' is given 2 times; give each effect once"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, effects=[loss, loss])
    cold = Effect("nonlinear_diffusion", {"a0": 0.1, "beta": 0.5, "T_ref": 30.0})
    with pytest.raises(
        ValueError, match=r"nonlinear_diffusion: a0 \(1 \+ beta \(T - T_ref\)\) must stay positive"
    ) as err:
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, effects=[cold])  # T = 0 is 30 below T_ref
    one_line(err)
    with pytest.raises(TypeError, match="effects must be Effect instances, got str"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, effects=["linear_loss"])
    with pytest.raises(ValueError, match="unknown boundary 'open'"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, boundary="open")
    with pytest.raises(ValueError, match="dt must be a positive finite number in s"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.0, n_frames=3)
    with pytest.raises(ValueError, match=r"initial must have shape \(H, W\) or \(B, H, W\)"):
        simulate_effects(torch.zeros(8), a=0.1, dx=0.5, dt=0.1, n_frames=3)
    with pytest.raises(ValueError, match="boundary_value applies to boundary='dirichlet' only"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, boundary_value=1.0)


# ------------------------------------------------------------------------------------------ truth
def test_effects_json_round_trip_with_derived_values() -> None:
    effects = tuple(
        Effect(name, EXAMPLES[name]) for name in ("linear_loss", "source", "advection", "anisotropy")
    )
    text = effects_to_json(effects)
    records = json.loads(text)
    assert [r["name"] for r in records] == ["linear_loss", "source", "advection", "anisotropy"]
    assert set(records[3]["params"]) == {"a_x", "a_y", "a_xy", "angle_deg", "ratio"}
    assert records[3]["units"]["angle_deg"] == "deg" and records[1]["units"]["rate"] == "K/s"
    assert effects_from_json(text) == effects
    records[3]["params"]["ratio"] = 9.0
    with pytest.raises(ValueError, match=r"anisotropy.ratio=9.0 disagrees with the parameters"):
        effects_from_json(json.dumps(records))
    with pytest.raises(ValueError, match="effects must be a JSON list"):
        effects_from_json("{not json")
    assert hash(effects[0]) == hash(Effect("linear_loss", dict(EXAMPLES["linear_loss"])))


def test_hidden_video_is_deterministic_and_records_the_truth() -> None:
    names = ["linear_loss", "advection", "source"]
    first = hidden_effect_video(names, seed=7, size=48, duration=1.0)
    again = hidden_effect_video(names, seed=7, size=48, duration=1.0)
    other = hidden_effect_video(names, seed=8, size=48, duration=1.0)
    assert isinstance(first, HiddenEffectVideo)
    torch.testing.assert_close(first.frames, again.frames, rtol=0, atol=0)
    assert first.effects == again.effects and first.effects != other.effects
    assert [e.name for e in first.effects] == names
    assert first.frames.shape == (31, 48, 48) and first.times[-1] == pytest.approx(1.0)
    # The truth is what was simulated.
    u0 = first.clean[0]
    redo = simulate_effects(u0, a=0.15, dx=0.5, dt=1 / 30, n_frames=31, effects=first.effects)
    torch.testing.assert_close(first.clean, redo, rtol=0, atol=1e-12)
    # Noise: white, sd = 1 % of the peak initial rise over the background.
    rise = float(u0.max()) - 30.0
    assert 5.0 <= rise <= 40.0 and first.noise_sd == pytest.approx(0.01 * rise)
    assert float((first.frames - first.clean).std()) == pytest.approx(first.noise_sd, rel=0.02)
    pure = hidden_effect_video((), seed=7, size=48, duration=1.0, noise_frac=0.0)
    assert pure.effects == () and pure.a == 0.15 and pure.a_map is None
    torch.testing.assert_close(pure.frames, simulate_heat(u0, a=0.15, dx=0.5, dt=1 / 30, n_frames=31))


def test_hidden_video_time_error_is_negligible() -> None:
    video = hidden_effect_video(
        ["linear_loss", "source", "advection", "anisotropy"], seed=0, size=48, noise_frac=0.0
    )
    fine = simulate_effects(
        video.clean[0], a=0.15, dx=0.5, dt=1 / 30, n_frames=91, effects=video.effects, substeps=8
    )
    rise = float(video.clean[0].max()) - 30.0
    assert float((video.clean - fine).abs().max()) < 1e-6 * rise


def test_params_override_only_what_they_name() -> None:
    base = hidden_effect_video(["advection", "heterogeneity"], seed=3, size=48, duration=0.5)
    fixed = hidden_effect_video(
        ["advection", "heterogeneity"], seed=3, size=48, duration=0.5, params={"advection": {"vx": 0.25}}
    )
    assert fixed.effects[0].params == {"vx": 0.25, "vy": base.effects[0].params["vy"]}
    assert fixed.effects[1] == base.effects[1]
    with pytest.raises(ValueError, match="params given for effect 'source', which is not among the effects"):
        hidden_effect_video(["advection"], seed=3, size=48, params={"source": {"rate": 1.0}})
    with pytest.raises(ValueError, match="unknown effect 'perfusion'; expected one of: linear_loss"):
        hidden_effect_video(["perfusion"], seed=3)
    with pytest.raises(ValueError, match="both replace the diffusion term"):
        hidden_effect_video(["anisotropy", "nonlinear_diffusion"], seed=3, size=48)
    with pytest.raises(ValueError, match="effect 'source' is given 2 times"):
        hidden_effect_video(["source", "source"], seed=3, size=48)


def test_sampled_parameters_are_in_their_detectable_ranges() -> None:
    for seed in range(6):
        rng = np.random.default_rng(seed)
        g = Geometry((96, 96), 0.5, 3.0, 0.15, rise=12.0, background=30.0, hotspots=((20.0, 25.0, 2.0),))
        loss = EFFECTS["linear_loss"].sample(rng, g)
        assert 0.3 <= math.exp(-loss["b"] * 3.0) <= 0.8 and 30.0 - 2.4 <= loss["T_ref"] <= 30.0
        src = EFFECTS["source"].sample(rng, g)
        assert 0.2 <= src["rate"] * 3.0 / 12.0 <= 1.0 and 1.0 <= src["width"] <= 2.5
        ends = np.array([src["x0"], src["y0"], src["x1"], src["y1"]])
        assert bool(((ends >= 3 * src["width"]) & (ends <= 48.0 - 3 * src["width"])).all())
        assert math.hypot(src["x1"] - src["x0"], src["y1"] - src["y0"]) <= 10.0
        flow = EFFECTS["advection"].sample(rng, g)
        assert 2.0 <= math.hypot(flow["vx"], flow["vy"]) * 3.0 / 0.5 <= 10.0
        aniso = Effect("anisotropy", EFFECTS["anisotropy"].sample(rng, g))
        assert 1.5 <= aniso.derived()["ratio"] <= 4.0
        assert EFFECTS["anisotropy"].reference_a(aniso.params) == pytest.approx(0.15)
        het = EFFECTS["heterogeneity"].sample(rng, g)
        contrast = het["a_inside"] / het["a_outside"]
        assert (0.3 <= contrast <= 0.6 or 1.7 <= contrast <= 3.0) and het["a_outside"] == 0.15
        assert (
            4.0 <= het["radius"] <= 10.0
            and math.hypot(het["x"] - 20.0, het["y"] - 25.0) <= 0.5 * het["radius"]
        )
        law = EFFECTS["nonlinear_diffusion"].sample(rng, g)
        assert 0.3 <= law["beta"] * 12.0 <= 1.0 and law["a0"] == 0.15 and law["T_ref"] == 30.0


@pytest.mark.slow
@pytest.mark.parametrize("name", list(EFFECTS))
def test_hidden_videos_stay_physical_and_show_the_effect(name: str) -> None:
    for seed in range(4):
        video = hidden_effect_video([name], seed=seed, noise_frac=0.0)
        pure = hidden_effect_video([], seed=seed, noise_frac=0.0)
        rise = float(pure.clean[0].max()) - 30.0
        assert bool(video.clean.isfinite().all())
        assert 30.0 - 0.2 * rise - 1e-6 <= float(video.clean.min())
        assert float(video.clean.max()) <= 30.0 + 2.0 * rise
        # Clearly present at the default noise (1 % of the rise): the matched-filter signal-to-noise ratio
        # of the effect, ||with - without|| / noise sd over every pixel of every frame, is far above 1.
        snr = float((video.clean - pure.clean).square().sum().sqrt()) / (0.01 * rise)
        assert snr > 50.0, snr
        if name == "heterogeneity":
            assert video.a_map is not None and video.a_map.shape == (96, 96)


def test_hidden_video_npz_round_trip_and_crop(tmp_path) -> None:  # noqa: ANN001
    video = hidden_effect_video(
        ["source", "heterogeneity"], seed=2, size=48, duration=0.5, dtype=torch.float32
    )
    assert video.frames.dtype == torch.float32 and video.a_map is not None
    path = video.to_npz(tmp_path / "truth")
    assert path.name == "truth.npz"
    with np.load(path) as data:
        assert {"frames", "dt", "dx", "t", "a_true", "noise_sd", "seed", "effects", "a_map"} <= set(
            data.files
        )
        assert effects_from_json(str(data["effects"])) == video.effects
        np.testing.assert_array_equal(data["frames"], video.frames.numpy())
        assert float(data["a_true"]) == video.a == video.effects[1].params["a_outside"]
    loaded = load_video(path)
    assert loaded.dt == pytest.approx(1 / 30) and loaded.dx == 0.5
    assert effects_from_json(loaded.meta["effects"]) == video.effects
    # Cropping shifts the positions in the truth to the window.
    window = video.crop(4, 8, 32, 30)
    assert window.frames.shape == (16, 32, 30) and window.a_map.shape == (32, 30)
    src, het = window.effects
    assert src.params["x0"] == pytest.approx(video.effects[0].params["x0"] - 4.0)
    assert src.params["y1"] == pytest.approx(video.effects[0].params["y1"] - 2.0)
    assert het.params["x"] == pytest.approx(video.effects[1].params["x"] - 4.0)
    assert het.params["radius"] == video.effects[1].params["radius"]
    with pytest.raises(ValueError, match="crop window .* must lie inside the 48 x 48 px frame"):
        video.crop(40, 0, 16, 16)


def test_heterogeneity_sample_puts_the_disc_edge_near_the_first_hot_spot() -> None:
    # The edge must lie within two hot-spot widths (sigma) of the spot, or no heat crosses it in the video.
    for seed in range(20):
        video = hidden_effect_video(["heterogeneity"], seed=seed, size=64, duration=0.1)
        p = video.effects[0].params
        rng = np.random.default_rng(seed)  # replay the hot-spot draws of hidden_effect_video
        rng.integers(1, 3)  # number of spots
        rng.uniform(5.0, 20.0)  # rise of the first
        sigma = rng.uniform(3.0, 8.0)
        margin = min(2.5 * sigma + 10.0, 32.0)
        sx, sy = rng.uniform(margin, 64 - margin), rng.uniform(margin, 64 - margin)
        centre = math.hypot(p["x"] / 0.5 - sx, p["y"] / 0.5 - sy)
        radius = p["radius"] / 0.5
        assert 8.0 <= radius <= 20.0 and centre <= 0.5 * radius + 1e-9
        assert abs(radius - centre) <= 2.0 * sigma + 1e-9, (seed, radius, centre, sigma)


def _spreading_gaussian(
    t: np.ndarray, size: int, dx: float, a: float, centre: tuple[float, float]
) -> torch.Tensor:
    """The heat equation's exact solution on an unbounded plane: a Gaussian of 0.6 mm sigma at t = 0."""
    y, x = np.mgrid[:size, :size] * dx
    var = 0.6**2 + 2 * a * t[:, None, None]
    r2 = (x - centre[0]) ** 2 + (y - centre[1]) ** 2
    return torch.from_numpy(20.0 + 5.0 * 0.6**2 / var * np.exp(-r2 / (2 * var)))


def test_measured_edges_bound_a_crop_of_an_unbounded_field() -> None:
    """A 32 px window on a spreading Gaussian that crosses its edges: with the exact field's edge ring as
    the boundary the interior follows the exact solution; zero-flux edges keep the heat in."""
    a, dx, dt = 0.15, 0.1, 0.05
    t = np.arange(41) * dt
    exact = _spreading_gaussian(t, 32, dx, a, centre=(0.8, 1.2))  # near a corner: heat leaves the window
    inner = (slice(None), slice(3, -3), slice(3, -3))
    change = float((exact[-1] - exact[0])[inner[1:]].abs().max())
    bounded = simulate_effects(exact[0], a=a, dx=dx, dt=dt, n_frames=41, edges=exact)
    closed = simulate_effects(exact[0], a=a, dx=dx, dt=dt, n_frames=41)
    assert float((bounded - exact)[inner].abs().max()) < 0.01 * change  # the 5-point Laplacian's error
    assert float((closed - exact)[inner].abs().max()) > 0.1 * change
    torch.testing.assert_close(bounded[:, 0], exact[:, 0], rtol=0, atol=1e-9)  # the ring is the measured ring
    with pytest.raises(ValueError, match=r"edges must be the measured frames of shape \(41, 32, 32\)"):
        simulate_effects(exact[0], a=a, dx=dx, dt=dt, n_frames=41, edges=exact[:40])
    with pytest.raises(ValueError, match="edges must be finite"):
        simulate_effects(exact[0], a=a, dx=dx, dt=dt, n_frames=41, edges=exact * math.nan)
