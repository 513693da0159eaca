"""The windowed loss-rate fit of :class:`anra_torch.tissue.TissueFeatures`, with its standard error.

In a window around each pixel, on the frames after the pixel's peak (cooling: no source acts there in a
heating-then-cooling history), ``U = a L - b R`` is fitted by least squares with the errors-in-variables
correction of ``L`` (:mod:`anra_torch.balance.moments`); ``U`` and ``L`` are the balance's time derivative
and Laplacian, ``R = T - T_0`` the rise of the averaged frames since the first. Where the 2 x 2 system is
ill-conditioned (a single spot cooling: ``L`` follows ``R``) ``a`` is the video's and ``b`` the window's fit
with it. What the balance leaves over the whole video is the source.

The standard error of ``b`` is the measured white noise propagated through the same filters and the
window's normal equations, to first order (:func:`anra_torch.balance.loss_error.loss_rate_error`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance.filters import MatchedFilters
from anra_torch.balance.loss_error import loss_rate_error
from anra_torch.balance.moments import Moments, TermNoise, accumulate

__all__ = ["LossFit", "fit_loss_windows"]

_F64 = torch.float64
_MIN_DECORRELATION = 0.05  # 1 - corr(L, T - T_0)^2 below this: a and b cannot be told apart
_BLOCK_VALUES = 1 << 18  # values per block of the per-pixel sums (2 MiB of float64: stays in the cache)


@dataclass(frozen=True)
class LossFit:
    """Maps of :func:`fit_loss_windows`, each ``(B, H, W)``.

    Attributes:
        loss_rate: ``b`` in 1/s.
        source: ``sum_k (U - a L + b R) dt`` in K, the data's units.
        std_error: standard error of ``b`` in 1/s; inf where the window never cools (``b`` is the
            video's there).
        diffusivity: ``a`` in mm^2/s of the same joint fit on the cooling frames (the video's where the
            window is ill-conditioned): the diffusivity measured where no source acts.
    """

    loss_rate: Tensor
    source: Tensor
    std_error: Tensor
    diffusivity: Tensor


def _solve(
    s_ll: Tensor, s_lt: Tensor, s_tt: Tensor, s_ul: Tensor, s_ut: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Least squares ``U = a L - b R`` from its sums: ``(a, b, well_conditioned)``."""
    det = s_lt * s_lt - s_ll * s_tt  # of [s_ll, -s_lt; s_lt, -s_tt]; <= 0 for a positive semi-definite system
    # -det / (s_ll s_tt) = 1 - corr^2. The noise-corrected sums of a window without signal can make it
    # negative (an indefinite system): such a window is not well conditioned either.
    ok = (s_ll > 0) & (s_tt > 0) & (-det > _MIN_DECORRELATION * s_ll * s_tt)
    safe = torch.where(ok, det, 1.0)
    a = torch.where(ok, (-s_ul * s_tt + s_lt * s_ut) / safe, 0.0)
    b = torch.where(ok, (s_ll * s_ut - s_lt * s_ul) / safe, 0.0)
    return a, b, ok


def _box(x: Tensor, window: int) -> Tensor:
    """Mean over the ``window x window`` px around each pixel (inside the frame), ``(..., H, W)``."""
    flat = x.reshape(-1, 1, *x.shape[-2:])
    pooled = F.avg_pool2d(flat, window, stride=1, padding=window // 2, count_include_pad=False)
    return pooled.reshape(x.shape)


def _sums(moments: Moments) -> tuple[Tensor, ...]:
    c = moments.corrected  # (B, 3, 3, ...): U, L, R
    return c[:, 1, 1], c[:, 1, 2], c[:, 2, 2], c[:, 0, 1], c[:, 0, 2]


def _per_pixel(terms: dict[str, Tensor], weights: Tensor, covariance: Tensor) -> Moments:
    """Each pixel's weighted sums of ``terms`` (``U``, ``L``, ``R``, each ``(B, K, H, W)``) over its frames,
    noise-corrected, as ``(B, 3, 3, H, W)`` moments; in blocks of rows whose products stay in the cache."""
    rate = terms["U"]
    rows = max(1, _BLOCK_VALUES // max(rate.shape[0] * rate.shape[1] * rate.shape[-1], 1))
    blocks = [
        accumulate(
            {name: term[..., r : r + rows, :] for name, term in terms.items()},
            ("U", "L", "R"),
            dims=(1,),
            weights=weights[..., r : r + rows, :],
            noise=TermNoise(covariance),
        )
        for r in range(0, rate.shape[-2], rows)
    ]
    return Moments(
        blocks[0].names, torch.cat([m.raw for m in blocks], 1), torch.cat([m.noise for m in blocks], 1)
    ).map(lambda x: x.movedim((-2, -1), (1, 2)))


def fit_loss_windows(
    filters: MatchedFilters,
    terms: dict[str, Tensor],
    fallback: Tensor,
    noise_sd: Tensor,
    dt: Tensor,
    dx: Tensor,
    *,
    window: int,
) -> LossFit:
    """Loss rate, source and the loss rate's standard error of every ``window`` around each pixel.

    Args:
        filters: the filters ``terms`` were made with (the noise goes through them too).
        terms: ``U``, ``L`` and ``T`` (the averaged frames), each ``(B, K, H, W)``.
        fallback: diffusivity map in mm^2/s whose median is ``a`` where even the whole video's system is
            ill-conditioned, ``(B, H, W)``.
        noise_sd: white noise sd of the frames, ``(B,)``.
        dt: frame period in s, ``(B,)``.
        dx: pixel size in mm, ``(B,)``.
        window: side of the windows (px, odd).

    Returns:
        :class:`LossFit`.

    Shape:
        Terms ``(B, K, H, W)``; maps ``(B, H, W)``.
    """
    rate, lap, average = terms["U"], terms["L"], terms["T"]
    rise = average - average[:, :1]
    k = torch.arange(average.shape[1], device=average.device).view(1, -1, 1, 1)
    cooling = (k > average.argmax(1, keepdim=True)).to(_F64)
    # The noise of U and L (rise's is left uncorrected: it enters b only through its own energy).
    covariance = torch.zeros(len(noise_sd), 3, 3, dtype=_F64, device=noise_sd.device)
    covariance[:, :2, :2] = filters.noise_covariance(("U", "L"), noise_sd**2, dt, dx)
    per_pixel = _per_pixel({"U": rate, "L": lap, "R": rise}, cooling, covariance)
    # Whole video first (the fallback), then each window.
    a_video, b_video, ok_video = _solve(*_sums(per_pixel.map(lambda x: x.sum((-2, -1), keepdim=True))))
    a_video = torch.where(ok_video, a_video, fallback.flatten(1).median(1).values.view(-1, 1, 1))
    b_video = torch.where(ok_video, b_video, 0.0)
    s_ll, s_lt, s_tt, s_ul, s_ut = _sums(per_pixel.map(lambda x: _box(x, window)))
    a, b, ok = _solve(s_ll, s_lt, s_tt, s_ul, s_ut)
    # Ill-conditioned window (a single spot cooling: L follows T - T_0): the video's a, local b.
    b_local = torch.where(s_tt > 0, -(s_ut - a_video * s_lt) / torch.where(s_tt > 0, s_tt, 1.0), b_video)
    a = torch.where(ok, a, a_video.expand_as(a))
    b = torch.where(ok, b, b_local)
    # What the balance leaves, summed over the frames: U - a L + b R, from each term's sum.
    source = (rate.sum(1) - a * lap.sum(1) + b * rise.sum(1)) * dt.view(-1, 1, 1)
    levers = (lap, rise, cooling)
    error = _loss_error(filters, levers, (a, b), ok, (s_ll, s_lt, s_tt), noise_sd, dt, dx, window)
    return LossFit(b, source, error, a)


def _loss_error(
    filters: MatchedFilters,
    levers: tuple[Tensor, Tensor, Tensor],
    fitted: tuple[Tensor, Tensor],
    ok: Tensor,
    normal: tuple[Tensor, Tensor, Tensor],
    noise_sd: Tensor,
    dt: Tensor,
    dx: Tensor,
    window: int,
) -> Tensor:
    """Standard error in 1/s of each window's ``b``, ``(B, H, W)``: inf where the window never cools (or
    where the propagation gives no positive variance).

    A change ``d_L``, ``d_R`` of the window's sums of residual times ``L`` and ``R`` moves ``b`` by
    ``c_L d_L + c_R d_R`` (the 2 x 2 normal equations' inverse; ``-d_R / s_RR`` where ``a`` is the video's);
    :func:`~anra_torch.balance.loss_error.loss_rate_error` propagates the noise into ``d_L``, ``d_R``.
    """
    lap, rise, cooling = levers
    a, b = fitted
    s_ll, s_lt, s_tt = normal
    det = torch.where(ok, s_lt * s_lt - s_ll * s_tt, 1.0)
    c_lap = torch.where(ok, -s_lt / det, 0.0)
    c_rise = torch.where(ok, s_ll / det, -1.0 / torch.where(s_tt > 0, s_tt, 1.0))
    per_dt, per_area = 1.0 / dt.view(-1, 1, 1), 1.0 / dx.view(-1, 1, 1) ** 2
    coefficients = {}
    for name, c in (("L", c_lap), ("R", c_rise)):
        coefficients |= {f"u{name}": c * per_dt, f"z{name}": c * b, f"m{name}": -c * a * per_area}
    unit = loss_rate_error(
        filters, (cooling * lap, cooling * rise), coefficients, torch.ones_like(noise_sd), window
    )
    # A cooling window's error per unit noise is positive; should the propagation's approximation not give it
    # one (not met on the scenes tested), the window counts as unmeasured, like one that never cools.
    return torch.where((s_tt > 0) & (unit > 0), noise_sd.view(-1, 1, 1) * unit, torch.inf)
