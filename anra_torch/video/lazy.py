"""Frames read on demand: a ``.npy`` file, the ``frames`` of an uncompressed ``.npz``, or a FLIR sequence
(``.seq``, ``.csq``, ``.fff``), one slice at a time.

A camera recording (640 x 512 px, 900 frames: 1.2 GB in float32) need not sit in memory to be analysed:
:func:`anra_torch.estimation.estimate_chunked` reads it in chunks of frames. ``numpy.load(...,
mmap_mode="r")`` would do the reading, but its mapped pages stay resident and count towards the process's
memory as the file is read; :class:`LazyFrames` reads each slice with plain file reads, so only the requested
frames are ever in memory. ``numpy.savez`` (and :func:`~anra_torch.video.save_npz`) store arrays uncompressed,
so their ``frames`` is read the same way; a compressed archive (``savez_compressed``) is not lazily readable.
A FLIR sequence is indexed once and its frames decoded on demand
(:class:`~anra_torch.video.formats.flir_seq.FLIRFrames`). Both are a :class:`FrameSource`, the one protocol
:func:`in_memory`, :func:`frame_span`, :attr:`Video.span <anra_torch.video.Video.span>` and the chunked
readers rely on.
"""

from __future__ import annotations

import math
import os
import zipfile
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import uniform_step
from anra_torch.video.core import UNIFORM_RTOL, Truth, Video
from anra_torch.video.formats import LAZY_REGISTRY
from anra_torch.video.formats.flir_objects import ObjectParameters

__all__ = [
    "FrameSource",
    "LazyFrames",
    "decimated",
    "frame_span",
    "in_memory",
    "lazy_npz_fields",
    "lazy_video",
]


@runtime_checkable
class FrameSource(Protocol):
    """Frames ``(T, H, W)`` left on disk and read a contiguous slice at a time (:class:`LazyFrames`,
    :class:`~anra_torch.video.formats.flir_seq.FLIRFrames`).

    Shape:
        ``shape`` ``(T, H, W)``; ``frames[a:b]`` -> ``numpy.ndarray`` ``(b - a, H, W)``.
    """

    shape: tuple[int, ...]
    dtype: np.dtype

    def __len__(self) -> int: ...

    def __getitem__(self, index: slice) -> np.ndarray: ...

    def window(self, start: int, stop: int) -> FrameSource:
        """Frames ``start .. stop - 1``, still unread."""
        ...


class LazyFrames:
    """Frames of a ``(T, H, W)`` array stored as ``.npy`` (a file, or a member of an uncompressed ``.npz``),
    read on demand by plain file reads.

    Args:
        path: a ``.npy`` file, or an ``.npz`` archive whose ``member`` is stored uncompressed.
        member: the ``.npz`` entry (default ``"frames"``); ignored for a ``.npy`` file.
        start: first frame of the view (frames before it are not part of it).
        stop: frame after the view's last (default the end).

    Shape:
        ``frames[a:b]`` -> ``numpy.ndarray`` ``(b - a, H, W)``; ``shape`` ``(T, H, W)``.

    Raises:
        ValueError: not a readable ``.npy`` (or ``.npz`` member), a compressed member, or not a C-ordered
            real ``(T, H, W)`` array.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        member: str = "frames",
        start: int = 0,
        stop: int | None = None,
    ) -> None:
        self.path = Path(path)
        offset = _member_offset(self.path, member) if _is_zip(self.path) else 0
        try:
            with self.path.open("rb") as handle:
                handle.seek(offset)
                version = np.lib.format.read_magic(handle)
                read_header = (
                    np.lib.format.read_array_header_1_0
                    if version == (1, 0)
                    else np.lib.format.read_array_header_2_0
                )
                shape, fortran, dtype = read_header(handle)
                self._offset = handle.tell()
        except (OSError, ValueError) as err:
            raise ValueError(f"{self.path}: cannot read as .npy ({' '.join(str(err).split())})") from err
        if len(shape) != 3 or fortran or dtype.kind not in "iuf":
            raise ValueError(
                f"{self.path}: frames must be a C-ordered real array (T, H, W), got shape {shape}, "
                f"dtype {dtype}{', Fortran order' if fortran else ''}"
            )
        stop = shape[0] if stop is None else stop
        if not 0 <= start <= stop <= shape[0]:
            raise ValueError(
                f"start and stop must satisfy 0 <= start <= stop <= {shape[0]}, got {start}, {stop}"
            )
        self._start, self._stored = start, tuple(shape)
        self.shape, self.dtype = (stop - start, *shape[1:]), dtype

    def __len__(self) -> int:
        return self.shape[0]

    def window(self, start: int, stop: int) -> LazyFrames:
        """Frames ``start .. stop - 1`` of this view, still unread."""
        view = object.__new__(LazyFrames)
        view.__dict__.update(self.__dict__)
        first, last, _ = slice(start, stop).indices(self.shape[0])
        view._start, view.shape = self._start + first, (max(last - first, 0), *self.shape[1:])
        return view

    def __getitem__(self, index: slice) -> np.ndarray:
        if not isinstance(index, slice):
            raise TypeError(f"LazyFrames supports slices of frames, got {type(index).__name__}")
        start, stop, step = index.indices(self.shape[0])
        if step != 1:
            raise ValueError(f"LazyFrames reads contiguous frames only (step 1), got step {step}")
        frame = self.shape[1] * self.shape[2]
        count = max(stop - start, 0)
        with self.path.open("rb") as handle:
            handle.seek(self._offset + (self._start + start) * frame * self.dtype.itemsize)
            data = np.fromfile(handle, dtype=self.dtype, count=count * frame)
        if data.size != count * frame:
            raise ValueError(f"{self.path}: truncated: frames {start}-{stop - 1} are not all in the file")
        return data.reshape(count, *self.shape[1:])


def in_memory(frames: Any) -> Any:
    """``frames`` in memory: a :class:`FrameSource` read whole into a tensor, anything else as it is.

    Shape:
        ``(T, H, W)`` -> ``(T, H, W)``.
    """
    return torch.as_tensor(frames[0 : len(frames)]) if isinstance(frames, FrameSource) else frames


def frame_span(frames: Any, start: int, stop: int) -> Any:
    """Frames ``start .. stop - 1``: a :class:`FrameSource` view (still unread), else a slice.

    Shape:
        ``(T, H, W)`` -> ``(stop - start, H, W)``.
    """
    return frames.window(start, stop) if isinstance(frames, FrameSource) else frames[start:stop]


def decimated(frames: Any, values: int, *, chunk_values: int = 2**19) -> Tensor:
    """An in-memory copy of every frame, strided in space to at most ``values`` pixel values, read
    ``chunk_values`` at a time (a camera-sized recording's phases are found on it without holding it).

    Shape:
        ``(T, H, W)`` -> ``(T, ceil(H / k), ceil(W / k))``, ``k`` the stride.
    """
    t, h, w = frames.shape
    step = max(1, math.ceil(math.sqrt(t * h * w / values)))
    chunk = max(1, chunk_values // (h * w))
    parts = [
        torch.as_tensor(np.ascontiguousarray(frames[i : i + chunk][:, ::step, ::step]))
        for i in range(0, t, chunk)
    ]
    return torch.cat(parts)


def _is_zip(path: Path) -> bool:
    try:
        with path.open("rb") as handle:
            return handle.read(2) == b"PK"
    except OSError as err:
        raise ValueError(f"{path}: cannot read ({' '.join(str(err).split())})") from err


def _member_offset(path: Path, member: str) -> int:
    """Byte offset of an uncompressed ``.npz`` member's ``.npy`` data in the archive."""
    try:
        with zipfile.ZipFile(path) as archive:
            info = archive.getinfo(member + ".npy")
        with path.open("rb") as handle:  # the local header: 30 bytes, then the name and the extra field
            handle.seek(info.header_offset)
            header = handle.read(30)
    except (OSError, zipfile.BadZipFile, KeyError) as err:
        raise ValueError(f"{path}: no readable {member!r} array ({' '.join(str(err).split())})") from err
    if info.compress_type != zipfile.ZIP_STORED:
        raise ValueError(f"{path}: {member!r} is compressed; only an uncompressed .npz is read lazily")
    name_length = int.from_bytes(header[26:28], "little")
    extra_length = int.from_bytes(header[28:30], "little")
    return info.header_offset + 30 + name_length + extra_length


def lazy_npz_fields(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Every entry of an ``.npz`` archive except ``frames``, each read on its own (small: spacing, truth).

    Raises:
        ValueError: not a readable ``.npz``.
    """
    try:
        with open(path, "rb") as handle, np.load(handle, allow_pickle=False) as archive:
            return {key: archive[key] for key in archive.files if key != "frames"}
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise ValueError(f"{path}: cannot read as .npz ({' '.join(str(err).split())})") from err


def lazy_video(
    path: str | os.PathLike[str], *, dt: float | None = None, dx: float | None = None, **objects: float | None
) -> Video | None:
    """The video of a ``.npy`` file, an uncompressed ``.npz`` archive or a FLIR sequence (``.seq``,
    ``.csq``, ``.fff``: :data:`~anra_torch.video.formats.LAZY_REGISTRY`) with its frames left unread (a
    :class:`FrameSource` in :attr:`Video.frames <anra_torch.video.Video.frames>`), or None when the file is
    not read that way: another format, a compressed archive, non-uniform timestamps, or no spacing (the
    whole-file loader then says what is wrong).

    Args:
        path: the file.
        dt: frame period in s (overrides the file).
        dx: pixel size in mm (overrides the file).
        **objects: a FLIR recording's object parameters that replace the file's (``emissivity``,
            ``reflected_temp``, ``distance``, ``atmospheric_temp``, ``humidity``, as in
            :func:`~anra_torch.video.load_video`); a file of another format is then left to the loader.

    Shape:
        ``frames`` ``(T, H, W)``, unread.

    Raises:
        ValueError: a FLIR sequence that cannot be indexed, or whose times repeat or go backwards; an object
            parameter out of range.
        TypeError: an object parameter that is not a number.
    """
    path = Path(path)
    params = ObjectParameters(**objects)
    if path.suffix.lower() in LAZY_REGISTRY and path.is_file():
        return _lazy_recording(path, dt, dx, params)
    if path.suffix.lower() not in (".npy", ".npz") or not path.is_file() or params.given:
        return None
    try:
        frames = LazyFrames(path)
        fields = lazy_npz_fields(path) if _is_zip(path) else {}
    except ValueError:
        return None
    if "t" in fields:
        try:
            fields.setdefault("dt", np.float64(uniform_step(fields.pop("t"))))
        except ValueError:
            return None  # non-uniform timestamps: the loader resamples them
    dt = dt if dt is not None else (float(fields["dt"]) if "dt" in fields else None)
    dx = dx if dx is not None else (float(fields["dx"]) if "dx" in fields else None)
    if dt is None or dx is None or not (dt > 0 and dx > 0):
        return None
    meta: dict[str, Any] = {"format": path.suffix.lower(), "read": "in chunks"}
    if "unit" in fields:
        meta["unit"] = str(fields["unit"])
    try:
        truth = Truth.from_arrays(fields, path)
    except ValueError:
        truth = None
    return Video(frames=frames, dt=float(dt), dx=float(dx), source=path, meta=meta, truth=truth)  # type: ignore[arg-type]


def _lazy_recording(
    path: Path, dt: float | None, dx: float | None, objects: ObjectParameters
) -> Video | None:
    """A FLIR recording indexed and left unread, timed by its capture times (uniform within the clock's
    resolution) or ``dt``; None without ``dx`` or with times that must be resampled."""
    raw = LAZY_REGISTRY[path.suffix.lower()](path, objects=objects if objects.given else None)
    t = np.asarray(raw.t, dtype=np.float64)
    steps = np.diff(t)
    if (steps <= 0).any():  # as load_video: the frames' times are checked even when dt replaces them
        k = int(np.flatnonzero(steps <= 0)[0])
        kind = "duplicate" if steps[k] == 0 else "unsorted"
        raise ValueError(
            f"{path}: {kind} timestamps: frame {k + 1} was captured at t = {t[k + 1]:.3f} s, not after frame "
            f"{k} at {t[k]:.3f} s"
        )
    if dx is None or not dx > 0 or (dt is not None and not dt > 0):
        return None
    meta = {**raw.meta, "read": "in chunks", "dx_source": "argument"}
    if dt is None:
        try:
            dt = uniform_step(t, rtol=UNIFORM_RTOL, atol=float(raw.meta.get("t_resolution", 0.0)))
        except ValueError:
            return None  # a single frame, or non-uniform times: the loader says so or resamples them
        meta["dt_source"] = "t"
        times = torch.from_numpy(t)
    else:
        meta["dt_source"], times = "argument", None
    return Video(frames=raw.frames, dt=float(dt), dx=float(dx), t=times, source=path, meta=meta)
