"""The ANRA estimator: thermal diffusivity straight from video, without solving the PDE.

For ``dT/dt = a (d11 + d22) T`` it balances the PDE on the measured frames, both sides through the same
filters (time derivative and its partner, Gaussian smoothing, Laplacian), with per-pixel weights:
``mode="lsq"`` is weighted least squares with the errors-in-variables correction, ``mode="ratio"`` the
paper's weighted average of pointwise ratios. How: ``docs/architecture.md`` and ``docs/results/paper.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

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
    spectral_stage,
    spectral_terms,
)
from anra_torch.checks import (
    POOR_FIT,
    as_spacing,
    as_video,
    poor_fit,
    verdicts,
)
from anra_torch.estimation.candidates import (
    Candidate,
    ErrorPass,
    choose,
    explained_of,
    lsq_error,
    pilot_contenders,
    ratio_sums,
    reliability_of,
    windowed_field,
)
from anra_torch.estimation.result import ANRAResult, concat_results
from anra_torch.layers import RTCAttention, UniformAttention

__all__ = ["ANRAEstimator", "ANRAResult", "MODES", "AUTO_SMOOTHING", "POOR_FIT"]

MODES = ("lsq", "ratio")
AUTO_SMOOTHING: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0)
"""Spatial smoothing candidates in px tried by ``smoothing="auto"``."""

_MIN_VALID_PX = 8  # a candidate smoothing must leave at least this many pixels per side


_NAMES = ("U", "L")  # the plain balance dT/dt = a Lap T


_SLICE_ELEMENTS = 2**21  # pixel values per slice of a batch (8 MiB in float32): keeps the work in cache

_NO_FINITE = "no finite frame: every sample is NaN, infinite or a dead element; no diffusivity estimated"


def _smoothing_candidates(mode: str, smoothing: float | Sequence[float] | str | None) -> tuple[float, ...]:
    """The smoothing sigmas in px that ``smoothing`` names for ``mode`` (see :class:`ANRAEstimator`).

    Raises:
        ValueError: an unknown mode, a string other than ``"auto"``, an empty sequence.
    """
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of: {', '.join(MODES)}")
    if smoothing is None:
        smoothing = "auto" if mode == "lsq" else 0.0
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
    return sigmas


class ANRAEstimator(nn.Module):
    """Attention-based noise-robust averaging estimator of the thermal diffusivity.

    Args:
        mode: ``"lsq"``, the default, is weighted least squares with the errors-in-variables
            correction; ``"ratio"`` is the paper's RTC-weighted average of ``dT/dt / Laplacian``, kept as
            published.
        smoothing: spatial Gaussian sigma in px, a sequence of candidates, or ``"auto"`` for
            :data:`AUTO_SMOOTHING`; with several candidates each video takes the one with the smallest
            standard error. Default: ``"auto"`` for ``"lsq"``, 0 as published for ``"ratio"``.
        time_family: Holoborodko time family: ``"smooth"``, ``"centred"`` or ``"hybrid"``.
        time_length: time window length in frames.
        laplacian_size: spatial kernel size: 3, 5, 7, 9 or 11.
        laplacian_family: ``"central"`` or ``"holoborodko"``; default ``"central"`` for ``"lsq"``,
            ``"holoborodko"`` as published for ``"ratio"``. Why each: ``docs/architecture.md``, section
            "The estimator".
        attention: per-pixel weighting with ``with_slope(rate, mask)``. Default: the paper's
            :class:`RTCAttention` for ``"ratio"``, :class:`UniformAttention` for ``"lsq"``; why:
            ``docs/results/paper.md``.
        eiv_correction: subtract the noise variance from the Laplacian energy, in lsq mode.
        noise_sd: known noise standard deviation in the data's units; default estimated per video.
        window: odd side in px of the windowed diffusivity field; None skips the field.
        strict: raise ``ValueError`` when a video shows no measurable thermal activity; otherwise
            return it flagged: ``valid`` False, NaN diffusivity, a message. A video of a batch without a
            finite sample is flagged "no finite frame" either way, and the others' estimates stand.
        pilot: choose among several smoothing candidates on a pilot of the frames, computing only the
            pilot's best and its near ties on every frame. Faster by about one candidate, but the choice
            may differ from the default one made on every frame; when: ``docs/architecture.md``, section
            "The estimator".

    Shape:
        ``frames`` ``(B, T, H, W)`` or ``(T, H, W)``; ``dt`` in s and ``dx`` in mm per px, floats or
        ``(B,)``.

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
        sigmas = _smoothing_candidates(mode, smoothing)
        if laplacian_family is None:
            laplacian_family = "central" if mode == "lsq" else "holoborodko"
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
        """Spatial smoothing candidates in px."""
        return tuple(f.sigma for f in self.filters)

    @property
    def minimum_frame_size(self) -> int:
        """The smallest frame side in px these filters accept: the least wide candidate's margins plus the
        least valid interior."""
        return min(2 * f.margin for f in self.filters) + _MIN_VALID_PX

    def usable(self, height: int, width: int) -> list[int]:
        """The smoothing candidates, by index, whose filters leave enough of a ``height`` x ``width`` frame.

        Raises:
            ValueError: no candidate fits: the frame is smaller than :attr:`minimum_frame_size`.
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
        error: ErrorPass | None = None,
        stage: SpectralStage | None = None,
    ) -> Candidate:
        """The sums of smoothing candidate ``index`` over a centred ``(B, T, H, W)`` batch.

        ``error``, a :class:`~.candidates.ErrorPass`, says what is computed of the standard error; by
        default the batch's standard error. ``stage``, the batch's time-filtered spectra of
        :mod:`anra_torch.balance.spectral`, is shared by every candidate; None computes it here."""
        error = ErrorPass() if error is None else error
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
        ratio = ratio_sums(rate, lap, weights) if self.mode == "ratio" else torch.zeros_like(num)
        if self.mode == "lsq" and not error.with_error and error.back_at is None:
            spread = torch.full_like(num[:, 0], torch.nan)
            std_error, back = spread, None
        elif self.mode == "lsq":
            lever = noise.fixed_effects((weights * lap).detach())  # the projection is its own transpose
            sums = (num, den, energy)
            std_error, spread, back = lsq_error(
                filters, stage, noise, lever, sums, dt, dx, error.back_at, error.frames, rate.dtype
            )
        else:
            spread = ratio.std(dim=1) if ratio.shape[1] > 1 else ratio.abs()[:, 0]
            std_error, back = spread / ratio.shape[1] ** 0.5, None
        maps = (None, None, None)
        if self.window is not None:
            maps = self._maps(terms, weights, term_noise, filters.margin)
        return Candidate(rate_energy, num, den, energy, ratio, std_error, spread, back, *maps)

    def _maps(
        self, terms: dict[str, Tensor], weights: Tensor, term_noise: TermNoise | None, margin: int
    ) -> tuple[Tensor, Tensor, Tensor]:
        """The windowed sums ``(num, den, energy)`` of the diffusivity field, each ``(B, H, W)``."""
        field = accumulate(
            terms, _NAMES, reduce=lambda x: self._box(x.sum(1)), weights=weights, noise=term_noise
        )
        maps = (field.corrected[..., 0, 1], field.corrected[..., 1, 1], field.raw[..., 1, 1])
        return tuple(self._to_frame(m, margin) for m in maps)  # type: ignore[return-value]

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
            frames: temperatures in any linear unit; integer counts are converted to floats. Non-finite
                pixels and dead elements, up to 1 % of pixels exactly constant in every frame, are masked
                and counted in ``n_masked``.
            dt: frame period in s, float or ``(B,)``.
            dx: pixel size in mm, float or ``(B,)``.
            prepared: ``frames`` with the artefacts, noise and masks
                :func:`~anra_torch.balance.prepare_batch` measured already; nothing is measured again.

        Returns:
            :class:`ANRAResult`, unbatched for a single ``(T, H, W)`` video.

        Shape:
            ``frames`` ``(T, H, W)`` or ``(B, T, H, W)``.

        Raises:
            ValueError: bad shapes or spacings; too few frames or pixels for the filters; with ``strict``,
                a video without measurable thermal activity.
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
        h, w = video.shape[-2:]
        prepared = prepare_batch(video, noise_sd=self.noise_sd) if prepared is None else prepared
        video, noise = prepared.video, prepared.noise
        noise_sd = noise.sd
        usable = self.usable(h, w)
        chosen, measured, choice = self._chosen(video, prepared.good, dt_, dx_, noise, usable)
        num, den, energy, ratio = chosen.num, chosen.den, chosen.energy, chosen.ratio
        total_den = den.sum(1)
        reliability = reliability_of(total_den, energy.sum(1))
        if self.mode == "lsq":
            per_frame = num / torch.where(den == 0, torch.ones_like(den), den)
            per_frame = torch.where(den == 0, torch.zeros_like(per_frame), per_frame)
            estimate = num.sum(1) / torch.where(total_den == 0, torch.ones_like(total_den), total_den)
        else:
            per_frame, estimate = ratio, ratio.mean(1)
        changing = prepared.changing
        valid = changing & measured & torch.isfinite(estimate)
        explained = explained_of(chosen) if self.mode == "lsq" else torch.full_like(estimate, torch.nan)
        messages, warnings = verdicts(valid, changing, reliability, estimate, chosen.std_error, dt_, dx_)
        rows = zip(warnings, explained.tolist(), valid.tolist(), strict=True)
        warnings = tuple(w + poor_fit(e) if ok else w for w, e, ok in rows)
        field, confidence = windowed_field(chosen) if self.window is not None else (None, None)
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

    def _chosen(
        self,
        video: Tensor,
        good: Tensor | None,
        dt_: Tensor,
        dx_: Tensor,
        noise: BatchNoise,
        usable: list[int],
    ) -> tuple[Candidate, Tensor, Tensor]:
        """Per video, the smoothing candidate (of ``usable``) with the smallest standard error among the
        measurable ones (on a pilot first, where :attr:`pilot` asks): its sums, whether it is measurable
        ``(B,)`` and its index in ``usable`` ``(B,)``."""
        b, _, h, w = video.shape
        rate, average = self.time.with_average(video, dt_)  # one time filter for every candidate
        piloted = self.pilot and self.mode == "lsq"
        contenders = (
            pilot_contenders(
                self.candidate_sums, self.time.length, rate, average, good, dt_, dx_, noise, usable
            )
            if piloted
            else None
        )
        stage = SpectralStage(torch.fft.rfft2(rate), torch.fft.rfft2(average), (h, w))
        del rate, average
        if contenders is None:  # every candidate on every frame
            contenders = torch.ones(b, len(usable), dtype=torch.bool, device="cpu")
        picked = contenders.any(0).nonzero()[:, 0].tolist()
        candidates = [
            self.candidate_sums(usable[i], video, good, dt_, dx_, noise, stage=stage) for i in picked
        ]
        chosen, measured, position = choose(candidates, self.mode, contenders[:, picked].to(video.device))
        choice = torch.tensor(picked, device=video.device)[position]
        if not bool(measured.all()) and len(picked) < len(usable):  # the pilot missed: all of them
            candidates = [self.candidate_sums(i, video, good, dt_, dx_, noise, stage=stage) for i in usable]
            chosen, measured, choice = choose(candidates, self.mode)
        return chosen, measured, choice

    def extra_repr(self) -> str:
        return (
            f"mode={self.mode!r}, smoothing={self.sigmas}, eiv_correction={self.eiv_correction}, "
            f"noise_sd={self.noise_sd}, window={self.window}, strict={self.strict}, pilot={self.pilot}"
        )
