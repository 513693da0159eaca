"""The balance's two terms ``U`` and ``L`` through the 2-D FFT: one time filter and one spectrum for every
smoothing candidate, and the standard error's pushed-back lever without pushing it back.

:func:`spectral_stage` applies the time filters once and transforms the two filtered videos;
:func:`spectral_terms` multiplies the spectra by each candidate's transfer functions and transforms back,
equal to the slice route of :class:`~anra_torch.balance.MatchedFilters` on the cropped pixels, to rounding;
:func:`pushed_norm` gives ``||A^T lever||`` by Parseval without an inverse transform, and :func:`pushed_back`
the pushed-back field where it is needed. Only ``border="crop"`` filters with symmetric kernels, all of the
balance's, go this way. Why and how: ``docs/architecture.md``, section "The balance through the spectra".

Shape:
    Videos ``(B, T, H, W)``; stage spectra ``(B, K, H, W // 2 + 1)``; terms ``(B, K, H - 2m, W - 2m)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

if TYPE_CHECKING:
    from anra_torch.balance.filters import MatchedFilters

__all__ = ["SpectralStage", "pushed_back", "pushed_norm", "spectral_stage", "spectral_terms", "supports"]

_F64 = torch.float64


@dataclass(frozen=True)
class SpectralStage:
    """The time-filtered frames' 2-D spectra, shared by every smoothing candidate.

    Attributes:
        rate: ``rfft2`` of ``D_t T`` (data units per s), ``(B, K, H, W // 2 + 1)`` complex.
        average: ``rfft2`` of ``S_t T``, the same shape.
        size: the frames' ``(H, W)``.
    """

    rate: Tensor
    average: Tensor
    size: tuple[int, int]


def supports(filters: MatchedFilters) -> bool:
    """Whether ``filters`` can run through the spectra: cropping borders everywhere."""
    return filters.smoother.border == "crop" and filters.laplacian.border == "crop"


def spectral_stage(filters: MatchedFilters, frames: Tensor, dt: float | Tensor) -> SpectralStage:
    """``(D_t T, S_t T)`` of centred frames, each transformed once: the stage every candidate shares.

    Shape:
        ``frames`` ``(B, T, H, W)``; spectra ``(B, T - L + 1, H, W // 2 + 1)``.
    """
    rate, average = filters.time.with_average(frames, dt)
    return SpectralStage(torch.fft.rfft2(rate), torch.fft.rfft2(average), tuple(frames.shape[-2:]))


def _wrapped(kernel: Tensor, size: tuple[int, int]) -> Tensor:
    """A centred ``(k, k)`` kernel on a ``size`` grid with its centre at ``(0, 0)`` (circularly)."""
    k = kernel.shape[-1]
    grid = torch.zeros(size, dtype=_F64, device=kernel.device)
    grid[:k, :k] = kernel
    return torch.roll(grid, shifts=(-(k // 2), -(k // 2)), dims=(0, 1))


def _transfer(kernels: list[Tensor], size: tuple[int, int]) -> Tensor:
    """The transfer of a correlation with each kernel in turn, ``(H, W // 2 + 1)`` float64 (real: every
    kernel is symmetric)."""
    out = torch.ones(size[0], size[1] // 2 + 1, dtype=_F64, device="cpu")
    for kernel in kernels:
        out = out * torch.fft.rfft2(_wrapped(kernel, size)).real
    return out


def _transfers(filters: MatchedFilters, like: Tensor, size: tuple[int, int]) -> tuple[Tensor, Tensor]:
    """``(T_U, T_L)`` for unit ``dx``: the transfers of ``P G`` and ``Lap G``, ``(H, W // 2 + 1)`` in
    ``like``'s real dtype on its device, built once per size, device and dtype."""
    dtype = like.real.dtype if like.is_complex() else like.dtype
    key = (size, like.device, dtype)
    cache = filters._spectral
    if key not in cache:
        taps = filters.smoother.taps.detach().to("cpu", _F64)
        gaussian = torch.outer(taps, taps)
        laplacian = filters.laplacian.kernels.detach().to("cpu", _F64)[0]
        partner = filters.laplacian.partner.kernels.detach().to("cpu", _F64)[0]
        for kernel in (gaussian, laplacian, partner):  # the transfers are real only for these
            if not torch.allclose(kernel, kernel.flip(0, 1), rtol=0, atol=1e-12 * float(kernel.abs().max())):
                raise ValueError("the spectral route needs symmetric kernels")
        rate = _transfer([gaussian, partner], size)
        average = _transfer([gaussian, laplacian], size)
        cache[key] = (rate.to(like.device, dtype), average.to(like.device, dtype))
    return cache[key]


def _per_video(spacing: float | Tensor, like: Tensor, dims: int) -> Tensor | float:
    if isinstance(spacing, Tensor):
        return spacing.to(like.real.dtype if like.is_complex() else like.dtype).reshape(-1, *([1] * dims))
    return float(spacing)


def spectral_terms(filters: MatchedFilters, stage: SpectralStage, dx: float | Tensor) -> dict[str, Tensor]:
    """``U = P G D_t T`` (per s) and ``L = Lap G S_t T`` (per mm^2) of one candidate from the shared stage:
    the terms :meth:`MatchedFilters.terms <anra_torch.balance.MatchedFilters.terms>` gives for
    ``("U", "L")``, to rounding.

    Shape:
        ``(B, K, H - 2m, W - 2m)`` each, ``m`` the filters' margin.
    """
    h, w = stage.size
    m = filters.margin
    rate_transfer, average_transfer = _transfers(filters, stage.rate, stage.size)
    scale = _per_video(dx, stage.average, 3)
    rate = _cropped_inverse(stage.rate * rate_transfer, stage.size, m)
    average = _cropped_inverse(stage.average * (average_transfer / scale**2), stage.size, m)
    return {"U": rate, "L": average}


def _cropped_inverse(spectrum: Tensor, size: tuple[int, int], margin: int) -> Tensor:
    """``irfft2(spectrum, s=size)`` cropped by ``margin`` px on every side: the inverse along the rows
    first, then along the columns of the kept rows only (``docs/architecture.md``, "Choices in the hot
    paths")."""
    h, w = size
    rows = torch.fft.ifft(spectrum, dim=-2)[..., margin : h - margin, :]
    return torch.fft.irfft(rows, n=w, dim=-1)[..., margin : w - margin]


def _lever_spectrum(filters: MatchedFilters, lever: Tensor, size: tuple[int, int]) -> Tensor:
    """``rfft2`` of a ``(B, K, h, w)`` lever placed on the crop's interior of ``size`` frames."""
    m = filters.margin
    full = lever.new_zeros(*lever.shape[:-2], *size)
    full[..., m : m + lever.shape[-2], m : m + lever.shape[-1]] = lever
    return torch.fft.rfft2(full)


def pushed_back(
    filters: MatchedFilters,
    lever: Tensor,
    a: Tensor,
    dt: Tensor,
    dx: Tensor,
    size: tuple[int, int],
) -> Tensor:
    """``A_U^T lever - a A_L^T lever`` on the frames: :meth:`MatchedFilters.adjoint
    <anra_torch.balance.MatchedFilters.adjoint>` of ``{"U": lever, "L": -a lever}``, through the spectra.

    Shape:
        ``lever`` ``(B, K, h, w)``; ``a``, ``dt``, ``dx`` ``(B,)``; output ``(B, K + L - 1, H, W)``.
    """
    spectrum = _lever_spectrum(filters, lever, size)
    rate_transfer, average_transfer = _transfers(filters, spectrum, size)
    rate = rate_transfer / _per_video(dt, spectrum, 2)  # (B, H, W')
    average = average_transfer * (-_per_video(a, spectrum, 2) / _per_video(dx, spectrum, 2) ** 2)
    k = spectrum.shape[1]
    taps, pair = filters.time.taps.tolist(), filters.time.pair.tolist()
    out = spectrum.new_zeros(spectrum.shape[0], k + len(taps) - 1, *spectrum.shape[2:])
    for i, (tap, partner) in enumerate(zip(taps, pair, strict=True)):  # the transposed time filters
        if tap or partner:
            out[:, i : i + k].addcmul_(spectrum, (tap * rate + partner * average).unsqueeze(1))
    return torch.fft.irfft2(out, s=size)


def _lag_products(x: Tensor, length: int) -> Tensor:
    """``rho_d = Re sum_s x_s conj(x_{s+d})`` along dim 1 for ``d = 0 .. length - 1``, ``(B, length, ...)``
    (zero where the lag exceeds the frames). Summed over the frames first, real and imaginary parts side by
    side: a reduction over the outer dim of contiguous rows."""
    b, k = x.shape[:2]
    flat = torch.view_as_real(x).reshape(b, k, -1)
    lags = [(flat[:, : k - d] * flat[:, d:]).sum(1) if d < k else flat.new_zeros(b, flat.shape[-1])
            for d in range(length)]  # fmt: skip
    return torch.stack(lags, 1).reshape(b, length, *x.shape[2:], 2).sum(-1)


def _lag_weights(x: Tensor, y: Tensor) -> Tensor:
    """``kappa_d = sum_{|i - j| = d} x_i y_j`` for ``d = 0 .. L - 1``, float64."""
    length = x.numel()
    outer = torch.outer(x, y)
    i = torch.arange(length, device=x.device)
    lag = (i[:, None] - i[None, :]).abs()
    return torch.zeros(length, dtype=_F64, device=x.device).index_add_(0, lag.reshape(-1), outer.reshape(-1))


def pushed_norm(
    filters: MatchedFilters,
    lever: Tensor,
    a: Tensor,
    dt: Tensor,
    dx: Tensor,
    size: tuple[int, int],
    *,
    frames: int | None = None,
) -> Tensor:
    """``||A_U^T lever - a A_L^T lever||^2`` per video by Parseval, without the pushed-back field: what
    :func:`pushed_back`'s sum of squares gives, to rounding; derived in ``docs/architecture.md``. With
    ``frames``, that of a video of ``frames`` output frames whose lever is as stationary as this block's:
    each lag's products scaled from the block's ``K - d`` pairs to the video's ``frames - d``, a pilot's
    estimate.

    Shape:
        ``lever`` ``(B, K, h, w)``; ``a``, ``dt``, ``dx`` ``(B,)``; output ``(B,)`` float64.
    """
    spectrum = _lever_spectrum(filters, lever, size)
    rate_transfer, average_transfer = _transfers(filters, spectrum, size)
    taps = filters.time.taps.detach().to("cpu", _F64)
    pair = filters.time.pair.detach().to("cpu", _F64)
    kappa = torch.stack([_lag_weights(taps, taps), _lag_weights(taps, pair), _lag_weights(pair, pair)], 1).to(
        lever.device
    )  # (L, 3)
    rho = _lag_products(spectrum, taps.numel()).to(_F64)  # (B, L, H, W')
    if frames is not None:
        k, lags = spectrum.shape[1], torch.arange(taps.numel(), dtype=_F64, device=lever.device)
        rho = rho * ((frames - lags) / (k - lags).clamp_min(1)).clamp_min(0).view(1, -1, 1, 1)
    # rfft2 keeps half the columns: the others are the conjugates of columns 1 .. W/2 - 1 (or (W-1)/2).
    h, w = size
    half = torch.full((w // 2 + 1,), 2.0, dtype=_F64, device=lever.device)
    half[0] = 1.0
    if w % 2 == 0:
        half[-1] = 1.0
    p, q = rate_transfer.to(_F64), average_transfer.to(_F64)
    factors = torch.stack([p * p, p * q, q * q]) * half  # (3, H, W')
    sums = torch.einsum("blhw,khw->blk", rho, factors)  # (B, L, 3)
    parts = (sums * kappa).sum(1)  # (B, 3): the U-U, U-L and L-L parts for unit spacing
    dt64, dx64, a64 = (v.detach().to(_F64).reshape(-1) for v in (dt, dx, a))
    total = parts[:, 0] / dt64**2 - 2 * a64 * parts[:, 1] / (dt64 * dx64**2) + a64**2 * parts[:, 2] / dx64**4
    return total / (h * w)
