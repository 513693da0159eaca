"""A folder of per-frame text matrices (``.csv`` comma-separated or ``.txt`` whitespace-separated).

One file per frame, each an ``H x W`` matrix of temperatures; frames are ordered by file name in natural
order (``frame_2`` before ``frame_10``). The files record no frame period or pixel size: pass ``dt`` and
``dx``. A folder of FLIR CSV exports (``Frame N,`` blocks) is refused: each export is a whole video.
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
        first = handle.readline()
    delimiter = "," if "," in first else None
    try:
        matrix = np.loadtxt(path, delimiter=delimiter, dtype=np.float64, ndmin=2, encoding="utf-8-sig")
    except (ValueError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: cannot read as a numeric matrix ({one_line(err, kind=True)})") from err
    if matrix.size == 0:
        raise ValueError(f"{path}: empty matrix; every frame file must hold H x W temperatures")
    return matrix


def load_matrix_folder(folder: Path) -> RawVideo:
    """Read every ``.csv`` / ``.txt`` matrix in ``folder`` as one frame each (frames ``(T, H, W)``)."""
    files = sorted(
        (p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES and p.name[0] != "."),
        key=_natural,
    )
    frames = stack_frames([_matrix(p) for p in files], files, folder)
    return RawVideo(
        frames=frames, meta={"format": "matrix_folder", "files": f"{files[0].name} .. {files[-1].name}"}
    )
