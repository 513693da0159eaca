"""The independent solver (:mod:`anra_torch.simulation.independent`): exact spreading of a Gaussian and
decay of Fourier modes, heat conserved, second order in time, and no operator shared with the library.
"""

from __future__ import annotations

import ast
import inspect
import math

import pytest
import torch

import anra_torch.simulation.independent as independent
from anra_torch.effects import Effect
from anra_torch.effects.independent import (
    simulate_independent,
)
from anra_torch.simulation import ContinuumGrid

F64 = torch.float64


BACKGROUND = 30.0


def _cells(edges: torch.Tensor, centre: float, sd: float) -> torch.Tensor:
    """A unit Gaussian of sd ``sd`` averaged over the cells between ``edges`` (exact)."""
    s = math.sqrt(2.0) * sd
    return (
        (torch.erf((edges[1:] - centre) / s) - torch.erf((edges[:-1] - centre) / s))
        * (0.5 * math.sqrt(math.pi) * s)
        / (edges[1:] - edges[:-1])
    )


def _spot(rise: float, cx: float, cy: float, sd: float):
    return lambda x, y: BACKGROUND + rise * torch.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sd**2))


def _spreading_gaussian(t: float, shape, dx, a, rise, cx, cy, sd) -> torch.Tensor:
    """Pixel averages of ``rise sd^2 / s^2 exp(-r^2 / (2 s^2))``, ``s^2 = sd^2 + 2 a t``: pure diffusion."""
    s = math.sqrt(sd**2 + 2.0 * a * t)
    ey = torch.arange(shape[0] + 1, dtype=F64) * dx
    ex = torch.arange(shape[1] + 1, dtype=F64) * dx
    return BACKGROUND + rise * (sd / s) ** 2 * torch.outer(_cells(ey, cy, s), _cells(ex, cx, s))


# ------------------------------------------------------------------------------ exact solutions
def test_gaussian_spreads_exactly_spectral() -> None:
    shape, dx, a, dt = (40, 48), 0.5, 0.2, 0.5
    args = (3.0, 11.0, 9.5, 1.5)  # rise, x, y, sd (mm)
    video = simulate_independent(_spot(*args), shape=shape, a=a, dx=dx, dt=dt, n_frames=9)
    for k in range(9):
        expected = _spreading_gaussian(k * dt, shape, dx, a, *args)
        torch.testing.assert_close(video[k], expected, rtol=0, atol=1e-11 * args[0])


def test_gaussian_spreads_finite_volume_second_order() -> None:
    shape, dx, a, dt = (32, 32), 0.5, 0.2, 0.5
    args = (3.0, 8.0, 7.5, 1.5)
    expected = torch.stack([_spreading_gaussian(k * dt, shape, dx, a, *args) for k in range(5)])
    errors = []
    for refine in (1, 2):
        video = simulate_independent(
            _spot(*args), shape=shape, a=a, dx=dx, dt=dt, n_frames=5,
            grid=ContinuumGrid(refine=refine, substeps=4, method="finite_volume"),
        )  # fmt: skip
        errors.append(float((video - expected).abs().max()) / args[0])
    assert errors[1] < 2e-3
    assert 3.0 < errors[0] / errors[1] < 5.0  # O(h^2): halving the cells quarters the error


def _mode_video(method: str, **effects: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """A Fourier mode under loss, advection and anisotropy on a periodic frame (pad=0): simulated and exact.

    ``T = T_ref + (T0 - T_ref) e^{-bt} + A e^{-(k.A.k + b) t} cos(k.(r - v t))``, pixel-averaged (a box
    average multiplies a mode by ``sinc(kx dx / 2) sinc(ky dx / 2)``).
    """
    shape, dx, dt, n = (24, 32), 0.5, 0.4, 6
    kx, ky = 2 * math.pi * 2 / (shape[1] * dx), 2 * math.pi / (shape[0] * dx)
    amp, b, t_ref = 2.0, 0.3, 27.0
    vx, vy = 0.7, -0.4
    a_x, a_y, a_xy = 0.3, 0.12, 0.08
    chosen = [
        Effect("linear_loss", {"b": b, "T_ref": t_ref}),
        Effect("advection", {"vx": vx, "vy": vy}),
        Effect("anisotropy", {"a_x": a_x, "a_y": a_y, "a_xy": a_xy}),
    ]
    video = simulate_independent(
        lambda x, y: BACKGROUND + amp * torch.cos(kx * x + ky * y),
        shape=shape, a=0.0, dx=dx, dt=dt, n_frames=n, effects=chosen, grid=ContinuumGrid(0, method=method),
    )  # fmt: skip
    x = (torch.arange(shape[1], dtype=F64) + 0.5) * dx
    y = (torch.arange(shape[0], dtype=F64) + 0.5) * dx
    box = math.sin(kx * dx / 2) / (kx * dx / 2) * math.sin(ky * dx / 2) / (ky * dx / 2)
    decay = a_x * kx**2 + a_y * ky**2 + 2 * a_xy * kx * ky + b
    frames = []
    for k in range(n):
        t = k * dt
        phase = kx * (x[None, :] - vx * t) + ky * (y[:, None] - vy * t)
        mode = amp * box * math.exp(-decay * t) * torch.cos(phase)
        frames.append(t_ref + (BACKGROUND - t_ref) * math.exp(-b * t) + mode)
    return video, torch.stack(frames)


def test_fourier_mode_under_loss_advection_anisotropy_spectral() -> None:
    video, exact = _mode_video("spectral")
    torch.testing.assert_close(video, exact, rtol=0, atol=1e-11)


def test_fourier_mode_finite_volume_agrees() -> None:
    video, exact = _mode_video("finite_volume")
    # O(h^2) in space (h = 0.25 mm, wavelength 8 mm) and O(dt^2) in time
    assert float((video - exact).abs().max()) < 2e-3 * 2.0


# ------------------------------------------------------------------------------ conservation
def _heat(video: torch.Tensor, dx: float) -> torch.Tensor:
    return (video - BACKGROUND).sum((-2, -1)) * dx**2


@pytest.mark.parametrize(
    "effect",
    [None, Effect("advection", {"vx": 0.4, "vy": 0.2}),
     Effect("anisotropy", {"a_x": 0.3, "a_y": 0.1, "a_xy": 0.05}),
     Effect("heterogeneity", {"x": 8.0, "y": 7.0, "radius": 3.0, "a_inside": 0.45, "a_outside": 0.15}),
     Effect("nonlinear_diffusion", {"a0": 0.15, "beta": 0.2, "T_ref": 30.0})],
    ids=lambda e: "pure" if e is None else e.name,
)  # fmt: skip
def test_heat_is_conserved_on_a_periodic_frame(effect: Effect | None) -> None:
    effects = () if effect is None else (effect,)
    for method in ("spectral", "finite_volume"):
        if (
            method == "spectral"
            and effect is not None
            and effect.name in ("heterogeneity", "nonlinear_diffusion")
        ):
            continue
        video = simulate_independent(
            _spot(4.0, 8.0, 8.0, 2.0), shape=(32, 32), a=0.15, dx=0.5, dt=0.5, n_frames=6,
            effects=effects, grid=ContinuumGrid(pad=0, method=method),
        )  # fmt: skip
        heat = _heat(video, 0.5)
        torch.testing.assert_close(heat, heat[:1].expand_as(heat), rtol=1e-12, atol=1e-12 * float(heat[0]))
        assert float((video[-1] - video[0]).abs().max()) > 0.05  # and something happened


def test_finite_volume_time_steps_converge_at_second_order() -> None:
    source = Effect("source", {"x0": 6.0, "y0": 8.0, "x1": 10.0, "y1": 8.0, "rate": 3.0, "width": 1.0})
    run = [
        simulate_independent(
            _spot(4.0, 7.0, 9.0, 2.0),
            shape=(32, 32),
            a=0.3,
            dx=0.5,
            dt=0.5,
            n_frames=5,
            effects=[source],
            grid=ContinuumGrid(substeps=s),
        )  # fmt: skip
        for s in (1, 2, 8)
    ]
    coarse, fine = float((run[0] - run[2]).abs().max()), float((run[1] - run[2]).abs().max())
    assert 2.5 < coarse / fine < 5.0


# ------------------------------------------------------------------------------ independence
FORBIDDEN = {"HeatRHS", "effect_rhs", "ExtendedHeatRHS", "simulate_effects", "simulate_heat", "integrate",
             "stable_substeps", "heat", "integrator", "build"}  # fmt: skip


def test_shares_no_operator_or_integrator_with_the_library() -> None:
    tree = ast.parse(inspect.getsource(independent))
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            imported |= {alias.name for alias in node.names} | set((node.module or "").split("."))
        elif isinstance(node, ast.Import):
            imported |= {part for alias in node.names for part in alias.name.split(".")}
        elif isinstance(node, ast.Attribute) and node.attr in ("build", "term"):
            imported.add(node.attr)  # an effect's own forward term
    assert not imported & FORBIDDEN
