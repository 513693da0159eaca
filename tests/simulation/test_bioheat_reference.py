"""The independent 3-D bioheat simulator against closed forms of the half-space, its own convergence and the
Green's function of a Gaussian beam; the random scenes' ranges."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import erf, erfc, erfcx

from anra_torch.simulation.bioheat_reference import camera_frames, simulate_bioheat
from anra_torch.simulation.bioheat_scenes import flux_peak, random_scene
from anra_torch.simulation.bioheat_setup import BioheatScene, Contact, DepthGrid, SurfaceFlux, Tissue

A, BODY = 0.15, 37.0


def uniform(
    source: SurfaceFlux | Contact, *, perfusion: float = 0.0, duration: float = 10.0, rate: float = 10.0
):
    """A source over the whole surface of a tissue without loss to air: a 1-D half-space (depth 15 mm)."""
    tissue = Tissue(diffusivity=A, perfusion=perfusion, air=0.0)
    return simulate_bioheat(BioheatScene(tissue, (source,), duration, (4, 4), 0.1, rate, 0.0))


FLUX = SurfaceFlux((0.2, 0.2), (0.2, 0.2), math.inf, 3.0, 0.0, 100.0)  # q = 3 K mm/s everywhere


def test_surface_under_a_constant_flux_is_2q_sqrt_t_over_pi_a() -> None:
    result = uniform(FLUX)
    t = np.arange(result.frames.shape[0]) * result.dt
    exact = BODY + 2.0 * 3.0 * np.sqrt(t / (math.pi * A))  # 27.6 K at 10 s
    np.testing.assert_allclose(result.frames[:, 0, 0], exact, rtol=0, atol=0.04)  # the first steps' error
    np.testing.assert_allclose(result.frames[20:, 0, 0], exact[20:], rtol=0, atol=0.02)
    assert np.ptp(result.frames[-1]) < 1e-9  # uniform: no lateral structure


def test_flux_depth_profile_is_the_ierfc_form() -> None:
    result = uniform(FLUX)
    z, t = result.depths, 10.0
    s = math.sqrt(A * t)
    exact = (2 * 3.0 / A) * (
        s / math.sqrt(math.pi) * np.exp(-(z**2) / (4 * A * t)) - z / 2 * erfc(z / (2 * s))
    )
    np.testing.assert_allclose(result.peak[:, 0, 0] - BODY, exact, rtol=0, atol=0.01)


def test_perfusion_under_a_constant_flux_saturates_as_erf() -> None:
    b = 0.01
    result = uniform(FLUX, perfusion=b, duration=60.0, rate=5.0)
    t = np.arange(result.frames.shape[0]) * result.dt
    exact = BODY + 3.0 / math.sqrt(A * b) * erf(np.sqrt(b * t))  # 56 K at 60 s, 77 K in the limit
    np.testing.assert_allclose(result.frames[:, 0, 0], exact, rtol=0, atol=0.04)


def test_contact_step_is_the_robin_erfc_profile() -> None:
    h, tc, t = 50.0, 80.0, 10.0  # probe conductance (1/mm) and temperature
    result = uniform(Contact((0.2, 0.2), math.inf, tc, 0.0, 100.0, conductance=h))
    z, s = result.depths, math.sqrt(A * t)
    x = z / (2 * s)
    exact = (tc - BODY) * (erfc(x) - np.exp(h * z + h * h * A * t - (x + h * s) ** 2) * erfcx(x + h * s))
    hot = exact > 6.0  # Omega and the profile are kept where the tissue passes 42 C
    np.testing.assert_allclose(result.peak[hot, 0, 0] - BODY, exact[hot], rtol=0, atol=0.01)
    surface = (tc - BODY) * (1 - erfcx(h * np.sqrt(A * np.arange(2, 101) * result.dt)))
    # From the second frame on: the probe's first 0.1 s step (a surface jumping by 43 K) is 0.4 K off.
    np.testing.assert_allclose(result.frames[2:, 0, 0] - BODY, surface, rtol=0, atol=0.02)


@pytest.fixture(scope="module")
def spot() -> BioheatScene:
    """A 0.4 mm Gaussian beam for 4 s at the centre of a 32 x 32 px view, peak near 80 C."""
    tissue = Tissue(diffusivity=A, perfusion=0.004, air=0.0)
    centre = (3.2, 3.2)
    unit = SurfaceFlux(centre, centre, 0.4, 1.0, 0.5, 4.5)
    power = 43.0 / flux_peak(unit, tissue, np.array([centre]), np.array([4.5]))
    source = SurfaceFlux(centre, centre, 0.4, power, 0.5, 4.5)
    return BioheatScene(tissue, (source,), 8.0, (32, 32), 0.2, 10.0, 2.0)


@pytest.fixture(scope="module")
def spot_run(spot: BioheatScene, disk_cache):
    """``simulate_bioheat(spot)`` at its defaults (0.1 s steps, 2 cells per pixel side), once per test run for
    the Green's-function test and as the coarse run of the convergence test (read only)."""
    return disk_cache("bioheat-spot-default", lambda: simulate_bioheat(spot))


def green_mean(source: SurfaceFlux, tissue: Tissue, t: float, half: float) -> float:
    """Mean rise (K) over the square of side ``2 half`` mm centred on a Gaussian beam at time ``t``: the
    half-space's Green's function (surface: ``1 / sqrt(pi a u)``; lateral: the Gaussian spread to
    ``s2 = w^2 + 2 a u``) integrated over the elapsed time ``u = v^2`` (scipy quad)."""
    from scipy.integrate import quad

    a, b, w2 = tissue.diffusivity, tissue.perfusion, source.width**2

    def integrand(v: float) -> float:
        u = v * v
        s2 = w2 + 2 * a * u
        square = (math.sqrt(2 * math.pi * s2) * erf(half / math.sqrt(2 * s2)) / (2 * half)) ** 2
        return 2 * v * source.power * w2 / s2 * square / math.sqrt(math.pi * a * u) * math.exp(-b * u)

    lo, hi = math.sqrt(max(t - source.t_off, 0.0)), math.sqrt(t - source.t_on)
    return quad(integrand, lo, hi, epsabs=1e-10)[0]


@pytest.mark.slow
def test_beam_centre_follows_the_greens_function(spot: BioheatScene, spot_run) -> None:
    result = spot_run
    assert result.info["mirror"] == (True, True)
    for frame in (20, 45, 60):  # heating, switch-off, cooling: 34, 43 and 15 K
        centre = result.frames[frame, 15:17, 15:17].mean() - BODY  # the 2 x 2 px around the beam
        expected = green_mean(spot.sources[0], spot.tissue, frame * result.dt, 0.2)
        # The split step (depth, lateral, depth) runs 1.1-1.3 % warm under a beam at its 0.1 s steps (0.6 % at
        # 0.025 s: the beam's switch-on is a singular start); the damage depth converges much faster (below).
        assert centre == pytest.approx(expected, rel=0.02)


@pytest.mark.slow
def test_damage_depth_converges_in_time_step_and_grid(spot: BioheatScene, spot_run) -> None:
    coarse = spot_run  # step=0.1, refine=2: simulate_bioheat's defaults
    fine = simulate_bioheat(spot, step=0.025, refine=3, depth=DepthGrid(first=0.01, step=0.04))
    deep = fine.damage_depth > 0.05
    assert deep.sum() > 20
    assert np.abs(coarse.damage_depth - fine.damage_depth)[deep].max() < 0.01  # mm, of a 0.27 mm burn
    assert 0.2 < fine.damage_depth.max() < 0.35


def test_inputs_are_checked() -> None:
    scene = BioheatScene(Tissue(), (FLUX,), 1.0, (4, 4), 0.1, 10.0, 0.0)
    with pytest.raises(ValueError, match="refine must be an integer >= 1"):
        simulate_bioheat(scene, refine=0)
    with pytest.raises(ValueError, match="step must be a positive time"):
        simulate_bioheat(scene, step=0.0)
    with pytest.raises(ValueError, match="unknown kind 'laser'"):
        random_scene(0, kind="laser")


def test_camera_noise_is_seeded_white_noise() -> None:
    result = uniform(FLUX, duration=2.0)
    a, b = camera_frames(result, 0.3, 1), camera_frames(result, 0.3, 1)
    np.testing.assert_array_equal(a, b)
    assert np.std(a - result.frames) == pytest.approx(0.3, rel=0.15)
