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

from anra_torch.balance.artefacts import Artefacts, find_artefacts
from anra_torch.balance.moments import within
from anra_torch.balance.noise import NoiseModel, estimate_noise_sd, measure_noise

if TYPE_CHECKING:
    from anra_torch.balance.filters import MatchedFilters

__all__ = ["BatchNoise", "batch_noise"]

_F64 = torch.float64


@dataclass(frozen=True)
class BatchNoise:
    """Per video of a batch: the repaired frames, the noise model, the fixed effects, the artefacts.

    Attributes:
        cleaned: the videos with spikes and hot elements repaired, ``(B, T, H, W)``.
        sd: noise standard deviation per sample (data units), ``(B,)``.
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
        return torch.tensor([self.balanced(b).variance_error for b in range(len(self.models))], dtype=_F64)

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


def batch_noise(video: Tensor, finite: Tensor, *, noise_sd: float | None = None) -> BatchNoise:
    """Repair, measure and choose for each video of a batch (see the module docs).

    Left out of ``torch.compile`` graphs (it runs eagerly there, gradients included): its branches on
    measured values would only break the graph many times over and cost most of the compile time. (The
    exclusion is made when compiling: ``torch.compiler.disable`` at import would load the compiler, 1.3 s,
    into every process.)

    Args:
        video: centred frames ``(B, T, H, W)``; masked samples (``~finite``) are left to the caller.
        finite: the caller's mask of usable samples.
        noise_sd: a known white-noise sd (data units); default measured.

    Shape:
        ``video``, ``finite`` ``(B, T, H, W)``.
    """
    if torch.compiler.is_compiling():
        return torch.compiler.disable(_batch_noise)(video, finite, noise_sd=noise_sd)
    return _batch_noise(video, finite, noise_sd=noise_sd)


def _batch_noise(video: Tensor, finite: Tensor, *, noise_sd: float | None) -> BatchNoise:
    b = video.shape[0]
    white = None if noise_sd is not None else estimate_noise_sd(video.detach(), mask=finite).reshape(b)
    cleaned, artefacts, models = [], [], []
    for index in range(b):  # artefacts and noise are properties of each recording
        one = torch.where(finite[index], video[index], torch.nan)
        repaired, found = find_artefacts(one.detach())
        cleaned.append(repaired.to(video.dtype))
        artefacts.append(found)
        if white is None:
            models.append(NoiseModel(float(noise_sd)))
        else:  # nothing repaired: the white estimate of the repaired video is the batch's
            known = None if found.any else float(white[index])
            models.append(measure_noise(repaired, static_pattern=found.fixed_pattern, white_sd=known))
    if white is None:
        sd = torch.full((b,), float(noise_sd), dtype=video.dtype)
    else:
        white = white.to(video.dtype)
        sd = torch.stack(
            [white[i] if models[i].white and not artefacts[i].fixed_pattern else torch.tensor(
                float(models[i].sd), dtype=video.dtype) for i in range(b)]
        )  # fmt: skip
    pixel = torch.tensor(["pixel" in a.within for a in artefacts])
    frame = torch.tensor([a.global_offsets for a in artefacts])
    # The repairs enter as a constant correction, so gradients flow through every sample as before.
    cleaned = video + (torch.stack(cleaned) - video.detach())
    return BatchNoise(cleaned, sd, tuple(models), pixel, frame, tuple(artefacts))
