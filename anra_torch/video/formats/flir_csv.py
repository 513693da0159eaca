"""FLIR Tools CSV exports: a header of camera parameters, then one ``Frame N,`` block per frame.

Layout (as FLIR Tools writes a box region over a sequence)::

    Parameters:,Emissivity:,1.00
    ,Refl. temp.:,5.0 °C
    ...
    Frame 1,25.913,25.825,...      <- first row of frame 1, after the label
    ,25.927,26.000,...             <- further rows start with an empty field
    ,25.942,25.942,...,            <- a trailing comma is allowed
                                   <- a blank line ends the block
    Frame 2,...

Values are apparent temperatures in degC (with the header's emissivity). The export records no frame
period and no pixel size: pass ``dt`` and ``dx``. Parsing is exact: every block must have the same number
of rows and columns and frames must be numbered 1, 2, 3, ...; anything else is a one-line error naming the
file, the frame and the row.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from anra_torch.video.core import RawVideo

__all__ = ["is_flir_csv", "load_flir_csv"]

_FRAME = re.compile(r"^\s*Frame\s+(\d+)\s*$")


def is_flir_csv(path: Path) -> bool:
    """Whether the text file holds ``Frame N,`` blocks (looks at the first 64 kB)."""
    with open(path, encoding="utf-8-sig", errors="replace") as handle:
        head = handle.read(65536)
    return re.search(r"(^|\n)\s*Frame\s+\d+\s*,", head) is not None


def _values(cells: list[str], path: Path, frame: int, row: int) -> np.ndarray:
    if cells and cells[-1].strip() == "":
        cells = cells[:-1]  # trailing comma
    try:
        return np.array([float(c) for c in cells], dtype=np.float64)
    except ValueError:
        bad = next(c for c in cells if not _is_number(c))
        raise ValueError(
            f"{path}: frame {frame} row {row}: not a number: {bad.strip()!r}; the file may be corrupt"
        ) from None


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _header(lines: list[str]) -> dict:
    meta: dict = {}
    for line in lines:
        cells = [c.strip() for c in line.split(",")]
        if len(cells) >= 3 and cells[1].endswith(":") and cells[2]:
            key = "flir_" + re.sub(r"[^a-z]+", "_", cells[1][:-1].lower()).strip("_")
            number = re.match(r"^-?\d+(\.\d+)?", cells[2])
            meta.setdefault(key, float(number.group()) if number else cells[2])
    return meta


def load_flir_csv(path: Path) -> RawVideo:
    """Read a FLIR CSV export (apparent degC, frames ``(T, H, W)``; no ``dt`` / ``dx`` in the file)."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise ValueError(
            f"{path}: not a text file ({err.reason} at byte {err.start}); expected a CSV"
        ) from err
    lines = text.splitlines()
    blocks: list[tuple[int, int, list[np.ndarray]]] = []  # (frame number, line number, rows)
    header_end = None
    current: list[np.ndarray] | None = None
    for number, line in enumerate(lines, start=1):
        label, _, rest = line.partition(",")
        match = _FRAME.match(label)
        if match:
            header_end = number if header_end is None else header_end
            frame = int(match.group(1))
            current = [_values(rest.split(","), path, frame, 1)]
            blocks.append((frame, number, current))
        elif current is not None and line.strip() and label.strip() == "":
            frame = blocks[-1][0]
            current.append(_values(rest.split(","), path, frame, len(current) + 1))
        elif not line.strip(" ,"):
            current = None  # a blank line ends the block
        elif current is not None or header_end is not None:
            raise ValueError(f"{path}: line {number}: unexpected text {line[:40]!r} between frame blocks")
    if not blocks:
        raise ValueError(f"{path}: no 'Frame N,' blocks; expected a FLIR CSV export")
    rows, cols = len(blocks[0][2]), blocks[0][2][0].size
    for k, (frame, number, block) in enumerate(blocks):
        if frame != k + 1:
            raise ValueError(f"{path}: line {number}: frame {frame} where frame {k + 1} was expected")
        if len(block) != rows:
            raise ValueError(
                f"{path}: frame {frame} (line {number}) has {len(block)} rows, expected {rows} like frame 1; "
                "the file may be truncated or edited"
            )
        for r, values in enumerate(block, start=1):
            if values.size != cols:
                raise ValueError(
                    f"{path}: frame {frame} row {r} has {values.size} values, expected {cols} like frame 1"
                )
    frames = np.stack([np.stack(block) for _, _, block in blocks])
    meta = _header(lines[: (header_end or 1) - 1])
    meta.update(unit="degC", format="flir_csv")
    return RawVideo(frames=frames, meta=meta)
