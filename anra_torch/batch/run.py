"""The batch run: load every input, estimate same-shaped videos together, diagnose, write rows as they go."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch

from anra_torch.batch.inputs import PathLike, expand_inputs
from anra_torch.batch.options import BatchOptions
from anra_torch.batch.resume import plan
from anra_torch.batch.table import check_format, parquet, read_table, row_key, write_table
from anra_torch.checks import join_messages, one_line
from anra_torch.chunked import CHUNKED_VALUES, estimate_chunked
from anra_torch.estimator import ANRAEstimator, ANRAResult
from anra_torch.video import (
    ROI,
    CalibrationTable,
    Video,
    input_warnings,
    load_calibration,
    parse_roi,
    prepare_video,
)
from anra_torch.video.lazy import frame_span, in_memory, lazy_video
from anra_torch.video.phases import MIN_PHASE_FRAMES, phase_preference

__all__ = ["BatchSummary", "process_paths", "run_batch"]

_RECORD_COLUMNS = (
    "diffusivity",
    "std_error",
    "smoothing_px",
    "noise_sd",
    "reliability",
    "n_masked",
    "explained",
)
"""The columns taken as they are from :meth:`~anra_torch.estimator.ANRAResult.to_record`."""
_DIAGNOSIS_COLUMNS = ("top_effect", "effects", "gain", "noise_floor", "base_rmse", "extended_rmse")


def _error_row(path: str, message: str) -> dict[str, Any]:
    return {"path": path, "status": "error", "error": message}


def _message(record: dict[str, Any], video: Video) -> str:
    """The ``message`` cell of an estimator record: what the input policy masked, the estimator's warnings,
    then its own line (a warning on a valid result, or why nothing was measured)."""
    return join_messages([*input_warnings(video), *(record.get("warnings") or []), record.get("message")])


def _load(path: str, options: BatchOptions) -> Video:
    return prepare_video(
        path,
        dt=options.dt,
        dx=options.dx,
        timestamps="resample",  # as every command: only non-uniform timestamps are resampled, and said so
        roi=options.roi,
        calibration=options.calibration,
    )


def _phase_part(video: Video) -> tuple[Video, str | None]:
    """For a recording with a heating and a cooling, the phase its diffusivity is measured on (the preferred
    one with frames enough, :func:`~anra_torch.video.phases.phase_preference`, as ``anra estimate`` prefers)
    and its kind; the video itself and None for a recording of one phase."""
    # The forecast stack is imported only where phases are looked for.
    from anra_torch.forecast.recording import find_phases

    phases = find_phases(video.frames, video.t, dt=video.dt, measured_t=video.meta.get("measured_t"))
    usable = [p for p in phases if p.frames >= MIN_PHASE_FRAMES]
    if len(phases) < 2 or not usable:
        return video, None
    phase = max(usable, key=phase_preference)
    span = slice(phase.start, phase.stop)
    frames = frame_span(video.frames, phase.start, phase.stop)  # a recording on disk stays unread
    return replace(video, frames=frames, t=None if video.t is None else video.t[span]), phase.name


def _preparation(video: Video) -> dict[str, Any]:
    """The ``roi`` and ``calibration`` cells: what :func:`prepare_video` did to this video."""
    roi = video.meta.get("roi")
    calibration = video.meta.get("calibration")
    return {
        "roi": ",".join(str(v) for v in roi) if roi else None,
        "calibration": calibration["table"] if calibration else None,
    }


def _estimate_group(videos: list[Video], options: BatchOptions) -> list[dict[str, Any]]:
    """Rows of same-shaped videos estimated in one estimator call."""
    dtype = getattr(torch, options.dtype)
    est = ANRAEstimator(strict=False)
    start = time.perf_counter()
    frames = torch.stack([v.frames.to(dtype) for v in videos])
    dt = torch.tensor([v.dt for v in videos], dtype=torch.float64)
    dx = torch.tensor([v.dx for v in videos], dtype=torch.float64)
    result = est(frames, dt, dx)
    share = (time.perf_counter() - start) / len(videos)
    return [_row(video, result, i, share) for i, video in enumerate(videos)]


def _row(video: Video, result: ANRAResult, index: int, seconds: float) -> dict[str, Any]:
    """The row of video ``index`` of a (batched) result."""
    record = result.to_record(index)
    return _record_row(video, record, {key: record[key] for key in _RECORD_COLUMNS}, seconds)


def _record_row(
    video: Video, record: dict[str, Any], columns: dict[str, Any], seconds: float
) -> dict[str, Any]:
    """The row of one estimate ``record`` (``valid``, ``message``) with its result ``columns``: an error row
    with the reason when it is not valid, its numbers kept."""
    t, h, w = video.frames.shape
    ok = record["valid"]
    return {
        "path": str(video.source),
        "status": "ok" if ok else "error",
        "error": "" if ok else f"{video.source}: {record['message']}",
        **columns,
        "frames": t,
        "height": h,
        "width": w,
        "dt": video.dt,
        "dx": video.dx,
        "a_true": video.truth.a if video.truth is not None else None,
        "seconds": seconds,
        **_preparation(video),
        "message": _message(record, video),
    }


def _small_box_row(video: Video) -> dict[str, Any]:
    """The row of a region too small for the filters: the small-box estimate, as ``anra estimate`` gives
    it (:func:`~anra_torch.forecast.small_box.small_box_estimate`)."""
    from anra_torch.forecast.small_box import small_box_estimate

    start = time.perf_counter()
    record = small_box_estimate(in_memory(video.frames), video.dt, video.dx)
    columns = {"diffusivity": record["diffusivity"], "std_error": record["std_error"]}
    return _record_row(video, record, columns, time.perf_counter() - start)


def _small(video: Video) -> bool:
    """Whether ``video`` is a region too small for the estimator's filters (with frames enough for them)."""
    est = ANRAEstimator(strict=False)
    t, h, w = video.frames.shape
    return min(h, w) < est.minimum_frame_size and t >= est.time.length


def _large(path: str, options: BatchOptions) -> Video | None:
    """A recording to read in time chunks: over :data:`~anra_torch.chunked.CHUNKED_VALUES` pixel values,
    or any with ``precision``; left on disk when it is a ``.npy`` or an uncompressed ``.npz`` (no region or
    calibration), else loaded. None for the others."""
    if options.roi is None and options.calibration is None:
        video = lazy_video(path, dt=options.dt, dx=options.dx)
        if video is not None and (options.precision or math.prod(video.frames.shape) > CHUNKED_VALUES):
            return video
    return _load(path, options) if options.precision else None


def _estimate_large(video: Video, options: BatchOptions) -> dict[str, Any]:
    """The row of a recording read in time chunks (:func:`~anra_torch.chunked.estimate_chunked`)."""
    start = time.perf_counter()
    dtype = getattr(torch, options.dtype)
    # With a precision target the recording is one phase, as in anra estimate: phases would read all of it.
    part, kind = (video, None) if options.precision else _phase_part(video)
    done = estimate_chunked(part.frames, part.dt, part.dx, precision=options.precision, dtype=dtype)
    row = _row(part, done.result, 0, time.perf_counter() - start)
    row.update(frames_used=done.frames_used, phase=kind)
    if options.diagnose and row["status"] == "ok":
        _diagnose_row(row, video, options)
    return row


def _estimate_large_all(
    videos: list[tuple[int, Video]], options: BatchOptions
) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(index, row)`` of each recording read in chunks. Several at once, one per torch thread, each on one
    thread: their medians and memory-bound passes then use every core (``experiments/bench_batch.py``). A
    recording that fails gets its error row; the others go on."""

    def one(item: tuple[int, Video]) -> tuple[int, dict[str, Any]]:
        i, video = item
        try:
            return i, _estimate_large(video, options)
        except (ValueError, TypeError, OSError, RuntimeError) as err:
            return i, _error_row(str(video.source), one_line(err))

    threads = torch.get_num_threads()
    workers = min(len(videos), threads)
    if workers < 2:
        yield from map(one, videos)
        return
    torch.set_num_threads(1)
    try:
        with ThreadPoolExecutor(workers) as pool:
            yield from pool.map(one, videos)
    finally:
        torch.set_num_threads(threads)


def _diagnose_row(row: dict[str, Any], video: Video, options: BatchOptions) -> None:
    """The diagnosis columns of ``row``. A recording above
    :data:`~anra_torch.forecast.decimate.DIAGNOSE_VALUES` pixel values is diagnosed on its block-averaged
    copy (read chunk by chunk), and ``message`` says so."""
    from anra_torch.forecast import assess_gain, decimate

    start = time.perf_counter()
    try:
        copy, decimated = decimate.camera_copy(video, decimate.DIAGNOSE_VALUES)
        result = assess_gain(in_memory(copy.frames), copy.dt, copy.dx, fit_fraction=options.fit_fraction)
    except (ValueError, TypeError) as err:
        row.update(status="error", error=f"{video.source}: diagnose: {one_line(err)}")
        return
    if decimated is not None:
        k, m = decimated["space_px"], decimated["time_frames"]
        said = f"diagnosed on a copy averaged over {k} x {k} px and {m} frames"
        row["message"] = join_messages([row.get("message"), said])
    names = [e["name"] for e in result.diagnosis.effects]
    row.update(
        top_effect=names[0] if names else "none",
        effects=";".join(names),
        gain=result.gain,
        noise_floor=result.noise_floor,
        base_rmse=result.base_rmse,
        extended_rmse=result.extended_rmse,
        seconds=row["seconds"] + time.perf_counter() - start,
    )


def process_paths(paths: Sequence[str], options: BatchOptions) -> list[dict[str, Any]]:
    """One row per path, in order: load, estimate same-shaped videos together, diagnose if asked.

    Never raises for a bad input: its row says ``status="error"`` with the one-line reason. Used as is by
    the local run and by each Dask task.
    """
    rows: dict[int, dict[str, Any]] = {}
    phases: dict[int, str | None] = {}  # the phase a recording with several is estimated on
    groups: dict[tuple[int, ...], list[tuple[int, Video]]] = {}
    large: list[tuple[int, Video]] = []
    for i, path in enumerate(paths):
        try:
            found = _large(path, options)
            if found is not None:
                large.append((i, found))
                continue
            video, phases[i] = _phase_part(_load(path, options))
        except (ValueError, TypeError, OSError) as err:
            rows[i] = _error_row(path, one_line(err))
            continue
        groups.setdefault(tuple(video.frames.shape), []).append((i, video))
    for i, row in _estimate_large_all(large, options):
        rows[i] = {**row, "path": paths[i]}
    for members in groups.values():
        try:
            found = _estimate_group([v for _, v in members], options)
        except (ValueError, TypeError, RuntimeError):
            # Something in the batch is wrong (e.g. frames too small): estimate one by one for exact rows.
            found = []
            for i, video in members:
                try:
                    found.append(
                        _small_box_row(video) if _small(video) else _estimate_group([video], options)[0]
                    )
                except (ValueError, TypeError, RuntimeError) as err:
                    found.append(_error_row(paths[i], f"{video.source}: {one_line(err)}"))
        for (i, video), row in zip(members, found, strict=True):
            row["path"], row["phase"] = paths[i], phases.get(i)
            if options.diagnose and row["status"] == "ok":
                _diagnose_row(row, video, options)
            rows[i] = row
    return [rows[i] for i in range(len(paths))]


def _chunks(items: Sequence[str], size: int) -> Iterator[list[str]]:
    for start in range(0, len(items), size):
        yield list(items[start : start + size])


@dataclass(frozen=True)
class BatchSummary:
    """What :func:`run_batch` did.

    Attributes:
        out: the table written.
        total: inputs after expansion.
        skipped: inputs already done in an earlier run.
        ok: inputs processed now with status ``ok``.
        failed: inputs processed now with status ``error``.
        seconds: wall time of this run.
    """

    out: Path
    total: int
    skipped: int
    ok: int
    failed: int
    seconds: float


Runner = Callable[[list[list[str]], BatchOptions], Iterable[list[dict[str, Any]]]]
"""Maps chunks of paths to their rows, yielding one list per chunk as it finishes (any order)."""


def _local_runner(chunks: list[list[str]], options: BatchOptions) -> Iterator[list[dict[str, Any]]]:
    for chunk in chunks:
        yield process_paths(chunk, options)


def _check_run(out: Path, batch_size: object, dtype: object) -> None:
    """The checks of :func:`run_batch` on its table, batch size and dtype (see its Raises)."""
    check_format(out)
    if not (isinstance(batch_size, int) and batch_size >= 1):
        raise ValueError(f"batch_size must be an integer >= 1, got {batch_size!r}")
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    if out.suffix.lower() == ".parquet":
        parquet()


def _options(
    *,
    roi: ROI | str | None,
    calibration: CalibrationTable | PathLike | None,
    precision: float | None,
    **rest: Any,
) -> BatchOptions:
    """The checked options: a malformed region, a bad calibration file or precision is the caller's
    mistake, not one row's."""
    if roi is not None:
        roi = parse_roi(roi if isinstance(roi, str) else ",".join(str(v) for v in roi))
    if calibration is not None and not isinstance(calibration, CalibrationTable):
        calibration = load_calibration(calibration)
    if precision is not None and not (isinstance(precision, int | float) and 0 < precision < 1):
        raise ValueError(f"precision must be a relative standard error in (0, 1), got {precision!r}")
    return BatchOptions(roi=roi, calibration=calibration, precision=precision, **rest)


def run_batch(
    inputs: Iterable[PathLike],
    out: PathLike,
    *,
    dt: float | None = None,
    dx: float | None = None,
    diagnose: bool = False,
    batch_size: int = 8,
    dtype: str = "float32",
    progress: bool = True,
    runner: Runner | None = None,
    resample: bool = False,
    roi: ROI | str | None = None,
    calibration: CalibrationTable | PathLike | None = None,
    rerun: bool = False,
    precision: float | None = None,
) -> BatchSummary:
    """Estimate (and optionally diagnose) every input video into a resumable table.

    Args:
        inputs: files, folders or glob patterns (see :func:`expand_inputs`).
        out: the table, ``.csv`` or ``.parquet`` (Parquet needs the ``parquet`` extra); rows of earlier
            runs are kept, inputs already ``ok`` are skipped.
        dt: frame period in s overriding the files.
        dx: pixel size in mm overriding the files.
        diagnose: also diagnose each video (hidden effects, forecast gain; ~1-5 s per video).
        batch_size: consecutive inputs read and estimated together (same-shaped ones in one call); also the
            number of rows at risk if the run is interrupted.
        dtype: ``"float32"`` (default, fast) or ``"float64"``.
        progress: show a tqdm progress bar on stderr.
        runner: how chunks are processed; default in this process (see :mod:`anra_torch.distributed`).
        resample: resample non-uniform timestamps onto a uniform step instead of an error row.
        roi: analyse only this region of every video: ``(x0, y0, width, height)`` px or ``"X0,Y0,W,H"``; a
            video it does not fit gets an error row.
        calibration: map apparent to true temperature in every video: a table or the path of a
            ``true,apparent`` CSV (read once, here).
        rerun: recompute and replace ``ok`` rows made with other parameters (otherwise they stop the run).
        precision: read each video in time chunks until its relative standard error reaches it (e.g.
            0.001; :func:`~anra_torch.chunked.estimate_chunked`); ``frames_used`` says how many were read.

    Returns:
        :class:`BatchSummary`.

    Shape:
        No tensors: each video is read as ``(T, H, W)`` frames and estimated with same-shaped others.

    Raises:
        ValueError: bad ``out`` suffix, ``batch_size`` < 1, unknown ``dtype``, a ``precision`` outside (0, 1),
            a malformed ``roi``, a bad calibration file, an ``out`` that is not a batch table or (without
            ``rerun``) holds ``ok`` rows of these inputs made with other parameters. Bad inputs never raise:
            they get error rows.
    """
    out = Path(out)
    _check_run(out, batch_size, dtype)
    given = {"dt": dt, "dx": dx, "diagnose": diagnose, "dtype": dtype, "resample": resample, "roi": roi}
    options = _options(**given, calibration=calibration, precision=precision)
    start = time.perf_counter()
    paths = expand_inputs(inputs)
    table = {row_key(row["path"]): row for row in read_table(out)}
    todo, stamps, changed = plan(paths, table, options, rerun=rerun, out=out)
    key = json.dumps(options.parameters(), sort_keys=True)
    skipped = len(paths) - len(todo)
    ok = failed = 0
    from tqdm.auto import tqdm

    with tqdm(total=len(todo), unit="video", desc="anra batch", disable=not progress) as bar:
        for rows in (runner or _local_runner)(list(_chunks(todo, batch_size)), options):
            for row in rows:
                row |= {"input_stamp": stamps.get(row["path"], ""), "parameters": key}
                if row["path"] in changed:
                    row["message"] = join_messages([row.get("message"), "recomputed: the input has changed"])
                table[row_key(row["path"])] = row
                ok += row["status"] == "ok"
                failed += row["status"] != "ok"
            write_table(out, list(table.values()))
            bar.update(len(rows))
    if not todo and not out.exists():
        write_table(out, [])
    return BatchSummary(out, len(paths), skipped, ok, failed, time.perf_counter() - start)
