"""The standard error of a recording read in chunks (:mod:`anra_torch.estimation.chunk_error`): the
totals of the sums, and the sampled gain."""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.estimation.chunk_error import NoiseVariance, gain, totals


def test_totals_are_the_ratio_of_sums_and_nan_without_regressor_energy() -> None:
    sums = {name: torch.tensor([1.0, 1.0], dtype=torch.float64) for name in ("num", "energy")}
    sums["den"] = torch.tensor([2.0, 2.0], dtype=torch.float64)
    variance = NoiseVariance(5, exact=0.16)
    a, se, reliability = totals(sums, variance, {"frames": 6, "finished": True}, variance_error=0.0)
    assert a == pytest.approx(0.5) and se == pytest.approx(0.1) and reliability == pytest.approx(2.0)
    sums["den"] = torch.zeros(2, dtype=torch.float64)
    a, se, reliability = totals(sums, variance, {"frames": 6, "finished": True}, variance_error=0.0)
    assert math.isnan(a) and math.isnan(se) and reliability == 0.0


def test_the_gain_is_nan_when_every_chunk_was_chained() -> None:
    assert math.isnan(gain(NoiseVariance(5)))
    assert gain(NoiseVariance(5, interior=2.0, weight=4.0)) == 0.5


def test_the_sampled_interior_scales_to_the_recording() -> None:
    variance = NoiseVariance(5, exact=1.0, interior=2.0, weight=4.0)  # 0.5 per frame and unit of energy
    # 20 output frames of total energy 40 (2 per frame) over 24 input frames, 8 of them at the two ends
    assert variance.total(40.0, 20, 24, finished=True) == pytest.approx(1.0 + 0.5 * 2.0 * 16)
