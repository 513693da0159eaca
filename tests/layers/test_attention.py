"""Tests for anra_torch.layers.attention: the paper's RTC, its overflow-free form, masks and stage V."""

from __future__ import annotations

import numpy as np
import pytest
import reference as ref
import torch
from tolerances import assert_rounding_close

from anra_torch.layers.attention import RTCAttention, confidence_mask, rtc_attention
from anra_torch.layers.derivatives import TimeDerivative

F64 = torch.float64


RTOL = {torch.float32: 2e-5, torch.float64: 1e-12}
"""Relative tolerance against the float64 NumPy RTC (exp of rates of a few units loses a few ulps)."""


def distinct_rates(shape: tuple[int, ...]) -> torch.Tensor:
    """Rates with distinct magnitudes in [0.2, 2.5] and random signs: no ties, no zeros (smooth |.|)."""
    n = int(np.prod(shape))
    magnitudes = torch.linspace(0.2, 2.5, n, dtype=F64)[torch.randperm(n)]
    signs = torch.where(torch.rand(n) < 0.5, -1.0, 1.0).to(F64)
    return (magnitudes * signs).reshape(shape)


def test_rtc_matches_paper_reference(dtype: torch.dtype) -> None:
    rate = 2.0 * torch.randn(2, 3, 6, 7, dtype=F64)
    weights = rtc_attention(rate.to(dtype))
    assert weights.shape == rate.shape and weights.dtype == dtype
    expected = ref.rtc(rate.numpy())
    np.testing.assert_allclose(weights.double().numpy(), expected, rtol=RTOL[dtype], atol=RTOL[dtype] * 1e-3)


def test_rtc_sums_to_one_per_frame_and_zeroes_the_slowest_pixel(dtype: torch.dtype, tol: float) -> None:
    rate = torch.randn(3, 4, 5, 6, dtype=dtype)
    weights = rtc_attention(rate)
    torch.testing.assert_close(weights.sum(dim=(-2, -1)), torch.ones(3, 4, dtype=dtype), rtol=tol, atol=tol)
    assert bool((weights >= 0).all())
    slowest = rate.abs().flatten(-2).argmin(dim=-1)
    assert bool((weights.flatten(-2).gather(-1, slowest[..., None]) == 0).all())
    fastest = rate.abs().flatten(-2).argmax(dim=-1)
    torch.testing.assert_close(weights.flatten(-2).argmax(dim=-1), fastest)


def test_rtc_has_no_overflow_at_huge_rates(dtype: torch.dtype) -> None:
    rate = 10.0 * torch.randn(2, 8, 8, dtype=dtype)
    rate[0, 1, 2], rate[0, 5, 5] = 1e4, -1e4  # two fastest pixels (|dT/dt| counts, not its sign)
    rate[1, 0, 0] = 1e4
    weights = rtc_attention(rate)
    assert bool(torch.isfinite(weights).all())
    expected = torch.zeros_like(rate)
    expected[0, 1, 2] = expected[0, 5, 5] = 0.5
    expected[1, 0, 0] = 1.0
    assert_rounding_close(weights, expected, scale=1.0)
    # the paper's literal three lines overflow here: exp(1e4) = inf and inf / inf = NaN
    with np.errstate(over="ignore", invalid="ignore"):
        assert np.isnan(ref.rtc(rate.double().numpy())).any()


def test_unit_invariant_weights_ignore_the_units_of_T_and_t(dtype: torch.dtype) -> None:
    derivative = TimeDerivative("smooth", 5)
    video = (torch.randn(2, 9, 6, 7, dtype=F64) + torch.linspace(0, 3, 9, dtype=F64)[:, None, None]) * 0.1
    dt = 0.05
    rate = derivative(video, dt).to(dtype)
    rate_rescaled = derivative(video * 1000, dt * 0.01).to(dtype)  # K -> mK, s -> 10 ms
    invariant = rtc_attention(rate, unit_invariant=True)
    torch.testing.assert_close(
        rtc_attention(rate_rescaled, unit_invariant=True),
        invariant,
        rtol=RTOL[dtype],
        atol=RTOL[dtype] * 1e-2,
    )
    # it is the paper's formula applied to |dT/dt| / max |dT/dt| per frame
    peak = rate.double().abs().amax(dim=(-2, -1), keepdim=True)
    expected = ref.rtc((rate.double() / peak).numpy())
    np.testing.assert_allclose(
        invariant.double().numpy(), expected, rtol=RTOL[dtype], atol=RTOL[dtype] * 1e-2
    )
    # whereas the paper's own form changes completely with the units
    paper, paper_rescaled = rtc_attention(rate), rtc_attention(rate_rescaled)
    assert float((paper - paper_rescaled).abs().max()) > 0.1


def test_masked_pixels_get_exactly_zero(dtype: torch.dtype) -> None:
    rate = 2.0 * torch.randn(2, 3, 6, 7, dtype=F64)
    mask = torch.rand(6, 7) < 0.6
    rate[..., ~mask] += 50.0  # the fastest pixels are all masked out and must take no weight
    weights = rtc_attention(rate.to(dtype), mask=mask)
    assert bool((weights[..., ~mask] == 0).all())
    expected = ref.rtc(rate.numpy(), mask.numpy())
    np.testing.assert_allclose(weights.double().numpy(), expected, rtol=RTOL[dtype], atol=RTOL[dtype] * 1e-3)
    sums = weights.double().sum(dim=(-2, -1))
    # Sums of H W weights, each rounded in `dtype`.
    assert_rounding_close(sums, torch.ones_like(sums), ops=4 * weights[0, 0].numel(), scale=1.0, dtype=dtype)


def test_non_finite_rates_are_ignored(dtype: torch.dtype) -> None:
    rate = torch.randn(1, 2, 5, 5, dtype=F64)
    rate[0, 0, 1, 1], rate[0, 1, 2, 3], rate[0, 1, 4, 0] = float("nan"), float("inf"), -float("inf")
    weights = rtc_attention(rate.to(dtype))
    finite = torch.isfinite(rate)
    assert bool(torch.isfinite(weights).all())
    assert bool((weights[~finite] == 0).all())
    expected = ref.rtc(np.nan_to_num(rate.numpy(), nan=0.0, posinf=0.0, neginf=0.0), finite.numpy())
    np.testing.assert_allclose(weights.double().numpy(), expected, rtol=RTOL[dtype], atol=RTOL[dtype] * 1e-3)


def test_frames_without_activity_give_zeros_not_nan(dtype: torch.dtype) -> None:
    rate = torch.randn(4, 5, 6, dtype=dtype)
    rate[0] = 3.0  # constant
    rate[1] = 0.0  # no change at all
    rate[2, 2, 3] = 5.0  # a single valid pixel: constant over the valid set
    mask = torch.zeros(4, 5, 6, dtype=torch.bool)
    mask[0], mask[1], mask[3] = True, True, True
    mask[2, 2, 3] = True
    weights = rtc_attention(rate, mask=mask)
    assert bool(torch.isfinite(weights).all())
    assert bool((weights[:3] == 0).all())
    assert float(weights[3].sum()) == pytest.approx(1.0, rel=1e-5)
    # a frame with every pixel masked also gets zeros
    assert bool((rtc_attention(rate, mask=torch.zeros(5, 6, dtype=torch.bool)) == 0).all())


def test_sharpness_scales_the_rate(dtype: torch.dtype) -> None:
    rate = torch.randn(2, 5, 5, dtype=dtype)
    torch.testing.assert_close(rtc_attention(rate, sharpness=2.5), rtc_attention(2.5 * rate))


def test_confidence_mask_keeps_pixels_above_the_fraction_of_the_peak() -> None:
    weights = rtc_attention(torch.randn(2, 3, 6, 6, dtype=F64))
    w = weights.numpy()
    peak = w.max(axis=(-2, -1), keepdims=True)
    for threshold in (0.0, 0.25, 0.6):
        kept = confidence_mask(weights, threshold)
        assert kept.dtype == torch.bool
        np.testing.assert_array_equal(kept.numpy(), (w > 0) & (w >= threshold * peak))
    # the fastest pixel of each frame is always kept
    assert bool(confidence_mask(weights, 0.99).flatten(-2).any(dim=-1).all())


def test_threshold_keeps_the_right_pixels_and_renormalises(dtype: torch.dtype) -> None:
    rate = 2.0 * torch.randn(2, 3, 7, 6, dtype=F64)
    weights = RTCAttention(threshold=0.3)(rate.to(dtype))
    w = ref.rtc(rate.numpy())
    keep = w >= 0.3 * w.max(axis=(-2, -1), keepdims=True)
    expected = np.where(keep, w, 0.0)
    expected /= expected.sum(axis=(-2, -1), keepdims=True)
    np.testing.assert_allclose(weights.double().numpy(), expected, rtol=RTOL[dtype], atol=RTOL[dtype] * 1e-3)
    np.testing.assert_array_equal((weights > 0).numpy(), keep)
    sums = weights.double().sum(dim=(-2, -1))
    # Sums of H W weights, each rounded in `dtype`.
    assert_rounding_close(sums, torch.ones_like(sums), ops=4 * weights[0, 0].numel(), scale=1.0, dtype=dtype)
    assert 0 < keep.sum() < keep.size  # the threshold really dropped some pixels


def test_module_without_threshold_is_the_function(dtype: torch.dtype) -> None:
    rate = torch.randn(2, 3, 5, 5, dtype=dtype)
    mask = torch.rand(5, 5) < 0.7
    module = RTCAttention(sharpness=0.7, unit_invariant=True)
    torch.testing.assert_close(
        module(rate, mask), rtc_attention(rate, sharpness=0.7, unit_invariant=True, mask=mask), rtol=0, atol=0
    )
    assert len(module.state_dict()) == 0
    assert "threshold=0" in repr(module)


def test_with_slope_is_the_diagonal_of_the_jacobian() -> None:
    # Away from each frame's slowest pixel (which sets the subtracted minimum), w_ij depends on rate_ij only
    # through its own exponential and the normalisation, so the diagonal derivative is exact.
    rate = distinct_rates((2, 4, 4))
    mask = torch.ones(4, 4, dtype=torch.bool)
    mask[0, 1] = False
    weights, slope = RTCAttention(sharpness=0.8).with_slope(rate, mask)
    torch.testing.assert_close(weights, rtc_attention(rate, sharpness=0.8, mask=mask))
    jacobian = torch.autograd.functional.jacobian(lambda r: rtc_attention(r, sharpness=0.8, mask=mask), rate)
    diagonal = torch.einsum("abcabc->abc", jacobian)
    valid = mask.expand_as(rate)
    slowest = torch.where(valid, rate.abs(), torch.inf).flatten(-2).argmin(-1)
    away = torch.ones_like(rate, dtype=torch.bool).flatten(-2)
    away.scatter_(-1, slowest[..., None], False)
    away = away.reshape(rate.shape) & valid
    torch.testing.assert_close(slope[away], diagonal[away], rtol=1e-10, atol=1e-12)
    assert bool((slope[~valid] == 0).all())


@pytest.mark.parametrize("unit_invariant", [False, True])
def test_rtc_gradcheck(unit_invariant: bool) -> None:
    rate = distinct_rates((1, 2, 3, 3)).requires_grad_()
    assert torch.autograd.gradcheck(lambda r: rtc_attention(r, unit_invariant=unit_invariant), (rate,))


def test_thresholded_module_gradcheck() -> None:
    rate = distinct_rates((1, 2, 3, 3))
    weights = rtc_attention(rate)
    ratio = weights / weights.amax(dim=(-2, -1), keepdim=True)
    threshold = 0.35
    assert float((ratio - threshold).abs().min()) > 1e-3  # no pixel sits on the threshold
    module = RTCAttention(threshold=threshold)
    assert torch.autograd.gradcheck(module, (rate.requires_grad_(),))


@pytest.mark.parametrize("sharpness", [0.0, -1.0, float("nan")])
def test_rejects_bad_sharpness(sharpness: float) -> None:
    with pytest.raises(ValueError, match="sharpness must be a positive number"):
        rtc_attention(torch.randn(2, 3, 3), sharpness=sharpness)
    with pytest.raises(ValueError, match="sharpness must be a positive number"):
        RTCAttention(sharpness=sharpness)


@pytest.mark.parametrize("threshold", [-0.1, 1.0, 1.5])
def test_rejects_bad_threshold(threshold: float) -> None:
    with pytest.raises(ValueError, match=r"threshold must be in \[0, 1\)"):
        confidence_mask(torch.rand(2, 3, 3), threshold)
    with pytest.raises(ValueError, match=r"threshold must be in \[0, 1\)"):
        RTCAttention(threshold=threshold)


def test_rejects_integer_rates() -> None:
    with pytest.raises(TypeError, match="rate must be a floating tensor, got dtype torch.int64"):
        rtc_attention(torch.ones(2, 3, 3, dtype=torch.int64))
