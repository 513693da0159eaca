"""A smoothing candidate's sums, and the choice among the candidates: on every frame, or on a pilot.

Smoothing does not bias the estimate (it acts on both sides of the balance), so each video takes the
candidate whose noise-propagated standard error is smallest among the measurable ones.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import torch
from torch import Tensor

from anra_torch.balance import BatchNoise, MatchedFilters, SpectralStage, pushed_back
from anra_torch.checks import MIN_RELIABILITY, MIN_SIGNIFICANCE

__all__ = [
    "Candidate",
    "ErrorPass",
    "choose",
    "explained_of",
    "lsq_error",
    "pilot_contenders",
    "ratio_sums",
    "reliability_of",
    "windowed_field",
]

_PILOT_SHARE = 6  # the pilot that chooses the smoothing holds one output frame in this many ...
_PILOT_MIN = 3  # ... and at least this many
_PILOT_BLOCKS = 2  # ... in this many blocks of consecutive frames
_PILOT_MARGIN = 1.03
"""Smoothing candidates whose pilot standard error is within this factor of the smallest are computed on
every frame, and the smallest there wins: the pilot's extrapolation errs by a few per cent on videos whose
signal changes fast, and near ties then decide on the whole video, as without a pilot."""


def reliability_of(den: Tensor, energy: Tensor) -> Tensor:
    """Fraction of the regressor energy that is signal (0 where there is no energy)."""
    return torch.where(energy > 0, den / energy.clamp_min(1e-300), torch.zeros_like(den))


@dataclass
class Candidate:
    """Sums for one smoothing level, all batched over videos."""

    def estimate(self, mode: str) -> Tensor:
        """Global estimate per video, ``(B,)``."""
        if mode == "ratio":
            return self.ratio.mean(1)
        total = self.den.sum(1)
        return self.num.sum(1) / torch.where(total == 0, torch.ones_like(total), total)

    def measurable(self, mode: str) -> Tensor:
        """Signal clearly above the noise: enough signal energy and (lsq) an estimate >= 3 standard errors.

        The paper's ratio estimator has no such test: it is reported as it comes out.
        """
        enough = reliability_of(self.den.sum(1), self.energy.sum(1)) >= MIN_RELIABILITY
        if mode == "ratio":
            return enough
        return enough & (self.estimate(mode).abs() >= MIN_SIGNIFICANCE * self.std_error)

    rate_energy: Tensor  # (B, K) sum_ij w U^2 - variance correction
    num: Tensor  # (B, K) sum_ij w U L - covariance correction
    den: Tensor  # (B, K) sum_ij w L^2 - variance correction
    energy: Tensor  # (B, K) sum_ij w L^2
    ratio: Tensor  # (B, K) paper's sum_ij w U / L
    std_error: Tensor  # (B,)
    spread: Tensor  # (B,) sd of the noise part of sum w (U - a L) L: std_error's numerator, NaN unless asked
    back: Tensor | None  # (B, T, H, W) the lever pushed back (candidate_sums' back_at), else None
    field_num: Tensor | None  # (B, H, W)
    field_den: Tensor | None
    field_energy: Tensor | None


@dataclass(frozen=True)
class ErrorPass:
    """What :meth:`~anra_torch.estimation.ANRAEstimator.candidate_sums` computes of the standard error.

    Attributes:
        with_error: the least-squares standard error (an adjoint pass); False leaves it NaN.
        back_at: ``a`` per video ``(B,)``: the noise lever pushed back onto the frames at that ``a`` is
            returned in ``back`` instead (:mod:`anra_torch.estimation.chunked` adds it up over chunks).
        frames: the spread of a video of this many output frames whose lever is as stationary as the
            batch's (a pilot's estimate), instead of the batch's own.
    """

    with_error: bool = True
    back_at: Tensor | None = None
    frames: int | None = None


def lsq_error(
    filters: MatchedFilters,
    stage: SpectralStage,
    noise: BatchNoise,
    lever: Tensor,
    sums: tuple[Tensor, Tensor, Tensor],
    dt: Tensor,
    dx: Tensor,
    back_at: Tensor | None,
    frames: int | None,
    dtype: torch.dtype,
) -> tuple[Tensor, Tensor, Tensor | None]:
    """The least-squares estimate's standard error ``(B,)``, its numerator ``spread`` ``(B,)`` and, with
    ``back_at``, the lever pushed back onto the frames (see
    :meth:`~anra_torch.estimation.ANRAEstimator.candidate_sums`).

    ``lever`` is ``w L`` after the fixed effects ``(B, K, H', W')``; ``sums`` the per-frame ``(num, den,
    energy)``, each ``(B, K)``; ``dtype`` the terms' dtype."""
    num, den, energy = sums
    spread = torch.full_like(num[:, 0], torch.nan)
    back = None
    total = den.sum(1)
    estimate = num.sum(1) / torch.where(total == 0, torch.ones_like(total), total)
    # Sandwich for one regressor: sd |A^T (w L)| / |sum w (L^2 - var)|.
    a = (estimate if back_at is None else back_at.to(estimate)).detach()
    pushed = (filters, lever, a, dt.detach(), dx.detach(), stage.size)
    if back_at is None:  # Parseval: the spread without the pushed-back field
        spread = noise.pushed_spread(*pushed, frames=frames)
    else:
        back = pushed_back(*pushed)
    std_error = spread / total.abs().clamp_min(torch.finfo(dtype).tiny)
    # The correction's own error: the measured noise variance is known to a relative error.
    correction = (energy - den).sum(1) * noise.variance_error.to(dtype)
    std_error = torch.hypot(std_error, estimate.detach() * correction / total.abs().clamp_min(1e-300))
    return std_error, spread, back


def ratio_sums(rate: Tensor, lap: Tensor, weights: Tensor) -> Tensor:
    """The paper's weighted sums of pointwise ratios ``sum w U / L`` per frame, ``(B, K)`` (0 where
    ``L = 0``)."""
    safe_lap = torch.where(lap == 0, torch.ones_like(lap), lap)
    return torch.where(lap == 0, torch.zeros_like(lap), weights * rate / safe_lap).sum((-2, -1))


def choose(
    candidates: list[Candidate], mode: str, allowed: Tensor | None = None
) -> tuple[Candidate, Tensor, Tensor]:
    """Per video, the candidate with the smallest standard error among the measurable ones (and those
    ``allowed``, ``(B, C)``, where given): its sums, whether it is measurable ``(B,)`` and its index
    ``(B,)``."""
    # A candidate without measurable signal (e.g. all of its pixels masked) must not win on a zero error.
    measurable = torch.stack([c.measurable(mode) for c in candidates], dim=1)
    errors = torch.stack([c.std_error for c in candidates], dim=1)  # (B, C)
    errors = torch.where(measurable, torch.nan_to_num(errors, nan=torch.inf), torch.inf)
    if allowed is not None:
        errors = torch.where(allowed, errors, torch.inf)
    choice = errors.argmin(dim=1)
    b = choice.shape[0]

    def pick(name: str) -> Tensor | None:
        if getattr(candidates[0], name) is None:
            return None
        stacked = torch.stack([getattr(c, name) for c in candidates], dim=1)
        index = choice.view(b, *([1] * (stacked.ndim - 1))).expand(b, 1, *stacked.shape[2:])
        return stacked.gather(1, index).squeeze(1)

    chosen = Candidate(**{f.name: pick(f.name) for f in fields(Candidate)})
    return chosen, measurable.gather(1, choice[:, None])[:, 0], choice


def pilot_contenders(
    sums_of: Callable[..., Candidate],
    length: int,
    rate: Tensor,
    average: Tensor,
    good: Tensor | None,
    dt: Tensor,
    dx: Tensor,
    noise: BatchNoise,
    usable: list[int],
) -> Tensor | None:
    """Per video, the smoothing candidates (``(B, len(usable))`` bool) worth computing on every frame of an
    ``"lsq"`` estimate (its filters' time length ``length``, its candidate sums ``sums_of(index, ...)``):
    those whose standard error on a pilot of the time-filtered frames ``rate``, ``average``
    (``(B, K, H, W)``) is within :data:`_PILOT_MARGIN` of the smallest.

    The pilot is :data:`_PILOT_BLOCKS` blocks of consecutive output frames spread over the video, one
    frame in :data:`_PILOT_SHARE` in all. Each block's noise norm is extrapolated lag by lag to the
    frames it stands for (:func:`~anra_torch.balance.spectral.pushed_norm`), so that the block's ends
    (where the time derivative's noise does not cancel) weigh as little as the video's do. None where no
    pilot applies: one candidate, too few frames, fixed effects or correlated noise, nothing measured.
    """
    b, k, h, w = rate.shape
    n = _PILOT_BLOCKS
    m = max(_PILOT_MIN, -(-k // (_PILOT_SHARE * n)))  # consecutive output frames per block
    if len(usable) < 2 or k < 2 * m * n or any(map(noise.special, range(b))):
        return None
    starts = torch.linspace(0, k - m, n + 2, device="cpu").round().long().tolist()[1:-1]

    def blocks(x: Tensor, size: int) -> Tensor:  # each video's blocks as videos of their own
        return torch.stack([x[:, i : i + size] for i in starts], 1).reshape(b * n, size, *x.shape[2:])

    stage = SpectralStage(torch.fft.rfft2(blocks(rate, m)), torch.fft.rfft2(blocks(average, m)), (h, w))
    finite = None if good is None else blocks(good, m + length - 1)
    pilot_noise = BatchNoise(
        rate.new_zeros(0),
        noise.sd.repeat_interleave(n),
        tuple(model for model in noise.models for _ in range(n)),
        noise.pixel.repeat_interleave(n),
        noise.frame.repeat_interleave(n),
        tuple(a for a in noise.artefacts for _ in range(n)),
    )
    spacing = (dt.repeat_interleave(n), dx.repeat_interleave(n))
    scale, variance_error = k / (n * m), noise.variance_error.cpu()
    variances = []
    for i in usable:
        sums = sums_of(i, rate, finite, *spacing, pilot_noise, stage=stage, error=ErrorPass(frames=k / n))
        totals = (x.double().reshape(b, -1).sum(1).cpu() for x in (sums.num, sums.den, sums.energy))
        num, den, energy = totals
        noise_var = sums.spread.double().pow(2).reshape(b, n).sum(1).cpu()  # the whole video's
        safe = torch.where(den > 0, den, torch.ones_like(den))
        correction = (energy - den) * variance_error * num / safe
        variance = torch.where(den > 0, (noise_var / scale**2 + correction**2) / safe**2, torch.inf)
        significant = (num / safe).abs() >= MIN_SIGNIFICANCE * variance.sqrt()
        variances.append(torch.where((den > MIN_RELIABILITY * energy) & significant, variance, torch.inf))
    stacked = torch.stack(variances, 1)  # (B, C)
    best = stacked.amin(1, keepdim=True)
    if not bool(torch.isfinite(best).all()):
        return None
    return stacked <= best * _PILOT_MARGIN**2


def windowed_field(chosen: Candidate) -> tuple[Tensor, Tensor]:
    """The windowed diffusivity (NaN where unmeasurable) and its confidence, both ``(B, H, W)``."""
    f_num, f_den, f_energy = chosen.field_num, chosen.field_den, chosen.field_energy
    assert f_num is not None and f_den is not None and f_energy is not None
    confidence = torch.where(
        f_energy > 0, (f_den / f_energy.clamp_min(1e-300)).clamp(0, 1), torch.zeros_like(f_den)
    )
    ok = (confidence > MIN_RELIABILITY) & (f_den > 0)
    source = f_num / torch.where(ok, f_den, torch.ones_like(f_den))
    field = torch.where(ok, source, torch.full_like(source, torch.nan))
    return field, torch.where(ok, confidence, torch.zeros_like(confidence))


def explained_of(chosen: Candidate) -> Tensor:
    """The noise-corrected ``R^2`` of ``U = a L`` at the least-squares ``a``: ``(sum U L)^2 / (sum L^2 sum
    U^2)`` over the weighted, corrected sums, in [0, 1] (0 where ``dT/dt`` has no energy above the noise)."""
    uu, ul, ll = chosen.rate_energy.sum(1), chosen.num.sum(1), chosen.den.sum(1)
    ok = (uu > 0) & (ll > 0)
    share = ul * ul / torch.where(ok, uu * ll, torch.ones_like(uu))
    return torch.where(ok, share.clamp(0.0, 1.0), torch.zeros_like(uu))
