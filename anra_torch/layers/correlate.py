"""The one engine that filters along an axis: fixed taps correlated along one dimension, and its transpose.

Every fixed kernel of ``layers`` runs through it: a time filter is a correlation along T, a separable
spatial kernel two correlations along W and H. A correlation is valid (the output shorter by ``L - 1``);
borders (:data:`BORDERS`) are padded before it. The transpose (:func:`correlate1d_adjoint`) maps output-space
weights back onto the input, which is also the backward of every correlation here.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = ["BORDERS", "correlate1d", "correlate1d_adjoint", "time_filter"]

BORDERS: dict[str, str | None] = {
    "crop": None,
    "reflect": "reflect",
    "replicate": "replicate",
    "circular": "circular",
    "zeros": "constant",
}
"""Border handling: ``"crop"`` keeps only fully supported pixels; the others pad (``F.pad`` modes)."""

_BLOCK_BYTES = 1 << 20
"""The size of the blocks that a correlation on the CPU filters one after the other (:func:`_blocks`):
small enough to stay in a core's cache while every tap passes over them."""


def check_border(border: str) -> None:
    """Raises:
    ValueError: ``border`` is not a key of :data:`BORDERS`."""
    if border not in BORDERS:
        raise ValueError(f"unknown border {border!r}; expected one of: {', '.join(BORDERS)}")


def check_spatial(x: Tensor, support: int, border: str) -> None:
    """Raises:
    ValueError: ``x`` is not ``(..., H, W)`` or its frames are too small for a ``support``-px kernel."""
    if x.ndim < 2:
        raise ValueError(f"input must have shape (..., H, W), got {tuple(x.shape)}")
    # 'crop' needs the whole kernel inside the frame; 'reflect' and 'circular' more than its radius.
    need = {"crop": support, "reflect": support // 2 + 1, "circular": support // 2 + 1}.get(border, 1)
    if min(x.shape[-2:]) < need:
        raise ValueError(
            f"need frames of at least {need} x {need} px for a {support}-px kernel with "
            f"border={border!r}, got {x.shape[-2]} x {x.shape[-1]}"
        )


def pad_frames(u: Tensor, r: int, border: str) -> Tensor:
    """``(..., H, W)`` padded by ``r`` px on each side with ``border``'s mode (unchanged for ``"crop"``)."""
    mode = BORDERS[border]
    if mode is None:
        return u
    padded = F.pad(u.reshape(-1, 1, *u.shape[-2:]), (r, r, r, r), mode=mode)
    return padded.reshape(*u.shape[:-2], u.shape[-2] + 2 * r, u.shape[-1] + 2 * r)


def time_filter(frames: Tensor, taps: Tensor) -> Tensor:
    """Correlate a video with ``C`` tap vectors along T as one Conv3d (its backward: the transposed taps).

    Shape:
        ``frames`` ``(B, T, H, W)``, ``taps`` ``(C, L)``; output ``(B, C, T - L + 1, H, W)``.
    """
    if frames.requires_grad and torch.is_grad_enabled():
        return _Correlate1d.apply(frames, taps, 1, True)
    return _time_conv(frames, taps)


def correlate1d(x: Tensor, taps: list[float], dim: int) -> Tensor:
    """Valid correlation of ``x`` with ``taps`` along ``dim``, as an in-place sum of shifted slices.

    Zero taps are skipped and a lone unit tap returns a view. Differentiable through its transpose.

    Shape:
        ``x`` any shape; output the same with ``len(taps) - 1`` fewer entries along ``dim``.
    """
    nonzero = [tap for tap in taps if tap != 0.0]
    if x.requires_grad and torch.is_grad_enabled() and not (len(nonzero) == 1 and nonzero[0] == 1.0):
        return _Correlate1d.apply(x, taps, dim, False)
    return _slices(x, taps, dim)


def correlate1d_adjoint(y: Tensor, taps: list[float], dim: int) -> Tensor:
    """Transpose of :func:`correlate1d`: ``sum(y * correlate1d(x)) == sum(correlate1d_adjoint(y) * x)``.

    Each tap's shifted copy of ``y`` is added into the longer output in place; with gradients, a zero-padded
    correlation with the reversed taps (the same map, differentiable again).

    Shape:
        ``y`` any shape; output the same with ``len(taps) - 1`` more entries along ``dim``.
    """
    k = len(taps)
    if y.requires_grad and torch.is_grad_enabled():
        pad = [0, 0] * (y.ndim - (dim % y.ndim) - 1) + [k - 1, k - 1]
        return correlate1d(F.pad(y, pad), taps[::-1], dim)
    n = y.shape[dim]
    shape = list(y.shape)
    shape[dim] = n + k - 1
    nonzero = [(i, tap) for i, tap in enumerate(taps) if tap != 0.0]
    if not nonzero:
        return y.new_zeros(shape)
    out = y.new_empty(shape)
    first, tap = nonzero[0]
    for y_block, block, d in _blocks(y, out, dim):
        block.narrow(d, 0, first).zero_()
        block.narrow(d, first + n, k - 1 - first).zero_()
        torch.mul(y_block, tap, out=block.narrow(d, first, n))
        for i, tap_i in nonzero[1:]:
            block.narrow(d, i, n).add_(y_block, alpha=tap_i)
    return out


def _time_conv(frames: Tensor, taps: Tensor) -> Tensor:
    """The forward of :func:`time_filter`: one Conv3d."""
    weight = taps.to(frames).reshape(taps.shape[0], 1, -1, 1, 1)
    return F.conv3d(frames.unsqueeze(1), weight)


def _slices(x: Tensor, taps: list[float], dim: int) -> Tensor:
    """The forward of :func:`correlate1d`: ~3 memory passes per tap, accumulated in place."""
    n = x.shape[dim] - len(taps) + 1
    nonzero = [(i, tap) for i, tap in enumerate(taps) if tap != 0.0]
    if not nonzero:
        return x.narrow(dim, 0, n) * 0.0
    first, tap = nonzero[0]
    if len(nonzero) == 1 and tap == 1.0:  # a shifted identity: a view, no pass over memory
        return x.narrow(dim, first, n)
    if not _blockable(x, dim):  # the product's own layout and type
        out = x.narrow(dim, first, n) * tap
        for i, tap_i in nonzero[1:]:
            out.add_(x.narrow(dim, i, n), alpha=tap_i)
        return out
    shape = list(x.shape)
    shape[dim] = n
    out = x.new_empty(shape)
    for x_block, block, d in _blocks(x, out, dim):
        torch.mul(x_block.narrow(d, first, n), tap, out=block)
        for i, tap_i in nonzero[1:]:
            block.add_(x_block.narrow(d, i, n), alpha=tap_i)
    return out


def _blockable(x: Tensor, dim: int) -> bool:
    """Whether :func:`_blocks` cuts ``x``: a non-empty contiguous floating-point tensor on the CPU,
    filtered along another dim than its first."""
    return (
        x.device.type == "cpu"
        and x.is_floating_point()
        and x.is_contiguous()
        and x.numel() > 0
        and dim % x.ndim != 0
    )


def _blocks(x: Tensor, out: Tensor, dim: int) -> list[tuple[Tensor, Tensor, int]]:
    """``(x, out)`` cut into matching blocks of whole rows along the dims before ``dim`` (where
    :func:`_blockable`, ``out`` contiguous and non-empty too), each with the filtered dim's index in it:
    every tap then passes over a block that stays in the core's cache instead of over the whole tensor, with
    the same operations on every entry in the same order (the same numbers). Otherwise one block."""
    d = dim % x.ndim
    if not (_blockable(x, dim) and out.is_contiguous() and out.numel() > 0):
        return [(x, out, d)]
    rows, out_rows = x.view(-1, *x.shape[d:]), out.view(-1, *out.shape[d:])
    step = max(1, _BLOCK_BYTES // (max(rows[0].numel(), out_rows[0].numel()) * x.element_size()))
    return [(rows[s : s + step], out_rows[s : s + step], 1) for s in range(0, rows.shape[0], step)]


class _Correlate1d(torch.autograd.Function):
    """A correlation along ``dim`` whose backward is its transpose (itself differentiable the same way).

    ``stacked``: ``taps`` is a ``(C, L)`` tensor correlated along T as one Conv3d (:func:`time_filter`),
    the backward summing the channels' transposes; otherwise ``taps`` is one list (:func:`correlate1d`).
    """

    @staticmethod
    def forward(ctx: Any, x: Tensor, taps: Any, dim: int, stacked: bool) -> Tensor:
        ctx.dim, ctx.stacked = dim, stacked
        ctx.taps = taps.tolist() if stacked else taps
        return _time_conv(x, taps) if stacked else _slices(x, taps, dim)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None, None, None]:
        if not ctx.stacked:
            return correlate1d_adjoint(grad, ctx.taps, ctx.dim), None, None, None
        channels = [correlate1d_adjoint(grad[:, c], taps, ctx.dim) for c, taps in enumerate(ctx.taps)]
        return sum(channels[1:], channels[0]), None, None, None
