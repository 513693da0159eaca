"""Input checks (:mod:`anra_torch.checks.inputs`): numbers, spacings, choices and value ranges, each with
its one-line error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.checks import in_range_values
from anra_torch.checks.inputs import (
    as_fields,
    as_spacing,
    as_video,
    check_choice,
    check_dtype,
    check_int,
    check_shape,
    join_messages,
    mostly_finite,
    number,
    one_line,
    positive,
    spacing_in_range,
    uniform_step,
)


# --------------------------------------------------------------------------------- the pieces alone
def test_in_range_values_masks_and_counts_like_numpy() -> None:
    rng = np.random.default_rng(0)
    values = 30 + rng.standard_normal((5, 6, 7))
    values[0, 0, :3] = [np.nan, np.inf, -np.inf]
    values[1, 2, 3], values[4, 5, 6] = 2e6, -1e300
    masked, found = in_range_values(torch.from_numpy(values))
    bad = ~np.isfinite(values) | (np.abs(np.nan_to_num(values, posinf=0, neginf=0)) > 1e6)
    np.testing.assert_array_equal(np.isnan(masked.numpy()), bad)
    np.testing.assert_array_equal(masked.numpy()[~bad], values[~bad])
    assert found == {"non_finite": 3, "beyond_limit": 2, "samples": 210, "limit": 1e6, "largest": 1e300}
    # integer counts: kept as they are unless one is beyond the limit
    counts = torch.tensor([[[20000, 65535]]], dtype=torch.int32)
    assert in_range_values(counts)[0] is counts
    big = in_range_values(torch.tensor([[[20000, 2**31 - 1]]], dtype=torch.int32))[0]
    assert big.dtype == torch.float64 and math.isnan(big[0, 0, 1]) and big[0, 0, 0] == 20000
    with pytest.raises(ValueError, match=r"got none: 0 non-finite and 0 beyond the limit of 0 samples"):
        in_range_values(torch.zeros(0, 4, 4))


def test_numbers_and_integers_name_the_argument_and_unit() -> None:
    assert number(np.array([2.5]), "dx", "mm", positive=True) == 2.5
    assert number(torch.tensor(0.0), "t", "s", minimum=0.0) == 0.0
    with pytest.raises(TypeError, match=r"^dx must be a number in mm, got True$"):
        number(True, "dx", "mm")
    with pytest.raises(TypeError, match=r"^dx must be a number in mm, got 'wide'$"):
        number("wide", "dx", "mm")
    with pytest.raises(ValueError, match=r"^dt must be a positive finite number in s, got 0$"):
        positive(0, "dt", "s")
    with pytest.raises(ValueError, match=r"^b must be a finite number in 1/s, got inf$"):
        number(math.inf, "b", "1/s")
    with pytest.raises(ValueError, match=r"^t must be a finite number >= 0 in s, got -1$"):
        number(-1, "t", "s", minimum=0.0)
    assert check_int(3, "frames", 1) == 3
    with pytest.raises(ValueError, match=r"^frames must be an integer >= 1, got 2.0$"):
        check_int(2.0, "frames", 1)
    with pytest.raises(ValueError, match=r"^frames must be an integer >= 0, got False$"):
        check_int(False, "frames", 0)


def test_choices_dtypes_and_frame_sizes() -> None:
    assert check_choice("smooth", "family", ["smooth", "hybrid"]) == "smooth"
    with pytest.raises(ValueError, match=r"^unknown family 'fast'; expected one of: smooth, hybrid$"):
        check_choice("fast", "family", ["smooth", "hybrid"])
    assert check_dtype(torch.float32) is torch.float32
    with pytest.raises(TypeError, match=r"dtype must be torch.float32 or torch.float64, got torch.float16"):
        check_dtype(torch.float16)
    assert check_shape([3, 4]) == (3, 4)
    with pytest.raises(ValueError, match=r"shape must be \(H, W\) with positive integers, got \(3, 0\)"):
        check_shape((3, 0))


def test_videos_and_fields_become_batches_of_floats() -> None:
    video, batched = as_video(np.zeros((6, 4, 5), dtype=np.int16))
    assert video.shape == (1, 6, 4, 5) and video.is_floating_point() and not batched
    with pytest.raises(
        ValueError, match=r"^frames must have shape \(T, H, W\) or \(B, T, H, W\), got \(4, 5\)$"
    ):
        as_video(torch.zeros(4, 5))
    with pytest.raises(ValueError, match=r"^frames needs at least 7 frames for these filters, got 4$"):
        as_video(torch.zeros(4, 5, 5), min_frames=7)
    with pytest.raises(TypeError, match=r"^frames must hold real temperatures, got dtype torch.complex64$"):
        as_video(torch.zeros(6, 4, 5, dtype=torch.complex64))
    fields, batched = as_fields(torch.zeros(2, 3, 3, dtype=torch.float64))
    assert fields.shape == (2, 3, 3) and batched
    with pytest.raises(ValueError, match=r"^initial must be finite, got 1 non-finite values; mask or fill"):
        as_fields(torch.tensor([[0.0, math.nan], [1.0, 2.0]]))


def test_spacings_per_video() -> None:
    like = torch.zeros(1, dtype=torch.float64)
    same = as_spacing(0.5, name="dx", unit="mm", batch=3, like=like)
    torch.testing.assert_close(same, torch.full((3,), 0.5, dtype=torch.float64))
    per_video = as_spacing(torch.tensor([0.1, 0.2]), name="dt", unit="s", batch=2, like=like)
    assert per_video.dtype == torch.float64 and per_video.tolist() == pytest.approx([0.1, 0.2])
    with pytest.raises(ValueError, match=r"^dt must be a number or have shape \(2,\), got shape \(3,\)$"):
        as_spacing([0.1, 0.2, 0.3], name="dt", unit="s", batch=2, like=like)
    with pytest.raises(ValueError, match=r"^dx must be a positive finite number in mm, got \[0.1, -1.0\]$"):
        as_spacing(torch.tensor([0.1, -1.0], dtype=torch.float64), name="dx", unit="mm", batch=2, like=like)
    assert spacing_in_range(0.04, "dt", "s") == 0.04
    with pytest.raises(
        ValueError, match=r"^dx must be between 1e-06 and 1e\+06 mm, got 5e-08; check its unit"
    ):
        spacing_in_range(5e-8, "dx", "mm")


def test_timestamps_must_be_increasing_and_uniform() -> None:
    assert uniform_step([0.0, 0.5, 1.0, 1.5]) == pytest.approx(0.5)
    with pytest.raises(ValueError, match=r"^t needs at least 2 timestamps, got 1$"):
        uniform_step([3.0])
    with pytest.raises(ValueError, match=r"^t must be strictly increasing, got t\[1\]=2 s then t\[2\]=2 s$"):
        uniform_step([1.0, 2.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"^t must be uniformly spaced, got steps from 1 to 2 s; resample"):
        uniform_step([0.0, 1.0, 3.0, 4.0])


def test_mostly_finite_allows_a_few_repairable_samples() -> None:
    frames = torch.zeros(10, 10, 10)
    frames.view(-1)[:50] = math.nan  # 5 %
    assert mostly_finite(frames) is frames
    frames.view(-1)[50] = math.nan
    message = (
        r"^frames must be mostly finite, got 51 non-finite values of 1000 \(more than 5 %\); crop or fill"
    )
    with pytest.raises(ValueError, match=message):
        mostly_finite(frames)
    assert join_messages(["a", "", None, "b", "a"]) == "a; b"
    assert one_line(OSError("disk\n  full")) == "disk full"
