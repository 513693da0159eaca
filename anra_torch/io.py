"""Thermal videos from files: one loader per file format, chosen by suffix from :data:`REGISTRY`.

A loader reads what the file holds into a :class:`RawVideo` (frames as stored, and whatever spacing and
timestamps the file records); :func:`load_video` then applies the caller's explicit ``dt`` / ``dx`` (they win
over the file), checks everything once and returns a :class:`Video`. A new format is one function and one
registry entry.

Formats:
    ``.npz``: arrays ``frames`` ``(T, H, W)`` and ``dt`` (s) or ``t`` (timestamps in s, uniformly spaced),
    optional ``dx`` (mm) and ``unit`` (temperature unit, a string); other scalar or string entries (e.g.
    ``a_true``) go to :attr:`Video.meta`.
    ``.npy``: frames only; ``dt`` (and ``dx``) must be passed explicitly.

Every error is a one-line ``ValueError`` that names the file, the requirement and what was found.
"""

from __future__ import annotations

import os
import pickle
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from anra_torch._validation import uniform_step

__all__ = ["REGISTRY", "RawVideo", "Video", "load_video", "save_npz"]

PathLike = str | os.PathLike[str]


@dataclass(frozen=True)
class Video:
    """A thermal video read from a file, with its spacing.

    Attributes:
        frames: temperatures in any linear unit, as stored (integer raw counts are kept; the estimator
            converts them to floats).
        dt: frame period in s.
        dx: pixel size in mm, or None when neither the file nor the caller gave one.
        t: timestamps in s when the file has them (uniform, step ``dt``), else None.
        source: the file it was read from (None for a video built in memory).
        meta: extra facts from the file: ``"unit"`` (temperature unit) when known, scalars such as
            ``"a_true"``, and ``"dt_source"`` / ``"dx_source"`` (``"file"``, ``"t"`` or ``"argument"``).

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.
    """

    frames: Tensor
    dt: float
    dx: float | None
    t: Tensor | None = None
    source: Path | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def unit(self) -> str:
        """Temperature unit for labels (``"data units"`` when the file does not say)."""
        return str(self.meta.get("unit") or "data units")

    @property
    def name(self) -> str:
        """Short name for messages: the file name, or ``"<memory>"``."""
        return self.source.name if self.source is not None else "<memory>"


@dataclass
class RawVideo:
    """What a loader found in a file, before overrides and checks.

    Attributes:
        frames: the stored array (any shape or dtype; :func:`load_video` checks it).
        dt: frame period in s, or None.
        dx: pixel size in mm, or None.
        t: timestamps in s, or None.
        meta: extra facts (see :attr:`Video.meta`).
    """

    frames: Any
    dt: Any = None
    dx: Any = None
    t: Any = None
    meta: dict[str, Any] = field(default_factory=dict)


Loader = Callable[[Path], RawVideo]


# ----------------------------------------------------------------------------------------------- loaders
def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return f"{type(err).__name__}: {text}"


class _NotAnArchive(Exception):
    pass


def _load_npz(path: Path) -> RawVideo:
    try:
        archive = np.load(path, allow_pickle=False)
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise _NotAnArchive
        with archive:
            data = {key: archive[key] for key in archive.files}
    except _NotAnArchive:
        raise ValueError(f"{path}: is a single .npy array, not an .npz archive; rename it to .npy") from None
    except ValueError as err:
        if "pickle" in str(err) or "Object arrays" in str(err):
            raise ValueError(
                f"{path}: holds pickled Python objects, which are never loaded; save numeric arrays "
                "(numpy.savez) instead"
            ) from err
        raise ValueError(f"{path}: cannot read as .npz ({_one_line(err)}); the file may be corrupt") from err
    except (zipfile.BadZipFile, EOFError, zlib.error, pickle.UnpicklingError, KeyError, OSError) as err:
        raise ValueError(
            f"{path}: cannot read as .npz ({_one_line(err)}); the file may be truncated or corrupt"
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


def _load_npy(path: Path) -> RawVideo:
    try:
        frames = np.load(path, allow_pickle=False)
    except ValueError as err:
        if "pickle" in str(err) or "Object arrays" in str(err):
            raise ValueError(
                f"{path}: holds pickled Python objects, which are never loaded; save a numeric array "
                "(numpy.save) instead"
            ) from err
        raise ValueError(f"{path}: cannot read as .npy ({_one_line(err)}); the file may be corrupt") from err
    except (EOFError, OSError, pickle.UnpicklingError) as err:
        raise ValueError(
            f"{path}: cannot read as .npy ({_one_line(err)}); the file may be truncated or corrupt"
        ) from err
    if not isinstance(frames, np.ndarray):
        frames.close()
        raise ValueError(f"{path}: is an .npz archive, not a single .npy array; rename it to .npz")
    return RawVideo(frames=frames)


REGISTRY: dict[str, Loader] = {
    ".npz": _load_npz,
    ".npy": _load_npy,
}
"""File suffix (lower case, with the dot; may be compound such as ``.csv.gz``) -> loader."""


# ------------------------------------------------------------------------------------------- checks
def _loader_for(path: Path) -> Loader:
    name = path.name.lower()
    for suffix in sorted(REGISTRY, key=len, reverse=True):
        if name.endswith(suffix):
            return REGISTRY[suffix]
    got = repr("".join(path.suffixes)) if path.suffixes else "(no suffix)"
    raise ValueError(f"{path}: unknown video format {got}; expected one of: {', '.join(REGISTRY)}")


def _positive(value: object, path: Path, name: str, unit: str, origin: str) -> float:
    """A positive finite float from a scalar-like ``value``."""
    try:
        array = np.asarray(value, dtype=np.float64)
        number = float(array.reshape(-1)[0]) if array.size == 1 else None
    except (TypeError, ValueError):
        number = None
    if number is None or not np.isfinite(number) or number <= 0:
        shown = np.asarray(value).tolist() if isinstance(value, np.ndarray) else value
        raise ValueError(f"{path}: {name} {origin} must be a positive finite number in {unit}, got {shown!r}")
    return number


def _frames(array: Any, path: Path) -> Tensor:
    array = np.asarray(array)
    if array.dtype.kind not in "iuf":
        raise ValueError(
            f"{path}: frames must hold real numbers (temperatures or counts), got dtype {array.dtype}"
        )
    if array.ndim != 3:
        hint = "; store one video per file" if array.ndim == 4 else ""
        raise ValueError(f"{path}: frames must have shape (T, H, W), got {tuple(array.shape)}{hint}")
    if min(array.shape) < 1:
        raise ValueError(f"{path}: frames must not be empty, got shape {tuple(array.shape)}")
    if not array.dtype.isnative:
        array = array.astype(array.dtype.newbyteorder("="))
    return torch.from_numpy(np.ascontiguousarray(array))


def load_video(path: PathLike, *, dt: float | None = None, dx: float | None = None) -> Video:
    """Read a thermal video; explicit ``dt`` / ``dx`` override what the file says.

    The format is chosen from the file suffix (:data:`REGISTRY`). When the file has timestamps ``t``
    they must be uniformly spaced (resample the video first otherwise); an explicit ``dt`` replaces
    both the file's ``dt`` and its timestamps.

    Args:
        path: the video file.
        dt: frame period in s (required when the file has neither ``dt`` nor ``t``).
        dx: pixel size in mm (optional: :attr:`Video.dx` is None without it).

    Returns:
        A :class:`Video` with ``frames`` as stored (integer counts stay integers).

    Shape:
        The file's frames must be ``(T, H, W)``.

    Raises:
        ValueError: missing file, unknown suffix, unreadable or corrupt file, no ``frames``, wrong shape or
            dtype, no frame period, non-positive spacing, timestamps that are not uniform or disagree with
            ``dt``.

    Example:
        >>> import tempfile, numpy as np
        >>> path = Path(tempfile.mkdtemp()) / "video.npz"
        >>> _ = save_npz(path, np.zeros((6, 8, 8)), dt=0.04, dx=0.1)
        >>> video = load_video(path, dx=0.2)
        >>> tuple(video.frames.shape), video.dt, video.dx
        ((6, 8, 8), 0.04, 0.2)
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file")
    if path.is_dir():
        raise ValueError(f"{path}: is a directory, expected a video file")
    loader = _loader_for(path)
    raw = loader(path)
    frames = _frames(raw.frames, path)
    meta = dict(raw.meta)
    n = frames.shape[0]

    t = None
    if raw.t is not None:
        stamps = np.asarray(raw.t)
        if stamps.dtype.kind not in "iuf" or stamps.ndim != 1 or stamps.size != n:
            raise ValueError(
                f"{path}: t must hold {n} timestamps in s (one per frame), got shape {tuple(stamps.shape)} "
                f"dtype {stamps.dtype}"
            )
        t = torch.as_tensor(stamps, dtype=torch.float64)

    if dt is not None:
        step = _positive(dt, path, "dt", "s", "(argument)")
        meta["dt_source"], t = "argument", None
    elif t is not None:
        if n < 2:
            raise ValueError(f"{path}: a single frame has no frame period; pass dt in s (--dt)")
        try:
            step = uniform_step(t)
        except ValueError as err:
            raise ValueError(f"{path}: {err}") from err
        if raw.dt is not None:
            stored = _positive(raw.dt, path, "dt", "s", "in the file")
            if abs(stored - step) > 1e-3 * step:
                raise ValueError(
                    f"{path}: dt = {stored:g} s disagrees with the step of t = {step:g} s; fix the file "
                    "or pass dt explicitly (--dt)"
                )
            step = stored
        meta["dt_source"] = "t"
    elif raw.dt is not None:
        step = _positive(raw.dt, path, "dt", "s", "in the file")
        meta["dt_source"] = "file"
    else:
        raise ValueError(
            f"{path}: no frame period: the file has neither 'dt' nor 't'; "
            "pass dt in s (--dt on the command line)"
        )

    spacing = None
    if dx is not None:
        spacing = _positive(dx, path, "dx", "mm", "(argument)")
        meta["dx_source"] = "argument"
    elif raw.dx is not None:
        spacing = _positive(raw.dx, path, "dx", "mm", "in the file")
        meta["dx_source"] = "file"
    return Video(frames=frames, dt=step, dx=spacing, t=t, source=path, meta=meta)


def save_npz(
    path: PathLike,
    frames: Tensor | np.ndarray,
    *,
    dt: float,
    dx: float | None,
    t: Tensor | np.ndarray | None = None,
    **extra: Any,
) -> Path:
    """Write a video as ``.npz`` readable by :func:`load_video` (``frames``, ``dt``, ``dx``, ``t``, extras).

    The file is written next to its final name and renamed into place, so an interrupted write never
    leaves a truncated archive. ``.npz`` is appended when the path lacks it.

    Args:
        path: output file.
        frames: temperatures, dtype kept.
        dt: frame period in s.
        dx: pixel size in mm (None leaves it out).
        t: optional timestamps in s.
        **extra: more arrays or scalars, e.g. ``a_true=0.2`` (mm^2/s) or ``unit="degC"``.

    Returns:
        The path written.

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.

    Raises:
        ValueError: wrong frames shape, non-positive ``dt`` or ``dx``, or ``t`` of the wrong length.
    """
    path = Path(path)
    if path.suffix.lower() != ".npz":
        path = path.with_name(path.name + ".npz")
    array = frames.detach().cpu().numpy() if isinstance(frames, Tensor) else np.asarray(frames)
    if array.ndim != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {tuple(array.shape)}")
    data: dict[str, Any] = {"frames": array, "dt": np.float64(_positive(dt, path, "dt", "s", "(argument)"))}
    if dx is not None:
        data["dx"] = np.float64(_positive(dx, path, "dx", "mm", "(argument)"))
    if t is not None:
        stamps = t.detach().cpu().numpy() if isinstance(t, Tensor) else np.asarray(t)
        if stamps.shape != (array.shape[0],):
            raise ValueError(f"t must have shape ({array.shape[0]},) in s, got {tuple(stamps.shape)}")
        data["t"] = stamps.astype(np.float64)
    for key, value in extra.items():
        data[key] = value.detach().cpu().numpy() if isinstance(value, Tensor) else np.asarray(value)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".part")
    try:
        with open(partial, "wb") as handle:
            np.savez(handle, **data)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path
