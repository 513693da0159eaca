"""Which videos a batch run reads: files, folders (recursive, or one video of per-frame files) and globs."""

from __future__ import annotations

import glob
import os
from collections.abc import Iterable
from pathlib import Path

from anra_torch.video import FOLDER_REGISTRY, REGISTRY

__all__ = ["PathLike", "expand_inputs"]

PathLike = str | os.PathLike[str]


def _is_video_file(path: Path) -> bool:
    name = path.name.lower()
    return path.is_file() and any(name.endswith(suffix) for suffix in REGISTRY)


def _is_video_folder(path: Path) -> bool:
    """A folder that is itself one video (:data:`anra_torch.video.FOLDER_REGISTRY`): one file per frame.

    JPEGs and ``.fff`` files are single frames (FLIR radiometric JPEGs, FFF frames as a camera streams them),
    so a folder holding them is one video. A ``.csv`` / ``.txt`` file is either a per-frame matrix (its first
    line is numbers) or a whole video (a FLIR CSV export starts with a header): the first such file decides.
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
    if any(f.suffix.lower() in (".jpg", ".jpeg", ".fff") for f in frames):
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
