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

The plan (phases and routes) is :mod:`~anra_torch.recording.plan`; the records
(:meth:`RecordingEstimate.to_record`, the ``anra estimate --json`` object, and :meth:`RecordingEstimate.row`,
the ``anra batch`` row) are :mod:`~anra_torch.recording.records`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from anra_torch.balance import PreparedBatch, concat_prepared
from anra_torch.checks import POOR_FIT, one_line
from anra_torch.estimation import ANRAEstimator, estimate_chunked, small_box_estimate
from anra_torch.recording.parallel import side_by_side
from anra_torch.recording.phases import SOURCE_FREE, phase_preference
from anra_torch.recording.plan import RecordingPlan, plan_recording, whole_groups
from anra_torch.recording.records import PhaseEstimate, RecordingEstimate
from anra_torch.selection import depth_aware_diffusivity
from anra_torch.video import Video

__all__ = ["estimate_recording", "estimate_recordings", "phase_diffusivities"]


@dataclass(frozen=True)
class _Settings:
    """What every phase of a run is estimated with: the estimator, the precision target (chunked reads),
    the dtype and whether chunked reads show a progress bar."""

    estimator: ANRAEstimator
    precision: float | None = None
    dtype: torch.dtype | None = None
    progress: bool = False


# ----------------------------------------------------------------------------------------- estimating
def _estimate_small(p: PhaseEstimate) -> None:
    start = time.perf_counter()
    part = p.part.loaded()
    p.small_box = small_box_estimate(part.frames, part.dt, part.dx)
    p.seconds = time.perf_counter() - start


def _estimate_chunked(p: PhaseEstimate, s: _Settings) -> None:
    start = time.perf_counter()
    done = estimate_chunked(
        p.part.frames,
        p.part.dt,
        p.part.dx,
        estimator=s.estimator,
        precision=s.precision,
        progress=s.progress,
        dtype=s.dtype,
        device=s.estimator.time.taps.device,
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
    (:data:`~anra_torch.recording.plan.CAMERA_SIZED`) and recordings read in chunks run side by side. A
    recording that fails gets its one-line ``ValueError`` (naming the file) in its place; the others go on.

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
    plans: list[RecordingPlan | ValueError] = []
    for video, plan, err in side_by_side(videos, lambda v: plan_recording(v, est, precision, dtype)):
        plans.append(plan if err is None else ValueError(f"{video.source}: {one_line(err)}"))
    return _run(videos, plans, _Settings(est, precision, dtype, progress))


def _run(
    videos: Sequence[Video], plans: list[RecordingPlan | ValueError], s: _Settings
) -> list[RecordingEstimate | ValueError]:
    """Every planned phase estimated by its route, then each recording's described phase and depth."""
    failed: dict[int, ValueError] = {}
    owner = {
        id(p): i for i, plan in enumerate(plans) if not isinstance(plan, ValueError) for p in plan.phases
    }
    tasks = [p for plan in plans if not isinstance(plan, ValueError) for p in plan.phases]

    def fail(p: PhaseEstimate, err: BaseException) -> None:
        i = owner[id(p)]
        failed.setdefault(i, ValueError(f"{videos[i].source}: {one_line(err)}"))

    for p in (p for p in tasks if p.route == "small_box"):
        try:
            _estimate_small(p)
        except (ValueError, TypeError, RuntimeError) as err:
            fail(p, err)
    chunked = [p for p in tasks if p.route == "chunked"]
    for p, _, err in side_by_side(chunked, lambda p: _estimate_chunked(p, s)):
        if err is not None:
            fail(p, err)
    retry = []
    for members, _, err in side_by_side(
        whole_groups(plans), lambda m: _estimate_whole(m, s.estimator, s.dtype)
    ):
        retry += members if err is not None and len(members) > 1 else []
        if err is not None and len(members) == 1:
            fail(members[0], err)
    for p, _, err in side_by_side(retry, lambda p: _estimate_whole([p], s.estimator, s.dtype)):
        if err is not None:  # something in its batch was wrong: one by one, for exact messages
            fail(p, err)
    out: list[RecordingEstimate | ValueError] = []
    for i, plan in enumerate(plans):
        if isinstance(plan, ValueError) or i in failed:
            out.append(plan if isinstance(plan, ValueError) else failed[i])
            continue
        phases, several = plan.phases, plan.several
        _depth_aware(phases, several)
        described = _described(phases, several)
        listed = [p for p in phases if p.phase.name != "recording"] if several else phases
        out.append(RecordingEstimate(videos[i], listed, described, several, s.estimator))
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


def phase_diffusivities(
    video: Video, *, measured: PreparedBatch | None = None
) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """The phases of a recording, each with its estimate as ``anra estimate`` gives it (``kind``, frames,
    times, ``diffusivity``, ...), and the record of the phase that describes the recording; ``([], None)``
    for a recording of one phase (nothing is estimated then). ``measured``: the frames' measurement
    (:func:`~anra_torch.balance.prepare_batch`) made already, not made again.

    Shape:
        ``video.frames`` ``(T, H, W)``.

    Raises:
        ValueError: one line naming the file, when a phase cannot be estimated.
    """
    est = ANRAEstimator(strict=False)
    plan = plan_recording(video, est, None, None, measured)
    if not plan.several:
        return [], None
    (done,) = _run([video], [plan], _Settings(est))
    if isinstance(done, ValueError):
        raise done
    records = [p.to_record() for p in done.phases]
    described = next((r for p, r in zip(done.phases, records, strict=True) if p is done.described), None)
    return records, described
