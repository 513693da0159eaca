"""The independent simulator: exact solutions, the library's simulator on smooth scenes, conservation of
heat, the same draws as ``hidden_effect_video``, and no shared operator."""

from __future__ import annotations

import ast
import inspect
import math

import pytest
import torch

import anra_torch.simulation.independent as independent
from anra_torch.effects import EFFECTS, Effect, hidden_effect_video
from anra_torch.effects.independent import (
    independent_effect_video,
    simulate_independent,
)
from anra_torch.effects.scene import draw_scene

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


def _rise(video: torch.Tensor) -> float:
    return float(video[0].max() - BACKGROUND)


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
            _spot(*args), shape=shape, a=a, dx=dx, dt=dt, n_frames=5, method="finite_volume",
            refine=refine, substeps=4,
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
        shape=shape, a=0.0, dx=dx, dt=dt, n_frames=n, effects=chosen, pad=0, method=method,
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


# --------------------------------------------------------------------- the library's simulator
SMOOTH = {"seed": 3, "size": 48, "dx": 0.1, "fps": 20.0, "duration": 1.0, "noise_frac": 0.0}
EFFECT_AGREEMENT = {"anisotropy": 0.15}  # a small change of the diffusion term: the 5-point O(dx^2) shows
"""How far the effect's contribution (video with it minus the pure video) may differ, relative to its size."""


@pytest.fixture(scope="module")
def pure_pair() -> tuple[torch.Tensor, torch.Tensor]:
    return hidden_effect_video((), **SMOOTH).clean, independent_effect_video((), **SMOOTH).clean


@pytest.mark.parametrize(
    "names",
    [("linear_loss",), ("advection",), ("anisotropy",), ("source",), ("heterogeneity",),
     ("nonlinear_diffusion",), ("periodic_source",), ("linear_loss", "advection", "source")],
    ids="+".join,
)  # fmt: skip
def test_agrees_with_library_on_a_smooth_scene(names: tuple[str, ...], pure_pair) -> None:
    library = hidden_effect_video(names, **SMOOTH).clean
    ours = independent_effect_video(names, **SMOOTH).clean
    rise = _rise(library)
    diff = (ours - library) / rise
    # Pixel averages against pixel-centre samples, 5-point operators, open against zero-flux edges: O(dx^2).
    assert float(diff.pow(2).mean().sqrt()) < 0.01
    assert float(diff.abs().max()) < 0.05
    assert float(diff[0].abs().max()) < 0.01  # the same first frame, up to the pixel average
    effect_library, effect_ours = library - pure_pair[0], ours - pure_pair[1]
    size = float(effect_library.pow(2).mean().sqrt())
    assert size > 0.005 * rise  # the effect shows
    allowed = EFFECT_AGREEMENT.get(names[0], 0.05)
    assert float((effect_ours - effect_library).pow(2).mean().sqrt()) < allowed * size


def test_same_seed_same_scene_and_effects() -> None:
    for names in [("source", "advection"), ("heterogeneity",), ("nonlinear_diffusion", "linear_loss")]:
        library = hidden_effect_video(names, seed=7, size=32, duration=0.4, noise_frac=0.02)
        ours = independent_effect_video(names, seed=7, size=32, duration=0.4, noise_frac=0.02)
        assert ours.effects == library.effects
        assert ours.truth_json == library.truth_json
        assert (ours.noise_sd, ours.a, ours.dt, ours.dx) == (
            library.noise_sd,
            library.a,
            library.dt,
            library.dx,
        )
        # the same white-noise draw on another clean video
        torch.testing.assert_close(ours.frames - ours.clean, library.frames - library.clean)
    scene = draw_scene(["heterogeneity"], seed=7, size=32, duration=0.4)
    assert scene.effects == hidden_effect_video(["heterogeneity"], seed=7, size=32, duration=0.4).effects


def test_scene_temperature_is_the_first_frame() -> None:
    scene = draw_scene((), seed=11, size=48)
    centres = (torch.arange(48, dtype=F64) + 0.5) * scene.dx
    torch.testing.assert_close(scene.temperature(centres[None, :], centres[:, None]), scene.initial)


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
            effects=effects, pad=0, method=method,
        )  # fmt: skip
        heat = _heat(video, 0.5)
        torch.testing.assert_close(heat, heat[:1].expand_as(heat), rtol=1e-12, atol=1e-12 * float(heat[0]))
        assert float((video[-1] - video[0]).abs().max()) > 0.05  # and something happened


def test_source_adds_its_heat_and_loss_removes_it() -> None:
    dx, dt, n = 0.5, 0.25, 9
    rate, width = 2.0, 1.0
    source = Effect("source", {"x0": 8.0, "y0": 8.0, "x1": 8.0, "y1": 8.0, "rate": rate, "width": width})
    video = simulate_independent(
        _spot(4.0, 7.0, 9.0, 2.0), shape=(32, 32), a=0.15, dx=dx, dt=dt, n_frames=n, effects=[source], pad=0
    )
    heat = _heat(video, dx)
    added = rate * 2 * math.pi * width**2 * torch.arange(n, dtype=F64) * dt  # integral of the Gaussian input
    torch.testing.assert_close(heat - heat[0], added, rtol=1e-9, atol=1e-9)
    b = 0.4
    loss = Effect("linear_loss", {"b": b, "T_ref": BACKGROUND})
    video = simulate_independent(
        _spot(4.0, 7.0, 9.0, 2.0), shape=(32, 32), a=0.15, dx=dx, dt=dt, n_frames=n, effects=[loss], pad=0
    )
    heat = _heat(video, dx)
    expected = heat[0] * torch.exp(-b * torch.arange(n, dtype=F64) * dt)
    torch.testing.assert_close(heat, expected, rtol=1e-12, atol=0.0)


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
            substeps=s,
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


def test_every_effect_has_a_continuous_model() -> None:
    # a delamination does not separate into lateral and depth problems: its independent check is the 3-D
    # plate of anra_torch.simulation.flash_plate_video (tests/test_delamination.py)
    assert {name for name, spec in EFFECTS.items() if spec.continuum is None} == {"delamination"}


def test_errors() -> None:
    source = Effect("source", {"x0": 6.0, "y0": 8.0, "x1": 10.0, "y1": 8.0, "rate": 3.0, "width": 1.0})
    common = {"shape": (16, 16), "a": 0.1, "dx": 0.5, "dt": 0.1, "n_frames": 3}
    with pytest.raises(ValueError, match="method='spectral' needs constant coefficients"):
        simulate_independent(_spot(1.0, 4.0, 4.0, 1.0), effects=[source], method="spectral", **common)
    with pytest.raises(ValueError, match="unknown method 'rk4'"):
        simulate_independent(_spot(1.0, 4.0, 4.0, 1.0), method="rk4", **common)
    with pytest.raises(TypeError, match="initial must be a function"):
        simulate_independent(torch.zeros(16, 16), **common)
    with pytest.raises(ValueError, match="pad must be an integer >= 0"):
        simulate_independent(_spot(1.0, 4.0, 4.0, 1.0), pad=-1, **common)
    with pytest.raises(ValueError, match="initial must give finite temperatures"):
        simulate_independent(lambda x, y: x / 0.0 + y, **common)
    with pytest.raises(ValueError, match="noise_frac must be a finite number >= 0"):
        independent_effect_video(seed=1, size=16, noise_frac=-1.0)
