"""The fit of ``a`` and ``b`` on the cooling and the volumetric flag, on the independent 3-D simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depth_scenes import (
    BODY,
    burn_video,
    reference_scene,
)

from anra_torch.simulation import GreenScene, camera_frames, simulate_bioheat, simulate_spot
from anra_torch.tissue import (
    DEPTH_MAPS,
    DepthSettings,
    damage_in_depth,
    depth_features,
    fit_depth_parameters,
)
from anra_torch.tissue.depth_cooling import cooling_start
from anra_torch.tissue.depth_fit import VOLUMETRIC_MISFIT, square_root_drop


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    return burn_video()


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
    # the scene's own extent (with the simulator's loss to air): 16 pixels damaged deeper than 0.1 mm
    assert damaged.sum() >= 12 and 0.2 < result.damage_depth.max() < 0.35
    error = np.abs(maps.damage_depth.numpy() - result.damage_depth)[damaged]
    assert np.median(error) < 0.005 and error.max() < 0.01  # mm
    one_d = damage_in_depth(
        frames, result.dt, result.dx, diffusivity=0.15, loss_rate=0.004, settings=DepthSettings(lateral=False)
    )
    assert np.median(one_d.damage_depth.numpy()[damaged] - result.damage_depth[damaged]) > 0.02  # too deep


@pytest.mark.slow
def test_fit_recovers_a_and_the_flag_stays_down_under_surface_heating(surface_burn) -> None:
    result, frames = surface_burn
    fit = fit_depth_parameters(frames, result.dt, result.dx, body_temperature=BODY)
    assert bool(fit.valid) and not bool(fit.volumetric) and fit.messages == ""
    assert float(fit.diffusivity) == pytest.approx(0.15, rel=0.03)
    assert abs(float(fit.diffusivity) - 0.15) < 3 * float(fit.diffusivity_std)
    assert 0.0 <= float(fit.loss_rate) < 0.015 and 0.0 <= float(fit.surface_loss) < 0.2  # truth 0.004, 0.02
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


@pytest.fixture(scope="module")
def window_spot():
    """A spot wider than the frame and off its centre (the Green's-function reference: no edges), switched
    off between frames, at 10 frames/s with 0.3 K noise."""
    scene = GreenScene(0.17, 0.0, 0.03, (2.2, 3.9), 2.2, 80.0, 0.5, 5.47, 11.0, 10.0, (40, 40), 0.15)
    result = simulate_spot(scene, damage=False)
    noise = 0.3 * np.random.default_rng(7).standard_normal(result.frames.shape)
    return result, torch.from_numpy(result.frames + noise)


def test_a_long_exposure_gives_a() -> None:
    """40 s under a spot nearly as wide as the frame: the heat reaches millimetres beyond the frame; the
    frames continued 1.6 mm by a straight line read a 18 % low and a perfusion where there is none."""
    scene = GreenScene(0.15, 0.0, 0.03, (3.2, 3.2), 2.0, 80.0, 0.5, 40.3, 50.0, 5.0, (32, 32), 0.2)
    result = simulate_spot(scene, damage=False)
    noise = 0.3 * np.random.default_rng(3).standard_normal(result.frames.shape)
    fit = fit_depth_parameters(torch.from_numpy(result.frames + noise), result.dt, result.dx)
    assert bool(fit.valid) and not bool(fit.volumetric)
    assert float(fit.diffusivity) == pytest.approx(0.15, rel=0.1)
    assert float(fit.loss_rate) < 0.002


def test_a_spot_wider_than_the_frame_gives_a(window_spot) -> None:
    result, frames = window_spot
    fit = fit_depth_parameters(frames, result.dt, result.dx)
    assert bool(fit.valid) and not bool(fit.volumetric)
    assert float(fit.diffusivity) == pytest.approx(0.17, rel=0.05)
    assert abs(float(fit.diffusivity) - 0.17) < 3 * float(fit.diffusivity_std)
    assert (
        float(fit.loss_rate) < 0.01
    )  # the frame's cosine modes alone read 0.04 1/s into the heat leaving it


@pytest.fixture(scope="module")
def slow_camera():
    """5 frames/s switched off right at a frame (the Green's-function reference: another solver than the
    finite volumes whose scenes showed it): the straight line across the surface's square-root fall puts
    heat into the tissue that was never there."""
    scene = GreenScene(0.17, 0.005, 0.02, (4.0, 4.0), 1.2, 80.0, 0.4, 10.4, 20.0, 5.0, (32, 32), 0.25)
    result = simulate_spot(scene, damage=False)
    noise = 0.3 * np.random.default_rng(5).standard_normal(result.frames.shape)
    return result, torch.from_numpy(result.frames + noise)


def test_a_switch_off_at_a_frame_stays_inside_the_standard_errors(slow_camera) -> None:
    """Before the sampling part, b 0.0018 +- 0.0006 and h/k 0.044 +- 0.004 (truth 0.005, 0.02: 5 and 6
    standard errors off); the fit on the frames of a square-root fall recovers both."""
    result, frames = slow_camera
    fit = fit_depth_parameters(frames, result.dt, result.dx)
    assert bool(fit.valid) and float(fit.diffusivity) == pytest.approx(0.17, rel=0.02)
    assert abs(float(fit.loss_rate) - 0.005) < 2 * float(fit.loss_rate_std)
    assert abs(float(fit.surface_loss) - 0.02) < 2 * float(fit.surface_loss_std)
    switch = cooling_start((frames - BODY).unsqueeze(0)) - 2
    assert int(switch) == 52  # the frame at the switch-off (10.4 s)
    dropped = fit_depth_parameters(square_root_drop(frames.unsqueeze(0), switch)[0], result.dt, result.dx)
    assert float(dropped.loss_rate) == pytest.approx(0.005, abs=0.0015)
    assert float(dropped.surface_loss) == pytest.approx(0.02, abs=0.008)


def test_the_square_root_drop_puts_the_heat_of_a_switch_off_at_a_frame() -> None:
    """The half-space's surface under a constant flux switched off at frame 10 (``sqrt(t) - sqrt(t - t_e)``):
    the heat of the two intervals after it by the frames joined by straight lines errs +3.7 %, by the
    dropped frames +0.8 %."""
    t = np.arange(21) * 0.2
    surface = np.sqrt(t) - np.sqrt(np.clip(t - 2.0, 0.0, None))
    dropped = square_root_drop(torch.from_numpy(surface).view(1, -1, 1, 1), torch.tensor([10]))[0, :, 0, 0]
    exact = 2.0 / 3.0 * (t[12] ** 1.5 - t[10] ** 1.5 - (t[12] - 2.0) ** 1.5)

    def heat(values) -> float:
        return 0.2 * (values[10] / 2 + values[11] + values[12] / 2)

    assert heat(surface) / exact - 1 > 0.03
    assert abs(heat(dropped.numpy()) / exact - 1) < 0.01
    assert torch.equal(dropped[:11], torch.from_numpy(surface[:11]))  # only the frame after the switch-off
