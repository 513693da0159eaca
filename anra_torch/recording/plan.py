"""A recording's plan: its phases, the route of each (too short, small box, in chunks, whole), and which
phases estimated whole share an estimator call (the module text of :mod:`~anra_torch.recording.estimate`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from anra_torch.balance import PreparedBatch, prepare_batch
from anra_torch.estimation import CHUNKED_VALUES, ANRAEstimator
from anra_torch.recording.phases import MIN_PHASE_FRAMES, find_phases, whole_recording
from anra_torch.recording.records import PhaseEstimate
from anra_torch.video import Video

__all__ = [
    "CAMERA_SIZED",
    "RecordingPlan",
    "on_disk_above",
    "plan_recording",
    "reads_in_chunks",
    "whole_groups",
]

CAMERA_SIZED = 2**20
"""Pixel values from which a phase estimated whole gets an estimator call of its own."""


def on_disk_above(precision: float | None) -> int:
    """Pixel values above which a recording to estimate is left on disk and read in chunks
    (:func:`~anra_torch.recording.open_recording`'s ``on_disk_above``): any with a precision target, else
    :data:`~anra_torch.estimation.CHUNKED_VALUES`."""
    return 0 if precision is not None else CHUNKED_VALUES


def reads_in_chunks(video: Video, estimator: ANRAEstimator, precision: float | None) -> bool:
    """Whether ``video`` is estimated in time chunks: a precision target, or more than
    :data:`~anra_torch.estimation.CHUNKED_VALUES` pixel values (not for ``mode="ratio"`` or a window, which
    the chunked estimate cannot accumulate: those are read whole)."""
    chunked = precision is not None or math.prod(video.frames.shape) > CHUNKED_VALUES
    return chunked and estimator.mode == "lsq" and estimator.window is None


@dataclass
class RecordingPlan:
    """A recording's phases with their routes, and whether it has several.

    Attributes:
        phases: every phase's :class:`~anra_torch.recording.PhaseEstimate`, not yet estimated.
        several: whether the recording has more than one phase.
    """

    phases: list[PhaseEstimate]
    several: bool


def plan_recording(
    video: Video,
    est: ANRAEstimator,
    precision: float | None,
    dtype: torch.dtype | None,
    measured: PreparedBatch | None = None,
) -> RecordingPlan:
    """Every phase of ``video`` with its route, and whether it has several phases. A recording read whole
    is measured once (:func:`~anra_torch.balance.prepare_batch`; ``measured``: that measurement made
    already, of the same frames with ``est.noise_sd``): the phases are searched in its repaired frames, and
    a recording of one phase is estimated on that measurement."""
    chunked, prepared, frames = reads_in_chunks(video, est, precision), None, video.frames
    whole = _route(video, est, chunked) == "whole" and isinstance(frames, torch.Tensor) and frames.ndim == 3
    if whole and frames.shape[0] >= est.time.length:
        frames = frames.to(est.time.taps.device, dtype or frames.dtype)
        like = (tuple(frames[None].shape), frames.dtype, frames.device)
        if (
            measured is not None
            and (tuple(measured.video.shape), measured.video.dtype, measured.video.device) == like
        ):
            prepared = measured
        elif frames.is_floating_point():
            prepared = prepare_batch(frames[None], noise_sd=est.noise_sd)
    # With a precision target the recording is one phase: finding phases would read all of it.
    phases = (
        []
        if precision is not None
        else find_phases(
            video.frames,
            video.t,
            dt=video.dt,
            measured_t=video.meta.get("measured_t"),
            repaired_frames=None if prepared is None else prepared.repaired(0),
        )
    )
    several = len(phases) > 1
    if not several:  # the recording is estimated whole, named after its one phase
        phase = phases[0] if phases else whole_recording(video)
        route = _route(video, est, chunked)
        return RecordingPlan(
            [PhaseEstimate(phase, video, route, prepared=prepared if route == "whole" else None)], False
        )
    out = []
    for phase in phases:
        part = video.span(phase.start, phase.stop)
        route = "too_short" if phase.frames < MIN_PHASE_FRAMES else _route(part, est, chunked)
        out.append(PhaseEstimate(phase, part, route))
    if all(p.route == "too_short" for p in out):  # the top level then describes the whole recording
        out.append(PhaseEstimate(whole_recording(video), video, _route(video, est, chunked)))
    return RecordingPlan(out, True)


def _route(part: Video, est: ANRAEstimator, chunked: bool) -> str:
    t, h, w = part.frames.shape
    if min(h, w) < est.minimum_frame_size and t >= est.time.length:  # too few frames: the estimator says so
        return "small_box"
    return "chunked" if chunked else "whole"


def whole_groups(plans: list[RecordingPlan | ValueError]) -> list[list[PhaseEstimate]]:
    """The phases estimated whole, in groups that share an estimator call: same-shaped phases of different
    recordings (a recording's own phases never share one: each is estimated as it would be alone), each
    camera-sized one on its own (the estimator would take it alone anyway; alone, it runs beside another)."""
    groups: dict[tuple, list[PhaseEstimate]] = {}
    for plan in (plan for plan in plans if not isinstance(plan, ValueError)):
        for k, p in enumerate(p for p in plan.phases if p.route == "whole"):
            shape = tuple(p.part.frames.shape)
            alone = math.prod(shape) >= CAMERA_SIZED
            groups.setdefault((k, *shape, id(p) if alone else 0), []).append(p)
    return list(groups.values())
