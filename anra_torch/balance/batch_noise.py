"""The noise context of a batch of videos: artefacts repaired, noise measured, fixed effects chosen, per
video; and what the estimator's errors-in-variables correction and standard error need of it.

Each video of a batch gets :func:`~anra_torch.balance.find_artefacts` and
:func:`~anra_torch.balance.measure_noise`. A clean video with white noise keeps exactly the white
estimate :func:`~anra_torch.balance.estimate_noise_sd` over its unmasked pixels, so its result does
not change; a video with correlated noise or fixed effects gets its own noise covariance per point and its
own standard error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from anra_torch.balance.artefacts import Artefacts, find_artefacts, stuck_pixels
from anra_torch.balance.moments import within
from anra_torch.balance.noise import estimate_noise_sd, measure_noise
from anra_torch.balance.noise_model import NoiseModel
from anra_torch.balance.robust import pixel_stats
from anra_torch.balance.spectral import pushed_back, pushed_norm

if TYPE_CHECKING:
    from anra_torch.balance.filters import MatchedFilters

__all__ = ["BatchNoise", "PreparedBatch", "batch_noise", "concat_prepared", "prepare_batch"]

_F64 = torch.float64


@dataclass(frozen=True)
class BatchNoise:
    """Per video of a batch: the repaired frames, the noise model, the fixed effects, the artefacts.

    Attributes:
        cleaned: the videos with spikes and hot elements repaired, ``(B, T, H, W)``.
        sd: noise standard deviation per sample in data units, ``(B,)``.
        models: the measured noise model of each video.
        pixel: per-pixel fixed effects (a static pattern), ``(B,)`` bool.
        frame: per-frame fixed effects (global offsets), ``(B,)`` bool.
        artefacts: what was found in each video.
    """

    cleaned: Tensor
    sd: Tensor
    models: tuple[NoiseModel, ...]
    pixel: Tensor
    frame: Tensor
    artefacts: tuple[Artefacts, ...]

    def special(self, index: int) -> bool:
        """Whether video ``index`` needs more than the white-noise formulas."""
        return not self.models[index].white or bool(self.pixel[index]) or bool(self.frame[index])

    def balanced(self, index: int) -> NoiseModel:
        """Video ``index``'s noise model as its balance sees it: without the static part where per-pixel
        fixed effects remove it (:meth:`NoiseModel.without_static`)."""
        model = self.models[index]
        return model.without_static() if bool(self.pixel[index]) else model

    @property
    def variance_error(self) -> Tensor:
        """Relative error of each video's measured noise variance, ``(B,)`` float64
        (:attr:`NoiseModel.variance_error <anra_torch.balance.NoiseModel.variance_error>`)."""
        errors = [self.balanced(b).variance_error for b in range(len(self.models))]
        return torch.tensor(errors, dtype=_F64, device=self.sd.device)

    def fixed_effects(self, term: Tensor) -> Tensor:
        """``term`` ``(B, K, h, w)`` with each video's fixed effects removed."""
        return within(term, pixel=self.pixel, frame=self.frame)

    def covariance(
        self, filters: MatchedFilters, names: Sequence[str], dt: Tensor, dx: Tensor, extent: Sequence[int]
    ) -> Tensor:
        """Noise covariance per point of the named terms of each video, ``(B, P, P)`` float64."""
        out = filters.noise_covariance(names, self.sd.double() ** 2, dt, dx)
        frames, pixels = int(extent[0]), int(extent[1]) * int(extent[2])
        for b in range(len(self.models)):  # the few videos with correlated noise or fixed effects
            if self.special(b):
                out[b] = filters.noise_covariance(
                    names,
                    float(self.sd[b]) ** 2,
                    float(dt[b]),
                    float(dx[b]),
                    noise=self.balanced(b),
                    within=("pixel",) * bool(self.pixel[b]) + ("frame",) * bool(self.frame[b]),
                    extent=(frames, pixels),
                )
        return out

    def spread(self, backs: Tensor) -> Tensor:
        """Standard deviation of ``<back, noise>`` for each video's pushed-back lever, ``(B,)``.

        Shape:
            ``backs`` ``(B, T, H, W)``.
        """
        out = self.sd * backs.pow(2).sum((1, 2, 3)).sqrt()
        for b in range(len(self.models)):
            model = self.balanced(b)
            if not model.white:
                out[b] = model.quadratic(backs[b : b + 1].to(_F64))[0, 0].clamp_min(0).sqrt().to(out.dtype)
        return out

    def pushed_spread(
        self,
        filters: MatchedFilters,
        lever: Tensor,
        a: Tensor,
        dt: Tensor,
        dx: Tensor,
        size: tuple[int, int],
        *,
        frames: int | None = None,
    ) -> Tensor:
        """:meth:`spread` of ``A_U^T lever - a A_L^T lever`` without the pushed-back field where the noise is
        white (:func:`~anra_torch.balance.spectral.pushed_norm`, ``frames`` as there); the field of the
        others only, ``(B,)``.

        Shape:
            ``lever`` ``(B, K, h, w)``; ``a``, ``dt``, ``dx`` ``(B,)``.
        """
        norm = pushed_norm(filters, lever, a, dt, dx, size, frames=frames)
        out = (self.sd.to(_F64) * norm.clamp_min(0).sqrt()).to(self.sd)
        for b in range(len(self.models)):  # the few videos with correlated noise: their field
            model = self.balanced(b)
            if not model.white:
                one = [v[b : b + 1] for v in (lever, a, dt, dx)]
                back = pushed_back(filters, *one, size).to(_F64)
                out[b] = model.quadratic(back)[0, 0].clamp_min(0).sqrt().to(out.dtype)
        return out


def batch_noise(video: Tensor, finite: Tensor | None, *, noise_sd: float | None = None) -> BatchNoise:
    """Repair, measure and choose for each video of a batch (see the module docs).

    Left out of ``torch.compile`` graphs: it runs eagerly there, gradients included (why:
    ``docs/architecture.md``, "Choices in the hot paths").

    Args:
        video: centred frames ``(B, T, H, W)``; masked samples (``~finite``) are left to the caller.
        finite: the caller's mask of usable samples (None: every sample).
        noise_sd: a known white-noise sd in data units; default measured.

    Shape:
        ``video``, ``finite`` ``(B, T, H, W)``.
    """
    if torch.compiler.is_compiling():
        return torch.compiler.disable(_batch_noise)(video, finite, noise_sd=noise_sd)
    return _batch_noise(video, finite, noise_sd=noise_sd)


def _batch_noise(video: Tensor, finite: Tensor | None, *, noise_sd: float | None) -> BatchNoise:
    b, device = video.shape[0], video.device
    white = None if noise_sd is not None else estimate_noise_sd(video.detach(), mask=finite).reshape(b)
    cleaned, artefacts, models = [], [], []
    for index in range(b):  # artefacts and noise are properties of each recording
        one = video[index] if finite is None else torch.where(finite[index], video[index], torch.nan)
        one = one.detach()
        stats = pixel_stats(one) if finite is None and one.is_floating_point() else None  # read once
        repaired, found = find_artefacts(one, stats=stats)
        cleaned.append(repaired.to(video.dtype))
        artefacts.append(found)
        if white is None:
            models.append(NoiseModel(float(noise_sd)))
        else:  # nothing repaired: the white estimate and the pixels' statistics are the video's
            known, same = (None, None) if found.any else (float(white[index]), stats)
            models.append(
                measure_noise(repaired, static_pattern=found.fixed_pattern, white_sd=known, stats=same)
            )
    if white is None:
        sd = torch.full((b,), float(noise_sd), dtype=video.dtype, device=device)
    else:
        white = white.to(video.dtype)
        sd = torch.stack(
            [white[i] if models[i].white and not artefacts[i].fixed_pattern else torch.tensor(
                float(models[i].sd), dtype=video.dtype, device=device) for i in range(b)]
        )  # fmt: skip
    pixel = torch.tensor(["pixel" in a.within for a in artefacts], device=device)
    frame = torch.tensor([a.global_offsets for a in artefacts], device=device)
    if not any(a.any for a in artefacts):  # nothing repaired: the frames as they came
        return BatchNoise(video, sd, tuple(models), pixel, frame, tuple(artefacts))
    # The repairs enter as a constant correction, so gradients flow through every sample as before.
    cleaned = video + (torch.stack(cleaned) - video.detach())
    return BatchNoise(cleaned, sd, tuple(models), pixel, frame, tuple(artefacts))


@dataclass(frozen=True)
class PreparedBatch:
    """A batch of videos ready for the balance (:func:`prepare_batch`).

    Attributes:
        video: each video centred on its mean, dead elements and camera artefacts repaired (masked samples
            0), ``(B, T, H, W)``.
        good: the samples in the fit (finite, or a dead element's repair), ``(B, T, H, W)`` bool; None
            when that is every sample.
        noise: the batch's noise context (:func:`batch_noise`).
        changing: whether each video's good samples change at all, ``(B,)`` bool.
        masked: samples left out of each video (non-finite or dead), ``(B,)``.
        offset: the mean subtracted from each video, ``(B,)`` (``video + offset`` is in the frames' units).
    """

    video: Tensor
    good: Tensor | None
    noise: BatchNoise
    changing: Tensor
    masked: Tensor
    offset: Tensor

    def repaired(self, index: int) -> Tensor:
        """Video ``index`` with its artefacts repaired and every sample finite, in the frames' units:
        what :func:`~anra_torch.balance.find_artefacts` returns for it, ``(T, H, W)``."""
        return self.noise.cleaned[index].detach() + self.offset[index].to(self.noise.cleaned.dtype)


def concat_prepared(parts: Sequence[PreparedBatch]) -> PreparedBatch:
    """Prepared batches of same-shaped videos as one batch, in order."""
    if len(parts) == 1:
        return parts[0]
    good = None
    if any(p.good is not None for p in parts):
        good = torch.cat(
            [torch.ones_like(p.video, dtype=torch.bool) if p.good is None else p.good for p in parts]
        )
    noises = [p.noise for p in parts]
    noise = BatchNoise(
        torch.cat([n.cleaned for n in noises]),
        torch.cat([n.sd for n in noises]),
        tuple(m for n in noises for m in n.models),
        torch.cat([n.pixel for n in noises]),
        torch.cat([n.frame for n in noises]),
        tuple(a for n in noises for a in n.artefacts),
    )
    cat = [torch.cat([getattr(p, name) for p in parts]) for name in ("video", "changing", "masked", "offset")]
    return PreparedBatch(cat[0], good, noise, cat[1], cat[2], cat[3])


def prepare_batch(video: Tensor, *, noise_sd: float | None = None) -> PreparedBatch:
    """Mask non-finite samples and dead elements, centre each video on its mean, measure and repair
    (:func:`batch_noise`): what the estimator does before the balance. A batch without a non-finite
    sample or a dead element (one sum and one pass tell) takes no masked copies.

    Args:
        video: frames ``(B, T, H, W)`` (any linear unit).
        noise_sd: a known white-noise sd in data units; default measured.

    Shape:
        ``video`` ``(B, T, H, W)``; see :class:`PreparedBatch`.
    """
    b = video.shape[0]
    finite = None if bool(torch.isfinite(video.detach().sum())) else torch.isfinite(video)
    stuck = stuck_pixels(video, finite)
    if finite is None and not bool(stuck.any()):
        # Remove each video's mean (derivatives ignore it): keeps float32 precise on e.g. 300 K scenes.
        offset = video.sum((1, 2, 3), keepdim=True) / video[0].numel()
        centred = video - offset
        noise = batch_noise(centred, None, noise_sd=noise_sd)
        flat = noise.cleaned.detach().flatten(1)
        changing = flat.amax(1) > flat.amin(1)
        zeros = video.new_zeros(b, dtype=torch.long)
        return PreparedBatch(noise.cleaned, None, noise, changing, zeros, offset.detach().reshape(b))
    finite = (torch.isfinite(video) if finite is None else finite) & ~stuck
    # ... and fills masked pixels with a neutral value.
    counts = finite.sum((1, 2, 3)).clamp_min(1)
    mean = torch.where(finite, video, torch.zeros_like(video)).sum((1, 2, 3)) / counts
    video = torch.where(finite, video - mean.view(b, 1, 1, 1), torch.zeros_like(video))
    noise = batch_noise(video, finite, noise_sd=noise_sd)
    # Dead elements take their repair (the good neighbours' median) and stay in the fit: masked, each cut
    # its filters' support out of every frame: on the artefact benchmark's pure videos with dead and hot
    # elements, up to 2.7 % from the clean estimate (0.02 % with the repair).
    repaired = stuck & torch.isfinite(noise.cleaned)
    video = torch.where(finite | repaired, noise.cleaned, video)
    low = torch.where(finite, video, torch.full_like(video, torch.inf)).amin((1, 2, 3))
    changing = torch.where(finite, video, torch.full_like(video, -torch.inf)).amax((1, 2, 3)) > low
    masked = (~finite).sum((1, 2, 3))
    return PreparedBatch(video, finite | repaired, noise, changing, masked, mean.detach())
