"""flash_maps: the flash found (the warmest frame), the defect map and the contrasts on the frames after it,
the arrays and the record that ``anra diagnose --maps`` writes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.flash import TSR_FRAMES, FlashMaps, flash_maps, pct, ppt


def _recording() -> torch.Tensor:
    """5 frames at 20 C before the flash, then an insulated 1-D plate (L^2 / a_z 2 s) per pixel, a disc of
    d / L 0.5 in it, 20 mK noise: 24 x 24 px, 100 frames at 0.02 s."""
    t = 0.02 * np.arange(1, 101)
    yy, xx = np.mgrid[0:24, 0:24]
    taus = np.where((xx - 12) ** 2 + (yy - 11) ** 2 <= 25, 0.5, 2.0)
    n = np.arange(1, 200)
    depth = (
        1 + 2 * np.exp(-(n**2) * math.pi**2 * t[:, None, None, None] / taus[..., None]).sum(-1)
    ) / np.sqrt(taus)
    noise = 0.02 * np.random.default_rng(4).standard_normal((105, 24, 24))
    frames = np.concatenate([np.full((5, 24, 24), 20.0), 20 + 3 * depth]) + noise
    return torch.from_numpy(frames)


@pytest.fixture(scope="module")
def maps() -> tuple[FlashMaps, torch.Tensor]:
    frames = _recording()
    return flash_maps(frames, 0.02, 0.3), frames


def test_the_maps_start_at_the_flash_and_hold_the_contrasts_of_the_same_frames(maps) -> None:
    found, frames = maps
    assert found.flash_frame == 5
    cooling = frames[5:]
    torch.testing.assert_close(found.pct, pct(cooling).maps)
    torch.testing.assert_close(found.ppt, ppt(cooling, 0.02).phase)
    assert found.tsr_d2.shape == (len(found.tsr_times), 24, 24) and len(found.tsr_times) <= TSR_FRAMES
    assert bool((found.tsr_times.diff() > 0).all()) and float(found.tsr_times[0]) == found.defects.first_time
    assert len(found.defects.defects) == 1 and abs(found.defects.defects[0].depth_fraction - 0.5) < 0.08


def test_arrays_and_record_are_what_the_maps_file_and_the_json_hold(maps) -> None:
    found, _ = maps
    arrays = found.arrays()
    assert set(arrays) == {
        "defect_score", "defect_mask", "depth_fraction", "depth_time", "tsr_d2", "tsr_times", "pct", "ppt",
        "ppt_frequencies",
    }  # fmt: skip
    assert all(isinstance(v, np.ndarray) for v in arrays.values())
    assert arrays["defect_mask"].dtype == bool and arrays["defect_score"].shape == (24, 24)
    record = found.record()
    assert record["flash_frame"] == 5 and record["defect_pixels"] == int(arrays["defect_mask"].sum())
    (defect,) = record["defects"]
    assert set(defect) == {"x", "y", "area", "depth_fraction", "touches_edge"}
    assert abs(defect["x"] - 12.5 * 0.3) < 0.3 and abs(record["plate_time"] / 2.0 - 1) < 0.05


def test_too_few_frames_after_the_flash() -> None:
    frames = torch.ones(20, 10, 10)
    frames[15] += 5  # the warmest frame leaves 5 after it
    with pytest.raises(ValueError, match="at least 8 frames after the flash"):
        flash_maps(frames, 0.1, 0.3)
    with pytest.raises(ValueError, match=r"frames must be one recording \(T, H, W\)"):
        flash_maps(torch.ones(2, 20, 10, 10), 0.1, 0.3)
