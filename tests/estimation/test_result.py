"""Tests for anra_torch.estimation.result: the batched result, its slices joined, its JSON record."""

from __future__ import annotations

import json

import pytest
import torch

from anra_torch import ANRAEstimator, paper_video
from anra_torch.estimation.result import ANRAResult, concat_results


@pytest.fixture(scope="module")
def result() -> ANRAResult:
    video = paper_video(n_videos=3, seed=2, crop=48)
    frames = video.frames.clone()
    frames[1] = frames[1, :1].expand_as(frames[1])  # a static video: flagged, NaN diffusivity
    return ANRAEstimator(strict=False)(frames, video.dt, video.dx)


def _slice(result: ANRAResult, start: int, stop: int) -> ANRAResult:
    """Videos ``start:stop`` of a batched result (without its maps)."""
    parts = {k: v[start:stop] for k, v in vars(result).items() if v is not None}
    return ANRAResult(**parts | {"field": None, "confidence": None})


def test_slices_joined_are_the_whole(result: ANRAResult) -> None:
    joined = concat_results([_slice(result, i, i + 1) for i in range(3)])
    for name in ("diffusivity", "std_error", "per_frame", "valid", "smoothing"):
        torch.testing.assert_close(getattr(joined, name), getattr(result, name), equal_nan=True)
    assert joined.messages == result.messages and joined.noise == result.noise


def test_unbatched_drops_the_batch_dimension(result: ANRAResult) -> None:
    single = _slice(result, 0, 1).unbatched()
    assert single.diffusivity.shape == () and single.per_frame.ndim == 1
    assert float(single.diffusivity) == float(result.diffusivity[0])


def test_record_is_json_with_units_and_null_for_no_estimate(result: ANRAResult) -> None:
    good, flagged = result.to_record(0, unit="K"), result.to_record(1, unit="K")
    json.dumps([good, flagged])
    assert good["units"] == {
        "diffusivity": "mm^2/s",
        "std_error": "mm^2/s",
        "smoothing_px": "px",
        "noise_sd": "K",
    }
    assert good["valid"] and good["diffusivity"] == pytest.approx(float(result.diffusivity[0]))
    assert not flagged["valid"] and flagged["diffusivity"] is None and flagged["message"]


@pytest.mark.parametrize("index", [-1, 3, 1.0, True])
def test_record_index_outside_the_batch(result: ANRAResult, index: object) -> None:
    with pytest.raises(ValueError, match=r"index must be an integer in \[0, 3\)"):
        result.to_record(index)  # type: ignore[arg-type]
