"""Non-uniform timestamps (:mod:`anra_torch.video.resample`): the default step, linear and cubic
interpolation through the real times, phases without blended frames.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch.video import Phase, Video, load_video, resample_uniform

VIDEO = np.random.default_rng(1).normal(30, 2, (6, 5, 7))


def test_resampling_is_linear_in_time_and_stated(tmp_path: Path) -> None:
    t = np.array([0.0, 1.0, 5.0, 10.0, 15.5, 20.0])
    ramp = (3.0 * t)[:, None, None] + VIDEO[:1] * 0  # T = 3 t: linear interpolation is exact
    np.savez(tmp_path / "r.npz", frames=ramp, t=t)
    video = load_video(tmp_path / "r.npz", timestamps="resample")
    grid = video.t.numpy()
    np.testing.assert_allclose(grid, np.arange(len(grid)) * video.dt)
    np.testing.assert_allclose(video.frames[:, 2, 3].numpy(), 3.0 * grid, rtol=1e-12)
    assert video.meta["resampled"]["from_frames"] == 6 and video.meta["resampled"]["step_min"] == 1.0
    kept = load_video(tmp_path / "r.npz", timestamps="keep")
    assert not kept.uniform and kept.frames.shape[0] == 6


def test_resampled_phases_keep_no_frame_blended_across_the_switch() -> None:
    from anra_torch.video.resample import measured_frames, measured_part

    samples = [0.0, 5.0, 65.0, 75.0, 105.0, 120.0, 140.0, 145.0, 205.0, 215.0, 245.0]  # switch at 150 s
    grid = torch.arange(0.0, 246.0, 15.0, dtype=torch.float64)  # the median step
    heating = measured_part(Phase("heating", 0, 11, 0.0, 150.0), grid, samples)
    cooling = measured_part(Phase("cooling", 11, 17, 165.0, 240.0), grid, samples)
    # 150 s takes 1/12 of the 205 s sample (kept); 165-195 s take 17-67 % of the 145 s heating sample.
    assert (heating.start, heating.stop, heating.t_stop) == (0, 11, 150.0)
    assert (cooling.start, cooling.stop, cooling.t_start) == (14, 17, 210.0)
    # A camera's jitter: 54.1 s and 59.0 s samples on a 5 s grid; 60 s is the 59 s sample itself.
    jitter = measured_part(
        Phase("cooling", 12, 14, 60.0, 65.0), torch.arange(0.0, 66.0, 5.0), [54.1, 59.0, 64.9]
    )
    assert (jitter.start, jitter.stop) == (12, 14)
    # Scored: the frame nearest each sample; not the frames inside the 5-65 s and 145-205 s gaps.
    measured = measured_frames(grid, samples)
    assert grid[measured].tolist() == [0.0, 60.0, 75.0, 105.0, 120.0, 135.0, 150.0, 210.0, 240.0]
    jittered = torch.tensor([0.0, 4.1, 9.1, 14.2, 19.1, 24.1])  # a hand-triggered camera: every frame
    assert bool(measured_frames(torch.arange(6) * 4.82, jittered).all())


def _irregular(times: np.ndarray, signal: Callable[[np.ndarray], np.ndarray]) -> Video:
    """A 3 x 3 px video whose every pixel follows ``signal(t)`` (K), sampled at ``times`` (s)."""
    values = torch.as_tensor(signal(times), dtype=torch.float64)
    return Video(frames=values[:, None, None].expand(-1, 3, 3), dt=1.0, dx=1.0, t=torch.as_tensor(times))


def test_resampling_step_keeps_every_sample_on_a_frame_of_its_own() -> None:
    from anra_torch.video.resample import MAX_FRAMES_PER_SAMPLE, default_step

    jitter = torch.tensor([0.0, 4.1, 9.1, 14.2, 19.2, 24.0, 29.1, 34.0])  # a camera's 5 s period (FLIR C3-X)
    assert default_step(jitter) == pytest.approx(float(torch.diff(jitter).median()))
    dense_then_sparse = torch.tensor([0.0, 5, 15, 20, 30, 60, 90, 120, 150, 180, 210, 240, 270, 300])
    assert default_step(dense_then_sparse) == 5.0  # the median (30 s) puts 0 and 5 s on one frame
    burst = torch.tensor([0.0, 0.01, 60, 120, 180, 240, 300, 360])  # two frames 10 ms apart
    assert default_step(burst) == pytest.approx(360 / (MAX_FRAMES_PER_SAMPLE * 8))
    video = Video(torch.randn(14, 4, 4, dtype=torch.float64), dt=30.0, dx=0.5, t=dense_then_sparse)
    assert resample_uniform(video).frames.shape[0] == 61


def test_cubic_resampling_uses_the_real_timestamps() -> None:
    from anra_torch.video.resample import resample_uniform

    times = np.concatenate([[0.0], np.cumsum(np.tile([5.0, 60.0, 15.0, 40.0], 3))])  # 5-60 s steps
    # A parabola in time is reproduced exactly: the slopes are the parabolas' through the real times.
    parabola = resample_uniform(_irregular(times, lambda t: 3.0 + 0.02 * t - 1e-4 * t**2), dt=5.0)
    grid = parabola.t.numpy()
    np.testing.assert_allclose(parabola.frames[:, 1, 1], 3.0 + 0.02 * grid - 1e-4 * grid**2, atol=1e-12)
    assert parabola.meta["resampled"]["method"].startswith("cubic Hermite")
    # A decay with a 100 s time scale (a diffusing spot cooling), from 1: in the 60 s gaps linear
    # interpolation errs by up to 0.032, the cubic by 0.0048.
    error = {}
    for method in ("cubic", "linear"):
        decay = resample_uniform(_irregular(times, lambda t: np.exp(-t / 100)), dt=5.0, method=method)
        error[method] = float((decay.frames[:, 1, 1] - torch.exp(-decay.t / 100)).abs().max())
    assert error["cubic"] < 0.2 * error["linear"] and error["cubic"] < 0.006


def test_cubic_resampling_does_not_bend_across_a_switch() -> None:
    from anra_torch.video.resample import resample_uniform

    # Heating at 0.1 K/s until the 185 s sample, cooling at 0.05 K/s after: each phase's samples lie on a
    # line, so each phase's frames must too (a cubic through the kink would overshoot into both phases).
    times = np.array([0.0, 5.0, 65.0, 80.0, 120.0, 125.0, 185.0, 200.0, 240.0, 245.0, 305.0, 320.0])
    spot = np.where(times <= 185.0, 0.1 * times, 18.5 - 0.05 * (times - 185.0))
    video = Video(
        frames=torch.as_tensor(22.0 + np.einsum("t,hw->thw", spot, _bump(16))),
        dt=1.0,
        dx=0.5,
        t=torch.as_tensor(times),
    )
    resampled = resample_uniform(video, dt=5.0)
    grid = resampled.t.numpy()
    line = np.interp(grid, times, spot)  # and linear across the 185-200 s gap that holds the switch
    np.testing.assert_allclose(resampled.frames[:, 8, 8] - 22.0, line * _bump(16)[8, 8], atol=1e-9)


def _bump(size: int) -> np.ndarray:
    y, x = np.mgrid[:size, :size] - (size - 1) / 2
    return np.exp(-(x**2 + y**2) / (2 * 3.0**2))
