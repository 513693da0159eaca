"""Many videos in one run: input expansion, batched estimation, resumable atomic CSV/Parquet tables.

:func:`run_batch` reads every input (files, folders, glob patterns; any format in
:data:`anra_torch.video.REGISTRY`) as :func:`anra_torch.video.prepare_video` does for every command (resample,
region of interest, calibration), sends same-shaped videos through one
:class:`~anra_torch.estimator.ANRAEstimator` call as a batch, optionally diagnoses each video
(:func:`anra_torch.forecast.assess_gain`) and writes one row per input:

- ``path``; ``status`` (``"ok"`` or ``"error"``); ``error`` (one line, empty when ok);
- ``diffusivity``, ``std_error`` (mm^2/s); ``smoothing_px`` (px); ``noise_sd`` (data units);
  ``reliability``; ``n_masked``; ``frames``, ``height``, ``width`` (px); ``dt`` (s); ``dx`` (mm);
  ``a_true`` (mm^2/s, when the file records it); ``seconds`` (this video's share of its batch's time);
- with ``diagnose``: ``top_effect`` (``"none"`` for pure heat diffusion), ``effects`` (``;``-separated),
  ``gain``, ``noise_floor`` (data units), ``base_rmse``, ``extended_rmse`` (data units);
- ``roi`` (``"X0,Y0,W,H"`` px) and ``calibration`` (the table's path) when the video was cropped or
  calibrated, else empty.

A bad input (missing, unreadable, too small, no thermal activity) gets an ``error`` row and never stops the
others. The table is rewritten after every batch through a temporary file and :func:`os.replace`, so an
interrupted run keeps every finished row; re-running skips the inputs whose rows are already ``ok`` (errors
are retried).
"""

from __future__ import annotations

import csv
import glob
import math
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from anra_torch.checks import one_line
from anra_torch.estimator import ANRAEstimator
from anra_torch.video import (
    FOLDER_REGISTRY,
    REGISTRY,
    ROI,
    CalibrationTable,
    Video,
    load_calibration,
    parse_roi,
    prepare_video,
)

__all__ = ["BATCH_COLUMNS", "BatchSummary", "expand_inputs", "read_table", "run_batch", "write_table"]

PathLike = str | os.PathLike[str]

BATCH_COLUMNS: dict[str, type] = {
    "path": str,
    "status": str,
    "error": str,
    "diffusivity": float,
    "std_error": float,
    "smoothing_px": float,
    "noise_sd": float,
    "reliability": float,
    "n_masked": int,
    "frames": int,
    "height": int,
    "width": int,
    "dt": float,
    "dx": float,
    "a_true": float,
    "seconds": float,
    "top_effect": str,
    "effects": str,
    "gain": float,
    "noise_floor": float,
    "base_rmse": float,
    "extended_rmse": float,
    "roi": str,
    "calibration": str,
}
"""Output columns and their types (missing values are empty cells in CSV, nulls in Parquet)."""

_RECORD_COLUMNS = ("diffusivity", "std_error", "smoothing_px", "noise_sd", "reliability", "n_masked")
"""The columns taken as they are from :meth:`~anra_torch.estimator.ANRAResult.to_record`."""
_DIAGNOSIS_COLUMNS = ("top_effect", "effects", "gain", "noise_floor", "base_rmse", "extended_rmse")
_FORMATS = (".csv", ".parquet")


# ------------------------------------------------------------------------------------------- inputs
def _is_video_file(path: Path) -> bool:
    name = path.name.lower()
    return path.is_file() and any(name.endswith(suffix) for suffix in REGISTRY)


def _is_video_folder(path: Path) -> bool:
    """A folder that is itself one video (:data:`anra_torch.video.FOLDER_REGISTRY`): one file per frame.

    JPEGs are always single frames (FLIR radiometric JPEGs), so a folder holding them is one video. A
    ``.csv`` / ``.txt`` file is either a per-frame matrix (its first line is numbers) or a whole video (a
    FLIR CSV export starts with a header): the first such file decides.
    """
    if not path.is_dir():
        return False
    frames = sorted(
        child
        for child in path.iterdir()
        if child.is_file() and not child.name.startswith(".") and child.suffix.lower() in FOLDER_REGISTRY
    )
    if not frames:
        return False
    if any(f.suffix.lower() in (".jpg", ".jpeg") for f in frames):
        return True
    try:
        with frames[0].open("r", errors="replace") as handle:
            first = next((line for line in handle if line.strip()), "")
        [float(x) for x in first.replace(",", " ").split()]
    except (OSError, ValueError):
        return False
    return bool(first.strip())


def expand_inputs(inputs: Iterable[PathLike]) -> list[str]:
    """Turn files, folders and glob patterns into the list of videos to process, in a stable order.

    - a file is kept as given (a wrong format fails later, in its own row);
    - a folder contributes its video files (suffixes of :data:`REGISTRY`, recursively, sorted), or itself
      when it is one video (:func:`_is_video_folder`);
    - a pattern with ``*``, ``?`` or ``[`` contributes its matches (recursive ``**``), filtered like a folder;
    - anything else (a missing file, a pattern without match, an empty folder) is kept as given, so that it
      gets an error row instead of vanishing.

    Duplicates are dropped (first occurrence wins).

    Shape:
        No tensors.
    """
    out: list[str] = []
    for item in inputs:
        text = os.fspath(item)
        path = Path(text)
        if glob.has_magic(text):
            matches = [Path(m) for m in sorted(glob.glob(text, recursive=True))]
            found = [str(m) for m in matches if _is_video_file(m) or _is_video_folder(m)]
            for m in matches:
                if m.is_dir() and not _is_video_folder(m):
                    found.extend(expand_inputs([m]))
            out.extend(found or [text])
        elif path.is_dir() and not _is_video_folder(path):
            folders = [f for f in sorted(path.rglob("*")) if _is_video_folder(f)]
            found = [
                str(f)
                for f in sorted(path.rglob("*"))
                if f in folders or (_is_video_file(f) and f.parent not in folders)
            ]
            out.extend(found or [text])
        else:
            out.append(text)
    return list(dict.fromkeys(out))


# -------------------------------------------------------------------------------------------- table
def _key(path: str) -> str:
    return os.path.realpath(path)


def _check_format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _FORMATS:
        raise ValueError(f"--out must end in {' or '.join(_FORMATS)}, got {path.name!r}")
    return suffix


def _parquet():
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as err:
        raise ImportError("Parquet output needs pyarrow: pip install 'anra_torch[parquet]'") from err
    return pa, pq


def _typed(value: Any, kind: type) -> Any:
    """A cell as its column type (CSV cells come back as strings); None for empty or non-finite."""
    if value is None or value == "":
        return None
    if kind is float:
        number = float(value)
        return number if math.isfinite(number) else None
    if kind is int:
        return int(float(value))
    return str(value)


def read_table(path: PathLike) -> list[dict[str, Any]]:
    """Rows of a batch table (CSV or Parquet) with typed cells; ``[]`` when the file does not exist.

    Raises:
        ValueError: unsupported suffix, or a table without ``path`` and ``status`` columns.
    """
    path = Path(path)
    suffix = _check_format(path)
    if not path.exists():
        return []
    if suffix == ".csv":
        with path.open(newline="", encoding="utf-8") as handle:
            raw = list(csv.DictReader(handle))
            header = raw[0].keys() if raw else ()
    else:
        _, pq = _parquet()
        table = pq.read_table(path)
        raw, header = table.to_pylist(), table.column_names
    if raw and not {"path", "status"} <= set(header):
        raise ValueError(f"{path}: not a batch table: needs 'path' and 'status' columns, got {list(header)}")
    return [{k: _typed(row.get(k), kind) for k, kind in BATCH_COLUMNS.items()} for row in raw]


def write_table(path: PathLike, rows: Sequence[dict[str, Any]]) -> Path:
    """Write rows atomically: a temporary file in the same folder, then :func:`os.replace`.

    An interruption at any moment leaves either the previous table or the new one, never a partial file.
    """
    path = Path(path)
    suffix = _check_format(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean = [{k: _typed(row.get(k), kind) for k, kind in BATCH_COLUMNS.items()} for row in rows]
    handle, temp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        if suffix == ".csv":
            with os.fdopen(handle, "w", newline="", encoding="utf-8") as out:
                writer = csv.DictWriter(out, fieldnames=list(BATCH_COLUMNS))
                writer.writeheader()
                writer.writerows({k: ("" if v is None else v) for k, v in row.items()} for row in clean)
                out.flush()
                os.fsync(out.fileno())
        else:
            os.close(handle)
            pa, pq = _parquet()
            types = {str: pa.string(), float: pa.float64(), int: pa.int64()}
            schema = pa.schema([(k, types[kind]) for k, kind in BATCH_COLUMNS.items()])
            pq.write_table(pa.Table.from_pylist(clean, schema=schema), temp)
        os.replace(temp, path)
    except BaseException:
        Path(temp).unlink(missing_ok=True)
        raise
    return path


# --------------------------------------------------------------------------------------- processing
@dataclass(frozen=True)
class BatchOptions:
    """What every video of a batch run shares (picklable, sent to Dask workers as is).

    Attributes:
        dt: frame period in s overriding the files, or None.
        dx: pixel size in mm overriding the files, or None.
        diagnose: also diagnose each video and forecast held-out frames.
        dtype: ``"float32"`` (fast) or ``"float64"``.
        fit_fraction: fraction of the frames diagnosed with ``diagnose``.
        resample: resample non-uniform timestamps (FLIR JPEG folders) onto their median step
            (:func:`anra_torch.video.resample_uniform`); otherwise such a video is an error row.
        roi: region ``(x0, y0, width, height)`` in px analysed in every video, or None.
        calibration: apparent -> true temperature table applied to every video, or None (the table
            itself, not its path: Dask workers need not read it).

    Shape:
        No tensors.
    """

    dt: float | None = None
    dx: float | None = None
    diagnose: bool = False
    dtype: str = "float32"
    fit_fraction: float = 0.6
    resample: bool = False
    roi: ROI | None = None
    calibration: CalibrationTable | None = None


def _error_row(path: str, message: str) -> dict[str, Any]:
    return {"path": path, "status": "error", "error": message}


def _load(path: str, options: BatchOptions) -> Video:
    return prepare_video(
        path,
        dt=options.dt,
        dx=options.dx,
        timestamps="resample" if options.resample else "uniform",
        roi=options.roi,
        calibration=options.calibration,
    )


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
    rows = []
    for i, video in enumerate(videos):
        t, h, w = video.frames.shape
        record = result.to_record(i)
        ok = record["valid"]
        rows.append(
            {
                "path": str(video.source),
                "status": "ok" if ok else "error",
                "error": "" if ok else f"{video.source}: {record['message']}",
                **{key: record[key] for key in _RECORD_COLUMNS},
                "frames": t,
                "height": h,
                "width": w,
                "dt": video.dt,
                "dx": video.dx,
                "a_true": video.truth.a if video.truth is not None else None,
                "seconds": share,
                **_preparation(video),
            }
        )
    return rows


def _diagnose_row(row: dict[str, Any], video: Video, options: BatchOptions) -> None:
    from anra_torch.forecast import assess_gain

    start = time.perf_counter()
    try:
        result = assess_gain(video.frames, video.dt, video.dx, fit_fraction=options.fit_fraction)
    except (ValueError, TypeError) as err:
        row.update(status="error", error=f"{video.source}: diagnose: {one_line(err)}")
        return
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
    groups: dict[tuple[int, ...], list[tuple[int, Video]]] = {}
    for i, path in enumerate(paths):
        try:
            video = _load(path, options)
        except (ValueError, TypeError, OSError) as err:
            rows[i] = _error_row(path, one_line(err))
            continue
        groups.setdefault(tuple(video.frames.shape), []).append((i, video))
    for members in groups.values():
        try:
            found = _estimate_group([v for _, v in members], options)
        except (ValueError, TypeError, RuntimeError):
            # Something in the batch is wrong (e.g. frames too small): estimate one by one for exact rows.
            found = []
            for i, video in members:
                try:
                    found.extend(_estimate_group([video], options))
                except (ValueError, TypeError, RuntimeError) as err:
                    found.append(_error_row(paths[i], f"{video.source}: {one_line(err)}"))
        for (i, video), row in zip(members, found, strict=True):
            row["path"] = paths[i]
            if options.diagnose and row["status"] == "ok":
                _diagnose_row(row, video, options)
            rows[i] = row
    return [rows[i] for i in range(len(paths))]


def _chunks(items: Sequence[str], size: int) -> Iterator[list[str]]:
    for start in range(0, len(items), size):
        yield list(items[start : start + size])


def _done(row: dict[str, Any], options: BatchOptions) -> bool:
    if row.get("status") != "ok":
        return False
    return not options.diagnose or row.get("top_effect") not in (None, "")


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
        resample: resample non-uniform timestamps onto their median step instead of an error row.
        roi: analyse only this region of every video: ``(x0, y0, width, height)`` px or ``"X0,Y0,W,H"``; a
            video it does not fit gets an error row.
        calibration: map apparent to true temperature in every video: a table or the path of a
            ``true,apparent`` CSV (read once, here).

    Returns:
        :class:`BatchSummary`.

    Shape:
        No tensors: each video is read as ``(T, H, W)`` frames and estimated with same-shaped others.

    Raises:
        ValueError: bad ``out`` suffix, ``batch_size`` < 1, unknown ``dtype``, a malformed ``roi``, a bad
            calibration file, or an existing ``out`` that is not a batch table. Bad inputs never raise: they
            get error rows.
    """
    out = Path(out)
    _check_format(out)
    if not (isinstance(batch_size, int) and batch_size >= 1):
        raise ValueError(f"batch_size must be an integer >= 1, got {batch_size!r}")
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    if out.suffix.lower() == ".parquet":
        _parquet()
    if roi is not None:  # a malformed region is the caller's mistake, not one row's
        roi = parse_roi(roi if isinstance(roi, str) else ",".join(str(v) for v in roi))
    if calibration is not None and not isinstance(calibration, CalibrationTable):
        calibration = load_calibration(calibration)
    options = BatchOptions(
        dt=dt, dx=dx, diagnose=diagnose, dtype=dtype, resample=resample, roi=roi, calibration=calibration
    )
    start = time.perf_counter()
    paths = expand_inputs(inputs)
    table = {_key(row["path"]): row for row in read_table(out)}
    todo = [p for p in paths if not _done(table.get(_key(p), {}), options)]
    skipped = len(paths) - len(todo)
    ok = failed = 0
    from tqdm.auto import tqdm

    with tqdm(total=len(todo), unit="video", desc="anra batch", disable=not progress) as bar:
        for rows in (runner or _local_runner)(list(_chunks(todo, batch_size)), options):
            for row in rows:
                table[_key(row["path"])] = row
                ok += row["status"] == "ok"
                failed += row["status"] != "ok"
            write_table(out, list(table.values()))
            bar.update(len(rows))
    if not todo and not out.exists():
        write_table(out, [])
    return BatchSummary(out, len(paths), skipped, ok, failed, time.perf_counter() - start)
