"""Thermal videos from files and folders: one loader per format, chosen by suffix from a registry.

A loader reads what the file holds into a :class:`~anra_torch.video.RawVideo` (frames as stored, and
whatever spacing, timestamps and truth the file records); :func:`load_video` then applies the caller's
explicit ``dt`` / ``dx`` (they win over the file), checks everything once and returns a
:class:`~anra_torch.video.Video`. A new format is one function and one registry entry in
:mod:`anra_torch.video.formats`: ``REGISTRY`` maps a file suffix to a loader, ``FOLDER_REGISTRY`` maps the
suffix of the frame files inside a folder (one file per frame, e.g. FLIR radiometric JPEGs) to a folder
loader.

Measured timestamps are often not uniform (a FLIR camera triggered by hand). :func:`load_video` keeps the
true timestamps in :attr:`Video.t`; with ``timestamps="uniform"`` (default) it refuses non-uniform ones,
``"keep"`` returns them as they are (``dt`` is then their median step and :attr:`Video.uniform` is False),
``"resample"`` interpolates the frames onto a uniform grid with
:func:`anra_torch.video.resample_uniform`'s default, the phase-aware cubic, and records what it did in
``meta["resampled"]``.

Every error is a one-line ``ValueError`` that names the file, the requirement and what was found.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import in_range_values, uniform_step
from anra_torch.video.core import (
    UNIFORM_RTOL,
    Loader,
    PathLike,
    RawVideo,
    SingleFrameError,
    Video,
    positive_spacing,
)
from anra_torch.video.formats import FOLDER_REGISTRY, RADIOMETRIC, REGISTRY
from anra_torch.video.formats.flir_objects import ObjectParameters
from anra_torch.video.resample import resample_uniform

__all__ = ["TIMESTAMPS", "load_video"]

TIMESTAMPS = ("uniform", "keep", "resample")
"""What :func:`load_video` does with non-uniform timestamps: refuse, keep, or resample them."""


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
    if ".fff" in kinds:  # a camera's raw frames: text beside them (ExifTool's dumps, notes) is no frame
        kinds = {".fff"}
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


def _step_of(t: Tensor, stored: Any, path: Path, timestamps: str, resolution: float) -> tuple[float, bool]:
    """The frame period in s of timestamps ``t`` (uniform within ``resolution`` s, the clock's) and whether
    to resample them; a ``dt`` stored next to uniform timestamps must agree with their step."""
    if t.numel() < 2:
        raise SingleFrameError(
            f"{path}: a single frame has no time axis, so no frame period to read; pass dt in s (--dt) where "
            "one frame is meant"
        )
    resample = False
    try:
        step = uniform_step(t, rtol=UNIFORM_RTOL, atol=resolution)
    except ValueError as err:
        if timestamps == "uniform":
            raise ValueError(f"{path}: {err} (timestamps='resample' or 'keep' in load_video)") from err
        step, resample = float(torch.diff(t).median()), timestamps == "resample"
    if stored is not None and not resample and timestamps != "keep":
        file_step = positive_spacing(stored, path, "dt", "s", "in the file")
        if abs(file_step - step) > 1e-3 * step:
            raise ValueError(
                f"{path}: dt = {file_step:g} s disagrees with the step of t = {step:g} s; fix the file "
                "or pass dt explicitly (--dt)"
            )
        step = file_step
    return step, resample


def _masked(frames: Tensor, path: Path, meta: dict[str, Any]) -> Tensor:
    """``frames`` with the samples that cannot be measurements masked, counted in ``meta``."""
    try:
        frames, found = in_range_values(frames)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    if found["non_finite"] or found["beyond_limit"]:
        meta["masked_values"] = found
    return frames


def _pixel_size(dx: float | None, stored: Any, path: Path, meta: dict[str, Any]) -> float | None:
    """The pixel size in mm: the argument wins over the file; None without either."""
    if dx is None and stored is None:
        return None
    meta["dx_source"] = "argument" if dx is not None else "file"
    where = "(argument)" if dx is not None else "in the file"
    return positive_spacing(dx if dx is not None else stored, path, "dx", "mm", where)


def _timing(
    raw: RawVideo, n: int, dt: float | None, path: Path, timestamps: str, meta: dict[str, Any]
) -> tuple[Tensor | None, float, bool]:
    """The checked timestamps (None when ``dt`` replaces them), the frame period in s and whether to
    resample; ``meta["dt_source"]`` says where the period came from."""
    t = _timestamps(raw.t, path, n) if raw.t is not None else None
    if dt is not None:
        meta["dt_source"] = "argument"
        return None, positive_spacing(dt, path, "dt", "s", "(argument)"), False
    if t is not None:
        meta["dt_source"] = "t"
        return t, *_step_of(t, raw.dt, path, timestamps, float(raw.meta.get("t_resolution", 0.0)))
    if raw.dt is not None:
        meta["dt_source"] = "file"
        return None, positive_spacing(raw.dt, path, "dt", "s", "in the file"), False
    raise ValueError(
        f"{path}: no frame period: the file has neither 'dt' nor 't'; pass dt in s (--dt on the command line)"
    )


def _read(path: Path, objects: ObjectParameters) -> RawVideo:
    """What the file's loader finds, a radiometric one given the object parameters."""
    loader = _folder_loader_for(path) if path.is_dir() else _loader_for(path)
    if loader in RADIOMETRIC:
        return loader(path, objects=objects if objects.given else None)  # type: ignore[call-arg]
    if objects.given:
        raise ValueError(
            f"{path}: emissivity, reflected_temp, distance, atmospheric_temp and humidity apply to FLIR "
            "radiometric recordings (.jpg, .fff, .seq, .csq) only; this file holds temperatures or counts"
        )
    return loader(path)


def load_video(
    path: PathLike,
    *,
    dt: float | None = None,
    dx: float | None = None,
    timestamps: str = "uniform",
    mask_values: bool = False,
    **objects: float | None,
) -> Video:
    """Read a thermal video, a file or a folder of one file per frame; explicit ``dt`` and ``dx`` win.

    The format follows the suffix, by ``formats.REGISTRY`` and ``FOLDER_REGISTRY``. The file's timestamps
    are kept in :attr:`Video.t`; an explicit ``dt`` replaces them and the file's ``dt``.

    Args:
        path: the video file or folder.
        dt: frame period in s, required when the file has neither ``dt`` nor ``t``.
        dx: pixel size in mm; without it :attr:`Video.dx` is None.
        timestamps: non-uniform ones, by :data:`TIMESTAMPS`: ``"uniform"`` refuses them, ``"keep"`` keeps
            them, ``dt`` their median step; ``"resample"`` interpolates by
            :func:`~anra_torch.video.resample_uniform` and records it in ``meta["resampled"]``.
        mask_values: mask the samples :func:`~anra_torch.checks.in_range_values` rejects, as read and
            before any resampling; counted in ``meta["masked_values"]``.
        **objects: a FLIR radiometric file's object parameters replacing the file's: ``emissivity``,
            ``reflected_temp`` in degC, ``distance`` in m, ``atmospheric_temp`` in degC, ``humidity`` in %.

    Returns:
        A :class:`Video`, frames as stored: integer counts stay integers, resampled frames are float64.

    Shape:
        The frames must be ``(T, H, W)``.

    Raises:
        ValueError: a missing, unknown, unreadable or corrupt file; no ``frames`` or wrong shape, dtype or
            frame sizes; no frame period; bad spacing; timestamps not uniform with ``"uniform"`` or
            disagreeing with ``dt``; an object parameter out of range or for a file that is not radiometric.
        TypeError: an unknown object parameter, or one that is not a number.

    Example:
        >>> import tempfile, numpy as np
        >>> from anra_torch.video import save_npz
        >>> path = save_npz(Path(tempfile.mkdtemp()) / "video.npz", np.zeros((6, 8, 8)), dt=0.04, dx=0.1)
        >>> video = load_video(path, dx=0.2)
        >>> tuple(video.frames.shape), video.dt, video.dx
        ((6, 8, 8), 0.04, 0.2)
    """
    if timestamps not in TIMESTAMPS:
        raise ValueError(f"timestamps must be one of {', '.join(TIMESTAMPS)}, got {timestamps!r}")
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file")
    raw = _read(path, ObjectParameters(**objects))
    frames = _frames(raw.frames, path)
    meta = dict(raw.meta)
    t, step, resample = _timing(raw, frames.shape[0], dt, path, timestamps, meta)
    spacing = _pixel_size(dx, raw.dx, path, meta)
    if mask_values:
        frames = _masked(frames, path, meta)
    video = Video(frames=frames, dt=step, dx=spacing, t=t, source=path, meta=meta, truth=raw.truth)
    return resample_uniform(video) if resample else video
