"""NumPy files: ``.npz`` archives (frames with their spacing), bare ``.npy`` arrays; the one ``.npz`` writer.

``.npz``: arrays ``frames`` ``(T, H, W)`` and ``dt`` in s or ``t``, timestamps in s, optional ``dx`` in mm
and ``unit`` (temperature unit, a string); other scalar or string entries (e.g. ``a_true``) go to
:attr:`~anra_torch.video.Video.meta`, and a simulation's ``a_true``, ``effects``, ``noise_sd``, ``seed``
also to :attr:`~anra_torch.video.Video.truth`. ``.npy``: frames only; ``dt`` (and ``dx``) must be passed
explicitly. :func:`save_npz` writes what :func:`load_npz` reads; every ``.npz`` video of the package goes
through it.
"""

from __future__ import annotations

import pickle
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from torch import Tensor

from anra_torch.checks import atomic_output, check_output, one_line
from anra_torch.video.core import PathLike, RawVideo, Truth, positive_spacing

__all__ = ["load_npy", "load_npz", "save_npz"]


def _value_error(path: Path, err: ValueError, kind: str, save: str) -> ValueError:
    """The one-line error for a ``ValueError`` of ``numpy.load`` (pickled content, or corrupt)."""
    if "pickle" in str(err) or "Object arrays" in str(err):
        return ValueError(
            f"{path}: holds pickled Python objects, which are never loaded; save {save} instead"
        )
    return ValueError(f"{path}: cannot read as {kind} ({one_line(err, kind=True)}); the file may be corrupt")


_MAGIC = {b"PK": ".npz", b"\x93N": ".npy"}
"""The first bytes of a zip archive (``.npz``) and of a ``.npy`` array."""


def _check_magic(path: Path, kind: str) -> None:
    """Refuse a file that is neither an ``.npz`` (zip) nor an ``.npy`` before ``numpy.load`` reads it: numpy
    would take any other bytes for a pickle. A real pickle (protocol 2-5 header) is named as such."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(2)
    except OSError as err:
        raise ValueError(f"{path}: cannot read ({one_line(err, kind=True)})") from err
    if _MAGIC.get(head) == kind:
        return
    if head in _MAGIC:  # numpy reads by these bytes, not by the suffix: say which file it really is
        other = "a single .npy array" if kind == ".npz" else "an .npz archive"
        want = "an .npz archive" if kind == ".npz" else "a single .npy array"
        raise ValueError(f"{path}: is {other}, not {want}; rename it to {_MAGIC[head]}")
    if len(head) == 2 and head[0] == 0x80 and 2 <= head[1] <= 5:
        raise ValueError(f"{path}: holds pickled Python objects, which are never loaded; save numeric arrays")
    valid = "a valid .npz (zip) file" if kind == ".npz" else "a valid .npy file"
    empty = "is empty (0 bytes), " if not head else ""
    raise ValueError(f"{path}: {empty}not {valid}; the file may be corrupt or of another format")


def load_npz(path: Path) -> RawVideo:
    """An ``.npz`` archive: ``frames``, ``dt`` / ``t``, ``dx``, scalars to ``meta``, a simulation's truth.

    Shape:
        ``frames`` as stored (:func:`~anra_torch.video.load_video` requires ``(T, H, W)``); ``t`` ``(T,)``.
    """
    _check_magic(path, ".npz")
    try:
        # Our own handle: numpy leaves its own open when the zip directory is unreadable (ResourceWarning).
        with open(path, "rb") as handle, np.load(handle, allow_pickle=False) as archive:
            data = {key: archive[key] for key in archive.files}
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
    raw.truth = Truth.from_arrays(data, path)
    for key, value in data.items():
        if value.ndim == 0 and value.dtype.kind in "biuf":
            raw.meta[key] = value.item()
        elif value.ndim == 0 and value.dtype.kind == "U":
            raw.meta[key] = str(value)
    return raw


def load_npy(path: Path) -> RawVideo:
    """A bare ``.npy`` array of frames (no spacing: pass ``dt`` and ``dx``).

    Shape:
        ``frames`` as stored (:func:`~anra_torch.video.load_video` requires ``(T, H, W)``).
    """
    _check_magic(path, ".npy")
    try:
        with open(path, "rb") as handle:
            frames = np.load(handle, allow_pickle=False)
    except ValueError as err:
        raise _value_error(path, err, ".npy", "a numeric array (numpy.save)") from err
    except (EOFError, OSError, pickle.UnpicklingError) as err:
        raise ValueError(
            f"{path}: cannot read as .npy ({one_line(err, kind=True)}); the file may be truncated or corrupt"
        ) from err
    return RawVideo(frames=frames)


def save_npz(
    path: PathLike,
    frames: Tensor | np.ndarray,
    *,
    dt: float,
    dx: float | None,
    t: Tensor | np.ndarray | None = None,
    batch: bool = False,
    **extra: Any,
) -> Path:
    """Write a video as ``.npz`` readable by :func:`~anra_torch.video.load_video` (``frames``, ``dt``, ``dx``,
    ``t``, extras).

    The file is written next to its final name and renamed into place, so an interrupted write never
    leaves a truncated archive. ``.npz`` is appended when the path lacks it.

    Args:
        path: output file.
        frames: temperatures, dtype kept.
        dt: frame period in s.
        dx: pixel size in mm (None leaves it out).
        t: optional timestamps in s.
        batch: also accept a batch ``(B, T, H, W)``, stored as is (:func:`~anra_torch.video.load_video`
            reads one video per file: the default refuses it).
        **extra: more arrays or scalars, e.g. ``a_true=0.2`` in mm^2/s or ``unit="degC"``.

    Returns:
        The path written.

    Shape:
        ``frames`` ``(T, H, W)`` (or ``(B, T, H, W)`` with ``batch``); ``t`` ``(T,)``.

    Raises:
        ValueError: wrong frames shape, non-positive ``dt`` or ``dx``, ``t`` of the wrong length, or a path
            that is a folder or a device (``/dev/null``).
    """
    path = check_output(path, name="path")
    if path.suffix.lower() != ".npz":
        path = check_output(path.with_name(path.name + ".npz"), name="path")
    array = frames.detach().cpu().numpy() if isinstance(frames, Tensor) else np.asarray(frames)
    if array.ndim != 3 and not (batch and array.ndim == 4):
        shapes = "(T, H, W) or (B, T, H, W)" if batch else "(T, H, W)"
        raise ValueError(f"frames must have shape {shapes}, got {tuple(array.shape)}")
    n = array.shape[-3]
    data: dict[str, Any] = {
        "frames": array,
        "dt": np.float64(positive_spacing(dt, path, "dt", "s", "(argument)")),
    }
    if dx is not None:
        data["dx"] = np.float64(positive_spacing(dx, path, "dx", "mm", "(argument)"))
    if t is not None:
        stamps = t.detach().cpu().numpy() if isinstance(t, Tensor) else np.asarray(t)
        if stamps.shape != (n,):
            raise ValueError(f"t must have shape ({n},) in s, got {tuple(stamps.shape)}")
        data["t"] = stamps.astype(np.float64)
    for key, value in extra.items():
        data[key] = value.detach().cpu().numpy() if isinstance(value, Tensor) else np.asarray(value)
    with atomic_output(path) as temp, open(temp, "wb") as handle:
        np.savez(handle, **data)
    return path
