"""What happens to a recording's diffusivity: phases, routes, the described phase and its record.

One policy for ``anra estimate``, ``anra batch`` and ``anra features`` alike:

1. **Phases** (:func:`~anra_torch.recording.find_phases`): a heating and a cooling are estimated
   apart; a recording of one phase (or with a precision target, which reads it in chunks until reached) is
   one ``"recording"`` phase. Phases shorter than :data:`~anra_torch.recording.MIN_PHASE_FRAMES`
   are listed as too short.
2. **The route of each phase**: a region too small for the filters (with frames enough for them) gets the
   small-box estimate (:func:`~anra_torch.estimation.small_box_estimate`); a recording over
   :data:`~anra_torch.estimation.CHUNKED_VALUES` pixel values, or with a precision target, is read in time
   chunks (:func:`~anra_torch.estimation.estimate_chunked`, frames left on disk stay there); the others are
   estimated whole, same-shaped ones of many recordings in one :class:`~anra_torch.estimation.ANRAEstimator`
   call.
3. **The described phase**: the longest valid source-free one (cooling, then baseline or steady;
   :func:`~anra_torch.recording.phase_preference`), else the longest; the whole recording when every
   phase is too short.
4. **Depth**: a source-free phase read whole that follows a heating, or whose plain heat equation explains
   under :data:`~anra_torch.checks.POOR_FIT` of dT/dt, also gets the depth-aware fit
   (:func:`~anra_torch.selection.depth_aware_diffusivity`) and the flag of a plain value it contradicts.

:meth:`RecordingEstimate.to_record` is the ``anra estimate --json`` object; :meth:`RecordingEstimate.row`
the ``anra batch`` row.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from anra_torch.balance import PreparedBatch, concat_prepared, prepare_batch
from anra_torch.checks import POOR_FIT, depth_bias, join_messages, one_line
from anra_torch.estimation import (
    CHUNKED_VALUES,
    ANRAEstimator,
    ANRAResult,
    estimate_chunked,
    small_box_estimate,
)
from anra_torch.recording.parallel import side_by_side
from anra_torch.recording.phases import (
    MIN_PHASE_FRAMES,
    SOURCE_FREE,
    find_phases,
    phase_preference,
    whole_recording,
)
from anra_torch.recording.read import input_record
from anra_torch.selection import depth_aware_diffusivity
from anra_torch.video import Phase, Video, input_warnings

__all__ = [
    "PhaseEstimate",
    "RecordingEstimate",
    "estimate_recording",
    "estimate_recordings",
    "on_disk_above",
    "phase_diffusivities",
    "reads_in_chunks",
]

PHASE_KEYS = ("diffusivity", "std_error", "valid", "message", "warnings")
"""What each entry of ``phases`` takes from its estimate (a valid one's flags are in ``warnings``)."""


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
class PhaseEstimate:
    """One phase of a recording, its route and its estimate.

    Attributes:
        phase: the :class:`~anra_torch.video.Phase` (kind, frames, times).
        part: the phase's frames as a :class:`~anra_torch.video.Video` (unread when on disk).
        route: ``"too_short"``, ``"small_box"``, ``"chunked"`` or ``"whole"``.
        result: the estimator's (batched) result for ``"chunked"`` and ``"whole"``.
        index: this phase's video in ``result``.
        small_box: the small-box record (``diffusivity``, ``std_error``, ``valid``, ``message``, ...).
        chunked: ``chunk_frames``, ``frames_used`` and ``pilot`` of a chunked estimate.
        depth_aware: the depth-aware record (or ``{"error": ...}``) where it was fitted.
        seconds: wall time of this phase's estimate (its share of a batched call), s.
        prepared: the phase's frames as the estimator prepares them, measured once with the phases
            (a recording of one phase read whole), or None.
    """

    phase: Phase
    part: Video
    route: str
    result: ANRAResult | None = None
    index: int = 0
    small_box: dict[str, Any] | None = None
    chunked: dict[str, Any] | None = None
    depth_aware: dict[str, Any] | None = None
    seconds: float = 0.0
    prepared: PreparedBatch | None = field(default=None, repr=False)

    def estimate_record(self) -> dict[str, Any]:
        """The estimate's own record: :meth:`ANRAResult.to_record` or the small-box record."""
        if self.result is not None:
            return self.result.to_record(self.index, unit=self.part.unit)
        return dict(self.small_box or {})

    @property
    def valid(self) -> bool:
        return self.route != "too_short" and bool(self.estimate_record()["valid"])

    def to_record(self) -> dict[str, Any]:
        """The phase as an element of ``anra estimate --json``'s ``phases``."""
        p = self.phase
        head = {"kind": p.name, "start_frame": p.start, "stop_frame": p.stop, "t_start": p.t_start}
        head["t_stop"] = p.t_stop
        if self.route == "too_short":
            return {**head, "diffusivity": None, "valid": False, "message": "too short", "warnings": []}
        if self.result is None:
            return {"warnings": [], **head, **self.estimate_record()}
        record = self.estimate_record()
        own = {key: record[key] for key in PHASE_KEYS}
        own["warnings"] = own["warnings"] + depth_bias(own["diffusivity"], self.depth_aware)
        return {"warnings": [], **head, **own, "depth_aware": self.depth_aware}


@dataclass
class RecordingEstimate:
    """A recording's estimate: every phase's, and the phase that describes the recording.

    Attributes:
        video: the recording.
        phases: every phase's :class:`PhaseEstimate`, in time order (one ``"recording"`` phase for a
            recording of one phase).
        described: the phase the recording's diffusivity is measured on (see the module text).
        several: whether the recording has more than one phase.
        estimator: the estimator's settings (``mode``, ``window``) for the record.
        elapsed: wall time of the whole estimate (phases, every phase's estimate, depth), s.
    """

    video: Video
    phases: list[PhaseEstimate]
    described: PhaseEstimate
    several: bool
    estimator: ANRAEstimator = field(repr=False)
    elapsed: float = 0.0

    @property
    def result(self) -> ANRAResult | None:
        """The described phase's estimator result (None for a small box)."""
        return self.described.result

    def to_record(self) -> dict[str, Any]:
        """The ``anra estimate --json`` object (see :mod:`anra_torch.cli.estimate`)."""
        d = self.described
        record = _summary(d, self.estimator, self.elapsed) if d.result is not None else _small_summary(d)
        phases = [p.to_record() for p in self.phases] if self.several else [_one_phase(d, record)]
        described = next((r for p, r in zip(self.phases, phases, strict=True) if p is d), None)
        depth = (described or {}).get("depth_aware") if self.several else d.depth_aware
        record["depth_aware"] = depth
        record["warnings"] += depth_bias(record["diffusivity"], depth)
        record["chunked"] = d.chunked
        record["phase"] = d.phase.name
        record["phases"] = phases
        if any(input_record(self.video).values()):
            record["input"] = input_record(self.video)
        return record

    def row(self) -> dict[str, Any]:
        """The ``anra batch`` row (without its resume columns; see :mod:`anra_torch.batch`)."""
        d = self.described
        record = d.estimate_record()
        warnings = [*input_warnings(self.video), *(record.get("warnings") or [])]
        warnings += depth_bias(record["diffusivity"], d.depth_aware)
        t, h, w = d.part.frames.shape
        ok = bool(record["valid"])
        columns = _ROW_COLUMNS if d.result is not None else ("diffusivity", "std_error")
        roi, calibration = self.video.meta.get("roi"), self.video.meta.get("calibration")
        return {
            "path": str(self.video.source),
            "status": "ok" if ok else "error",
            "error": "" if ok else f"{self.video.source}: {record['message']}",
            **{key: record.get(key) for key in columns},
            "frames": t,
            "height": h,
            "width": w,
            "dt": self.video.dt,
            "dx": self.video.dx,
            "a_true": self.video.truth.a if self.video.truth is not None else None,
            "seconds": d.seconds,
            "roi": ",".join(str(v) for v in roi) if roi else None,
            "calibration": calibration["table"] if calibration else None,
            "message": join_messages([*warnings, record.get("message")]),
            "frames_used": None if d.chunked is None else d.chunked["frames_used"],
            "phase": d.phase.name if self.several else None,
        }


_ROW_COLUMNS = (
    "diffusivity",
    "std_error",
    "smoothing_px",
    "noise_sd",
    "reliability",
    "n_masked",
    "explained",
)
"""The batch columns taken as they are from :meth:`~anra_torch.estimation.ANRAResult.to_record`."""


def _summary(d: PhaseEstimate, est: ANRAEstimator, elapsed: float) -> dict[str, Any]:
    """The ``estimate --json`` keys of an estimator result: its record with the phase's shape and spacing,
    the estimator's settings and timing."""
    part, result = d.part, d.result
    assert result is not None
    t, h, w = part.frames.shape
    record = result.to_record(d.index, unit=part.unit)
    units = record["units"]
    summary: dict[str, Any] = {
        "path": str(part.source),
        **{key: record[key] for key in ("diffusivity", "std_error", "valid", "message")},
        "warnings": input_warnings(part) + record["warnings"],
        "frames": t,
        "height": h,
        "width": w,
        "dt": part.dt,
        "dx": part.dx,
        "mode": est.mode,
        **{key: record[key] for key in ("smoothing_px", "noise_sd", "reliability", "explained", "n_masked")},
        **{key: record[key] for key in ("noise", "artefacts")},
        "window_px": est.window,
        "field_median": None,
        "field_coverage": None,
        "a_true": part.truth.a if part.truth is not None else None,
        "elapsed_s": round(elapsed, 3),
        "units": {
            **{key: units[key] for key in ("diffusivity", "std_error")},
            "dt": "s",
            "dx": "mm",
            **{key: units[key] for key in ("smoothing_px", "noise_sd")},
            "elapsed_s": "s",
        },
    }
    if result.field is not None:
        field = result.field[d.index] if result.field.ndim == 3 else result.field
        finite = field[field.isfinite()]
        summary["field_coverage"] = float(finite.numel() / field.numel())
        if finite.numel():
            summary["field_median"] = float(finite.median())
    return summary


def _small_summary(d: PhaseEstimate) -> dict[str, Any]:
    """The ``estimate --json`` keys of a small-box estimate."""
    small = dict(d.small_box or {})
    flagged = [small["message"]] if not small["valid"] else []
    summary = {"path": str(d.part.source), **small, "warnings": input_warnings(d.part) + flagged}
    t, h, w = d.part.frames.shape
    summary.update(frames=t, height=h, width=w, dt=d.part.dt, dx=d.part.dx)
    return summary


def _one_phase(d: PhaseEstimate, summary: dict[str, Any]) -> dict[str, Any]:
    """The ``phases`` element of a recording of one phase: the summary's own keys."""
    p = d.phase
    head = {"kind": p.name, "start_frame": p.start, "stop_frame": p.stop, "t_start": p.t_start}
    head["t_stop"] = p.t_stop
    own = {key: summary.get(key) for key in PHASE_KEYS}
    own["warnings"] = list(own["warnings"] or []) + depth_bias(summary.get("diffusivity"), d.depth_aware)
    return {**head, **own, "depth_aware": d.depth_aware}


# ------------------------------------------------------------------------------------------- planning
_Plan = tuple[list[PhaseEstimate], bool]
"""A recording's phases with their routes, and whether it has several."""


def _plan(video: Video, est: ANRAEstimator, precision: float | None, dtype: torch.dtype | None) -> _Plan:
    """Every phase of ``video`` with its route, and whether it has several phases. A recording read whole
    is measured once (:func:`~anra_torch.balance.prepare_batch`): the phases are searched in its repaired
    frames, and a recording of one phase is estimated on that measurement."""
    chunked, prepared, frames = reads_in_chunks(video, est, precision), None, video.frames
    whole = _route(video, est, chunked) == "whole" and isinstance(frames, torch.Tensor) and frames.ndim == 3
    if whole and frames.shape[0] >= est.time.length:
        frames = frames.to(est.time.taps.device, dtype or frames.dtype)
        prepared = prepare_batch(frames[None], noise_sd=est.noise_sd) if frames.is_floating_point() else None
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
        return [PhaseEstimate(phase, video, route, prepared=prepared if route == "whole" else None)], False
    out = []
    for phase in phases:
        part = video.span(phase.start, phase.stop)
        route = "too_short" if phase.frames < MIN_PHASE_FRAMES else _route(part, est, chunked)
        out.append(PhaseEstimate(phase, part, route))
    if all(p.route == "too_short" for p in out):  # the top level then describes the whole recording
        out.append(PhaseEstimate(whole_recording(video), video, _route(video, est, chunked)))
    return out, True


def _route(part: Video, est: ANRAEstimator, chunked: bool) -> str:
    t, h, w = part.frames.shape
    if min(h, w) < est.minimum_frame_size and t >= est.time.length:  # too few frames: the estimator says so
        return "small_box"
    return "chunked" if chunked else "whole"


# ----------------------------------------------------------------------------------------- estimating
def _estimate_small(p: PhaseEstimate) -> None:
    start = time.perf_counter()
    part = p.part.loaded()
    p.small_box = small_box_estimate(part.frames, part.dt, part.dx)
    p.seconds = time.perf_counter() - start


def _estimate_chunked(
    p: PhaseEstimate, est: ANRAEstimator, precision: float | None, dtype: torch.dtype | None, progress: bool
) -> None:
    start = time.perf_counter()
    done = estimate_chunked(
        p.part.frames,
        p.part.dt,
        p.part.dx,
        estimator=est,
        precision=precision,
        progress=progress,
        dtype=dtype,
        device=est.time.taps.device,
    )
    p.result, p.index = done.result, 0
    p.chunked = {
        "chunk_frames": done.chunk_frames,
        "frames_used": done.frames_used,
        "pilot": [list(block) for block in done.pilot],
    }
    p.seconds = time.perf_counter() - start


def _estimate_whole(members: list[PhaseEstimate], est: ANRAEstimator, dtype: torch.dtype | None) -> None:
    """Same-shaped phases of one or many recordings in one estimator call."""
    start = time.perf_counter()
    device = est.time.taps.device  # the frames follow the estimator
    frames = [torch.as_tensor(p.part.loaded().frames).to(device) for p in members]
    kind = dtype or frames[0].dtype
    measured = [p.prepared for p in members]
    prepared = None if any(m is None for m in measured) else concat_prepared(measured)  # type: ignore[arg-type]
    if len(members) == 1 and dtype is None:
        result = est(frames[0][None], members[0].part.dt, members[0].part.dx, prepared=prepared).unbatched()
        members[0].result, members[0].index = result, 0
    else:
        stacked = torch.stack([f.to(kind) for f in frames])
        dt = torch.tensor([p.part.dt for p in members], dtype=torch.float64)
        dx = torch.tensor([p.part.dx for p in members], dtype=torch.float64)
        result = est(stacked, dt, dx, prepared=prepared)
        for i, p in enumerate(members):
            p.result, p.index = result, i
    share = (time.perf_counter() - start) / len(members)
    for p in members:
        p.seconds = share


def _depth_aware(phases: list[PhaseEstimate], several: bool) -> None:
    """The depth-aware fit of each source-free phase read whole that follows a heating (the source laid
    heat down that now flows into depth) or whose plain heat equation explains less than
    :data:`~anra_torch.checks.POOR_FIT` of dT/dt (an error record when it cannot be fitted)."""
    for k, p in enumerate(phases):
        if p.result is None or p.chunked is not None or p.phase.name not in SOURCE_FREE:
            continue
        heated = several and any(q.phase.name == "heating" for q in phases[:k])
        explained = p.estimate_record()["explained"]
        if not heated and (explained is None or not explained < POOR_FIT):
            continue
        part = p.part.loaded()
        try:
            p.depth_aware = depth_aware_diffusivity(part.frames, part.dt, part.dx).to_record()
        except ValueError as err:
            p.depth_aware = {"error": str(err)}


def _described(phases: list[PhaseEstimate], several: bool) -> PhaseEstimate:
    """The phase the recording's diffusivity is measured on (see the module text)."""
    if not several:
        return phases[0]
    if phases[-1].phase.name == "recording":  # every phase too short
        return phases[-1]
    chosen, rank = None, None
    for p in phases:
        if p.route == "too_short":
            continue
        source_free, *rest = phase_preference(p.phase)
        mine = (source_free and p.valid, *rest)
        if rank is None or mine > rank:
            chosen, rank = p, mine
    assert chosen is not None
    return chosen


def estimate_recordings(
    videos: Sequence[Video],
    estimator: ANRAEstimator | None = None,
    *,
    precision: float | None = None,
    dtype: torch.dtype | None = None,
    progress: bool = False,
) -> list[RecordingEstimate | ValueError]:
    """Estimate many recordings, each as :func:`estimate_recording` does, sharing estimator calls.

    Each recording is measured and its phases found side by side with the others, one per torch thread;
    same-shaped small phases estimated whole then go through one estimator call, camera-sized ones
    (:data:`CAMERA_SIZED`) and recordings read in chunks run side by side. A recording that fails gets its
    one-line ``ValueError`` (naming the file) in its place; the others go on.

    Args:
        videos: the recordings (frames in memory or on disk).
        estimator: the estimator's settings; default ``ANRAEstimator(strict=False)``.
        precision: read each recording in chunks until its relative standard error reaches it.
        dtype: the estimate's dtype (default: the frames' own, float64 when read in chunks from float64).
        progress: a progress bar over the frames of a recording read in chunks.

    Returns:
        One :class:`RecordingEstimate` (or ``ValueError``) per recording, in order.

    Shape:
        Each video's ``frames`` ``(T, H, W)``.
    """
    est = ANRAEstimator(strict=False) if estimator is None else estimator
    if precision is not None and (est.mode != "lsq" or est.window is not None):
        raise ValueError("--precision reads the recording in chunks: it needs --mode lsq without --window")
    plans: list[_Plan | ValueError] = []
    for video, plan, err in side_by_side(videos, lambda v: _plan(v, est, precision, dtype)):
        plans.append(plan if err is None else ValueError(f"{video.source}: {one_line(err)}"))
    return _run(videos, plans, est, precision, dtype, progress)


def _whole_groups(plans: list[_Plan | ValueError]) -> list[list[PhaseEstimate]]:
    """The phases estimated whole, in groups that share an estimator call: same-shaped phases of different
    recordings (a recording's own phases never share one: each is estimated as it would be alone), each
    camera-sized one on its own (the estimator would take it alone anyway; alone, it runs beside another)."""
    groups: dict[tuple, list[PhaseEstimate]] = {}
    for plan in (plan for plan in plans if not isinstance(plan, ValueError)):
        for k, p in enumerate(p for p in plan[0] if p.route == "whole"):
            shape = tuple(p.part.frames.shape)
            alone = math.prod(shape) >= CAMERA_SIZED
            groups.setdefault((k, *shape, id(p) if alone else 0), []).append(p)
    return list(groups.values())


CAMERA_SIZED = 2**20
"""Pixel values from which a phase estimated whole gets an estimator call of its own."""


def _run(
    videos: Sequence[Video],
    plans: list[_Plan | ValueError],
    est: ANRAEstimator,
    precision: float | None,
    dtype: torch.dtype | None,
    progress: bool,
) -> list[RecordingEstimate | ValueError]:
    """Every planned phase estimated by its route, then each recording's described phase and depth."""
    failed: dict[int, ValueError] = {}
    owner = {id(p): i for i, plan in enumerate(plans) if not isinstance(plan, ValueError) for p in plan[0]}
    tasks = [p for plan in plans if not isinstance(plan, ValueError) for p in plan[0]]

    def fail(p: PhaseEstimate, err: BaseException) -> None:
        i = owner[id(p)]
        failed.setdefault(i, ValueError(f"{videos[i].source}: {one_line(err)}"))

    for p in (p for p in tasks if p.route == "small_box"):
        try:
            _estimate_small(p)
        except (ValueError, TypeError, RuntimeError) as err:
            fail(p, err)
    chunked = [p for p in tasks if p.route == "chunked"]
    for p, _, err in side_by_side(chunked, lambda p: _estimate_chunked(p, est, precision, dtype, progress)):
        if err is not None:
            fail(p, err)
    retry = []
    for members, _, err in side_by_side(_whole_groups(plans), lambda m: _estimate_whole(m, est, dtype)):
        retry += members if err is not None and len(members) > 1 else []
        if err is not None and len(members) == 1:
            fail(members[0], err)
    for p, _, err in side_by_side(retry, lambda p: _estimate_whole([p], est, dtype)):
        if err is not None:  # something in its batch was wrong: one by one, for exact messages
            fail(p, err)
    out: list[RecordingEstimate | ValueError] = []
    for i, plan in enumerate(plans):
        if isinstance(plan, ValueError) or i in failed:
            out.append(plan if isinstance(plan, ValueError) else failed[i])
            continue
        phases, several = plan
        _depth_aware(phases, several)
        described = _described(phases, several)
        listed = [p for p in phases if p.phase.name != "recording"] if several else phases
        out.append(RecordingEstimate(videos[i], listed, described, several, est))
    return out


def estimate_recording(
    video: Video,
    estimator: ANRAEstimator | None = None,
    *,
    precision: float | None = None,
    dtype: torch.dtype | None = None,
    progress: bool = False,
) -> RecordingEstimate:
    """The diffusivity of one recording, phase by phase, as ``anra estimate`` measures it.

    Args:
        video: the recording (frames in memory or on disk, :func:`~anra_torch.recording.open_recording`).
        estimator: the estimator's settings; default ``ANRAEstimator(strict=False)``.
        precision: read the recording in chunks until its relative standard error reaches it (one phase).
        dtype: the estimate's dtype (default: the frames' own).
        progress: a progress bar over the frames of a recording read in chunks.

    Returns:
        :class:`RecordingEstimate`.

    Shape:
        ``video.frames`` ``(T, H, W)``.

    Raises:
        ValueError: one line naming the file: frames the estimator cannot take, a bad precision setting.
    """
    start = time.perf_counter()
    (done,) = estimate_recordings([video], estimator, precision=precision, dtype=dtype, progress=progress)
    if isinstance(done, ValueError):
        raise done
    done.elapsed = time.perf_counter() - start
    return done


def phase_diffusivities(video: Video) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """The phases of a recording, each with its estimate as ``anra estimate`` gives it (``kind``, frames,
    times, ``diffusivity``, ...), and the record of the phase that describes the recording; ``([], None)``
    for a recording of one phase (nothing is estimated then).

    Shape:
        ``video.frames`` ``(T, H, W)``.

    Raises:
        ValueError: one line naming the file, when a phase cannot be estimated.
    """
    est = ANRAEstimator(strict=False)
    plan = _plan(video, est, None, None)
    if not plan[1]:
        return [], None
    (done,) = _run([video], [plan], est, None, None, False)
    if isinstance(done, ValueError):
        raise done
    records = [p.to_record() for p in done.phases]
    described = next((r for p, r in zip(done.phases, records, strict=True) if p is done.described), None)
    return records, described
