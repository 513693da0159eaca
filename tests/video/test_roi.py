"""Regions of interest and pixel masks (:mod:`anra_torch.video.roi`)."""

from __future__ import annotations

import pytest
import torch
from scenes import spot_video

from anra_torch.video import Video
from anra_torch.video.roi import apply_mask, crop, dead_pixel_mask, parse_roi, reflection_mask


# ------------------------------------------------------------------------------------------- ROI, masks
def test_roi_crop_and_errors() -> None:
    frames = torch.arange(2 * 6 * 8, dtype=torch.float64).reshape(2, 6, 8)
    video = crop(Video(frames, dt=1.0, dx=1.0), parse_roi("2,1,4,3"))
    torch.testing.assert_close(video.frames, frames[:, 1:4, 2:6])
    assert video.meta["roi"] == [2, 1, 4, 3]
    with pytest.raises(ValueError, match="does not fit in the 8 x 6 px frame"):
        crop(Video(frames, dt=1.0, dx=1.0), (5, 0, 4, 2))
    with pytest.raises(ValueError, match="four integers"):
        parse_roi("1,2,3")


def test_dead_pixels_and_reflections_are_masked() -> None:
    frames = spot_video(n=60, off=50)
    frames[:, 3, 20] = 55.0  # stuck
    frames[:, 20, 3] += 15.0  # hot spike
    mask = dead_pixel_mask(frames)
    assert bool(mask[3, 20]) and bool(mask[20, 3]) and int(mask.sum()) == 2
    masked = apply_mask(Video(frames, dt=0.1, dx=0.5), mask)
    assert masked.meta["masked_px"] == 2 and bool(masked.frames[:, 3, 20].isnan().all())
    mirror = frames.clone()
    mirror[:, 18:21, 18:21] = frames[:, 9:12, 11:14]  # a detached copy of the hot spot
    hot = torch.zeros(24, 24, dtype=torch.bool)
    hot[10, 12] = True
    reflection = reflection_mask(mirror, hot)
    assert bool(reflection[19, 19]) and not bool(reflection[10, 12])
