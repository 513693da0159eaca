"""Temperature histories as the doses read them: units, masked samples, the smooth division."""

from __future__ import annotations

import pytest
import torch

from anra_torch.tissue.histories import count_masked, divided, masked, stepper, to_celsius

F64 = torch.float64


def test_kelvin_become_celsius_and_wrong_units_are_named() -> None:
    kelvin = torch.tensor([310.15, 330.15], dtype=F64)
    torch.testing.assert_close(to_celsius(kelvin, "K"), torch.tensor([37.0, 57.0], dtype=F64))
    with pytest.raises(ValueError, match="units must be one of 'C', 'K', got 'F'"):
        to_celsius(kelvin, "F")
    with pytest.raises(ValueError, match=r"units='C' \(--units C\).*only makes sense in K"):
        to_celsius(kelvin, "C")


def test_masked_samples_are_counted_and_weighted_out() -> None:
    video = torch.full((2, 5, 3, 4), 40.0, dtype=F64)
    video[1, 2, 0, 1] = float("nan")
    video[1, 4, 0, 1] = float("inf")
    counts = count_masked(video)
    assert counts.shape == (2, 3, 4) and int(counts[1, 0, 1]) == 2 and int(counts.sum()) == 2
    history = video.reshape(2, 5, -1)
    filled, hold = masked(history, "hold")
    assert bool(torch.isfinite(filled).all()) and float(filled[1, 2, 1]) == 43.0
    assert hold is not None and hold[1, :, 1].tolist() == [1.0, 1.0, 0.0, 1.0, 0.0]
    _, linear = masked(history, "linear")  # a segment counts when both of its ends do
    assert linear is not None and linear[1, :, 1].tolist() == [1.0, 0.0, 0.0, 0.0]
    assert masked(history[:1], "hold")[1] is None  # nothing masked: every frame counts


def test_the_smooth_division_is_the_quotient_away_from_zero_and_the_limit_at_it() -> None:
    rise = torch.tensor([2.0, 1e-9, 0.0], dtype=F64)
    change = torch.tensor([1.0, 3e-9, 0.0], dtype=F64)
    limit = torch.tensor([9.0, 5.0, 7.0], dtype=F64)
    out = divided(change.clone(), rise, limit.clone(), 1e-6, stepper(rise))
    assert float(out[0]) == pytest.approx(0.5, rel=1e-10)
    assert float(out[1]) == pytest.approx(5.0, rel=1e-5) and float(out[2]) == pytest.approx(7.0, rel=1e-12)
