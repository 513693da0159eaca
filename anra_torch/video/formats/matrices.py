"""A folder of per-frame text matrices (``.csv`` comma-separated or ``.txt`` whitespace-separated).

One file per frame, each an ``H x W`` matrix of temperatures; frames are ordered by file name in natural
order (``frame_2`` before ``frame_10``). A folder of FLIR CSV exports (``Frame N,`` blocks) is refused: each
export is a whole video. The files record no pixel size (pass ``dx``). Their capture times, when a camera
was triggered by hand seconds apart, are read from the first of:

- a timestamps file beside the frames (``times``, ``timestamps`` or ``time`` ``.csv`` / ``.txt``): one time
  per frame in natural order, or rows of ``file name, time``; a header may name the unit (``ms``, ``s``,
  ``min``; default s);
- a comment line in every frame file: ``# t = 5.0 s`` or ``# time: 5`` (s unless a unit follows);
- every file name holding one time with its unit: ``frame_005s.txt``, ``t=12.5 s.csv``, ``2min.txt``
  (frames are then ordered by that time).

Without any of them, pass the frame period ``dt``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from anra_torch.checks import one_line
from anra_torch.video.core import RawVideo, stack_frames
from anra_torch.video.formats.flir_csv import is_flir_csv

__all__ = ["load_matrix_folder"]

SUFFIXES = (".csv", ".txt")


def _natural(path: Path) -> list:
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


def _matrix(path: Path) -> np.ndarray:
    if is_flir_csv(path):
        raise ValueError(f"{path}: is a FLIR CSV export (a whole video); load that file, not its folder")
    with open(path, encoding="utf-8-sig") as handle:
        first = next((line for line in handle if not line.startswith("#")), "")
    delimiter = "," if "," in first else None
    try:
        matrix = np.loadtxt(path, delimiter=delimiter, dtype=np.float64, ndmin=2, encoding="utf-8-sig")
    except (ValueError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: cannot read as a numeric matrix ({one_line(err, kind=True)})") from err
    if matrix.size == 0:
        raise ValueError(f"{path}: empty matrix; every frame file must hold H x W temperatures")
    return matrix


_UNITS = {"ms": 1e-3, "s": 1.0, "sec": 1.0, "secs": 1.0, "second": 1.0, "seconds": 1.0}
_UNITS.update({"min": 60.0, "mins": 60.0, "minute": 60.0, "minutes": 60.0})
_NUMBER = r"(\d+(?:\.\d*)?|\.\d+)"
_UNIT = r"(ms|s|secs?|seconds?|mins?|minutes?)"
_NAME_TIME = re.compile(rf"(?<![a-z\d.]){_NUMBER}\s*{_UNIT}(?![a-z])", re.IGNORECASE)
_HEADER_TIME = re.compile(rf"^#.*?\b(?:t|time)\s*[=:]\s*{_NUMBER}\s*{_UNIT}?(?![a-z])", re.IGNORECASE)
_SIDECAR_STEMS = ("times", "timestamps", "time")


def _sidecar(folder: Path) -> Path | None:
    found = [p for p in folder.iterdir() if p.is_file() and p.stem.lower() in _SIDECAR_STEMS]
    found = [p for p in found if p.suffix.lower() in SUFFIXES]
    if len(found) > 1:
        names = ", ".join(sorted(p.name for p in found))
        raise ValueError(f"{folder}: more than one timestamps file ({names}); keep one")
    return found[0] if found else None


def _seconds(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if value == value else None  # NaN is no time


def _sidecar_times(path: Path, files: list[Path]) -> tuple[np.ndarray, bool]:
    """Times in s from a timestamps file: one per frame in file order, or ``name, time`` rows (True)."""
    rows = []
    with open(path, encoding="utf-8-sig") as handle:
        for line in handle:
            separator = next((c for c in ",;\t" if c in line), None)  # else whitespace
            cells = [c.strip() for c in line.strip().split(separator) if c.strip()]
            if cells and not cells[0].startswith("#"):
                rows.append(cells)
    scale = 1.0
    if rows and _seconds(rows[0][-1]) is None:  # a header: it may name the unit
        unit = re.search(rf"(?<![a-z]){_UNIT}(?![a-z])", " ".join(rows[0]), re.IGNORECASE)
        scale = _UNITS[unit.group(1).lower()] if unit else 1.0
        rows = rows[1:]
    values = [_seconds(r[-1]) for r in rows]
    if not rows or any(v is None for v in values):
        raise ValueError(f"{path}: timestamps must be numbers, one per frame (or 'file name, time' rows)")
    if all(len(r) >= 2 and _seconds(r[0]) is None for r in rows):  # name, time
        by_name = {r[0]: v for r, v in zip(rows, values, strict=True)}
        missing = [f.name for f in files if f.name not in by_name and f.stem not in by_name]
        if missing:
            raise ValueError(f"{path}: no time for frame file {missing[0]} ({len(missing)} missing)")
        named = [by_name.get(f.name, by_name.get(f.stem)) for f in files]
        return scale * np.array(named, dtype=np.float64), True
    if len(values) != len(files):
        raise ValueError(f"{path}: {len(values)} timestamps for {len(files)} frame files; give one per frame")
    return scale * np.asarray(values, dtype=np.float64), False


def _header_time(path: Path) -> float | None:
    with open(path, encoding="utf-8-sig") as handle:
        for line in handle:
            if not line.startswith("#"):
                return None
            match = _HEADER_TIME.match(line.strip())
            if match:
                return float(match.group(1)) * _UNITS[(match.group(2) or "s").lower()]
    return None


def _name_time(path: Path) -> float | None:
    matches = _NAME_TIME.findall(path.stem)
    return float(matches[0][0]) * _UNITS[matches[0][1].lower()] if len(matches) == 1 else None


def _capture_times(files: list[Path], sidecar: Path | None) -> tuple[np.ndarray | None, str | None, bool]:
    """The frames' times in s, where they came from (None: the folder records none) and whether they are
    tied to the file names (the frames then go in time order; a list in file order must rise itself)."""
    if sidecar is not None:
        times, named = _sidecar_times(sidecar, files)
        return times, sidecar.name, named
    for reader, origin in ((_header_time, "comment lines"), (_name_time, "file names")):
        times = [reader(p) for p in files]
        # A time every name shares ("exposure_3s_0001") is no capture time.
        distinct = origin != "file names" or len(set(times)) == len(times)
        if all(t is not None for t in times) and distinct:
            return np.asarray(times, dtype=np.float64), origin, origin == "file names"
    return None, None, False


def load_matrix_folder(folder: Path) -> RawVideo:
    """Read every ``.csv`` / ``.txt`` matrix in ``folder`` as one frame each (frames ``(T, H, W)``), with
    their capture times when the folder records them (see the module)."""
    sidecar = _sidecar(folder)
    files = sorted(
        (
            p
            for p in folder.iterdir()
            if p.is_file() and p.suffix.lower() in SUFFIXES and p.name[0] != "." and p != sidecar
        ),
        key=_natural,
    )
    if not files:
        raise ValueError(f"{folder}: holds a timestamps file but no frame files")
    times, origin, named = _capture_times(files, sidecar)
    if times is not None and named:  # each name carries its time: the frames go in time order
        order = np.argsort(times, kind="stable")
        files, times = [files[k] for k in order], times[order]
    frames = stack_frames([_matrix(p) for p in files], files, folder)
    meta = {"format": "matrix_folder", "files": f"{files[0].name} .. {files[-1].name}"}
    if origin is not None:
        meta["timestamps"] = origin
    return RawVideo(frames=frames, t=times, meta=meta)
