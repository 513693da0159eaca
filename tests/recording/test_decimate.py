"""Tests for the block-averaged copy a camera-sized recording is diagnosed on (``forecast.decimate``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scenes import blob_video

import anra_torch.recording.decimate as decimate
from anra_torch.estimation.estimator import ANRAEstimator
from anra_torch.recording.decimate import (
    DIAGNOSE_VALUES,
    camera_copy,
    decimated_video,
    decimation,
    signal_box,
)
from anra_torch.video import Video


def block_means(frames: np.ndarray, k: int, m: int) -> np.ndarray:
    """An independent block average: reshape and mean in NumPy (float64)."""
    t, h, w = (n // f for n, f in zip(frames.shape, (m, k, k), strict=True))
    cut = frames[: t * m, : h * k, : w * k].astype(np.float64)
    return cut.reshape(t, m, h, k, w, k).mean(axis=(1, 3, 5))


def test_the_factors_keep_the_diffusion_per_frame_within_the_budget() -> None:
    # 640 x 512 x 900 (295 M values): 3 x 3 px and 8 frames keep a dt / dx^2 within 12 %.
    assert decimation((900, 512, 640)) == (3, 8)
    assert 112 * 170 * 213 <= DIAGNOSE_VALUES
    # 10x the frames: 5 x 5 px and 29 frames (m / k^2 = 1.16), still within the budget.
    assert decimation((9000, 512, 640)) == (5, 29)
    assert (9000 // 29) * (512 // 5) * (640 // 5) <= DIAGNOSE_VALUES
    assert decimation((81, 128, 128)) == (1, 1)  # within the budget: the recording itself
    with pytest.raises(ValueError, match="cannot be averaged down to 100 pixel values"):
        decimation((200, 64, 64), budget=100)
    with pytest.raises(ValueError, match="budget and shape must be positive, got budget 0"):
        decimation((10, 8, 8), budget=0)


def test_the_copy_is_the_block_average_read_in_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    video = blob_video(47, 50, noise=0.01)
    monkeypatch.setattr(decimate, "_CHUNK_VALUES", 5 * 50 * 50)  # one block per chunk
    copy, record = decimated_video(video, 3, 4)
    expected = block_means(video.frames.numpy(), 3, 4)
    assert copy.frames.shape == expected.shape == (11, 16, 16)
    np.testing.assert_allclose(copy.frames.numpy(), expected, rtol=1e-15, atol=0)
    assert record == {
        "space_px": 3,
        "time_frames": 4,
        "shape": [11, 16, 16],
        "dropped_frames": 3,
        "dropped_rows": 2,
        "dropped_columns": 2,
        "repaired_spikes": 0,
        "repaired_elements": 0,
        "region": None,
    }
    assert copy.dx == pytest.approx(0.3) and copy.dt == pytest.approx(4 / 30)
    np.testing.assert_allclose(copy.t.numpy(), (np.arange(44).reshape(11, 4) / 30).mean(1))


def test_spikes_and_hot_elements_are_repaired_before_the_average() -> None:
    clean = blob_video(64, 48, noise=0.01)
    planted = clean.frames.clone()
    planted[20, 30, 10] += 300.0  # a single-sample spike
    planted[:, 5, 40] += 8.0  # a hot element
    copy, record = decimated_video(Video(frames=planted, dt=clean.dt, dx=clean.dx), 2, 4)
    reference, _ = decimated_video(clean, 2, 4)
    assert record["repaired_spikes"] == 1 and record["repaired_elements"] == 1
    # Averaged unrepaired, the spike would add 300 / 16 = 19 K to its block and the element 2 K to its.
    assert float((copy.frames - reference.frames).abs().max()) < 0.05


def test_the_copy_obeys_the_heat_equation_with_the_same_diffusivity() -> None:
    # A block average of an exact solution is an exact solution (the equation is linear and shift
    # invariant), sampled at the coarse pixel size and frame period: the estimate finds the same a.
    video = blob_video(160, 96)
    copy, _ = decimated_video(video, 2, 4)
    estimate = ANRAEstimator()(copy.frames, copy.dt, copy.dx)
    assert float(estimate.diffusivity) == pytest.approx(0.2, rel=0.01)


def test_a_small_spot_is_copied_from_its_region_at_a_finer_block() -> None:
    video = blob_video(128, 256, noise=0.01)
    budget = 128 * 256 * 256 // 16
    first = decimation(video.frames.shape, budget)
    copy, record = camera_copy(video, budget)
    x0, y0, width, height = record["region"]
    assert x0 < 128 < x0 + width and y0 < 128 < y0 + height  # the spot's centre (pixel 127.5)
    assert width * height < 0.5 * 256 * 256
    assert record["space_px"] < first[0] and math.prod(copy.frames.shape) <= budget
    # the spot (0.6 mm, at least 1.2 mm at the end) stays resolved: about its radius, in the copy's pixels
    assert 1.2 / copy.dx >= 5


def test_a_change_over_the_whole_frame_is_not_cut() -> None:
    t = torch.arange(40, dtype=torch.float64)[:, None, None]
    field = 20 + 5 * torch.exp(-t / 20) * (1 + 0.1 * torch.linspace(0, 1, 64))[None, None, :]
    assert signal_box(field.expand(40, 64, 64).contiguous()) is None
    assert signal_box(torch.full((10, 32, 32), 3.0)) is None  # nothing changes
