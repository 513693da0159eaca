"""Thermal videos from files and folders: one loader per format, chosen by suffix from a registry.

A loader reads what the file holds into a :class:`RawVideo` (frames as stored, and whatever spacing and
timestamps the file records); :func:`load_video` then applies the caller's explicit ``dt`` / ``dx`` (they win
over the file), checks everything once and returns a :class:`Video`. A new format is one function and one
registry entry: :data:`REGISTRY` maps a file suffix to a loader, :data:`FOLDER_REGISTRY` maps the suffix of
the frame files inside a folder (one file per frame, e.g. FLIR radiometric JPEGs) to a folder loader.

Measured timestamps are often not uniform (a FLIR camera triggered by hand). :func:`load_video` keeps the
true timestamps in :attr:`Video.t`; with ``timestamps="uniform"`` (default) it refuses non-uniform ones,
``"keep"`` returns them as they are (``dt`` is then their median step and :attr:`Video.uniform` is False),
``"resample"`` interpolates the frames linearly onto a uniform grid
(:func:`anra_torch.resample.resample_uniform`) and records what it did in ``meta["resampled"]``.

Every error is a one-line ``ValueError`` that names the file, the requirement and what was found.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import uniform_step

__all__ = ["FOLDER_REGISTRY", "REGISTRY", "TIMESTAMPS", "RawVideo", "Video", "load_video", "save_npz"]

PathLike = str | os.PathLike[str]
TIMESTAMPS = ("uniform", "keep", "resample")
"""What :func:`load_video` does with non-uniform timestamps: refuse, keep, or resample them."""
_UNIFORM_RTOL = 1e-3  # steps within 0.1 % of their mean count as uniform


@dataclass(frozen=True)
class Video:
    """A thermal video read from a file or folder, with its spacing.

    Attributes:
        frames: temperatures in any linear unit, as stored (integer raw counts are kept; the estimator
            converts them to floats).
        dt: frame period in s (for non-uniform timestamps kept as they are: their median step).
        dx: pixel size in mm, or None when neither the file nor the caller gave one.
        t: timestamps in s when the file has them, else None.
        source: the file or folder it was read from (None for a video built in memory).
        meta: extra facts from the file: ``"unit"`` (temperature unit) when known, scalars such as
            ``"a_true"``, ``"dt_source"`` / ``"dx_source"`` (``"file"``, ``"t"`` or ``"argument"``),
            ``"format"``, and ``"resampled"`` after a resampling (what it was resampled from).

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

    @property
    def uniform(self) -> bool:
        """Whether the frames are evenly spaced by ``dt`` (True without timestamps)."""
        if self.t is None or self.t.numel() < 3:
            return True
        steps = torch.diff(self.t.double())
        return bool((steps - steps.mean()).abs().max() <= _UNIFORM_RTOL * steps.mean())


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


# ----------------------------------------------------------------------------------------------- helpers
def stack_frames(frames: list[np.ndarray], names: list[Path], folder: Path) -> np.ndarray:
    """Stack per-frame 2D arrays into ``(T, H, W)``; a frame of another size is a one-line error naming it."""
    first = frames[0].shape
    for array, name in zip(frames, names, strict=True):
        if array.ndim != 2:
            raise ValueError(f"{name}: a frame must be a 2D matrix, got shape {tuple(array.shape)}")
        if array.shape != first:
            raise ValueError(
                f"{folder}: mixed frame sizes: {name.name} is {array.shape[0]} x {array.shape[1]} px, "
                f"{names[0].name} is {first[0]} x {first[1]} px; one folder must hold one video"
            )
    return np.stack(frames)


REGISTRY: dict[str, Loader] = {}
"""File suffix (lower case, with the dot; may be compound such as ``.csv.gz``) -> loader.

Filled by :mod:`anra_torch.io` (one module per format)."""

FOLDER_REGISTRY: dict[str, Loader] = {}
"""Suffix of the frame files inside a folder (one file per frame) -> loader of the whole folder."""


# ------------------------------------------------------------------------------------------- checks
def _loader_for(path: Path) -> Loader:
    name = path.name.lower()
    for suffix in sorted(REGISTRY, key=len, reverse=True):
        if name.endswith(suffix):
            return REGISTRY[suffix]
    got = repr("".join(path.suffixes)) if path.suffixes else "(no suffix)"
    raise ValueError(
        f"{path}: unknown video format {got}; expected one of: {', '.join(REGISTRY)} "
        f"(or a folder of {', '.join(FOLDER_REGISTRY)} frames)"
    )


def _folder_loader_for(path: Path) -> Loader:
    kinds = {
        suffix
        for child in path.iterdir()
        if child.is_file() and not child.name.startswith(".")
        for suffix in FOLDER_REGISTRY
        if child.name.lower().endswith(suffix)
    }
    if not kinds:
        raise ValueError(
            f"{path}: is a directory without frame files; expected one file per frame "
            f"({', '.join(FOLDER_REGISTRY)}) or a video file"
        )
    loaders = {FOLDER_REGISTRY[k] for k in kinds}
    if len(loaders) > 1:
        raise ValueError(
            f"{path}: mixes frame files of different formats ({', '.join(sorted(kinds))}); "
            "one folder must hold one video"
        )
    return loaders.pop()


def _timestamps(raw: Any, path: Path, n: int) -> Tensor:
    """Checked timestamps: ``n`` finite values in s, strictly increasing (no duplicates, sorted)."""
    stamps = np.asarray(raw)
    if stamps.dtype.kind not in "iuf" or stamps.ndim != 1 or stamps.size != n:
        raise ValueError(
            f"{path}: t must hold {n} timestamps in s (one per frame), got shape {tuple(stamps.shape)} "
            f"dtype {stamps.dtype}"
        )
    t = torch.as_tensor(stamps, dtype=torch.float64)
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{path}: t must be finite timestamps in s, got non-finite values")
    steps = torch.diff(t)
    if bool((steps <= 0).any()):
        k = int(torch.nonzero(steps <= 0)[0])
        kind = "duplicate" if steps[k] == 0 else "unsorted"
        raise ValueError(
            f"{path}: {kind} timestamps: t must be strictly increasing, got t[{k}]={t[k].item():g} s "
            f"then t[{k + 1}]={t[k + 1].item():g} s"
        )
    return t


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


def load_video(
    path: PathLike,
    *,
    dt: float | None = None,
    dx: float | None = None,
    timestamps: str = "uniform",
) -> Video:
    """Read a thermal video (a file, or a folder of one file per frame); explicit ``dt`` / ``dx`` win.

    The format is chosen from the file suffix (:data:`REGISTRY`) or, for a folder, from the suffix of the
    frame files in it (:data:`FOLDER_REGISTRY`). Timestamps from the file (``t``, e.g. FLIR EXIF times) are
    kept in :attr:`Video.t`; an explicit ``dt`` replaces both the file's ``dt`` and its timestamps.

    Args:
        path: the video file or folder.
        dt: frame period in s (required when the file has neither ``dt`` nor ``t``).
        dx: pixel size in mm (optional: :attr:`Video.dx` is None without it).
        timestamps: what to do when the timestamps are not uniform (:data:`TIMESTAMPS`): ``"uniform"``
            refuses them, ``"keep"`` keeps them (``dt`` = median step, :attr:`Video.uniform` False),
            ``"resample"`` interpolates linearly onto a uniform grid at the median step and states it in
            ``meta["resampled"]``.

    Returns:
        A :class:`Video` with ``frames`` as stored (integer counts stay integers; resampled frames are
        float64).

    Shape:
        The frames must be ``(T, H, W)``.

    Raises:
        ValueError: missing file, unknown suffix, unreadable, truncated or corrupt file, no ``frames``, wrong
            shape or dtype, mixed frame sizes in a folder, no frame period, non-positive spacing, unsorted or
            duplicate timestamps, timestamps that are not uniform (with ``"uniform"``) or disagree with
            ``dt``.

    Example:
        >>> import tempfile, numpy as np
        >>> path = Path(tempfile.mkdtemp()) / "video.npz"
        >>> _ = save_npz(path, np.zeros((6, 8, 8)), dt=0.04, dx=0.1)
        >>> video = load_video(path, dx=0.2)
        >>> tuple(video.frames.shape), video.dt, video.dx
        ((6, 8, 8), 0.04, 0.2)
    """
    if timestamps not in TIMESTAMPS:
        raise ValueError(f"timestamps must be one of {', '.join(TIMESTAMPS)}, got {timestamps!r}")
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file")
    loader = _folder_loader_for(path) if path.is_dir() else _loader_for(path)
    raw = loader(path)
    frames = _frames(raw.frames, path)
    meta = dict(raw.meta)
    n = frames.shape[0]
    t = _timestamps(raw.t, path, n) if raw.t is not None else None

    resample = False
    if dt is not None:
        step = _positive(dt, path, "dt", "s", "(argument)")
        meta["dt_source"], t = "argument", None
    elif t is not None:
        if n < 2:
            raise ValueError(f"{path}: a single frame has no frame period; pass dt in s (--dt)")
        try:
            step = uniform_step(t, rtol=_UNIFORM_RTOL)
        except ValueError as err:
            if timestamps == "uniform":
                raise ValueError(f"{path}: {err} (timestamps='resample' or 'keep' in load_video)") from err
            step, resample = float(torch.diff(t).median()), timestamps == "resample"
        if raw.dt is not None and not resample and timestamps != "keep":
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
    video = Video(frames=frames, dt=step, dx=spacing, t=t, source=path, meta=meta)
    if resample:
        from anra_torch.resample import resample_uniform

        video = resample_uniform(video)
    return video


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
