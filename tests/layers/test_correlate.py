"""The one engine that filters along an axis: correlation against numpy, the transpose, the Conv3d route
of the time filter, gradients through the transpose, borders."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from anra_torch.layers.correlate import (
    BORDERS,
    check_border,
    check_spatial,
    correlate1d,
    correlate1d_adjoint,
    pad_frames,
    time_filter,
)

F64 = torch.float64
TAPS = [[0.25, 0.0, -0.5, 0.0, 0.25], [1.0], [0.0, 1.0, 0.0], [0.0, 0.0], [-0.5, 0.0, 0.5]]


@pytest.mark.parametrize("taps", TAPS, ids=["wide", "unit", "shifted-unit", "zero", "central"])
@pytest.mark.parametrize("dim", [0, 1, -1])
def test_correlate1d_is_the_valid_correlation(taps: list[float], dim: int) -> None:
    x = torch.randn(9, 8, 7, dtype=F64)
    out = correlate1d(x, taps, dim)
    expected = np.apply_along_axis(lambda v: np.correlate(v, np.array(taps), "valid"), dim, x.numpy())
    np.testing.assert_allclose(out.numpy(), expected, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("taps", TAPS, ids=["wide", "unit", "shifted-unit", "zero", "central"])
def test_correlate1d_adjoint_is_the_exact_transpose(taps: list[float]) -> None:
    x = torch.randn(3, 12, 5, dtype=F64)
    y = torch.randn_like(correlate1d(x, taps, 1))
    back = correlate1d_adjoint(y, taps, 1)
    assert back.shape == x.shape
    torch.testing.assert_close((back * x).sum(), (y * correlate1d(x, taps, 1)).sum(), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("dim", [1, -2, -1])
def test_a_correlation_cut_into_blocks_gives_the_same_numbers_as_one_pass(dim: int, monkeypatch) -> None:
    """Blocks of a few rows (the CPU's cache-sized blocks, made small) give every entry the same operations
    in the same order as one pass of each tap over the whole tensor: equal, not close."""
    x = torch.randn(3, 12, 40, 37, dtype=F64)
    taps = torch.linspace(0.1, 1.0, 9, dtype=F64).tolist()
    n = x.shape[dim] - len(taps) + 1
    one_pass = x.narrow(dim, 0, n) * taps[0]
    for i, tap in enumerate(taps[1:], 1):
        one_pass.add_(x.narrow(dim, i, n), alpha=tap)
    y = torch.randn_like(one_pass)
    transposed = torch.zeros_like(x)
    for i, tap in enumerate(taps):
        transposed.narrow(dim, i, n).add_(y, alpha=tap)
    monkeypatch.setattr("anra_torch.layers.correlate._BLOCK_BYTES", 3 * 40 * 8)
    assert torch.equal(correlate1d(x, taps, dim), one_pass)
    assert torch.equal(correlate1d_adjoint(y, taps, dim), transposed)


def test_correlate1d_gradients_run_through_the_transpose_twice() -> None:
    x = torch.randn(2, 10, 4, dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: correlate1d(v, TAPS[0], 1), (x,), fast_mode=True)
    assert torch.autograd.gradgradcheck(lambda v: correlate1d(v, TAPS[0], 1) ** 2, (x,), fast_mode=True)


def test_time_filter_equals_one_correlation_per_channel_and_its_gradient_the_transpose() -> None:
    frames = torch.randn(2, 11, 4, 5, dtype=F64, requires_grad=True)
    taps = torch.tensor([TAPS[0], [0.2, 0.2, 0.2, 0.2, 0.2]], dtype=F64)
    out = time_filter(frames, taps)
    assert out.shape == (2, 2, 7, 4, 5)
    for c in range(2):
        torch.testing.assert_close(out[:, c], correlate1d(frames.detach(), taps[c].tolist(), 1))
    assert torch.autograd.gradcheck(lambda v: time_filter(v, taps), (frames,), fast_mode=True)


@pytest.mark.parametrize("border", list(BORDERS))
def test_pad_frames_keeps_the_size_after_a_valid_correlation(border: str) -> None:
    u = torch.randn(2, 3, 9, 10, dtype=F64)
    padded = pad_frames(u, 2, border)
    assert padded.shape == ((2, 3, 9, 10) if border == "crop" else (2, 3, 13, 14))


def test_border_and_frame_checks_name_what_they_received() -> None:
    with pytest.raises(ValueError, match="unknown border 'mirror'; expected one of: crop, reflect"):
        check_border("mirror")
    with pytest.raises(ValueError, match=r"need frames of at least 5 x 5 px for a 5-px kernel"):
        check_spatial(torch.zeros(4, 9), 5, "crop")
    with pytest.raises(ValueError, match=r"input must have shape \(..., H, W\), got \(4,\)"):
        check_spatial(torch.zeros(4), 5, "crop")
