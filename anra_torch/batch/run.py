"""The batch run: read every input, estimate and diagnose each as the commands do, write rows as they go.

What happens to each recording is the recording policy's (:mod:`anra_torch.recording`: the same phases,
routes and described phase as ``anra estimate``, the same diagnosis as ``anra diagnose``); this module
expands the inputs, shares estimator calls between recordings, and keeps the resumable table.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from tqdm.auto import tqdm

from anra_torch.batch.inputs import PathLike, expand_inputs
from anra_torch.batch.options import BatchOptions
from anra_torch.batch.resume import plan
from anra_torch.batch.table import check_format, parquet, read_table, row_key, write_table
from anra_torch.checks import check_output, join_messages, one_line
from anra_torch.estimation import ANRAEstimator
from anra_torch.recording import (
    RecordingEstimate,
    diagnose_video,
    diagnosis_copy,
    estimate_recordings,
    on_disk_above,
    open_recording,
)
from anra_torch.video import Video

__all__ = ["BatchSummary", "process_paths", "run_batch"]

_DIAGNOSIS_COLUMNS = ("top_effect", "effects", "gain", "noise_floor", "base_rmse", "extended_rmse")


def _error_row(path: str, message: str) -> dict[str, Any]:
    return {"path": path, "status": "error", "error": message}


def _open(path: str, options: BatchOptions) -> Video:
    """The recording as ``anra estimate`` reads it: left on disk above
    :data:`~anra_torch.estimation.CHUNKED_VALUES` pixel values (any, with ``precision``), else prepared."""
    return open_recording(
        path,
        dt=options.dt,
        dx=options.dx,
        roi=options.roi,
        calibration=options.calibration,
        on_disk_above=on_disk_above(options.precision),
    )


def _diagnose_row(row: dict[str, Any], video: Video, options: BatchOptions) -> None:
    """The diagnosis columns of ``row``, as ``anra diagnose`` reports the recording: above
    :data:`~anra_torch.recording.DIAGNOSE_VALUES` pixel values on its block-averaged copy (read
    chunk by chunk, and ``message`` says so), phase by phase, the longest analysed phase described."""
    start = time.perf_counter()
    try:
        copy, decimated = diagnosis_copy(video)
        copy = copy.loaded().map_frames(lambda f: torch.as_tensor(f).to(options.device))
        diagnosed = diagnose_video(copy, fit_fraction=options.fit_fraction, decimated=decimated)
        record = diagnosed.to_record()
    except (ValueError, TypeError) as err:
        row.update(status="error", error=f"{video.source}: diagnose: {one_line(err)}")
        return
    if decimated is not None:
        k, m = decimated["space_px"], decimated["time_frames"]
        said = f"diagnosed on a copy averaged over {k} x {k} px and {m} frames"
        row["message"] = join_messages([row.get("message"), said])
    names = [e["name"] for e in record["effects"]]
    row.update(
        top_effect=names[0] if names else "none",
        effects=";".join(names),
        gain=record["gain"],
        noise_floor=record["noise_floor"],
        base_rmse=record["base"]["prediction_rmse"],
        extended_rmse=record["extended"]["prediction_rmse"],
        seconds=row["seconds"] + time.perf_counter() - start,
    )


def process_paths(paths: Sequence[str], options: BatchOptions) -> list[dict[str, Any]]:
    """One row per path, in order: read, estimate (same-shaped phases of many recordings together), and
    diagnose if asked, each recording as the commands treat it (:mod:`anra_torch.recording`).

    Never raises for a bad input: its row says ``status="error"`` with the one-line reason. Used as is by
    the local run and by each Dask task.
    """
    rows: dict[int, dict[str, Any]] = {}
    videos: dict[int, Video] = {}
    for i, path in enumerate(paths):
        try:
            videos[i] = _open(path, options)
        except (ValueError, TypeError, OSError) as err:
            rows[i] = _error_row(path, one_line(err))
    order = list(videos)
    dtype = getattr(torch, options.dtype)
    est = ANRAEstimator(strict=False).to(options.device)  # the frames follow the estimator
    done = estimate_recordings([videos[i] for i in order], est, precision=options.precision, dtype=dtype)
    for i, estimate in zip(order, done, strict=True):
        if not isinstance(estimate, RecordingEstimate):
            rows[i] = _error_row(paths[i], str(estimate))
            continue
        row = {**estimate.row(), "path": paths[i]}
        if options.diagnose and row["status"] == "ok":
            _diagnose_row(row, videos[i], options)
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


def run_batch(
    inputs: Iterable[PathLike],
    out: PathLike,
    *,
    options: BatchOptions | None = None,
    batch_size: int = 8,
    progress: bool = True,
    runner: Runner | None = None,
    rerun: bool = False,
) -> BatchSummary:
    """Estimate (and optionally diagnose) every input video into a resumable table.

    Args:
        inputs: files, folders or glob patterns (see :func:`expand_inputs`).
        out: the table, ``.csv`` or ``.parquet`` (Parquet needs the ``parquet`` extra), none of the inputs
            (a folder holding it leaves it out); rows of earlier runs are kept, inputs ``ok`` are skipped.
        options: what every video shares (:class:`BatchOptions`); default ``BatchOptions()``.
        batch_size: consecutive inputs read and estimated together (same-shaped ones in one call); also the
            number of rows at risk if the run is interrupted.
        progress: show a tqdm progress bar on stderr.
        runner: how chunks are processed; default in this process (see :mod:`anra_torch.batch.dask`).
        rerun: recompute and replace ``ok`` rows made with other parameters (otherwise they stop the run).

    Returns:
        :class:`BatchSummary`.

    Shape:
        No tensors: each video is read as ``(T, H, W)`` frames and estimated with same-shaped others.

    Raises:
        ValueError: an ``out`` with a bad suffix, among the inputs, not a batch table or (without ``rerun``)
            holding ``ok`` rows of these inputs made with other parameters; ``batch_size`` < 1; bad options
            (``dtype``, ``precision``, ``roi``, calibration file). Bad inputs never raise: error rows.
    """
    out = Path(out)
    options = BatchOptions() if options is None else options
    _check_run(out, batch_size, options.dtype)
    options = options.checked()
    start = time.perf_counter()
    check_output(out, inputs, name="--out")
    paths = [p for p in expand_inputs(inputs) if Path(p).resolve() != out.resolve()]  # never its own table
    table = {row_key(row["path"]): row for row in read_table(out)}
    todo, stamps, changed = plan(paths, table, options, rerun=rerun, out=out)
    key = json.dumps(options.parameters(), sort_keys=True)
    skipped = len(paths) - len(todo)
    ok = failed = 0
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
