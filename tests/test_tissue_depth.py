"""The depth model: the subsurface solver against closed forms of the half-space (erfc step, perfusion's
exponential decay, a lateral mode, a layer), Omega in depth against direct integration, shapes, units,
devices, gradients, the fit of ``a`` and ``b`` and the volumetric flag on the independent 3-D simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.special import erfc

from anra_torch.features import TissueFeatures
from anra_torch.simulation.bioheat_reference import (
    BioheatScene,
    SurfaceFlux,
    Tissue,
    camera_frames,
    simulate_bioheat,
)
from anra_torch.simulation.bioheat_scenes import flux_peak
from anra_torch.tissue import (
    DEPTH_MAPS,
    damage_in_depth,
    depth_features,
    fit_depth_parameters,
    subsurface_temperature,
    surface_heat_input,
    threshold_depth,
)
from anra_torch.tissue.depth_fit import VOLUMETRIC_MISFIT, cooling_start

F64 = torch.float64
A, BODY, RISE = 0.14, 37.0, 43.0
A_SKIN, EA_SKIN, R_GAS = 3.1e98, 6.28e5, 8.314462618


def step_video(n: int, dt: float, shape: tuple[int, int] = (6, 6), dtype: torch.dtype = F64) -> torch.Tensor:
    """A surface at 37 C stepping to 80 C at the second frame (a ramp over the first frame interval)."""
    frames = torch.full((n, *shape), BODY, dtype=dtype)
    frames[1:] = BODY + RISE
    return frames


def ramp_response(z: np.ndarray, t: np.ndarray, a: float, tau: float) -> np.ndarray:
    """Half-space response (fraction) to a surface rising linearly from 0 to 1 over ``[0, tau]`` and held:
    ``(R(t) - R(t - tau)) / tau`` with ``R(s) = int_0^s erfc(z / 2 sqrt(a u)) du = 4 s i2erfc(x)``."""

    def integral(s: np.ndarray) -> np.ndarray:
        s = np.maximum(s, 1e-300)
        x = z / (2 * np.sqrt(a * s))
        value = s * ((1 + 2 * x**2) * erfc(x) - 2 * x * np.exp(-(x**2)) / math.sqrt(math.pi))
        return np.where(s > 1e-200, value, 0.0)

    return (integral(t) - integral(t - tau)) / tau


def decaying_response(z: np.ndarray, t: float, a: float, c: float, tau: float) -> np.ndarray:
    """The same with a loss rate ``c`` (1/s): the step response ``(e^{-zk} erfc(x - sqrt(ct)) + e^{zk}
    erfc(x + sqrt(ct))) / 2``, ``k = sqrt(c / a)``, averaged over the ramp (Gauss-Legendre, 64 nodes)."""
    nodes, weights = np.polynomial.legendre.leggauss(64)
    s = t - tau * 0.5 * (nodes + 1.0)
    k = math.sqrt(c / a)
    x = z[:, None] / (2 * np.sqrt(a * s[None]))
    step = 0.5 * (
        np.exp(-z[:, None] * k) * erfc(x - np.sqrt(c * s)) + np.exp(z[:, None] * k) * erfc(x + np.sqrt(c * s))
    )
    return (step * weights).sum(1) / 2


# ------------------------------------------------------------------------------------------ closed forms
def test_step_of_the_surface_gives_the_erfc_profile(dtype: torch.dtype) -> None:
    dt, n = 0.1, 101
    depths = np.array([0.0, 0.05, 0.2, 0.5, 1.0, 2.0])
    t = subsurface_temperature(
        step_video(n, dt, dtype=dtype), dt, 0.2, depths, diffusivity=A, body_temperature=BODY
    )
    assert t.dtype == dtype and t.shape == (n, 6, 6, 6)
    exact = BODY + RISE * ramp_response(depths[None], (np.arange(n) * dt)[:, None], A, dt)
    # 2nd-order depth grid (spacings 0.01 mm at the surface, 3 % more per node): 0.025 K of 43 K at 2 mm.
    np.testing.assert_allclose(t[:, :, 3, 3].double().numpy(), exact, rtol=0, atol=0.04)
    assert float(t.flatten(2).std(-1).max()) < 1e-4  # uniform surface: no lateral structure


@pytest.mark.parametrize("elapsed", [5.0, 30.0])
def test_perfusion_gives_the_decaying_step_response(elapsed: float) -> None:
    b, dt = 0.05, 0.5
    n = round(elapsed / dt) + 1
    depths = np.array([0.2, 0.5, 1.0, 2.0])
    t = subsurface_temperature(
        step_video(n, dt), dt, 0.2, depths, diffusivity=A, loss_rate=b, body_temperature=BODY
    )
    exact = BODY + RISE * decaying_response(depths, elapsed, A, b, dt)
    np.testing.assert_allclose(t[-1, :, 2, 2].numpy(), exact, rtol=0, atol=0.03)


def test_perfusion_profile_decays_exponentially_in_the_steady_state() -> None:
    b, dt = 0.05, 2.0
    depths = np.array([0.1, 0.5, 1.0, 2.0, 3.0])
    t = subsurface_temperature(
        step_video(151, dt), dt, 0.2, depths, diffusivity=A, loss_rate=b, body_temperature=BODY
    )
    exact = BODY + RISE * np.exp(-depths * math.sqrt(b / A))  # erfc(sqrt(b t)) ~ 1e-8 at 300 s
    np.testing.assert_allclose(t[-1, :, 0, 0].numpy(), exact, rtol=0, atol=0.03)  # 0.017 K at 3 mm


def test_a_lateral_cosine_mode_decays_faster_with_depth() -> None:
    """A surface ``20 cos(k x)`` switched on over the first frame: each depth follows the decaying step
    response with the lateral loss ``a k^2 + b``: the lateral terms of the 3-D problem."""
    w, dx, dt, b = 16, 0.1, 0.2, 0.01
    k = math.pi * 2 / (w * dx)  # the cosine mode p = 2 along x: 3.9 1/mm
    x = (torch.arange(w, dtype=F64) + 0.5) * dx
    mode = 20.0 * torch.cos(k * x).expand(8, w)
    frames = torch.full((26, 8, w), BODY, dtype=F64)
    frames[1:] += mode
    depths = np.array([0.05, 0.2, 0.5])
    t = subsurface_temperature(frames, dt, dx, depths, diffusivity=A, loss_rate=b, body_temperature=BODY)
    exact = decaying_response(depths, 25 * dt, A, A * k**2 + b, dt)
    profile = (t[-1, :, 4] - BODY) / mode[0]  # (Z, W)
    np.testing.assert_allclose(
        profile[:, [0, 3, 12]].numpy(), np.repeat(exact[:, None], 3, 1), rtol=0, atol=1e-3
    )
    steady = np.exp(-depths * math.sqrt(k**2 + b / A))
    # Far below the 1-D (lateral-free) profile; at 5 s already the steady one.
    assert np.all(exact < 0.9 * np.exp(-depths * math.sqrt(b / A)))
    np.testing.assert_allclose(exact, steady, rtol=1e-5)


def test_a_layer_held_at_its_bottom_reaches_the_linear_profile() -> None:
    depths = np.array([0.5, 1.0, 1.5])
    t = subsurface_temperature(
        step_video(121, 1.0), 1.0, 0.2, depths, diffusivity=A, thickness=2.0, body_temperature=BODY
    )
    np.testing.assert_allclose(t[-1, :, 0, 0].numpy(), BODY + RISE * (1 - depths / 2.0), rtol=0, atol=1e-6)


def test_equilibrium_start_and_the_surface_row() -> None:
    frames = step_video(3, 0.5)
    t = subsurface_temperature(frames, 0.5, 0.1, [0.0, 0.3], diffusivity=A)  # body: the first frame's median
    assert torch.equal(t[:, 0], frames)  # depth 0 is the surface itself
    assert torch.allclose(t[0], torch.full_like(t[0], BODY))  # in equilibrium with the first frame


def test_heat_input_of_a_constant_flux_grows_linearly() -> None:
    q, dt, n = 5.0, 0.1, 101  # K mm/s: the surface 37 + 2 q sqrt(t / (pi a))
    time = torch.arange(n, dtype=F64) * dt
    frames = (BODY + 2 * q * torch.sqrt(time / (math.pi * A))).view(n, 1, 1).expand(n, 4, 4)
    heat = surface_heat_input(frames, dt, 0.2, diffusivity=A, body_temperature=BODY)[:, 0, 0]
    # The first interval's sqrt(t) is sampled by a straight line: 0.1 K mm early, 0.5 % late.
    np.testing.assert_allclose(heat.numpy(), (q * time).numpy(), rtol=0.006, atol=0.12)


# ------------------------------------------------------------------------------------------ damage
def arrhenius_direct(history: np.ndarray, dt: float) -> np.ndarray:
    """Omega of piecewise-linear histories ``(T, ...)`` (C): every segment cut into 256 and Simpson's rule."""
    frac = np.linspace(0.0, 1.0, 257)
    simpson = np.ones(257)
    simpson[1:-1:2], simpson[2:-1:2] = 4.0, 2.0
    a, b = history[:-1, None], history[1:, None]
    temps = a + (b - a) * frac.reshape(1, -1, *([1] * (history.ndim - 1)))
    rate = A_SKIN * np.exp(-EA_SKIN / (R_GAS * (temps + 273.15)))
    return (np.tensordot(simpson, np.moveaxis(rate, 1, 0), axes=1) / (3 * 256) * dt).sum(0)


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    dt, dx = 0.25, 0.2
    y, x = torch.meshgrid(torch.arange(20, dtype=F64), torch.arange(20, dtype=F64), indexing="ij")
    spot = torch.exp(-((x - 9.5) ** 2 + (y - 9.5) ** 2) * dx**2 / (2 * 1.0**2))
    on = torch.zeros(33, dtype=F64)
    on[1:17] = 1.0
    return BODY + 48.0 * on.view(-1, 1, 1) * spot, dt, dx


def test_omega_in_depth_matches_direct_integration(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    maps = damage_in_depth(frames, dt, dx, diffusivity=A, loss_rate=0.003, body_temperature=BODY)
    hot = maps.peak[:, 10, 10] > 45.0
    # At every node of damage_in_depth's grid (and so on the same solver grid), then its hot nodes.
    history = subsurface_temperature(
        frames, dt, dx, maps.depths, diffusivity=A, loss_rate=0.003, body_temperature=BODY
    )[:, hot]
    direct = arrhenius_direct(history[:, :, 10, 10].numpy(), dt)
    np.testing.assert_allclose(maps.omega[hot, 10, 10].numpy(), direct, rtol=1e-6)
    np.testing.assert_allclose(
        maps.peak[hot, 10, 10].numpy(), history[:, :, 10, 10].amax(0).numpy(), rtol=1e-12
    )
    # The damage depth: where ln Omega, linear between the nodes, crosses 0.
    log = np.log(np.maximum(maps.omega[:, 10, 10].numpy(), 1e-300))
    j = int(np.flatnonzero(log >= 0).max())
    z = maps.depths.numpy()
    expected = z[j] + (z[j + 1] - z[j]) * log[j] / (log[j] - log[j + 1])
    assert float(maps.damage_depth[10, 10]) == pytest.approx(expected, rel=1e-12)
    assert 0.3 < expected < 1.5


def test_threshold_depth_interpolates_log_dose() -> None:
    dose = torch.tensor([100.0, 10.0, 1.0, 0.1]).view(4, 1, 1).expand(4, 2, 3).clone()
    dose[:, 1] = 0.5  # never reaches the threshold
    depth = threshold_depth(dose, torch.tensor([0.0, 0.1, 0.2, 0.3]), 3.0)
    assert depth.shape == (2, 3)
    assert float(depth[0, 0]) == pytest.approx(0.1 + 0.1 * math.log(10 / 3) / math.log(10))
    assert torch.all(depth[1] == 0.0)


def test_shapes_units_and_batches(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    batch = torch.stack([frames, frames])
    maps = damage_in_depth(
        batch, dt, dx, diffusivity=torch.tensor([A, 2 * A], dtype=F64), body_temperature=BODY
    )
    z = maps.depths.numel()
    assert maps.omega.shape == maps.cem43.shape == maps.peak.shape == (2, z, 20, 20)
    assert maps.damage_depth.shape == maps.damage_depth_std.shape == maps.cem43_depth.shape == (2, 20, 20)
    assert float(maps.depths[0]) == 0.0 and bool((maps.depths.diff() > 0).all())
    assert float(maps.damage_depth[1, 10, 10]) > float(maps.damage_depth[0, 10, 10])  # heat goes deeper
    # No parameter errors given: only the frames' sampling in time, half the two dose rules' difference.
    hold = damage_in_depth(batch, dt, dx, diffusivity=maps.diffusivity, body_temperature=BODY, rule="hold")
    torch.testing.assert_close(maps.damage_depth_std, 0.5 * (hold.damage_depth - maps.damage_depth).abs())
    assert float(maps.damage_depth_std.max()) < 0.01
    single = damage_in_depth(frames, dt, dx, diffusivity=A, body_temperature=BODY)
    assert single.damage_depth.shape == (20, 20)
    # The batch shares one depth grid (deep enough for its hottest video): 1e-6 mm apart.
    torch.testing.assert_close(single.damage_depth, maps.damage_depth[0], rtol=0, atol=1e-5)


def test_depth_scales_with_length(burn: tuple[torch.Tensor, float, float]) -> None:
    """Lengths x2 with a x4 (same times): the same solution at twice the depth (mm in, mm out)."""
    frames, dt, dx = burn
    base = damage_in_depth(frames, dt, dx, diffusivity=A, body_temperature=BODY).damage_depth
    scaled = damage_in_depth(frames, dt, 2 * dx, diffusivity=4 * A, body_temperature=BODY).damage_depth
    deep = base > 0.2
    np.testing.assert_allclose(scaled[deep].numpy(), 2 * base[deep].numpy(), rtol=0.01)


def test_standard_errors_follow_the_parameters(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    args = {"diffusivity": A, "loss_rate": 0.003, "body_temperature": BODY}
    maps = damage_in_depth(frames, dt, dx, diffusivity_std=0.014, loss_rate_std=0.002, noise_sd=0.3, **args)
    up = damage_in_depth(frames, dt, dx, **(args | {"diffusivity": 1.1 * A})).damage_depth
    down = damage_in_depth(frames, dt, dx, **(args | {"loss_rate": 0.005})).damage_depth
    base = maps.damage_depth
    floor = torch.sqrt((up - base) ** 2 + (down - base) ** 2)
    deep = base > 0.2
    assert bool((maps.damage_depth_std[deep] >= floor[deep] - 1e-12).all())
    assert bool((maps.damage_depth_std[deep] <= floor[deep] + 0.02).all())  # the noise adds little at depth
    # Deeper with a larger a, by less than the 1-D sqrt(a) scaling (5 %): the spot also loses more sideways.
    assert 0.0 < float((up - base)[10, 10]) < 0.05 * float(base[10, 10])


def test_gradients_flow_to_frames_and_parameters() -> None:
    frames = (BODY + 20 * torch.rand(3, 2, 2, dtype=F64)).requires_grad_()
    a = torch.tensor(A, dtype=F64, requires_grad=True)

    def solve(f: torch.Tensor, diffusivity: torch.Tensor) -> torch.Tensor:
        return subsurface_temperature(
            f, 0.5, 0.2, [0.05, 0.1], diffusivity=diffusivity, body_temperature=BODY
        )

    assert torch.autograd.gradcheck(solve, (frames, a))
    burn = BODY + 50 * torch.exp(-torch.arange(9, dtype=F64).view(9, 1, 1) / 6).expand(9, 3, 3)
    burn = torch.cat([torch.full((1, 3, 3), BODY, dtype=F64), burn])
    depth = damage_in_depth(burn, 0.5, 0.2, diffusivity=a, body_temperature=BODY).damage_depth[1, 1]
    (grad,) = torch.autograd.grad(depth, a)
    eps = 1e-6
    plus = damage_in_depth(burn, 0.5, 0.2, diffusivity=A + eps, body_temperature=BODY).damage_depth[1, 1]
    minus = damage_in_depth(burn, 0.5, 0.2, diffusivity=A - eps, body_temperature=BODY).damage_depth[1, 1]
    assert float(grad) == pytest.approx(float(plus - minus) / (2 * eps), rel=1e-4)
    assert float(grad) > 0


def test_runs_on_the_inputs_device_whatever_the_default(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    expected = damage_in_depth(frames, dt, dx, diffusivity=A, body_temperature=BODY).damage_depth
    with torch.device("meta"):
        t = subsurface_temperature(frames, dt, dx, [0.0, 0.5], diffusivity=A)
        maps = damage_in_depth(frames, dt, dx, diffusivity=A, body_temperature=BODY, noise_sd=0.1)
        heat = surface_heat_input(frames, dt, dx, diffusivity=A)
        fit = fit_depth_parameters(frames, dt, dx)
    assert t.device.type == maps.damage_depth.device.type == heat.device.type == "cpu"
    assert fit.diffusivity.device.type == "cpu"
    torch.testing.assert_close(maps.damage_depth, expected)


def test_errors_name_the_argument(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    with pytest.raises(ValueError, match="diffusivity must be positive and finite in mm\\^2/s"):
        damage_in_depth(frames, dt, dx, diffusivity=0.0)
    with pytest.raises(ValueError, match="loss_rate must be non-negative"):
        damage_in_depth(frames, dt, dx, diffusivity=A, loss_rate=-0.1)
    with pytest.raises(ValueError, match="depths must be finite depths >= 0 mm"):
        subsurface_temperature(frames, dt, dx, [-1.0], diffusivity=A)
    with pytest.raises(ValueError, match="thickness must be deeper than the deepest depth"):
        subsurface_temperature(frames, dt, dx, [1.0], diffusivity=A, thickness=0.5)
    with pytest.raises(ValueError, match="rule must be one of"):
        damage_in_depth(frames, dt, dx, diffusivity=A, rule="mean")
    holed = frames.clone()
    holed[3, 2, 2] = math.nan
    with pytest.raises(ValueError, match="frames must be finite for the depth solve, got 1 non-finite"):
        damage_in_depth(holed, dt, dx, diffusivity=A)
    with pytest.raises(ValueError, match="diffusivity must be a number or have shape \\(1,\\)"):
        damage_in_depth(frames, dt, dx, diffusivity=torch.tensor([A, A]))
    with pytest.raises(TypeError, match="diffusivity must be a number in mm\\^2/s"):
        damage_in_depth(frames, dt, dx, diffusivity="fast")


# ------------------------------------------------------------------------------------------ fit and flag
def test_cooling_starts_two_frames_after_the_switch_off(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, _, _ = burn
    assert int(cooling_start((frames - BODY).unsqueeze(0))[0]) == 16 + 2  # last heated frame: 16


def reference_scene(absorption: float | None) -> BioheatScene:
    """A 0.4 mm beam for 4 s at the centre of a 32 x 32 px view (0.2 mm), surface peak near 82 C."""
    tissue = Tissue(diffusivity=0.15, perfusion=0.004)
    centre = (3.2, 3.2)
    unit = SurfaceFlux(centre, centre, 0.4, 1.0, 0.5, 4.5)
    power = 45.0 / flux_peak(unit, tissue, np.array([centre]), np.array([4.5]))
    source = SurfaceFlux(centre, centre, 0.4, power * (1.5 if absorption else 1.0), 0.5, 4.5, absorption)
    return BioheatScene(tissue, (source,), 10.0, (32, 32), 0.2, 10.0, 1.5)


@pytest.fixture(scope="module")
def surface_burn():
    result = simulate_bioheat(reference_scene(None))
    return result, torch.from_numpy(camera_frames(result, 0.3, 3))


@pytest.mark.slow
def test_depth_model_matches_the_independent_3d_simulator(surface_burn) -> None:
    result, frames = surface_burn
    maps = damage_in_depth(
        frames, result.dt, result.dx, diffusivity=0.15, loss_rate=0.004, body_temperature=BODY
    )
    damaged = result.damage_depth > 0.1
    assert damaged.sum() > 30 and 0.2 < result.damage_depth.max() < 0.35
    error = np.abs(maps.damage_depth.numpy() - result.damage_depth)[damaged]
    assert np.median(error) < 0.005 and error.max() < 0.01  # mm
    one_d = damage_in_depth(frames, result.dt, result.dx, diffusivity=0.15, loss_rate=0.004, lateral=False)
    assert np.median(one_d.damage_depth.numpy()[damaged] - result.damage_depth[damaged]) > 0.02  # too deep


@pytest.mark.slow
def test_fit_recovers_a_and_the_flag_stays_down_under_surface_heating(surface_burn) -> None:
    result, frames = surface_burn
    fit = fit_depth_parameters(frames, result.dt, result.dx, body_temperature=BODY)
    assert bool(fit.valid) and not bool(fit.volumetric) and fit.messages == ""
    assert float(fit.diffusivity) == pytest.approx(0.15, rel=0.03)
    assert abs(float(fit.diffusivity) - 0.15) < 3 * float(fit.diffusivity_std)
    assert 0.0 <= float(fit.loss_rate) < 0.02  # perfusion 0.004 plus the loss to air
    assert float(fit.misfit) < VOLUMETRIC_MISFIT / 5


@pytest.mark.slow
def test_volumetric_heating_is_flagged_not_mapped() -> None:
    result = simulate_bioheat(reference_scene(1.0))  # near-infrared: mu = 1 1/mm
    frames = torch.from_numpy(camera_frames(result, 0.3, 4))
    fit = fit_depth_parameters(frames, result.dt, result.dx, body_temperature=BODY)
    assert bool(fit.valid) and bool(fit.volumetric) and "volumetrically heated" in fit.messages
    found = depth_features(frames, result.dt, result.dx)
    assert not bool(found.used[0]) and found.profiles is None
    assert all(bool(torch.isnan(found.maps[name]).all()) for name in DEPTH_MAPS)
    assert found.record(0)["volumetric"] is True


def test_no_cooling_means_no_fit(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    fit = fit_depth_parameters(frames[:18], dt, dx)  # ends at the switch-off
    assert not bool(fit.valid) and math.isnan(float(fit.diffusivity))
    assert "frames after the switch-off" in fit.messages


def test_tissue_features_gain_the_depth_maps_and_keep_the_others(
    burn: tuple[torch.Tensor, float, float],
) -> None:
    frames, dt, dx = burn
    plain = TissueFeatures()(frames, dt, dx)
    deep = TissueFeatures(depth=True)(frames, dt, dx)
    for name, m in plain.maps.items():
        torch.testing.assert_close(deep.maps[name], m, rtol=0, atol=0)
    assert set(DEPTH_MAPS) <= set(deep.maps) and all(deep.units[name] == "mm" for name in DEPTH_MAPS)
    assert deep.depth is not None and deep.depth.parameters.diffusivity.shape == (1,)
    assert "damage_depth_mm" in TissueFeatures(depth=True)(frames, dt).absent  # no pixel size
    assert isinstance(TissueFeatures(depth=True), torch.nn.Module)
