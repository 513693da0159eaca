"""Optional steps on each video of a :class:`~anra_torch.data.ThermalVideoDataset`, done by the library's own
steps: a region of interest, resampling in time, one phase of the recording.

Each is a small picklable object called as ``step(video) -> video``, so it runs in ``DataLoader`` workers;
:class:`Compose` chains them. A region also cuts the video's per-pixel labels. Each records what it did in
``video.meta``: ``"roi"``, ``"resampled"`` or ``"phase"``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import torch
from torch import Tensor

from anra_torch.recording import MIN_PHASE_FRAMES, find_phases, phase_head, phase_preference, whole_recording
from anra_torch.video import ROI, Video, crop, parse_roi, resample_uniform

__all__ = ["PHASES", "Compose", "RegionOfInterest", "Resample", "SelectPhase"]

PHASES = ("preferred", "baseline", "heating", "cooling", "steady", "recording")
"""What :class:`SelectPhase` keeps: ``"preferred"``, the phase a command describes the recording by, or the
longest phase of a kind."""


class Compose:
    """Apply ``steps`` in order.

    Shape:
        ``frames`` ``(T, H, W)`` -> as the steps make them.
    """

    def __init__(self, *steps: Callable[[Video], Video]) -> None:
        bad = next((s for s in steps if not callable(s)), None)
        if bad is not None:
            raise TypeError(f"steps must be callable (Video -> Video), got {type(bad).__name__}")
        self.steps = steps

    def __call__(self, video: Video) -> Video:
        for step in self.steps:
            video = step(video)
        return video

    def __repr__(self) -> str:
        return f"Compose({', '.join(map(repr, self.steps))})"


@dataclass(frozen=True)
class RegionOfInterest:
    """Keep the region ``roi`` = ``(x0, y0, width, height)`` px, or its text ``"X0,Y0,W,H"``, of every
    frame and of every per-pixel label, by :func:`anra_torch.video.crop`.

    Shape:
        ``frames`` ``(T, H, W)`` -> ``(T, height, width)``; a label ``(..., H, W)`` -> ``(..., height,
        width)``.

    Raises:
        ValueError: when built, a malformed region; when called, a region outside the frame.
    """

    roi: ROI | str

    def __post_init__(self) -> None:
        region = parse_roi(self.roi) if isinstance(self.roi, str) else tuple(self.roi)
        if not (len(region) == 4 and all(isinstance(v, int) for v in region)):
            raise ValueError(f"roi must be (x0, y0, width, height) px or 'X0,Y0,W,H', got {self.roi!r}")
        parse_roi(",".join(map(str, region)))  # the same checks as the text
        object.__setattr__(self, "roi", region)

    def __call__(self, video: Video) -> Video:
        _, height, width = video.frames.shape
        out = crop(video.loaded(), self.roi)  # type: ignore[arg-type]
        x0, y0, w, h = self.roi  # type: ignore[str-unpack]
        labels = {
            k: v[..., y0 : y0 + h, x0 : x0 + w] if _per_pixel(v, height, width) else v
            for k, v in (video.meta.get("labels") or {}).items()
        }
        return replace(out, meta={**out.meta, "labels": labels}) if "labels" in video.meta else out


@dataclass(frozen=True)
class Resample:
    """Resample in time onto a uniform step ``dt`` in s by :func:`anra_torch.video.resample_uniform`.

    ``dt=None`` makes non-uniform timestamps uniform and leaves uniform videos as they are.

    Shape:
        ``frames`` ``(T, H, W)`` -> ``(T', H, W)``.

    Raises:
        ValueError: when built, a non-positive ``dt`` or an unknown ``method``.
    """

    dt: float | None = None
    method: str = "cubic"

    def __post_init__(self) -> None:
        if self.dt is not None and not (isinstance(self.dt, int | float) and 0 < self.dt < float("inf")):
            raise ValueError(f"dt must be a positive number in s or None, got {self.dt!r}")
        if self.method not in ("cubic", "linear"):
            raise ValueError(f"method must be one of cubic, linear, got {self.method!r}")

    def __call__(self, video: Video) -> Video:
        video = video.loaded()
        if video.t is None:
            if self.dt is None or abs(self.dt - video.dt) <= 1e-9 * video.dt:
                return video
            steps = torch.arange(video.frames.shape[0], dtype=torch.float64, device=video.frames.device)
            video = replace(video, t=steps * video.dt)
        return resample_uniform(video, self.dt, method=self.method)


@dataclass(frozen=True)
class SelectPhase:
    """Keep one phase of the recording found by :func:`anra_torch.recording.find_phases`.

    The phases are found after the camera's artefacts are repaired; ``meta["phase"]`` records the one kept.

    Args:
        phase: one of :data:`PHASES`. ``"preferred"`` is the phase a command describes the recording by,
            ranked by :func:`~anra_torch.recording.phase_preference`: a source-free one first, then the
            longest; the whole recording when no phase is long enough. A kind keeps the longest phase of
            that kind.
        min_frames: phases shorter than this are not kept.

    Shape:
        ``frames`` ``(T, H, W)`` -> ``(stop - start, H, W)``; frames on disk stay unread.

    Raises:
        ValueError: when built, an unknown ``phase`` or ``min_frames`` < 2; when called, no phase of that
            kind of at least ``min_frames`` frames, naming the phases found.
    """

    phase: str = "preferred"
    min_frames: int = MIN_PHASE_FRAMES

    def __post_init__(self) -> None:
        if self.phase not in PHASES:
            raise ValueError(f"phase must be one of {', '.join(PHASES)}, got {self.phase!r}")
        if not (isinstance(self.min_frames, int) and self.min_frames >= 2):
            raise ValueError(f"min_frames must be an integer >= 2, got {self.min_frames!r}")

    def __call__(self, video: Video) -> Video:
        found = find_phases(video.frames, video.t, dt=video.dt, measured_t=video.meta.get("measured_t"))
        long = [p for p in found if p.frames >= self.min_frames]
        if self.phase == "preferred":
            chosen = max(long, key=phase_preference) if long else whole_recording(video)
        else:
            kind = [p for p in long if p.name == self.phase]
            if not kind:
                listed = ", ".join(f"{p.name} (frames {p.start}-{p.stop - 1})" for p in found) or "none"
                need = f"no {self.phase} phase of at least {self.min_frames} frames"
                raise ValueError(f"{video.name}: {need}; found {listed}")
            chosen = max(kind, key=lambda p: p.frames)
        part = video.span(chosen.start, chosen.stop)
        return replace(part, meta={**part.meta, "phase": phase_head(chosen)})


def _per_pixel(value: Any, height: int, width: int) -> bool:
    return isinstance(value, Tensor) and value.ndim >= 2 and tuple(value.shape[-2:]) == (height, width)
