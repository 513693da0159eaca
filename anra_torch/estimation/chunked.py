"""ANRA on recordings larger than memory: a pilot chooses, then time chunks accumulate the balance.

:class:`~anra_torch.estimation.ANRAEstimator` holds a whole video and its filtered terms at once; a camera
recording (640 x 512 px at 30 Hz for 30 s: 1.2 GB in float32) needs several times that. Its estimate is a
ratio of sums over output frames, ``a = sum_k num_k / sum_k den_k``, and frame ``k``'s sums depend only on
input frames ``k .. k + L - 1``. So the recording is read in chunks of frames that overlap by the time
filter's ``L - 1`` frames, and the per-frame sums are exactly the whole video's. Memory is bounded by the
chunk, not the recording. What needs more than one chunk is chosen on a pilot:

1. **Pilot.** ``pilot_blocks`` runs of ``pilot_frames`` consecutive frames, spread evenly over the recording
   (fewer where they would read more than a third of it), go through the estimator's own steps: dead
   elements, the camera-artefact search, the measured noise model, every smoothing candidate with its exact
   standard error (the adjoint pass). The blocks are pooled as independent pieces of one estimate: the
   smoothing with the smallest pooled standard error is chosen (the estimator's rule), the noise model is
   the block of median noise, and fixed effects are used when any block needs them.
2. **Chunks.** The chosen smoothing balances every chunk; spikes and hot elements are repaired per chunk
   when the pilot found any.
3. **Standard error.** On every ``error_every``-th chunk (the first included) the noise lever is pushed back
   through the transposed filters, as the estimator does for the whole video; consecutive such chunks pass
   their overlapping frames on, so with ``error_every=1`` the variance is the whole video's exactly. The
   noise variance per unit of regressor energy on those chunks, ``c = sum var / sum energy``, scales to
   the recording: ``std_error = sqrt(c sum_k energy_k) / |sum_k den_k|``, with the noise variance's own
   error as in the estimator.
4. **Precision on demand.** With ``precision``, reading stops after the chunk where ``std_error / |a|``
   reaches it; the result says how many frames were used.

Per-pixel fixed effects (a static pattern) are removed within each chunk, not over the whole recording.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor
from tqdm.auto import tqdm

from anra_torch.balance import BatchNoise, batch_noise, find_artefacts, spectral_stage, stuck_pixels
from anra_torch.checks import MIN_RELIABILITY, MIN_SIGNIFICANCE, as_spacing, poor_fit, verdicts
from anra_torch.estimation.estimator import ANRAEstimator, ANRAResult
from anra_torch.layers import UniformAttention

__all__ = ["CHUNKED_VALUES", "CHUNK_BYTES", "ChunkedEstimate", "estimate_chunked"]

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


def _repaired(frames: Any, raw: Tensor, start: int, pilot: _Pilot, new: slice) -> tuple[Tensor, Any, int]:
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


_PILOT_SHARE = 3
"""The pilot reads at most one ``_PILOT_SHARE``-th of the recording's frames (at least one block): on a
short recording it would otherwise cost more than the estimate itself."""


def _pilot_starts(total: int, length: int, blocks: int) -> list[int]:
    """First frames of at most ``blocks`` runs of ``length`` frames spread evenly over ``total`` (no overlap),
    within :data:`_PILOT_SHARE`."""
    n = max(1, min(blocks, total // (_PILOT_SHARE * length)))
    if n == 1:
        return [(total - length) // 2]
    return [round(i * (total - length) / (n - 1)) for i in range(n)]


def _frames_total(frames: Any, length: int) -> int:
    """The recording's frame count, checked: a ``(T, H, W)`` shape with at least ``length`` frames."""
    shape = tuple(getattr(frames, "shape", ()))
    if len(shape) != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {shape}")
    if shape[0] < length:
        raise ValueError(f"need at least {length} frames for the time filter, got {shape[0]}")
    return shape[0]


def _check(
    estimator: ANRAEstimator, precision: float | None, chunk_frames: int, dtype: torch.dtype | None
) -> None:
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


@dataclass
class _Pilot:
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


def _pilot(est: ANRAEstimator, blocks: Tensor, dt: Tensor, dx: Tensor, side: int, total: int) -> _Pilot:
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
    return _Pilot(best, offset, dead, one, repair, best_a)


def estimate_chunked(
    frames: Any,
    dt: float,
    dx: float,
    *,
    estimator: ANRAEstimator | None = None,
    chunk_frames: int | None = None,
    pilot_blocks: int = 3,
    pilot_frames: int = 16,
    pilot_side: int = 256,
    precision: float | None = None,
    error_every: int = 4,
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
        estimator: the configuration (``mode="lsq"``, uniform weights, no window); default
            ``ANRAEstimator(strict=False)``.
        chunk_frames: output frames per chunk (each chunk reads ``L - 1`` frames more); default as many
            as keep one chunk's field under :data:`CHUNK_BYTES` (at most ``4 L`` with ``precision``).
        pilot_blocks: pilot blocks spread over the recording (fewer when they would read more than a third
            of its frames).
        pilot_frames: frames per pilot block.
        pilot_side: side (px) of the pilot's window of most change, where the noise is measured and the
            smoothing chosen.
        precision: stop reading once the relative standard error reaches it (e.g. 0.001); None reads
            every frame.
        error_every: push the noise lever back on every this many chunks (1: the exact standard error,
            at the cost of a second spatial pass per chunk).
        progress: show a tqdm progress bar over the frames.
        dtype: the computation's dtype, ``torch.float32`` or ``torch.float64`` (the accumulators are
            float64 either way); default float64 for float64 frames, else float32.
        device: where each chunk is computed (default: the frames' own device, the CPU for arrays).

    Returns:
        :class:`ChunkedEstimate`.

    Raises:
        ValueError: frames without a ``(T, H, W)`` shape or shorter than the time filter, a bad
            ``dt``/``dx``/``precision``/``chunk_frames``/``dtype``, an estimator this cannot accumulate, or
            (with a ``strict`` estimator) a recording without measurable thermal activity.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    est = ANRAEstimator(strict=False) if estimator is None else estimator
    chunk_frames = _chunk_frames(frames, est.time.length, precision) if chunk_frames is None else chunk_frames
    _check(est, precision, chunk_frames, dtype)
    _check_counts(
        error_every=error_every, pilot_blocks=pilot_blocks, pilot_frames=pilot_frames, pilot_side=pilot_side
    )
    total, length = _frames_total(frames, est.time.length), est.time.length
    like = _like(frames, dtype, device)  # the computation's dtype and device: every tensor follows it
    dt_ = as_spacing(dt, name="dt", unit="s", batch=1, like=like)
    dx_ = as_spacing(dx, name="dx", unit="mm", batch=1, like=like)
    block = min(total, max(pilot_frames, 2 * length))
    starts = _pilot_starts(total, block, pilot_blocks)
    blocks = torch.stack([_read(frames, s, s + block, like.dtype).to(like.device) for s in starts])
    pilot = _pilot(est, blocks, dt_, dx_, pilot_side, total)
    del blocks
    plan = (chunk_frames, error_every, precision, progress)
    sums, seen = _accumulate(frames, est, pilot, dt_, dx_, like.dtype, plan)
    result = _result(est, pilot, sums, seen, dt_, dx_)
    if est.strict and not bool(result.valid):
        raise ValueError(result.messages[0])
    return ChunkedEstimate(
        result=result,
        frames_used=seen["frames"],
        frames_total=total,
        chunk_frames=chunk_frames,
        pilot=tuple((s, s + block) for s in starts),
        gain=_gain(seen["error"]),
    )


def _accumulate(
    frames: Any,
    est: ANRAEstimator,
    pilot: _Pilot,
    dt: Tensor,
    dx: Tensor,
    dtype: torch.dtype,
    plan: tuple[int, int, float | None, bool],
) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Per-frame sums over the chunks (``rate_energy``, ``num``, ``den``, ``energy``, each ``(K,)``) and
    what was seen (frames read, masked samples, value range, the standard error's sums)."""

    chunk, every, precision, progress = plan
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
    error = _NoiseVariance(length)
    at = torch.tensor([pilot.a], dtype=dtype, device=dt.device)
    with tqdm(total=total, unit="frame", desc="anra chunks", disable=not progress) as bar:
        for j, start in enumerate(range(0, outputs, chunk)):
            stop = min(outputs, start + chunk)
            raw = _read(frames, start, stop + length - 1, dtype).to(dt.device)
            # One sum tells a chunk without non-finite samples (inf and NaN carry through it).
            everywhere = bool(torch.isfinite(raw.sum())) and not bool(pilot.dead.any())
            finite = None if everywhere else torch.isfinite(raw) & ~pilot.dead
            new = slice(seen["frames"] - start, None)  # input frames not counted by an earlier chunk
            seen["frames"] = stop + length - 1
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
                finite, everywhere, artefacts = None, True, (found,)
                seen["spikes"] += spikes
            noise = replace(pilot.noise, cleaned=video[None], artefacts=artefacts)
            first, last = start == 0, stop == outputs
            sampled = chained or first or last or j % every == 0
            sums = est.candidate_sums(
                pilot.index, video[None], None if finite is None else finite[None], dt, dx, noise,
                with_error=False,
                back_at=at if sampled else None,
            )  # fmt: skip
            for name, values in sums_of.items():
                values[start:stop] = getattr(sums, name)[0]
            if sums.back is not None:
                error.add(sums, noise, first=first, last=last, chained=chained)
            seen["finished"], seen["error"], seen["outputs"] = last, error, stop
            bar.update(seen["frames"] - bar.n)
            if precision is not None:
                a, se = _totals({k: v[:stop] for k, v in sums_of.items()}, error, seen, variance_error)[:2]
                if math.isfinite(se) and abs(a) > 0 and se <= precision * abs(a):
                    break
    return {name: values[: seen["outputs"]] for name, values in sums_of.items()}, seen


@dataclass
class _NoiseVariance:
    """The noise variance of ``sum w (U - a L) L``, added up over chunks from their pushed-back levers.

    Input frame ``t`` of the lever pushed back collects the outputs ``t - L + 1 .. t``. Chained (every
    chunk sampled), a chunk passes its last ``L - 1`` frames on to the next and every frame is added
    exactly (``exact``). Sampled, a chunk's first and last ``L - 1`` frames are incomplete: its interior
    frames give the variance per frame and unit of mean output energy, which scales to the recording's
    interior; the recording's own first and last ``L - 1`` frames (first and last chunks, always sampled)
    are added exactly.
    """

    length: int
    exact: float = 0.0
    interior: float = 0.0  # variance of the sampled interior frames
    weight: float = 0.0  # their number times their chunk's mean energy per output frame
    carry: Tensor | None = None

    def add(self, sums: Any, noise: BatchNoise, *, first: bool, last: bool, chained: bool) -> None:
        """Add one chunk's ``sums.back``; ``first`` and ``last`` say whether it starts or ends the
        recording."""
        back, edge = sums.back, self.length - 1

        def variance(part: Tensor) -> float:
            return float(noise.spread(part).double().pow(2).sum()) if part.shape[1] else 0.0

        if chained:
            if self.carry is not None:
                back = back.clone()
                back[:, :edge] += self.carry
            done, self.carry = (back, None) if last or not edge else (back[:, :-edge], back[:, -edge:])
            self.exact += variance(done)
            return
        if first:
            self.exact += variance(back[:, :edge])
        if last:
            self.exact += variance(back[:, back.shape[1] - edge :])
        interior = back[:, edge : back.shape[1] - edge]
        self.interior += variance(interior)
        self.weight += interior.shape[1] * float(sums.energy.double().mean())

    def total(self, energy: float, outputs: int, frames: int, finished: bool) -> float:
        """The variance over ``frames`` input frames (``outputs`` output frames of total ``energy``)."""
        if self.weight == 0:
            return self.exact
        interior = frames - (self.length - 1) * (1 + finished)
        return self.exact + self.interior / self.weight * energy / outputs * max(interior, 0)


def _gain(error: _NoiseVariance) -> float:
    """The sampled noise variance per frame and unit of mean output energy (NaN when chained)."""
    return error.interior / error.weight if error.weight > 0 else math.nan


def _totals(
    sums: dict[str, Tensor], variance: _NoiseVariance, seen: dict[str, Any], variance_error: float
) -> tuple[float, float, float]:
    """``(a, std_error, reliability)`` of the sums so far."""
    num, den, energy = (float(sums[name].sum()) for name in ("num", "den", "energy"))
    if not den > 0:
        return math.nan, math.nan, 0.0
    a = num / den
    outputs = sums["num"].shape[0]
    noise = variance.total(energy, outputs, seen["frames"], seen["finished"])
    correction = (energy - den) * variance_error
    return a, math.hypot(math.sqrt(max(noise, 0.0)) / den, a * correction / den), den / energy


def _result(
    est: ANRAEstimator,
    pilot: _Pilot,
    sums: dict[str, Tensor],
    seen: dict[str, Any],
    dt: Tensor,
    dx: Tensor,
) -> ANRAResult:
    """The :class:`ANRAResult` of the accumulated sums (one video, unbatched)."""
    variance_error = float(pilot.noise.variance_error[0])
    a, se, reliability = _totals(sums, seen["error"], seen, variance_error)

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
