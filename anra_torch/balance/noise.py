"""The noise model of the balance: the sensor-noise level estimated from the video itself, and how noise
propagates into the balanced terms and the estimates."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from anra_torch.checks import as_video

__all__ = ["WhiteNoise", "estimate_noise_sd"]

# Fourth difference [1, -4, 6, -4, 1]: annihilates cubics, so smooth thermal fields barely leak in.
_TAPS = (1.0, -4.0, 6.0, -4.0, 1.0)
_GAIN = math.sqrt(sum(t * t for t in _TAPS))  # white-noise gain sqrt(70)
_MAD_TO_SD = 1.0 / 0.6744897501960817


def _fourth_difference(x: Tensor, finite: Tensor, dim: int) -> tuple[Tensor, Tensor]:
    n = x.shape[dim] - 4
    out = sum(t * x.narrow(dim, i, n) for i, t in enumerate(_TAPS))
    ok = finite.narrow(dim, 0, n)
    for i in range(1, 5):
        ok = ok & finite.narrow(dim, i, n)
    return out, ok


def estimate_noise_sd(frames: Tensor, *, mask: Tensor | None = None) -> Tensor:
    """Robust estimate of white sensor noise (units of the data), per video.

    The median absolute fourth difference along x, y and t (each scaled to a standard deviation by the
    filter gain and the normal MAD constant); the median of the three axis estimates is returned, so one
    axis dominated by fast signal (e.g. a slow frame rate) does not inflate it. Non-finite pixels and
    ``mask == False`` pixels are ignored.

    Args:
        frames: video ``(T, H, W)`` or ``(B, T, H, W)``.
        mask: optional boolean, True for usable pixels, same shape as ``frames``.

    Returns:
        Noise standard deviation, shape ``(B,)`` (or a 0-d tensor for a single video).

    Shape:
        ``(B, T, H, W)`` -> ``(B,)``.
    """
    video, batched = as_video(frames, name="frames")
    finite = torch.isfinite(video)
    if mask is not None:
        finite = finite & mask.reshape(video.shape).to(torch.bool)
    clean = torch.where(finite, video, torch.zeros_like(video))
    estimates = []
    for dim in (1, 2, 3):
        if video.shape[dim] < 5:
            continue
        diff, ok = _fourth_difference(clean, finite, dim)
        values = torch.where(ok, diff.abs(), torch.full_like(diff, torch.nan)).flatten(1)
        estimates.append(values.nanmedian(dim=1).values * (_MAD_TO_SD / _GAIN))
    if not estimates:
        raise ValueError(
            f"frames must be at least 5 long along some axis to estimate noise, got {tuple(video.shape)}"
        )
    stacked = torch.stack(estimates, dim=1)
    stacked = torch.nan_to_num(stacked, nan=0.0)
    sd = stacked.median(dim=1).values if stacked.shape[1] != 2 else stacked.mean(dim=1)
    return sd if batched else sd[0]


class WhiteNoise:
    """White sensor noise of standard deviation ``sd`` per video: the balance's noise model.

    The noise of a filtered term at one output point is the sensor noise through the term's impulse
    response ``k``, so two terms' noise parts have the covariance ``sd^2 <k_a, k_b>`` per point
    (:meth:`MatchedFilters.noise_inner <anra_torch.balance.filters.MatchedFilters.noise_inner>`), and a
    linear statistic ``sum x . A(frames)`` has the variance ``sd^2 |A^T x|^2``
    (:meth:`quadratic` of the pushed-back lever ``A^T x``).

    Args:
        sd: noise standard deviation (units of the data), a number or ``(B,)``.

    Shape:
        :attr:`variance` like ``sd``; :meth:`quadratic` ``(P, N) -> (P, P)``.
    """

    def __init__(self, sd: float | Tensor) -> None:
        self.sd = sd

    @property
    def variance(self) -> float | Tensor:
        """``sd^2`` (data units squared)."""
        return self.sd**2

    def quadratic(self, backs: Tensor) -> Tensor:
        """``Cov(<b_i, n>, <b_j, n>) = sd^2 <b_i, b_j>`` for pushed-back levers ``b`` (rows)."""
        return self.variance * (backs @ backs.T)
