"""ANRA on recordings larger than memory: a pilot chooses, then time chunks accumulate the balance.

The estimate is a ratio of sums over output frames, and frame ``k``'s sums depend only on input frames
``k .. k + L - 1``: the recording is read in chunks of frames that overlap by the time filter's ``L - 1``
frames, so the per-frame sums are exactly the whole video's and memory is bounded by the chunk. A pilot of
a few blocks chooses the smoothing, the noise model and the fixed effects; the standard error is pushed
back on every ``error_every``-th chunk and scaled to the recording; with ``precision`` reading stops once
it is reached. Per-pixel fixed effects are removed within each chunk. The steps in full:
``docs/architecture.md`` ("Recordings larger than memory").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from torch import Tensor
from tqdm.auto import tqdm

from anra_torch.balance import BatchNoise, find_artefacts
from anra_torch.checks import MIN_RELIABILITY, MIN_SIGNIFICANCE, as_spacing, poor_fit, verdicts
from anra_torch.estimation.candidates import ErrorPass
from anra_torch.estimation.chunk_error import NoiseVariance, gain, totals
from anra_torch.estimation.chunk_pilot import ChunkPilot, choose_on_pilot, pilot_starts
from anra_torch.estimation.estimator import ANRAEstimator, ANRAResult
from anra_torch.layers import UniformAttention

__all__ = ["CHUNKED_VALUES", "CHUNK_BYTES", "ChunkedEstimate", "Chunking", "estimate_chunked"]

_F64 = torch.float64

CHUNK_BYTES = 16 * 2**20
"""Default size of one chunk's field (bytes). Below glibc's largest mmap threshold (32 MiB) the allocator
reuses freed blocks; above it every temporary is a fresh mapping, and its page faults were measured to
double the time per frame (640 x 512 px)."""

CHUNKED_VALUES = CHUNK_BYTES // 4
"""Pixel values (one chunk of float32, 4 Mi values) above which ``anra estimate`` and ``anra batch`` read a
recording in time chunks, its smoothing chosen on the pilot instead of on every frame (3x faster on
224 x 224 x 120)."""


@dataclass(frozen=True)
class ChunkedEstimate:
    """The estimate of a recording read in chunks.

    Attributes:
        result: the estimate, as :class:`~anra_torch.estimation.ANRAEstimator` returns it for one video
            (``per_frame`` and ``frame_times`` over the frames used).
        frames_used: frames read for the estimate (fewer than ``frames_total`` when ``precision`` was
            reached early).
        frames_total: frames in the recording.
        chunk_frames: output frames per chunk.
        pilot: ``(start, stop)`` frames of each pilot block.
        gain: the standard error's noise variance per input frame and unit of mean regressor energy per
            output frame, on the sampled chunks' interiors (NaN when every chunk was chained).
    """

    result: ANRAResult
    frames_used: int
    frames_total: int
    chunk_frames: int
    pilot: tuple[tuple[int, int], ...]
    gain: float


@dataclass(frozen=True)
class Chunking:
    """How :func:`estimate_chunked` reads a recording: its chunks, the pilot, the standard error's sampling.

    Attributes:
        chunk_frames: output frames per chunk (each chunk reads ``L - 1`` frames more); default as many
            as keep one chunk's field under :data:`CHUNK_BYTES` (at most ``4 L`` with a precision target).
        pilot_blocks: pilot blocks spread over the recording (fewer when they would read more than a third
            of its frames).
        pilot_frames: frames per pilot block.
        pilot_side: side in px of the pilot's window of most change, where the noise is measured and the
            smoothing chosen.
        error_every: push the noise lever back on every this many chunks (1: the exact standard error,
            at the cost of a second spatial pass per chunk).
    """

    chunk_frames: int | None = None
    pilot_blocks: int = 3
    pilot_frames: int = 16
    pilot_side: int = 256
    error_every: int = 4


def _read(frames: Any, start: int, stop: int, dtype: torch.dtype) -> Tensor:
    block = frames[start:stop]
    tensor = block if isinstance(block, Tensor) else torch.from_numpy(np.ascontiguousarray(block))
    return tensor.to(dtype)


def _like(frames: Any, dtype: torch.dtype | None, device: torch.device | str | None) -> Tensor:
    """A scalar in ``dtype`` (default float64 for float64 frames, else float32) on ``device`` (default the
    frames' own, the CPU for arrays)."""
    if dtype is None:
        dtype = _F64 if getattr(frames, "dtype", None) in (np.float64, torch.float64) else torch.float32
    if device is None:
        device = frames.device if isinstance(frames, Tensor) else "cpu"
    return torch.zeros((), dtype=dtype, device=device)


_CONTEXT = 2  # frames on each side a spike search needs (its second difference in time, and a margin)


def _repaired(frames: Any, raw: Tensor, start: int, pilot: ChunkPilot, new: slice) -> tuple[Tensor, Any, int]:
    """The chunk ``raw`` (input frames from ``start``) centred and repaired
    (:func:`~anra_torch.balance.find_artefacts`), searched with :data:`_CONTEXT` frames more on
    each side, so a spike in a chunk's first or last frame is found as anywhere else; with what was found
    and the spikes repaired in the ``new`` frames (the overlap's were counted with the chunk before):
    finite samples the repair changed, outside dead and hot elements."""
    stop = start + raw.shape[0]
    low, high = max(0, start - _CONTEXT), min(frames.shape[0], stop + _CONTEXT)
    before, after = (_read(frames, a, b, raw.dtype).to(raw.device) for a, b in ((low, start), (stop, high)))
    context = torch.cat([before, raw, after])
    finite = torch.isfinite(context) & ~pilot.dead
    video = torch.where(finite, context - pilot.offset, torch.nan)
    repaired, found = find_artefacts(video)
    repaired = repaired.to(raw.dtype)
    spikes = (repaired != video) & finite
    for row, col in found.bad_pixels:
        spikes[:, row, col] = False
    keep = slice(start - low, stop - low)
    return repaired[keep], found, int(spikes[keep][new].sum())


def _range(raw: Tensor, finite: Tensor) -> tuple[float, float]:
    """The lowest and highest finite value (inf, -inf when there is none)."""
    low = torch.where(finite, raw, torch.full_like(raw, torch.inf)).amin()
    high = torch.where(finite, raw, torch.full_like(raw, -torch.inf)).amax()
    return float(low), float(high)


def _chunk_frames(frames: Any, length: int, precision: float | None) -> int:
    """The default chunk: its field under :data:`CHUNK_BYTES`, at most ``4 L`` frames with ``precision``
    (small steps stop near where the precision is reached), at least ``2 L``."""
    shape = tuple(getattr(frames, "shape", ()))
    per_frame = 4 * math.prod(shape[1:]) if len(shape) == 3 else 1
    chunk = max(2 * length, CHUNK_BYTES // max(per_frame, 1) - length + 1)
    return min(chunk, 4 * length) if precision is not None else chunk


def _frames_total(frames: Any, length: int) -> int:
    """The recording's frame count, checked: a ``(T, H, W)`` shape with at least ``length`` frames."""
    shape = tuple(getattr(frames, "shape", ()))
    if len(shape) != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {shape}")
    if shape[0] < length:
        raise ValueError(f"need at least {length} frames for the time filter, got {shape[0]}")
    return shape[0]


def _checked(
    estimator: ANRAEstimator, c: Chunking, frames: Any, precision: float | None, dtype: torch.dtype | None
) -> int:
    """The output frames per chunk (``c.chunk_frames`` or its default), after checking every setting."""
    chunk_frames = (
        _chunk_frames(frames, estimator.time.length, precision) if c.chunk_frames is None else c.chunk_frames
    )
    if dtype not in (None, torch.float32, torch.float64):
        raise ValueError(f"dtype must be torch.float32 or torch.float64, got {dtype!r}")
    if estimator.mode != "lsq" or not isinstance(estimator.attention, UniformAttention):
        raise ValueError(
            "estimate_chunked needs an estimator with mode='lsq' and uniform weights (its sums add over "
            f"frames), got mode={estimator.mode!r}, attention {type(estimator.attention).__name__}"
        )
    if estimator.window is not None:
        raise ValueError(f"estimate_chunked makes no windowed field: use window=None, got {estimator.window}")
    if precision is not None and not (isinstance(precision, int | float) and 0 < precision < 1):
        raise ValueError(f"precision must be a relative standard error in (0, 1), got {precision!r}")
    if isinstance(chunk_frames, bool) or not isinstance(chunk_frames, int) or chunk_frames < 1:
        raise ValueError(f"chunk_frames must be an integer >= 1 (frames), got {chunk_frames!r}")
    counts = (c.error_every, c.pilot_blocks, c.pilot_frames, c.pilot_side)
    _check_counts(
        **dict(zip(("error_every", "pilot_blocks", "pilot_frames", "pilot_side"), counts, strict=True))
    )
    return chunk_frames


_COUNT_UNITS = {
    "error_every": "chunks",
    "pilot_blocks": "blocks",
    "pilot_frames": "frames",
    "pilot_side": "px",
}


def _check_counts(**counts: object) -> None:
    for name, value in counts.items():
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1 ({_COUNT_UNITS[name]}), got {value!r}")


def estimate_chunked(
    frames: Any,
    dt: float,
    dx: float,
    *,
    estimator: ANRAEstimator | None = None,
    chunking: Chunking | None = None,
    precision: float | None = None,
    progress: bool = False,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> ChunkedEstimate:
    """Diffusivity of a recording read in time chunks (see the module docs), memory bounded by the chunk.

    Args:
        frames: anything with ``shape`` ``(T, H, W)`` that slices along T into arrays or tensors: a
            :class:`~anra_torch.video.LazyFrames` file, a memory map, an HDF5 dataset, a tensor.
        dt: frame period in s.
        dx: pixel size in mm.
        estimator: ``mode="lsq"``, uniform weights, no window; default ``ANRAEstimator(strict=False)``.
        chunking: the chunks and the pilot (:class:`Chunking`); default ``Chunking()``.
        precision: stop reading once the relative standard error reaches it (e.g. 0.001); None reads
            every frame.
        progress: show a tqdm progress bar over the frames.
        dtype: the computation's dtype, ``torch.float32`` or ``torch.float64`` (the accumulators are
            float64 either way); default float64 for float64 frames, else float32.
        device: where each chunk is computed (default: the frames' own device, the CPU for arrays).

    Returns:
        :class:`ChunkedEstimate`.

    Raises:
        ValueError: frames without a ``(T, H, W)`` shape or shorter than the time filter, a bad
            ``dt``/``dx``/``precision``/``dtype`` or setting of ``chunking``, an estimator this cannot
            accumulate, or (with a ``strict`` estimator) a recording without measurable thermal activity.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    est = ANRAEstimator(strict=False) if estimator is None else estimator
    c = Chunking() if chunking is None else chunking
    chunk_frames = _checked(est, c, frames, precision, dtype)
    total = _frames_total(frames, est.time.length)
    like = _like(frames, dtype, device)  # the computation's dtype and device: every tensor follows it
    dt_ = as_spacing(dt, name="dt", unit="s", batch=1, like=like)
    dx_ = as_spacing(dx, name="dx", unit="mm", batch=1, like=like)
    pilot, spans = _pilot(frames, est, c, like, dt_, dx_)
    plan = _Plan(chunk_frames, c.error_every, precision, progress)
    sums, seen = _accumulate(frames, est, pilot, dt_, dx_, like.dtype, plan)
    result = _result(est, pilot, sums, seen, dt_, dx_)
    if est.strict and not bool(result.valid):
        raise ValueError(result.messages[0])
    return ChunkedEstimate(
        result=result,
        frames_used=seen["frames"],
        frames_total=total,
        chunk_frames=chunk_frames,
        pilot=spans,
        gain=gain(seen["error"]),
    )


def _pilot(
    frames: Any, est: ANRAEstimator, c: Chunking, like: Tensor, dt: Tensor, dx: Tensor
) -> tuple[ChunkPilot, tuple[tuple[int, int], ...]]:
    """The pilot's choice (:func:`~anra_torch.estimation.chunk_pilot.choose_on_pilot`) on blocks read in
    ``like``'s dtype and device, and the blocks' ``(start, stop)`` frames."""
    total, length = frames.shape[0], est.time.length
    block = min(total, max(c.pilot_frames, 2 * length))
    starts = pilot_starts(total, block, c.pilot_blocks)
    blocks = torch.stack([_read(frames, s, s + block, like.dtype).to(like.device) for s in starts])
    return choose_on_pilot(est, blocks, dt, dx, c.pilot_side, total), tuple((s, s + block) for s in starts)


@dataclass(frozen=True)
class _Plan:
    """How the chunks are read: output frames per chunk, the error's sampling, precision, progress bar."""

    chunk: int
    every: int
    precision: float | None
    progress: bool


def _accumulate(
    frames: Any,
    est: ANRAEstimator,
    pilot: ChunkPilot,
    dt: Tensor,
    dx: Tensor,
    dtype: torch.dtype,
    plan: _Plan,
) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Per-frame sums over the chunks (``rate_energy``, ``num``, ``den``, ``energy``, each ``(K,)``) and
    what was seen (frames read, masked samples, value range, the standard error's sums)."""

    chunk, every, precision, progress = plan.chunk, plan.every, plan.precision, plan.progress
    total, length = frames.shape[0], est.time.length
    outputs = total - length + 1
    # Chunks too short to hold a complete frame pass their lever on: every chunk is then sampled.
    chained = every == 1 or chunk < 2 * length
    # Filled in place: small tensors kept per chunk pinned the heap between the chunks' large temporaries
    # (glibc could not reuse the holes: +1 MB of peak memory per frame over 9000 frames).
    sums_of = {n: dt.new_zeros(outputs, dtype=_F64) for n in ("rate_energy", "num", "den", "energy")}
    seen: dict[str, Any] = {"frames": 0, "masked": 0, "low": math.inf, "high": -math.inf, "spikes": 0}
    seen["finished"] = False
    variance_error = float(pilot.noise.variance_error[0])
    error = NoiseVariance(length)
    at = torch.tensor([pilot.a], dtype=dtype, device=dt.device)
    with tqdm(total=total, unit="frame", desc="anra chunks", disable=not progress) as bar:
        for j, start in enumerate(range(0, outputs, chunk)):
            stop = min(outputs, start + chunk)
            video, finite, noise = _chunk(frames, start, stop + length - 1, pilot, seen, dtype, dt.device)
            first, last = start == 0, stop == outputs
            sampled = chained or first or last or j % every == 0
            sums = est.candidate_sums(
                pilot.index, video[None], None if finite is None else finite[None], dt, dx, noise,
                error=ErrorPass(with_error=False, back_at=at if sampled else None),
            )  # fmt: skip
            for name, values in sums_of.items():
                values[start:stop] = getattr(sums, name)[0]
            if sums.back is not None:
                error.add(sums, noise, first=first, last=last, chained=chained)
            seen["finished"], seen["error"], seen["outputs"] = last, error, stop
            bar.update(seen["frames"] - bar.n)
            if precision is not None:
                a, se = totals({k: v[:stop] for k, v in sums_of.items()}, error, seen, variance_error)[:2]
                if math.isfinite(se) and abs(a) > 0 and se <= precision * abs(a):
                    break
    return {name: values[: seen["outputs"]] for name, values in sums_of.items()}, seen


def _chunk(
    frames: Any,
    start: int,
    stop: int,
    pilot: ChunkPilot,
    seen: dict[str, Any],
    dtype: torch.dtype,
    device: torch.device,
) -> tuple[Tensor, Tensor | None, BatchNoise]:
    """Input frames ``start .. stop - 1`` centred (masked, repaired where the pilot asks), where they are
    finite (None: everywhere) and their noise context; counts what is seen (frames, masked samples, value
    range, spikes) in ``seen``."""
    raw = _read(frames, start, stop, dtype).to(device)
    # One sum tells a chunk without non-finite samples (inf and NaN carry through it).
    everywhere = bool(torch.isfinite(raw.sum())) and not bool(pilot.dead.any())
    finite = None if everywhere else torch.isfinite(raw) & ~pilot.dead
    new = slice(seen["frames"] - start, None)  # input frames not counted by an earlier chunk
    seen["frames"] = stop
    if not everywhere:
        seen["masked"] += int((~finite[new]).sum())
    low, high = (float(v) for v in raw.aminmax()) if everywhere else _range(raw, finite)
    seen["low"], seen["high"] = min(seen["low"], low), max(seen["high"], high)
    video = raw - pilot.offset
    if not everywhere:
        video = torch.where(finite, video, torch.zeros_like(raw))
    artefacts = pilot.noise.artefacts
    if pilot.repair:
        video, found, spikes = _repaired(frames, raw, start, pilot, new)
        finite, artefacts = None, (found,)
        seen["spikes"] += spikes
    return video, finite, replace(pilot.noise, cleaned=video[None], artefacts=artefacts)


def _result(
    est: ANRAEstimator,
    pilot: ChunkPilot,
    sums: dict[str, Tensor],
    seen: dict[str, Any],
    dt: Tensor,
    dx: Tensor,
) -> ANRAResult:
    """The :class:`ANRAResult` of the accumulated sums (one video, unbatched)."""
    variance_error = float(pilot.noise.variance_error[0])
    a, se, reliability = totals(sums, seen["error"], seen, variance_error)

    def one(x: float | bool) -> Tensor:
        return torch.tensor([x], dtype=_F64 if not isinstance(x, bool) else torch.bool, device=dt.device)

    measurable = reliability >= MIN_RELIABILITY and math.isfinite(a) and abs(a) >= MIN_SIGNIFICANCE * se
    changing = seen["high"] > seen["low"]
    valid = one(bool(changing and measurable))
    estimate = one(a)
    messages, warnings = verdicts(
        valid, one(bool(changing)), one(reliability), estimate, one(se), dt.to(_F64), dx.to(_F64)
    )
    uu, ul, ll = (float(sums[k].sum()) for k in ("rate_energy", "num", "den"))
    explained = min(1.0, max(0.0, ul * ul / (uu * ll))) if uu > 0 and ll > 0 else 0.0
    if bool(valid):
        warnings = (warnings[0] + poor_fit(explained),)
    den = sums["den"]
    per_frame = torch.where(den == 0, torch.zeros_like(den), sums["num"] / torch.where(den == 0, 1.0, den))
    k = torch.arange(per_frame.shape[0], dtype=_F64, device=dt.device)
    nan = one(math.nan)
    noise = pilot.noise
    record = noise.artefacts[0].to_record()
    if pilot.repair:
        record["spikes"] = seen["spikes"]
    return ANRAResult(
        diffusivity=torch.where(valid, estimate, nan),
        std_error=torch.where(valid, one(se), nan),
        per_frame=per_frame[None],
        frame_times=((k + est.time.centre) * float(dt[0]))[None],
        noise_sd=noise.sd.to(_F64),
        smoothing=one(est.filters[pilot.index].sigma),
        reliability=one(reliability),
        explained=one(explained),
        valid=valid,
        n_masked=torch.tensor([seen["masked"]], device=dt.device),
        field=None,
        confidence=None,
        messages=messages,
        warnings=warnings,
        noise=(noise.models[0].describe() | {"sd": float(noise.sd[0])},),
        artefacts=(record,),
    ).unbatched()
