"""The batch table: its columns, typed reading and atomic writing of CSV and Parquet."""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from anra_torch.batch.inputs import PathLike
from anra_torch.checks import atomic_output

__all__ = ["BATCH_COLUMNS", "FORMATS", "check_format", "parquet", "read_table", "row_key", "write_table"]

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
    "message": str,
    "input_stamp": str,
    "parameters": str,
    "explained": float,
    "frames_used": int,
    "phase": str,
}
"""Output columns and their types (missing values are empty cells in CSV, nulls in Parquet)."""

FORMATS = (".csv", ".parquet")


def row_key(path: str) -> str:
    """The table's key of an input: its real path (one row per input)."""
    return os.path.realpath(path)


def check_format(path: Path) -> str:
    """The table's suffix, ``.csv`` or ``.parquet``.

    Raises:
        ValueError: any other suffix.
    """
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"--out must end in {' or '.join(FORMATS)}, got {path.name!r}")
    return suffix


def parquet():
    """``(pyarrow, pyarrow.parquet)``.

    Raises:
        ImportError: pyarrow missing, naming the extra to install.
    """
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
    suffix = check_format(path)
    if not path.exists():
        return []
    if suffix == ".csv":
        with path.open(newline="", encoding="utf-8") as handle:
            raw = list(csv.DictReader(handle))
            header = raw[0].keys() if raw else ()
    else:
        _, pq = parquet()
        table = pq.read_table(path)
        raw, header = table.to_pylist(), table.column_names
    if raw and not {"path", "status"} <= set(header):
        raise ValueError(f"{path}: not a batch table: needs 'path' and 'status' columns, got {list(header)}")
    return [{k: _typed(row.get(k), kind) for k, kind in BATCH_COLUMNS.items()} for row in raw]


def write_table(path: PathLike, rows: Sequence[dict[str, Any]]) -> Path:
    """Write rows atomically (:func:`~anra_torch.checks.atomic_output`: a temporary file in the same folder,
    then :func:`os.replace`).

    An interruption at any moment leaves either the previous table or the new one, never a partial file.
    The file gets the mode the umask allows (0644 under umask 022).
    """
    path = Path(path)
    suffix = check_format(path)
    clean = [{k: _typed(row.get(k), kind) for k, kind in BATCH_COLUMNS.items()} for row in rows]
    with atomic_output(path) as temp:
        if suffix == ".csv":
            with temp.open("w", newline="", encoding="utf-8") as out:
                writer = csv.DictWriter(out, fieldnames=list(BATCH_COLUMNS))
                writer.writeheader()
                writer.writerows({k: ("" if v is None else v) for k, v in row.items()} for row in clean)
                out.flush()
                os.fsync(out.fileno())
        else:
            pa, pq = parquet()
            types = {str: pa.string(), float: pa.float64(), int: pa.int64()}
            schema = pa.schema([(k, types[kind]) for k, kind in BATCH_COLUMNS.items()])
            pq.write_table(pa.Table.from_pylist(clean, schema=schema), temp)
    return path
