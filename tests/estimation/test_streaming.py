"""Streaming estimator: equal to the offline estimator on the same frames, bounded memory, long videos."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.balance.noise import estimate_noise_sd
from anra_torch.estimation.estimator import ANRAEstimator
from anra_torch.estimation.streaming import StreamingEstimator, estimate_long
from anra_torch.simulation.synthetic import paper_video

NOISE = 0.01


@pytest.fixture(scope="module")
def video():
    """The paper's case cropped to 96 px: (28, 96, 96) float64, a = 0.2 mm^2/s, noise sd 0.01."""
    return paper_video(n_videos=1, seed=2, crop=96)


@pytest.mark.parametrize("sigma", [1.0, 4.0])
def test_frame_by_frame_equals_offline(video, sigma: float) -> None:
    frames = video.frames[0]
    offline = ANRAEstimator(smoothing=sigma, noise_sd=NOISE)(frames, video.dt, video.dx)
    stream = StreamingEstimator(
        dt=video.dt, dx=video.dx, smoothing=sigma, noise_sd=NOISE, dtype=torch.float64
    )
    per_frame = []
    for frame in frames:
        est = stream.push(frame)
        if est.ready:
            per_frame.append(est.per_frame)
    assert est.diffusivity == pytest.approx(float(offline.diffusivity), rel=1e-10)
    np.testing.assert_allclose(per_frame, offline.per_frame.numpy(), rtol=1e-9)
    assert est.time == pytest.approx(float(offline.frame_times[-1]), rel=1e-12)
    assert est.reliability == pytest.approx(float(offline.reliability), rel=1e-9)
    assert abs(est.diffusivity - 0.2) < 0.005


def test_blocks_of_any_size_give_the_same_estimate(video) -> None:
    frames = video.frames[0]
    one = StreamingEstimator(dt=video.dt, dx=video.dx, noise_sd=NOISE, dtype=torch.float64)
    for frame in frames:
        last = one.push(frame)
    blocks = StreamingEstimator(dt=video.dt, dx=video.dx, noise_sd=NOISE, dtype=torch.float64)
    for start, stop in ((0, 3), (3, 4), (4, 17), (17, 28)):
        est = blocks.push(frames[start:stop])
    assert est.diffusivity == pytest.approx(last.diffusivity, rel=1e-12)
    assert est.windows == last.windows == 28 - 5 + 1


def test_masked_pixels_match_offline_masking(video) -> None:
    frames = video.frames[0].clone()
    frames[3, 40, 50] = math.nan
    frames[10:12, 20, 70] = math.inf
    offline = ANRAEstimator(smoothing=2.0, noise_sd=NOISE)(frames, video.dt, video.dx)
    stream = StreamingEstimator(dt=video.dt, dx=video.dx, smoothing=2.0, noise_sd=NOISE, dtype=torch.float64)
    for frame in frames:
        est = stream.push(frame)
    assert math.isfinite(est.diffusivity)
    assert est.diffusivity == pytest.approx(float(offline.diffusivity), rel=1e-10)


def test_float32_agrees_with_float64_on_a_hot_offset_scene(video) -> None:
    frames = video.frames[0] + 300.0  # kelvin-like offset: float32 must stay precise
    estimates = []
    for dtype in (torch.float32, torch.float64):
        stream = StreamingEstimator(dt=video.dt, dx=video.dx, noise_sd=NOISE, dtype=dtype)
        estimates.append(stream.push(frames).diffusivity)
    assert estimates[0] == pytest.approx(estimates[1], rel=1e-4)


def test_not_ready_is_flagged_not_silent(video) -> None:
    stream = StreamingEstimator(dt=video.dt, dx=video.dx)
    est = stream.push(video.frames[0][:4])
    assert not est.ready and math.isnan(est.diffusivity)
    assert est.message == "need 5 frames for the time filter, got 4"
    est = stream.push(video.frames[0][4:10])  # windows exist, noise needs 16 frames
    assert not est.ready and "noise level not known yet" in est.message
    est = stream.push(video.frames[0][10:])
    assert est.ready and est.message == ""
    expected = float(estimate_noise_sd(video.frames[0][:16]))
    assert est.noise_sd == pytest.approx(expected, rel=1e-5)


def test_memory_is_bounded_by_the_window(video) -> None:
    stream = StreamingEstimator(dt=video.dt, dx=video.dx, noise_sd=NOISE)
    frames = video.frames[0]
    for _ in range(5):
        for frame in frames:
            stream.push(frame)
    assert stream.frames_seen == 5 * 28
    assert len(stream._rate_ring) == len(stream._lap_ring) == stream.time.length - 1


def test_estimate_long_on_a_memmap_equals_offline(video, tmp_path) -> None:
    frames = video.frames[0]
    path = tmp_path / "long.npy"
    np.save(path, frames.numpy())
    mapped = np.load(path, mmap_mode="r")
    offline = ANRAEstimator(smoothing=4.0, noise_sd=NOISE)(frames, video.dt, video.dx)
    for chunk in (1, 6, 1000):
        est = estimate_long(mapped, video.dt, video.dx, chunk=chunk, noise_sd=NOISE, dtype=torch.float64)
        assert est.diffusivity == pytest.approx(float(offline.diffusivity), rel=1e-10)


def test_bad_input_messages(video) -> None:
    with pytest.raises(ValueError, match=r"dt must be a positive finite number in s, got -1"):
        StreamingEstimator(dt=-1, dx=0.1)
    stream = StreamingEstimator(dt=0.1, dx=0.1)
    with pytest.raises(ValueError, match=r"frames must have shape \(H, W\) or \(n, H, W\), got \(4,\)"):
        stream.push(torch.zeros(4))
    with pytest.raises(
        ValueError, match=r"frames must be at least 33 x 33 px for these filters, got 20 x 40"
    ):
        stream.push(torch.zeros(20, 40))
    stream.push(torch.zeros(40, 40))
    with pytest.raises(ValueError, match=r"frames must keep the stream's size 40 x 40, got 40 x 41"):
        stream.push(torch.zeros(40, 41))
    with pytest.raises(ValueError, match=r"chunk must be an integer >= 1 \(frames\), got 0"):
        estimate_long(np.zeros((10, 40, 40)), 0.1, 0.1, chunk=0)


def test_npy_frames_reads_slices_without_loading_the_file(video, tmp_path) -> None:
    from anra_torch.estimation.streaming import NpyFrames

    array = video.frames[0].numpy().astype(np.float32)
    np.save(tmp_path / "v.npy", array)
    frames = NpyFrames(tmp_path / "v.npy")
    assert frames.shape == (28, 96, 96) and len(frames) == 28
    np.testing.assert_array_equal(frames[5:9], array[5:9])
    np.testing.assert_array_equal(frames[20:100], array[20:])
    est = estimate_long(frames, video.dt, video.dx, chunk=10, noise_sd=NOISE)
    offline = ANRAEstimator(smoothing=4.0, noise_sd=NOISE)(torch.from_numpy(array), video.dt, video.dx)
    assert est.diffusivity == pytest.approx(float(offline.diffusivity), rel=1e-4)
    np.save(tmp_path / "flat.npy", np.zeros((4, 5)))
    with pytest.raises(
        ValueError, match=r"flat.npy: frames must be a C-ordered real array \(T, H, W\), got shape \(4, 5\)"
    ):
        NpyFrames(tmp_path / "flat.npy")
