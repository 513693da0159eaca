"""NumPy files: ``.npz`` archives (frames with their spacing) and bare ``.npy`` arrays.

``.npz``: arrays ``frames`` ``(T, H, W)`` and ``dt`` (s) or ``t`` (timestamps in s), optional ``dx`` (mm) and
``unit`` (temperature unit, a string); other scalar or string entries (e.g. ``a_true``) go to
:attr:`~anra_torch.io.Video.meta`. ``.npy``: frames only; ``dt`` (and ``dx``) must be passed explicitly.
"""

from __future__ import annotations

import pickle
import zipfile
import zlib
from pathlib import Path

import numpy as np

from anra_torch.checks import one_line
from anra_torch.io.video import RawVideo

__all__ = ["load_npy", "load_npz"]


class _NotAnArchive(Exception):
    pass


def _value_error(path: Path, err: ValueError, kind: str, save: str) -> ValueError:
    """The one-line error for a ``ValueError`` of ``numpy.load`` (pickled content, or corrupt)."""
    if "pickle" in str(err) or "Object arrays" in str(err):
        return ValueError(
            f"{path}: holds pickled Python objects, which are never loaded; save {save} instead"
        )
    return ValueError(f"{path}: cannot read as {kind} ({one_line(err, kind=True)}); the file may be corrupt")


def load_npz(path: Path) -> RawVideo:
    try:
        archive = np.load(path, allow_pickle=False)
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise _NotAnArchive
        with archive:
            data = {key: archive[key] for key in archive.files}
    except _NotAnArchive:
        raise ValueError(f"{path}: is a single .npy array, not an .npz archive; rename it to .npy") from None
    except ValueError as err:
        raise _value_error(path, err, ".npz", "numeric arrays (numpy.savez)") from err
    except (zipfile.BadZipFile, EOFError, zlib.error, pickle.UnpicklingError, KeyError, OSError) as err:
        raise ValueError(
            f"{path}: cannot read as .npz ({one_line(err, kind=True)}); the file may be truncated or corrupt"
        ) from err
    if "frames" not in data:
        found = ", ".join(repr(k) for k in data) or "nothing"
        raise ValueError(
            f"{path}: no 'frames' array; expected 'frames' (T, H, W) with 'dt' or 't', found {found}"
        )
    raw = RawVideo(frames=data.pop("frames"), dt=data.pop("dt", None), dx=data.pop("dx", None))
    raw.t = data.pop("t", None)
    for key, value in data.items():
        if value.ndim == 0 and value.dtype.kind in "biuf":
            raw.meta[key] = value.item()
        elif value.ndim == 0 and value.dtype.kind == "U":
            raw.meta[key] = str(value)
    return raw


def load_npy(path: Path) -> RawVideo:
    try:
        frames = np.load(path, allow_pickle=False)
    except ValueError as err:
        raise _value_error(path, err, ".npy", "a numeric array (numpy.save)") from err
    except (EOFError, OSError, pickle.UnpicklingError) as err:
        raise ValueError(
            f"{path}: cannot read as .npy ({one_line(err, kind=True)}); the file may be truncated or corrupt"
        ) from err
    if not isinstance(frames, np.ndarray):
        frames.close()
        raise ValueError(f"{path}: is an .npz archive, not a single .npy array; rename it to .npz")
    return RawVideo(frames=frames)
