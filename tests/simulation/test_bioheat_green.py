"""The Green's-function reference of a Gaussian spot on a half-space: the 1-D closed forms (a constant
flux's erfc profile, the Robin surface), the peak it is scaled to, and agreement with the 3-D finite-volume
simulator on the same scene."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import erfc, erfcx

from anra_torch.simulation import (
    BioheatScene,
    GreenScene,
    SurfaceFlux,
    Tissue,
    simulate_bioheat,
    simulate_spot,
    spot_peak,
)
from anra_torch.simulation.bioheat_green import _cumulative, _response

A = 0.15


def _wide(air: float) -> GreenScene:
    """A spot far wider than anything in the test: the half-space's 1-D problem under a constant flux."""
    return GreenScene(A, 0.0, air, (0.0, 0.0), 1e4, 80.0, 0.0, 100.0, 10.0, 10.0)


def test_constant_flux_gives_the_erfc_profile() -> None:
    times = np.array([0.5, 2.0, 9.0])
    for z in (0.0, 0.3):
        v, cumulative = _cumulative(_wide(0.0), np.zeros(1), z)
        x = z / (2 * np.sqrt(A * times))
        ierfc = np.exp(-(x**2)) / math.sqrt(math.pi) - x * erfc(x)
        exact = 2 * np.sqrt(A * times) * ierfc / A  # unit flux over rho c
        np.testing.assert_allclose(_response(v, cumulative, _wide(0.0), times)[0], exact, rtol=1e-6)


def test_the_surface_losing_to_the_air() -> None:
    beta, times = 0.5, np.array([0.5, 2.0, 9.0])
    v, cumulative = _cumulative(_wide(beta), np.zeros(1), 0.0)
    exact = (1 - erfcx(beta * np.sqrt(A * times))) / (A * beta)
    np.testing.assert_allclose(_response(v, cumulative, _wide(beta), times)[0], exact, rtol=1e-6)


@pytest.fixture(scope="module")
def pair() -> tuple:
    """A 1 mm spot switched off between frames, by both references (32 x 32 px of 0.15 mm at 10 Hz)."""
    green = GreenScene(0.14, 0.004, 0.02, (2.4, 2.4), 1.0, 75.0, 0.5, 3.53, 6.0, 10.0, (32, 32), 0.15)
    result = simulate_spot(green)
    tissue = Tissue(diffusivity=0.14, perfusion=0.004, air=0.02)
    flux = SurfaceFlux((2.4, 2.4), (2.4, 2.4), 1.0, result.power, 0.5, 3.53)
    grid = BioheatScene(tissue, (flux,), 6.0, (32, 32), 0.15, 10.0, 3.0)
    return result, simulate_bioheat(grid, refine=1, step=0.01)  # the switch-off on its steps


@pytest.mark.slow
def test_agrees_with_the_finite_volume_simulator(pair: tuple) -> None:
    green, grid = pair
    assert green.frames.max() == pytest.approx(75.0, abs=0.5)  # the peak it was scaled to (frames: means)
    assert np.abs(green.frames - grid.frames).max() < 0.12  # K, of a 38 K rise (its largest: the onset)
    damaged = grid.damage_depth > 0.1
    assert damaged.sum() > 50
    np.testing.assert_allclose(green.damage_depth[damaged], grid.damage_depth[damaged], rtol=0, atol=0.004)


def test_the_peak_and_the_errors() -> None:
    scene = GreenScene(0.14, 0.0, 0.02, (1.0, 1.0), 0.5, 70.0, 0.2, 1.2, 2.0, 10.0, (8, 8), 0.25)
    result = simulate_spot(scene, subpixel=1, damage=False)
    assert (scene.peak - 37.0) / spot_peak(scene) == pytest.approx(result.power)
    assert result.frames.shape == (21, 8, 8) and np.all(result.damage_depth == 0)
    with pytest.raises(ValueError, match="a scene needs 0 <= t_on < t_off"):
        simulate_spot(GreenScene(0.14, 0.0, 0.02, (1.0, 1.0), 0.5, 70.0, 1.2, 0.2, 2.0, 10.0))
