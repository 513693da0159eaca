"""The simulation of a model with effects (:mod:`anra_torch.effects.simulate`): degenerate effects equal to
``simulate_heat``, time convergence, stable substeps, combinations, measured edges, the boundary, errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from fields import EXAMPLES, blob, rough

from anra_torch.effects import Boundary, Effect, simulate_effects
from anra_torch.simulation import simulate_heat

F64 = torch.float64


def one_line(err: pytest.ExceptionInfo[BaseException]) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


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
    kw = {"dx": 0.5, "dt": 0.2, "n_frames": 8}
    video = simulate_effects(u0, a=0.7, effects=[effect], boundary=Boundary(boundary, value), **kw)
    heat = simulate_heat(u0, a=0.15, boundary=boundary, boundary_value=value, **kw)
    torch.testing.assert_close(video, heat, rtol=0, atol=1e-11)


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
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, boundary=Boundary("open"))
    with pytest.raises(ValueError, match="dt must be a positive finite number in s"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.0, n_frames=3)
    with pytest.raises(ValueError, match=r"initial must have shape \(H, W\) or \(B, H, W\)"):
        simulate_effects(torch.zeros(8), a=0.1, dx=0.5, dt=0.1, n_frames=3)
    with pytest.raises(ValueError, match="boundary_value applies to boundary='dirichlet' only"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, boundary=Boundary(value=1.0))
    with pytest.raises(
        TypeError, match=r"boundary must be a Boundary, e.g. Boundary\('dirichlet', 30.0\), got 'open'"
    ):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, boundary="open")


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
