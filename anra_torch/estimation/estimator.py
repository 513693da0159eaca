"""The ANRA estimator: thermal diffusivity straight from video, without solving the PDE.

For ``dT/dt = a (d11 + d22) T`` the estimator balances the PDE on the measured frames. Both sides see the
same filters, so the balance stays exact for the filtered field:

* the Holoborodko time derivative ``D_t`` (one Conv3d) for the left side, and the derivative's own
  temporal partner ``S_t`` (same centre: no time misalignment) for the right side;
* spatial Gaussian smoothing ``G`` (sigma in px) of both, then the Laplacian of the right side;
* per-pixel weights ``w`` (RTC attention or uniform);
* ``mode="lsq"``: weighted least squares ``a = sum w (U L - c) / sum w (L^2 - v)`` where ``v`` is the noise
  variance that the Laplacian passes and ``c`` the noise covariance of U and L (errors-in-variables
  correction, with the noise level estimated from the video), plus a Stein correction when the weights
  depend on the noisy U; or ``mode="ratio"``: the paper's weighted average of pointwise ratios ``U / L``.

With several smoothing candidates (``smoothing="auto"``) each video takes the one whose noise-propagated
standard error is smallest: smoothing does not bias the estimate (it acts on both sides), so the least
noisy choice is the best one. The standard error is exact for white noise: it pushes the estimator's
residual weights back through the transposed filters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from anra_torch.balance import (
    BatchNoise,
    MatchedFilters,
    PreparedBatch,
    SpectralStage,
    TermNoise,
    accumulate,
    prepare_batch,
    pushed_back,
    spectral_stage,
    spectral_terms,
)
from anra_torch.checks import (
    MIN_RELIABILITY,
    MIN_SIGNIFICANCE,
    POOR_FIT,
    as_spacing,
    as_video,
    poor_fit,
    verdicts,
)
from anra_torch.estimation.result import ANRAResult, concat_results
from anra_torch.layers import RTCAttention, UniformAttention

__all__ = ["ANRAEstimator", "ANRAResult", "MODES", "AUTO_SMOOTHING", "POOR_FIT"]

MODES = ("lsq", "ratio")
AUTO_SMOOTHING: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0)
"""Spatial smoothing candidates (px) tried by ``smoothing="auto"``."""

_MIN_VALID_PX = 8  # a candidate smoothing must leave at least this many pixels per side
_PILOT_SHARE = 6  # the pilot that chooses the smoothing holds one output frame in this many ...
_PILOT_MIN = 3  # ... and at least this many
_PILOT_BLOCKS = 2  # ... in this many blocks of consecutive frames
_PILOT_MARGIN = 1.03
"""Smoothing candidates whose pilot standard error is within this factor of the smallest are computed on
every frame, and the smallest there wins: the pilot's extrapolation errs by a few per cent on videos whose
signal changes fast (measured up to 25 % on a blob decaying within its 60 frames), and near ties then
decide on the whole video, as without a pilot."""


_NAMES = ("U", "L")  # the plain balance dT/dt = a Lap T


_SLICE_ELEMENTS = 2**21  # pixel values per slice of a batch (8 MiB in float32): keeps the work in cache

_NO_FINITE = "no finite frame: every sample is NaN, infinite or a dead element; no diffusivity estimated"


def _reliability(den: Tensor, energy: Tensor) -> Tensor:
    """Fraction of the regressor energy that is signal (0 where there is no energy)."""
    return torch.where(energy > 0, den / energy.clamp_min(1e-300), torch.zeros_like(den))


@dataclass
class _Candidate:
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
        enough = _reliability(self.den.sum(1), self.energy.sum(1)) >= MIN_RELIABILITY
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


class ANRAEstimator(nn.Module):
    """Attention-based noise-robust averaging estimator of the thermal diffusivity.

    Args:
        mode: ``"lsq"`` (weighted least squares with the errors-in-variables correction; default) or
            ``"ratio"`` (the paper's RTC-weighted average of ``dT/dt / Laplacian``, kept as published).
        smoothing: spatial Gaussian sigma in px, a sequence of candidates, or ``"auto"``
            (:data:`AUTO_SMOOTHING`); with several candidates each video takes the one with the smallest
            standard error. Default: ``"auto"`` for ``"lsq"``, 0 (as published) for ``"ratio"``.
        time_family: Holoborodko time family (``"smooth"``, ``"centred"``, ``"hybrid"``).
        time_length: time window length in frames.
        laplacian_size: spatial kernel size (3, 5, 7, 9, 11).
        laplacian_family: default ``"central"`` for ``"lsq"``, ``"holoborodko"`` (as published) for
            ``"ratio"``. ``"central"`` (maximal order: after Gaussian smoothing, accuracy at low
            wavenumbers is what matters) or ``"holoborodko"`` (its built-in binomial smoothing is applied
            to dT/dt as well, so it reads like the 5-point Laplacian of the smoothed field).
        attention: per-pixel weighting with ``with_slope(rate, mask)``. Default: for ``"ratio"`` the paper's
            :class:`RTCAttention`; for ``"lsq"`` :class:`UniformAttention`, because equal weights are the
            best linear unbiased choice for white noise and measured better (RTC weights are computed from
            the same noisy dT/dt they multiply: Stein's identity removes the bias this causes, but the
            variance stays higher; see experiments/paper_simulation.py).
        eiv_correction: subtract the noise variance from the Laplacian energy (lsq mode).
        noise_sd: known noise standard deviation (units of the data); default estimated per video.
        window: side (px, odd) of the windowed diffusivity field; None skips the field.
        strict: raise ``ValueError`` when a video shows no measurable thermal activity; otherwise
            return it flagged (``valid`` False, NaN diffusivity, a message). A video of a batch without a
            finite sample (a failed read, padding) is flagged either way ("no finite frame"): it holds no
            measurement to be strict about, and the others' estimates stand.
        pilot: choose among several smoothing candidates on a pilot of the frames (:meth:`_pilot`): only
            the pilot's best and its near ties are computed on every frame. Faster by about one candidate,
            but where the pilot misjudges a candidate beyond its margin (a scene that changes fast, or a
            source that moves) the choice differs from the one made on every frame (the default).

    Shape:
        ``frames`` ``(B, T, H, W)`` or ``(T, H, W)``; ``dt`` (s) and ``dx`` (mm/px) floats or ``(B,)``.

    Example:
        >>> from anra_torch.simulation import gaussian_blob
        >>> t = torch.arange(12) / 27.0
        >>> video = gaussian_blob(t, shape=(48, 48), dx=0.1, a=0.2, peak=3.0, sigma=1.0)
        >>> est = ANRAEstimator(smoothing=1.0)(video, dt=1 / 27, dx=0.1)
        >>> round(float(est.diffusivity), 3)
        0.2
    """

    def __init__(
        self,
        *,
        mode: str = "lsq",
        smoothing: float | Sequence[float] | str | None = None,
        time_family: str = "smooth",
        time_length: int = 5,
        laplacian_size: int = 5,
        laplacian_family: str | None = None,
        attention: nn.Module | None = None,
        eiv_correction: bool = True,
        noise_sd: float | None = None,
        window: int | None = None,
        strict: bool = True,
        pilot: bool = False,
    ) -> None:
        super().__init__()
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r}; expected one of: {', '.join(MODES)}")
        if smoothing is None:
            smoothing = "auto" if mode == "lsq" else 0.0
        if laplacian_family is None:
            laplacian_family = "central" if mode == "lsq" else "holoborodko"
        if isinstance(smoothing, str):
            if smoothing != "auto":
                raise ValueError(f"smoothing must be a sigma in px, a sequence or 'auto', got {smoothing!r}")
            sigmas = AUTO_SMOOTHING
        elif isinstance(smoothing, int | float):
            sigmas = (float(smoothing),)
        else:
            sigmas = tuple(float(s) for s in smoothing)
        if not sigmas:
            raise ValueError("smoothing needs at least one candidate sigma, got an empty sequence")
        if window is not None and (window < 1 or window % 2 == 0):
            raise ValueError(f"window must be an odd number of pixels >= 1, got {window!r}")
        if noise_sd is not None and not (noise_sd >= 0):
            raise ValueError(f"noise_sd must be >= 0 (units of the data), got {noise_sd!r}")
        self.mode = mode
        self.eiv_correction = eiv_correction
        self.noise_sd = noise_sd
        self.window = window
        self.strict = strict
        self.pilot = pilot
        # One set of matched filters per smoothing candidate; they share the time filter and Laplacian.
        self.filters = nn.ModuleList(
            MatchedFilters(
                s,
                time_family=time_family,
                time_length=time_length,
                laplacian_size=laplacian_size,
                laplacian_family=laplacian_family,
            )
            for s in sigmas
        )
        self.time = self.filters[0].time
        self.laplacian = self.filters[0].laplacian
        if attention is None:
            attention = UniformAttention() if mode == "lsq" else RTCAttention()
        if not hasattr(attention, "with_slope"):
            raise TypeError(
                "attention must provide with_slope(rate, mask) like RTCAttention, "
                f"got {type(attention).__name__}"
            )
        self.attention = attention

    @property
    def sigmas(self) -> tuple[float, ...]:
        """Spatial smoothing candidates (px)."""
        return tuple(f.sigma for f in self.filters)

    @property
    def minimum_frame_size(self) -> int:
        """The smallest frame side (px) these filters accept: the least wide candidate's margins plus the
        least valid interior."""
        return min(2 * f.margin for f in self.filters) + _MIN_VALID_PX

    def usable(self, height: int, width: int) -> list[int]:
        """The smoothing candidates (indices) whose filters leave enough of a ``height`` x ``width`` frame.

        Raises:
            ValueError: no candidate fits (the frame is smaller than :attr:`minimum_frame_size`).
        """
        usable = [i for i, f in enumerate(self.filters) if min(height, width) - 2 * f.margin >= _MIN_VALID_PX]
        if not usable:
            need = self.minimum_frame_size
            raise ValueError(
                f"frames must be at least {need} x {need} px for these filters, got {height} x {width}"
            )
        return usable

    def _valid_mask(self, finite: Tensor, margin: int) -> Tensor:
        """True where the whole filter support of an output pixel is finite; ``(B, K, H'', W'')``."""
        bad = (~finite).to(torch.float32).unsqueeze(1)
        k = 2 * margin + 1
        bad = F.max_pool3d(bad, (self.time.length, 1, 1), stride=1)
        bad = F.max_pool3d(bad, (1, k, 1), stride=1)
        bad = F.max_pool3d(bad, (1, 1, k), stride=1)
        return bad.squeeze(1) == 0

    def candidate_sums(
        self,
        index: int,
        video: Tensor,
        finite: Tensor | None,
        dt: Tensor,
        dx: Tensor,
        noise: BatchNoise,
        *,
        with_error: bool = True,
        back_at: Tensor | None = None,
        stage: SpectralStage | None = None,
        frames: int | None = None,
    ) -> _Candidate:
        """The sums of smoothing candidate ``index`` over a centred ``(B, T, H, W)`` batch.

        Without ``with_error`` the standard error is NaN (no adjoint pass); with ``back_at`` (``a`` per
        video, ``(B,)``) the noise lever pushed back onto the frames at that ``a`` is returned in ``back``
        instead (:mod:`anra_torch.estimation.chunked` adds it up over chunks). The terms come through the
        frames' spectra (:mod:`anra_torch.balance.spectral`): ``stage``, the batch's time-filtered
        spectra, is shared by every candidate (computed here when None)."""
        filters = self.filters[index]
        stage = spectral_stage(filters, video, dt) if stage is None else stage
        terms = spectral_terms(filters, stage, dx)
        terms = {k: noise.fixed_effects(v) for k, v in terms.items()}
        rate, lap = terms["U"], terms["L"]
        valid = None if finite is None or bool(finite.all()) else self._valid_mask(finite, filters.margin)
        weights, slope = self.attention.with_slope(rate, valid)
        term_noise = None
        if self.eiv_correction and self.mode == "lsq":
            covariance = noise.covariance(filters, _NAMES, dt, dx, rate.shape[1:]).to(rate.dtype)
            term_noise = TermNoise(covariance, slope=slope)  # Stein: noisy weights inflate sum(w U L)
        per_frame = accumulate(terms, _NAMES, dims=(-2, -1), weights=weights, noise=term_noise)
        rate_energy, num, den, energy = (
            per_frame.corrected[..., 0, 0],
            per_frame.corrected[..., 0, 1],
            per_frame.corrected[..., 1, 1],
            per_frame.raw[..., 1, 1],
        )
        if self.mode == "ratio":  # the paper's pointwise ratios; lsq never needs them
            safe_lap = torch.where(lap == 0, torch.ones_like(lap), lap)
            ratio = torch.where(lap == 0, torch.zeros_like(lap), weights * rate / safe_lap).sum((-2, -1))
        else:
            ratio = torch.zeros_like(num)
        spread = torch.full_like(num[:, 0], torch.nan)
        back = None
        if self.mode == "lsq" and not with_error and back_at is None:
            std_error = spread
        elif self.mode == "lsq":
            total = den.sum(1)
            estimate = num.sum(1) / torch.where(total == 0, torch.ones_like(total), total)
            # Sandwich for one regressor: sd |A^T (w L)| / |sum w (L^2 - var)|.
            lever = noise.fixed_effects((weights * lap).detach())  # the projection is its own transpose
            a = (estimate if back_at is None else back_at.to(estimate)).detach()
            pushed = (filters, lever, a, dt.detach(), dx.detach(), stage.size)
            if back_at is None:  # Parseval: the spread without the pushed-back field
                spread = noise.pushed_spread(*pushed, frames=frames)
            else:
                back = pushed_back(*pushed)
            std_error = spread / total.abs().clamp_min(torch.finfo(rate.dtype).tiny)
            # The correction's own error: the measured noise variance is known to a relative error.
            correction = (energy - den).sum(1) * noise.variance_error.to(rate.dtype)
            std_error = torch.hypot(std_error, estimate.detach() * correction / total.abs().clamp_min(1e-300))
        else:
            spread = ratio.std(dim=1) if ratio.shape[1] > 1 else ratio.abs()[:, 0]
            std_error = spread / ratio.shape[1] ** 0.5
        maps = (None, None, None)
        if self.window is not None:
            field = accumulate(
                terms, _NAMES, reduce=lambda x: self._box(x.sum(1)), weights=weights, noise=term_noise
            )
            maps = tuple(
                self._to_frame(m, filters.margin)
                for m in (field.corrected[..., 0, 1], field.corrected[..., 1, 1], field.raw[..., 1, 1])
            )
        back = back if back_at is not None else None
        return _Candidate(rate_energy, num, den, energy, ratio, std_error, spread, back, *maps)

    def _box(self, m: Tensor) -> Tensor:
        w = self.window
        return F.avg_pool2d(m.unsqueeze(1), w, stride=1, padding=w // 2).squeeze(1) * (w * w)

    @staticmethod
    def _to_frame(m: Tensor, margin: int) -> Tensor:
        """Pad a valid-region map back to the input frame size (zeros outside)."""
        return F.pad(m, (margin, margin, margin, margin)) if margin else m

    # -------------------------------------------------------------------------------- forward
    def forward(
        self,
        frames: Tensor,
        dt: float | Tensor,
        dx: float | Tensor,
        *,
        prepared: PreparedBatch | None = None,
    ) -> ANRAResult:
        """Estimate the diffusivity of each video.

        Args:
            frames: temperatures (any linear unit), ``(T, H, W)`` or ``(B, T, H, W)``; integer counts are
                converted to floats; non-finite pixels, and up to 1 % of pixels that are exactly constant
                in every frame (dead elements), are masked and counted in ``n_masked``.
            dt: frame period in s, float or ``(B,)``.
            dx: pixel size in mm, float or ``(B,)``.
            prepared: ``frames`` as :func:`~anra_torch.balance.prepare_batch` measured them already (their
                artefacts, noise and masks), where the caller has it: nothing is measured again.

        Returns:
            :class:`ANRAResult` (unbatched for a single ``(T, H, W)`` video).

        Raises:
            ValueError: bad shapes or spacings, too few frames or pixels for the filters, or (with
                ``strict``) a video without measurable thermal activity.
        """
        video, batched = as_video(frames, min_frames=self.time.length)
        b = video.shape[0]
        dt_ = as_spacing(dt, name="dt", unit="s", batch=b, like=video)
        dx_ = as_spacing(dx, name="dx", unit="mm", batch=b, like=video)
        # Videos are independent: a batch too big for the caches runs in slices of whole videos (on CPU a
        # 32 x 224 x 224 x 28 batch in one piece was measured ~3x slower per video than one at a time).
        step = max(1, _SLICE_ELEMENTS // video[0].numel()) if prepared is None else b
        if prepared is not None and tuple(prepared.video.shape) != tuple(video.shape):
            raise ValueError(
                f"prepared must be of these frames, of shape {tuple(video.shape)}, "
                f"got {tuple(prepared.video.shape)}"
            )
        parts = [
            self._estimate(video[i : i + step], dt_[i : i + step], dx_[i : i + step], prepared)
            for i in range(0, b, step)
        ]
        result = parts[0] if len(parts) == 1 else concat_results(parts)
        empty = result.n_masked >= video[0].numel()  # nothing finite to measure: said so per video
        if bool(empty.any()):
            flagged = zip(result.messages, empty.tolist(), strict=True)
            result = replace(result, messages=tuple(_NO_FINITE if e else m for m, e in flagged))
        refused = ~result.valid & (~empty if batched and not bool(empty.all()) else True)
        if self.strict and bool(refused.any()):
            bad = int(refused.nonzero()[0])
            where = f"video {bad}: " if batched else ""
            raise ValueError(f"{where}{result.messages[bad]}")
        return result if batched else result.unbatched()

    def _estimate(
        self, video: Tensor, dt_: Tensor, dx_: Tensor, prepared: PreparedBatch | None = None
    ) -> ANRAResult:
        """:meth:`forward` on a checked ``(B, T, H, W)`` batch with ``(B,)`` spacings; never raises on
        videos without activity (they come back flagged)."""
        b, t, h, w = video.shape
        prepared = prepare_batch(video, noise_sd=self.noise_sd) if prepared is None else prepared
        video, good, noise = prepared.video, prepared.good, prepared.noise
        noise_sd = noise.sd
        usable = self.usable(h, w)
        rate, average = self.time.with_average(video, dt_)  # one time filter for every candidate
        contenders = self._pilot(rate, average, good, dt_, dx_, noise, usable) if self.pilot else None
        stage = SpectralStage(torch.fft.rfft2(rate), torch.fft.rfft2(average), (h, w))
        del rate, average
        if contenders is None:  # every candidate on every frame
            contenders = torch.ones(b, len(usable), dtype=torch.bool, device="cpu")
        picked = contenders.any(0).nonzero()[:, 0].tolist()
        candidates = [
            self.candidate_sums(usable[i], video, good, dt_, dx_, noise, stage=stage) for i in picked
        ]
        chosen, measured, position = self._choose(candidates, contenders[:, picked].to(video.device))
        choice = torch.tensor(picked, device=video.device)[position]
        if not bool(measured.all()) and len(picked) < len(usable):  # the pilot missed: all of them
            candidates = [self.candidate_sums(i, video, good, dt_, dx_, noise, stage=stage) for i in usable]
            chosen, measured, choice = self._choose(candidates)
        num, den, energy, ratio = chosen.num, chosen.den, chosen.energy, chosen.ratio
        total_den = den.sum(1)
        reliability = _reliability(total_den, energy.sum(1))
        if self.mode == "lsq":
            per_frame = num / torch.where(den == 0, torch.ones_like(den), den)
            per_frame = torch.where(den == 0, torch.zeros_like(per_frame), per_frame)
            estimate = num.sum(1) / torch.where(total_den == 0, torch.ones_like(total_den), total_den)
        else:
            per_frame, estimate = ratio, ratio.mean(1)
        changing = prepared.changing
        valid = changing & measured & torch.isfinite(estimate)
        explained = _explained(chosen) if self.mode == "lsq" else torch.full_like(estimate, torch.nan)
        messages, warnings = verdicts(valid, changing, reliability, estimate, chosen.std_error, dt_, dx_)
        rows = zip(warnings, explained.tolist(), valid.tolist(), strict=True)
        warnings = tuple(w + poor_fit(e) if ok else w for w, e, ok in rows)
        field, confidence = self._field(chosen) if self.window is not None else (None, None)
        nan = torch.full_like(estimate, torch.nan)
        k = torch.arange(per_frame.shape[1], dtype=video.dtype, device=video.device)
        sigmas = torch.tensor([self.filters[i].sigma for i in usable], dtype=video.dtype, device=video.device)
        return ANRAResult(
            diffusivity=torch.where(valid, estimate, nan),
            std_error=torch.where(valid, chosen.std_error, nan),
            per_frame=per_frame,
            frame_times=(k + self.time.centre).unsqueeze(0) * dt_.unsqueeze(1),
            noise_sd=noise_sd,
            smoothing=sigmas[choice],
            reliability=reliability,
            explained=explained,
            valid=valid,
            n_masked=prepared.masked,
            field=field,
            confidence=confidence,
            messages=messages,
            warnings=warnings,
            noise=tuple(
                m.describe() | {"sd": float(sd)} for m, sd in zip(noise.models, noise_sd, strict=True)
            ),
            artefacts=tuple(a.to_record() for a in noise.artefacts),
        )

    def _choose(
        self, candidates: list[_Candidate], allowed: Tensor | None = None
    ) -> tuple[_Candidate, Tensor, Tensor]:
        """Per video, the candidate with the smallest standard error among the measurable ones (and those
        ``allowed``, ``(B, C)``, where given): its sums, whether it is measurable ``(B,)`` and its index
        ``(B,)``."""
        # A candidate without measurable signal (e.g. all of its pixels masked) must not win on a zero error.
        measurable = torch.stack([c.measurable(self.mode) for c in candidates], dim=1)
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

        chosen = _Candidate(**{f.name: pick(f.name) for f in fields(_Candidate)})
        return chosen, measurable.gather(1, choice[:, None])[:, 0], choice

    def _pilot(
        self,
        rate: Tensor,
        average: Tensor,
        good: Tensor | None,
        dt: Tensor,
        dx: Tensor,
        noise: BatchNoise,
        usable: list[int],
    ) -> Tensor | None:
        """Per video, the smoothing candidates (``(B, len(usable))`` bool) worth computing on every frame:
        those whose standard error on a pilot of the time-filtered frames ``rate``, ``average``
        (``(B, K, H, W)``) is within :data:`_PILOT_MARGIN` of the smallest.

        The pilot is :data:`_PILOT_BLOCKS` blocks of consecutive output frames spread over the video, one
        frame in :data:`_PILOT_SHARE` in all. Each block's noise norm is extrapolated lag by lag to the
        frames it stands for (:func:`~anra_torch.balance.spectral.pushed_norm`), so that the block's ends
        (where the time derivative's noise does not cancel) weigh as little as the video's do. None where
        no pilot applies: one candidate, ``"ratio"`` mode, too few frames, fixed effects or correlated
        noise, or a video whose pilot measures nothing.
        """
        b, k, h, w = rate.shape
        length, n = self.time.length, _PILOT_BLOCKS
        m = max(_PILOT_MIN, -(-k // (_PILOT_SHARE * n)))  # consecutive output frames per block
        if len(usable) < 2 or self.mode != "lsq" or k < 2 * m * n or any(map(noise.special, range(b))):
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
            sums = self.candidate_sums(i, rate, finite, *spacing, pilot_noise, stage=stage, frames=k / n)
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

    @staticmethod
    def _field(chosen: _Candidate) -> tuple[Tensor, Tensor]:
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

    def extra_repr(self) -> str:
        return (
            f"mode={self.mode!r}, smoothing={self.sigmas}, eiv_correction={self.eiv_correction}, "
            f"noise_sd={self.noise_sd}, window={self.window}, strict={self.strict}, pilot={self.pilot}"
        )


def _explained(chosen: _Candidate) -> Tensor:
    """The noise-corrected ``R^2`` of ``U = a L`` at the least-squares ``a``: ``(sum U L)^2 / (sum L^2 sum
    U^2)`` over the weighted, corrected sums, in [0, 1] (0 where ``dT/dt`` has no energy above the noise)."""
    uu, ul, ll = chosen.rate_energy.sum(1), chosen.num.sum(1), chosen.den.sum(1)
    ok = (uu > 0) & (ll > 0)
    share = ul * ul / torch.where(ok, uu * ll, torch.ones_like(uu))
    return torch.where(ok, share.clamp(0.0, 1.0), torch.zeros_like(uu))
