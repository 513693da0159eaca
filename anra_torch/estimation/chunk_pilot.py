"""The pilot of a recording read in chunks: blocks spread over the recording choose the smoothing, the
noise model and whether every chunk needs a repair (step 1 of :mod:`anra_torch.estimation.chunked`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance import BatchNoise, batch_noise, find_artefacts, spectral_stage, stuck_pixels
from anra_torch.checks import MIN_RELIABILITY, MIN_SIGNIFICANCE
from anra_torch.estimation.estimator import ANRAEstimator

__all__ = ["ChunkPilot", "choose_on_pilot", "pilot_starts"]


_PILOT_SHARE = 3
"""The pilot reads at most one ``_PILOT_SHARE``-th of the recording's frames (at least one block): on a
short recording it would otherwise cost more than the estimate itself."""


def pilot_starts(total: int, length: int, blocks: int) -> list[int]:
    """First frames of at most ``blocks`` runs of ``length`` frames spread evenly over ``total`` (no overlap),
    within :data:`_PILOT_SHARE`."""
    n = max(1, min(blocks, total // (_PILOT_SHARE * length)))
    if n == 1:
        return [(total - length) // 2]
    return [round(i * (total - length) / (n - 1)) for i in range(n)]


@dataclass
class ChunkPilot:
    """What the pilot chose for every chunk."""

    index: int  # the chosen smoothing candidate
    offset: float  # subtracted from every frame (float32 precision on e.g. 300 K scenes)
    dead: Tensor  # (H, W) dead elements
    noise: BatchNoise  # of one video: the block of median noise, with the pooled fixed effects
    repair: bool  # spikes or hot elements were found: repair each chunk
    a: float  # the pooled estimate, where the standard error is linearised


def _signal_crop(blocks: Tensor, finite: Tensor | None, side: int) -> tuple[slice, slice]:
    """The ``side`` x ``side`` px window (or the whole frame) where the pilot's frames change most
    (``finite`` None: every sample is)."""
    h, w = blocks.shape[-2:]
    if h <= side and w <= side:
        return slice(None), slice(None)
    usable = blocks if finite is None else torch.where(finite, blocks, torch.zeros_like(blocks))
    change = usable.var(1).sum(0).double()  # (H, W)
    sy, sx = min(side, h), min(side, w)
    table = F.pad(change.cumsum(0).cumsum(1), (1, 0, 1, 0))  # window sums from an integral image
    local = table[sy:, sx:] - table[:-sy, sx:] - table[sy:, :-sx] + table[:-sy, :-sx]
    y, x = divmod(int(local.argmax()), local.shape[1])
    return slice(y, y + sy), slice(x, x + sx)


def _needs_repair(found: Any) -> bool:
    """Whether a block's artefacts (spikes, hot or dead elements) make every chunk need a repair."""
    return bool(found.spikes or found.bad_pixels)


def choose_on_pilot(
    est: ANRAEstimator, blocks: Tensor, dt: Tensor, dx: Tensor, side: int, total: int
) -> ChunkPilot:
    """Choose the smoothing and the noise context on the pilot blocks of a ``total``-frame recording: dead
    elements and spikes over the whole frame, the noise model and the smoothing candidates in the ``side``
    px window of most change."""
    n = blocks.shape[0]
    length = est.time.length
    scale = max(1.0, (total - length + 1) / (n * (blocks.shape[1] - length + 1)))  # outputs per pilot output
    # One sum tells blocks without non-finite samples; without dead elements either, no masks (None).
    finite = None if bool(torch.isfinite(blocks.sum())) else torch.isfinite(blocks)
    stuck = stuck_pixels(blocks, finite)
    if finite is None and bool(stuck.any()):
        finite = torch.ones_like(blocks, dtype=torch.bool)
    dead = stuck[:, 0].all(0)  # constant through every block: masked (the in-memory estimator repairs them)
    rows, cols = _signal_crop(blocks, finite, side)
    whole = rows == slice(None)  # the window is the whole frame: its artefact search is the noise model's
    if not whole:
        masked = blocks if finite is None else torch.where(finite & ~dead, blocks, torch.nan)
        repair = any(_needs_repair(find_artefacts(b)[1]) for b in masked)
    blocks = blocks[..., rows, cols]
    finite = None if finite is None else (finite & ~stuck)[..., rows, cols]
    h, w = blocks.shape[-2:]
    values = blocks.reshape(-1) if finite is None else blocks[finite]
    offset = float(values.double().mean()) if values.numel() else 0.0
    centred = (
        blocks - offset if finite is None else torch.where(finite, blocks - offset, torch.zeros_like(blocks))
    )
    noise = batch_noise(centred, finite, noise_sd=est.noise_sd)
    if whole:  # an element stuck in one block only is masked there, not searched: it needs the repair too
        repair = bool((stuck[:, 0].any(0) & ~dead).any()) or any(_needs_repair(f) for f in noise.artefacts)
    video = noise.cleaned if finite is None else torch.where(finite, noise.cleaned, centred)
    usable = est.usable(h, w)
    best, best_var, best_a = usable[0], math.inf, 0.0
    stage = spectral_stage(est.filters[0], video, dt.expand(n))  # one time filter for every candidate
    for i in usable:  # the blocks pooled as one estimate: the candidate with the smallest standard error
        sums = est.candidate_sums(i, video, finite, dt.expand(n), dx.expand(n), noise, stage=stage)
        num, den, energy = (float(x.sum()) for x in (sums.num, sums.den, sums.energy))
        noise_var = float(sums.spread.double().pow(2).nansum())
        # The whole recording's standard error, as the estimator computes it, from the evenly spread blocks:
        # every sum scaled by `scale`, the noise part then falls as 1 / scale while the noise variance's
        # own error (a bias common to every frame) does not average out.
        correction = (energy - den) * float(noise.variance_error.mean()) * num / den if den > 0 else 0.0
        variance = (noise_var / scale + correction**2) / den**2 if den > 0 else math.inf
        measurable = den > MIN_RELIABILITY * energy and abs(num / den) >= MIN_SIGNIFICANCE * math.sqrt(
            variance
        )
        if measurable and variance < best_var:
            best, best_var, best_a = i, variance, num / den
    m = int(noise.sd.argsort()[n // 2])  # the block of median noise
    one = BatchNoise(
        noise.cleaned[m : m + 1],
        noise.sd[m : m + 1],
        (noise.models[m],),
        noise.pixel.any().view(1),
        noise.frame.any().view(1),
        (noise.artefacts[m],),
    )
    return ChunkPilot(best, offset, dead, one, repair, best_a)
