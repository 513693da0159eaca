"""Tests for anra_torch.balance.robust: exact medians by selection, fourth differences in full and sampled."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from anra_torch.balance.robust import (
    _select,
    fourth_difference,
    robust_sd,
    row_medians,
    sampled_fourth_difference,
)


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request: pytest.FixtureRequest) -> torch.dtype:
    return request.param


def test_row_medians_are_torch_medians(dtype: torch.dtype) -> None:
    x = torch.randn(3, 200_001, dtype=dtype).abs()
    x[1, ::7] = 0.5  # ties
    assert torch.equal(row_medians(x), x.median(1).values)
    valid = torch.rand(3, 200_001) > 0.4
    valid[2] = False  # a row without any value: NaN, as nanmedian
    got, expected = row_medians(x, valid), torch.where(valid, x, torch.nan).nanmedian(1).values
    assert torch.equal(got[:2], expected[:2]) and bool(got[2].isnan()) and bool(expected[2].isnan())


def test_sampled_fourth_differences_are_the_full_ones_sampled(dtype: torch.dtype) -> None:
    x = torch.randn(17, 60, 70, dtype=dtype)
    for dim in (0, -2, -1):
        full = fourth_difference(x, dim).reshape(-1)
        assert torch.equal(sampled_fourth_difference(x, dim, sample=5000), full[:: full.numel() // 5000])
    quiet = torch.rand(60, 70) > 0.5
    for dim in (-2, -1):
        centre = quiet.narrow(dim, 2, x.shape[dim] - 4)
        full = fourth_difference(x, dim)[..., centre].reshape(-1)
        got = sampled_fourth_difference(x, dim, where=centre, sample=5000)
        assert torch.equal(got, full[:: full.numel() // 5000])


@pytest.mark.parametrize("n", [1_000, 8_192, 20_001, 300_000])
def test_selection_is_the_partition_at_every_rank(n: int) -> None:
    rng = np.random.default_rng(n)
    rows = [
        rng.standard_normal(n).astype(np.float32),
        np.repeat(rng.standard_normal(n // 100 + 1), 100)[:n],  # many ties
        np.sort(rng.standard_normal(n))[::-1].copy(),  # ordered: the strided sample is not random
        np.where(rng.random(n) < 0.3, np.inf, rng.standard_normal(n)),  # invalid values at the end
    ]
    for row in rows:
        for rank in (0, 1, n // 3, (n - 1) // 2, n - 2, n - 1):
            assert _select(row, rank) == np.partition(row, rank)[rank]


def test_fourth_difference_annihilates_cubics_and_scales_white_noise() -> None:
    t = torch.arange(40, dtype=torch.float64)
    cubic = (0.3 * t**3 - 2 * t**2 + t - 5).view(40, 1, 1).expand(40, 3, 3)
    assert float(fourth_difference(cubic, 0).abs().max()) < 1e-9
    noise = torch.randn(400, 60, 60, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    assert float(fourth_difference(noise, -1).std()) == pytest.approx(70**0.5, rel=0.01)


def test_robust_sd_is_the_sd_of_gaussian_values_and_ignores_outliers() -> None:
    x = 0.7 * torch.randn(200_000, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    x[::500] = 1e6  # 0.2 % outliers: the median moves by about 0.25 %
    assert robust_sd(x, sample=None) == pytest.approx(0.7, rel=0.01)
    assert robust_sd(torch.tensor([float("nan")] * 5)) == 0.0
