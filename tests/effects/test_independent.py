"""The effects in the independent simulator (:mod:`anra_torch.effects.independent`): the same scenes as
``hidden_effect_video``, agreement with the library on smooth ones, heat added and removed, a continuous
model for every effect, one-line errors.
"""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.effects import EFFECTS, Effect, Sensor, hidden_effect_video
from anra_torch.effects.independent import (
    independent_effect_video,
    simulate_independent,
)
from anra_torch.effects.scene import draw_scene
from anra_torch.simulation import ContinuumGrid

F64 = torch.float64


BACKGROUND = 30.0


def _spot(rise: float, cx: float, cy: float, sd: float):
    return lambda x, y: BACKGROUND + rise * torch.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sd**2))


def _rise(video: torch.Tensor) -> float:
    return float(video[0].max() - BACKGROUND)


# --------------------------------------------------------------------- the library's simulator
SMOOTH = {"seed": 3, "size": 48, "dx": 0.1, "fps": 20.0, "duration": 1.0, "sensor": Sensor(noise_frac=0.0)}


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
@pytest.mark.slow
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
        library = hidden_effect_video(names, seed=7, size=32, duration=0.4, sensor=Sensor(noise_frac=0.02))
        ours = independent_effect_video(names, seed=7, size=32, duration=0.4, sensor=Sensor(noise_frac=0.02))
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


# ------------------------------------------------------------------------------ conservation
def _heat(video: torch.Tensor, dx: float) -> torch.Tensor:
    return (video - BACKGROUND).sum((-2, -1)) * dx**2


def test_source_adds_its_heat_and_loss_removes_it() -> None:
    dx, dt, n = 0.5, 0.25, 9
    rate, width = 2.0, 1.0
    source = Effect("source", {"x0": 8.0, "y0": 8.0, "x1": 8.0, "y1": 8.0, "rate": rate, "width": width})
    video = simulate_independent(
        _spot(4.0, 7.0, 9.0, 2.0),
        shape=(32, 32),
        a=0.15,
        dx=dx,
        dt=dt,
        n_frames=n,
        effects=[source],
        grid=ContinuumGrid(pad=0),
    )
    heat = _heat(video, dx)
    added = rate * 2 * math.pi * width**2 * torch.arange(n, dtype=F64) * dt  # integral of the Gaussian input
    torch.testing.assert_close(heat - heat[0], added, rtol=1e-9, atol=1e-9)
    b = 0.4
    loss = Effect("linear_loss", {"b": b, "T_ref": BACKGROUND})
    video = simulate_independent(
        _spot(4.0, 7.0, 9.0, 2.0),
        shape=(32, 32),
        a=0.15,
        dx=dx,
        dt=dt,
        n_frames=n,
        effects=[loss],
        grid=ContinuumGrid(pad=0),
    )
    heat = _heat(video, dx)
    expected = heat[0] * torch.exp(-b * torch.arange(n, dtype=F64) * dt)
    torch.testing.assert_close(heat, expected, rtol=1e-12, atol=0.0)


def test_every_effect_has_a_continuous_model() -> None:
    # a delamination does not separate into lateral and depth problems: its independent check is the 3-D
    # plate of anra_torch.simulation.flash_plate_video (tests/test_delamination.py)
    without = {name for name, spec in EFFECTS.items() if spec.continuum is None}
    assert without == {"delamination", "delamination_2"}


def test_errors() -> None:
    source = Effect("source", {"x0": 6.0, "y0": 8.0, "x1": 10.0, "y1": 8.0, "rate": 3.0, "width": 1.0})
    common = {"shape": (16, 16), "a": 0.1, "dx": 0.5, "dt": 0.1, "n_frames": 3}
    with pytest.raises(ValueError, match="method='spectral' needs constant coefficients"):
        simulate_independent(
            _spot(1.0, 4.0, 4.0, 1.0), effects=[source], grid=ContinuumGrid(method="spectral"), **common
        )
    with pytest.raises(ValueError, match="unknown method 'rk4'"):
        simulate_independent(_spot(1.0, 4.0, 4.0, 1.0), grid=ContinuumGrid(method="rk4"), **common)
    with pytest.raises(TypeError, match="initial must be a function"):
        simulate_independent(torch.zeros(16, 16), **common)
    with pytest.raises(ValueError, match="pad must be an integer >= 0"):
        simulate_independent(_spot(1.0, 4.0, 4.0, 1.0), grid=ContinuumGrid(pad=-1), **common)
    with pytest.raises(ValueError, match="initial must give finite temperatures"):
        simulate_independent(lambda x, y: x / 0.0 + y, **common)
    with pytest.raises(ValueError, match="noise_frac must be a finite number >= 0"):
        independent_effect_video(seed=1, size=16, sensor=Sensor(noise_frac=-1.0))
