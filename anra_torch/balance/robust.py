"""Robust statistics of thermal frames: exact medians by selection, fourth differences (which annihilate
the smooth thermal field) over the whole video or at sampled points, and the normal-consistent median
absolute deviation. The noise model and the artefact search are built on them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "PixelStats",
    "fourth_difference",
    "pixel_stats",
    "robust_sd",
    "row_medians",
    "sampled_fourth_difference",
]

# Fourth difference [1, -4, 6, -4, 1]: annihilates cubics, so smooth thermal fields barely leak in.
_TAPS = (1.0, -4.0, 6.0, -4.0, 1.0)
_GAIN = math.sqrt(sum(t * t for t in _TAPS))  # white-noise gain sqrt(70)
_MAD_TO_SD = 1.0 / 0.6744897501960817


def _taps_sum(x: Tensor, dim: int, stride: int) -> Tensor:
    """``sum_i _TAPS[i] x[i stride + k]`` along ``dim``, accumulated in place: one temporary instead of nine
    (at 48 MB each, fresh mappings whose page faults dominated a 120-frame noise model)."""
    n = x.shape[dim] - 4 * stride
    out = x.narrow(dim, 0, n) * _TAPS[0]
    for i, tap in enumerate(_TAPS[1:], start=1):
        out.add_(x.narrow(dim, i * stride, n), alpha=tap)
    return out


def row_medians(x: Tensor, valid: Tensor | None = None) -> Tensor:
    """The lower median of each row's ``valid`` values: ``torch.median`` (``nanmedian`` with NaN at the
    invalid values; NaN for a row without any), exactly.

    On the CPU by NumPy's selection (``docs/architecture.md``, "Choices in the hot paths"). Not
    differentiable: noise levels are measured on detached frames.

    Shape:
        ``x`` ``(R, N)``, ``valid`` ``(R, N)`` bool or None; output ``(R,)``.
    """
    if x.device.type != "cpu" or x.numel() == 0:
        return x.median(1).values if valid is None else torch.where(valid, x, torch.nan).nanmedian(1).values
    values = x.detach() if valid is None else torch.where(valid, x.detach(), torch.inf)  # invalid: last
    count = torch.full((x.shape[0],), x.shape[1], device="cpu") if valid is None else valid.sum(1)
    rank = ((count - 1).clamp_min(0) // 2).numpy()
    array = values.numpy()
    chosen = np.array([_select(row, int(k)) for row, k in zip(array, rank, strict=True)], dtype=array.dtype)
    out = torch.from_numpy(chosen.reshape(-1)).to(x.dtype)
    return out if valid is None else torch.where(count > 0, out, torch.nan)


_SELECT_SAMPLE = 4096  # values whose quantiles bracket the rank sought in a long row


def _select(row: np.ndarray, rank: int) -> np.generic:
    """The ``rank``-th smallest value of a 1-D array, exactly (``np.partition(row, rank)[rank]``).

    A long row is bracketed first by two quantiles of an evenly spaced sample, and the selection runs on
    the values between them; where the bracket misses the rank, on the whole row (``docs/architecture.md``,
    "Choices in the hot paths").
    """
    n = row.shape[0]
    if n < 8192:
        return np.partition(row, rank)[rank]
    sample = np.sort(row[:: max(16, n // _SELECT_SAMPLE)])
    m = sample.shape[0]
    centre, half = (rank + 0.5) / n * m, 3.5 * np.sqrt(m * 0.25) + 2
    low, high = sample[max(0, int(centre - half))], sample[min(m - 1, int(centre + half))]
    below = int(np.count_nonzero(row < low))
    inside = row[(row >= low) & (row <= high)]
    if 0 <= rank - below < inside.shape[0]:
        return np.partition(inside, rank - below)[rank - below]
    return np.partition(row, rank)[rank]


def _fourth_difference(x: Tensor, finite: Tensor, dim: int) -> tuple[Tensor, Tensor]:
    n = x.shape[dim] - 4
    out = _taps_sum(x, dim, 1)
    ok = finite.narrow(dim, 0, n)
    for i in range(1, 5):
        ok = ok & finite.narrow(dim, i, n)
    return out, ok


def fourth_difference(x: Tensor, dim: int, stride: int = 1) -> Tensor:
    """Fourth difference ``[1, -4, 6, -4, 1]`` of ``x`` along ``dim`` at ``stride`` (valid part: shorter by
    ``4 stride``); it annihilates cubics, so a smooth thermal field barely leaks into it."""
    return _taps_sum(x, dim, stride)


def _unravel(index: Tensor, shape: list[int]) -> list[Tensor]:
    """Row-major coordinates of flat ``index`` in ``shape``, as ``torch.unravel_index`` gives them, without
    its import of ``torch.fx``, slow on a command's first call."""
    coords = []
    for size in reversed(shape):
        coords.append(index % size)
        index = index // size
    return coords[::-1]


def sampled_fourth_difference(
    x: Tensor, dim: int, *, where: Tensor | None = None, sample: int = 50_000
) -> Tensor:
    """The values of ``fourth_difference(x, dim)`` (at the ``where`` pixels, a mask on its last two dims:
    ``[..., where]``) that :func:`robust_sd` with ``sample`` takes, computed at those points only: every
    ``n // sample``-th of the ``n`` values, in their order, each from its five samples of ``x``.

    Shape:
        ``x`` ``(..., H, W)``; ``where`` like the difference's last two dims; output ``(m,)``, ``m`` at
        most about ``sample``.
    """
    dim = dim % x.ndim
    shape = list(x.shape)
    shape[dim] -= 4
    if where is None:
        n = math.prod(shape)
        index = torch.arange(0, n, max(1, n // sample), device=x.device)
        coords = _unravel(index, shape)
    else:
        pixels = where.nonzero()  # (P, 2)
        n = math.prod(shape[:-2]) * pixels.shape[0]
        index = torch.arange(0, n, max(1, n // sample), device=x.device)
        lead = _unravel(index // pixels.shape[0], shape[:-2]) if x.ndim > 2 else []
        coords = [*lead, *pixels[index % pixels.shape[0]].unbind(1)]
    steps = [math.prod(x.shape[i + 1 :]) for i in range(x.ndim)]  # row-major, as take() reads
    linear = sum(c * step for c, step in zip(coords, steps, strict=True))
    out = x.take(linear) * _TAPS[0]  # as _taps_sum accumulates
    for i, weight in enumerate(_TAPS[1:], start=1):
        out.add_(x.take(linear + i * steps[dim]), alpha=weight)
    return out


def robust_sd(x: Tensor, *, sample: int | None = 50_000, nonzero: bool = False) -> float:
    """Normal-consistent median absolute deviation of the finite values of ``x`` (0 when there are none),
    over at most ``sample`` evenly spaced values (None: all of them), without exact zeros if ``nonzero``."""
    flat = x.reshape(-1)
    if sample is not None:
        flat = flat[:: max(1, flat.numel() // sample)]
    flat = flat[torch.isfinite(flat) & (flat != 0)] if nonzero else flat[torch.isfinite(flat)]
    if flat.numel() == 0:
        return 0.0
    centre = row_medians(flat[None])
    return float(row_medians((flat - centre).abs()[None])[0]) * _MAD_TO_SD


def _robust_var(x: Tensor) -> float:
    return robust_sd(x) ** 2


@dataclass(frozen=True)
class PixelStats:
    """Each pixel's statistics over time in one video, read once and shared by the artefact search and the
    noise model (:func:`pixel_stats`).

    Attributes:
        mean64: time mean, float64, ``(H, W)``.
        mean: the same in the frames' dtype.
        power: mean square deviation from it, the frames' dtype, ``(H, W)``.
        quiet: the quieter half of the pixels (``power`` at most its median), ``(H, W)`` bool.
    """

    mean64: Tensor
    mean: Tensor
    power: Tensor
    quiet: Tensor


def pixel_stats(frames: Tensor) -> PixelStats:
    """:class:`PixelStats` of finite frames ``(T, H, W)`` (floating): three passes over the video."""
    mean64 = frames.double().mean(0)  # a reduction along T of the copy: faster than one in place
    mean = mean64.to(frames.dtype)
    power = (frames - mean).pow_(2).mean(0)
    return PixelStats(mean64, mean, power, power <= row_medians(power.reshape(1, -1))[0])
