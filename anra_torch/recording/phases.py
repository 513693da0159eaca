"""A recording's phases as every command finds them, and which phase describes the recording.

:func:`find_phases` segments the frames (:func:`anra_torch.video.recording_phases`: baseline, heating,
cooling, or one phase) after repairing the camera's artefacts (a spike or a hot element is not a heat
source); a recording left on disk is looked at through a copy strided in space, every frame kept.
:func:`phase_preference` ranks the phases for the recording's one diffusivity: a source-free phase
(:data:`SOURCE_FREE`) before a heating, then the longest.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from anra_torch.balance import find_artefacts
from anra_torch.estimation import CHUNKED_VALUES
from anra_torch.video import Phase, Video, decimated, measured_part, recording_phases

__all__ = [
    "MIN_PHASE_FRAMES",
    "PHASE_COPY_VALUES",
    "SOURCE_FREE",
    "find_phases",
    "phase_preference",
    "recording_phases_of",
    "repaired",
    "whole_recording",
]

MIN_PHASE_FRAMES = 8
"""Frames a phase needs to be analysed on its own (a fit part of at least 5 and held-out frames)."""

SOURCE_FREE = ("cooling", "baseline", "steady")
"""Phase kinds without a heat source, in the order their diffusivity is preferred for a recording's."""

PHASE_COPY_VALUES = 2**22
"""Pixel values of the copy a recording read in chunks has its phases found on (every frame, strided in space:
the phases depend on a 3 x 3 px hot spot and the frame mean)."""

_F64 = torch.float64


def phase_preference(phase: Phase) -> tuple[bool, int, int]:
    """How ``phase`` ranks for a recording's diffusivity (larger first): source-free (in the order of
    :data:`SOURCE_FREE`), then the longest."""
    order = SOURCE_FREE.index(phase.name) if phase.name in SOURCE_FREE else len(SOURCE_FREE)
    return phase.name in SOURCE_FREE, -order, phase.frames


def whole_recording(video: Video) -> Phase:
    """The recording taken as one phase (``"recording"``), from its first frame to its last."""
    n = video.frames.shape[0]
    return Phase("recording", 0, n, 0.0, video.dt * (n - 1))


def find_phases(
    frames: Tensor,
    t: Tensor | None = None,
    *,
    dt: float | None = None,
    measured_t: Sequence[float] | Tensor | None = None,
    repaired_frames: Tensor | None = None,
) -> list[Phase]:
    """:func:`~anra_torch.video.recording_phases` of the frames with their camera artefacts repaired
    (:func:`~anra_torch.balance.find_artefacts`): a spike or a hot element is not a heat source.

    Args:
        frames: the recording; one read in time chunks (frames on disk, or over
            :data:`~anra_torch.estimation.CHUNKED_VALUES` values) is looked at through a copy strided
            in space to :data:`PHASE_COPY_VALUES` values, every frame kept.
        t: frame times in s; default ``k dt`` (frame numbers without ``dt``).
        dt: frame period in s, for the phases' times when ``t`` is None.
        measured_t: for resampled frames, the measured samples' times in s: each phase keeps only the
            frames interpolated from its own samples (:func:`~anra_torch.video.measured_part`).
        repaired_frames: the frames with their artefacts repaired already (the estimator's preparation,
            :meth:`~anra_torch.balance.PreparedBatch.repaired`): the search is not run again.

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.
    """
    if t is None and dt is not None:
        t = torch.arange(frames.shape[0], dtype=_F64) * dt
    if repaired_frames is not None:
        return recording_phases_of(repaired_frames, t, measured_t)
    if not isinstance(frames, Tensor) or math.prod(frames.shape) > CHUNKED_VALUES:
        frames = decimated(frames, PHASE_COPY_VALUES)  # a camera-sized recording is never held whole
    return recording_phases_of(repaired(torch.as_tensor(frames)), t, measured_t)


def recording_phases_of(
    frames: Tensor, t: Tensor | None, measured_t: Sequence[float] | Tensor | None
) -> list[Phase]:
    """The phases of repaired ``frames``; of resampled frames, each without frames blended from another
    phase's samples (:func:`~anra_torch.video.measured_part`).

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.
    """
    phases = recording_phases(frames, t)
    if measured_t is None or t is None:
        return phases
    return [measured_part(phase, t, measured_t) for phase in phases]


def repaired(frames: Tensor) -> Tensor:
    """The frames with their camera artefacts repaired and no sample left non-finite (as they are).

    Shape:
        ``(T, H, W)`` -> ``(T, H, W)``.
    """
    return find_artefacts(frames)[0] if frames.ndim == 3 and frames.shape[0] >= 3 else frames
