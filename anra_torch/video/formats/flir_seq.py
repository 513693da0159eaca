"""FLIR recordings of FFF frames: ``.seq`` and ``.csq`` sequences and single ``.fff`` frames, indexed once
and read lazily.

A sequence is FFF frames of :mod:`~anra_torch.video.formats.flir_fff` one after another. It is indexed once,
each frame's image offset, encoding, CameraInfo constants and capture time; :class:`FLIRFrames` then reads
frames on demand and turns their counts into degrees Celsius with the frame's own constants. All frames
must have the same width and height. A trailing partial frame, trailing bytes that hold no frame and frames
without a RawData or CameraInfo record are left out and flagged in ``meta["input_warnings"]``; bytes that
hold no frame header but could hold a frame are a one-line error. Counts read in the other byte order are
said so in ``meta["camera"]["counts_byteswapped"]``. Times are each frame's capture time in s from the
first frame's, to the millisecond, with ``meta["t_resolution"]`` 0.001 s. ``.csq`` counts are JPEG-LS,
decoded by ``imagecodecs``, the ``formats`` extra. How the file is walked and which layouts are read:
``docs/guides/research-camera.md``, section "How a sequence is read".
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from anra_torch.video.core import RawVideo, stack_frames
from anra_torch.video.formats.flir_counts import decode_counts, swapped_rougher
from anra_torch.video.formats.flir_fff import (
    MAGIC,
    PLANCK_KEYS,
    Frame,
    IncompleteFrame,
    RawImage,
    TruncatedFrame,
    read_frame,
)
from anra_torch.video.formats.flir_objects import ObjectParameters, object_record
from anra_torch.video.formats.flir_planck import celsius

__all__ = [
    "FLIRFrames",
    "SequenceIndex",
    "index_sequence",
    "load_flir_folder",
    "load_flir_sequence",
    "open_flir_sequence",
]

T_RESOLUTION = 0.001
"""The capture time's resolution in s (CameraInfo stores milliseconds)."""

_PADDING = 1 << 16  # zero bytes skipped between frames at most


@dataclass
class SequenceIndex:
    """Where every frame of a FLIR recording lies, found by one walk through the file.

    Attributes:
        path: the file.
        raws: each frame's raw image (offset and length of its counts, encoding, byte order).
        planck: each frame's :data:`~anra_torch.video.formats.flir_fff.PLANCK_KEYS` values.
        ms: each frame's capture time, Unix ms.
        first: the first frame (its CameraInfo and header, for the metadata).
        warnings: what was left out (a trailing partial frame, trailing bytes), one line each.
        swapped: the layouts read byte-swapped against the documented order (``"uint16 <"``, ...).

    Shape:
        ``planck`` ``(T, len(PLANCK_KEYS))``; ``ms`` ``(T,)``.
    """

    path: Path
    raws: list[RawImage]
    planck: np.ndarray
    ms: np.ndarray
    first: Frame
    warnings: list[str] = field(default_factory=list)
    swapped: list[str] = field(default_factory=list)

    @property
    def t(self) -> np.ndarray:
        """Each frame's time in s from the first frame's (exact: from integer milliseconds).

        Shape:
            ``(T,)``.
        """
        return (self.ms - self.ms[0]) / 1000.0

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(T, H, W)`` of the recording."""
        return len(self.raws), self.first.raw.height, self.first.raw.width


def _reader(handle: BinaryIO) -> Any:
    def read(offset: int, size: int) -> bytes:
        handle.seek(offset)
        return handle.read(size)

    return read


def _skip_zeros(read: Any, pos: int, size: int) -> int:
    """The first byte at or after ``pos`` that is not zero padding (at most :data:`_PADDING` bytes)."""
    end = min(size, pos + _PADDING)
    while pos < end:
        chunk = read(pos, min(4096, end - pos))
        stripped = chunk.lstrip(b"\x00")
        if stripped:
            return pos + len(chunk) - len(stripped)
        pos += len(chunk)
    return pos


def _walk(path: Path, read: Any, size: int) -> tuple[list[Frame], list[str]]:
    """Every whole frame from byte 0, and what was left out."""
    frames: list[Frame] = []
    warnings: list[str] = []
    pos = 0
    while pos < size:
        if read(pos, 4) not in MAGIC:
            if not frames:
                raise ValueError(f"{path}: not a FLIR FFF recording (no 'FFF' frame header at byte {pos})")
            left, last = size - pos, frames[-1].end - frames[-1].start
            if left >= last:
                raise ValueError(
                    f"{path}: no FFF frame header at byte {pos} after frame {len(frames) - 1} ({left} bytes "
                    "left); the file is damaged or not a sequence of FFF frames"
                )
            warnings.append(
                f"input: {left} trailing bytes after frame {len(frames) - 1} hold no frame; left out"
            )
            break
        try:
            frame = read_frame(read, pos, where=str(path))
        except IncompleteFrame as err:  # e.g. a frame of metadata only: no counts to read
            warnings.append(f"input: {str(err).removeprefix(f'{path}: ')}: left out")
            pos = _skip_zeros(read, err.end, size)
            continue
        except TruncatedFrame:
            warnings.append(
                f"input: frame {len(frames)} (from byte {pos}) is cut off at the end of the file "
                f"({size - pos} bytes): left out"
            )
            break
        frames.append(frame)
        pos = _skip_zeros(read, frame.end, size)
    return frames, warnings


def _layout(raw: RawImage) -> str:
    return f"{raw.encoding} {raw.order}"


def index_sequence(path: str | os.PathLike[str]) -> SequenceIndex:
    """Walk a FLIR ``.seq`` / ``.csq`` / ``.fff`` file's frames once: their counts' places and encodings,
    their constants and capture times; how: ``docs/guides/research-camera.md``.

    Shape:
        ``T`` frames of ``(H, W)`` px.

    Raises:
        ValueError: not an FFF recording, a damaged frame, no header where a frame should begin, or frames
            of different sizes.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size == 0:
            raise ValueError(f"{path}: the file is empty (0 bytes); expected FLIR FFF frames")
        with path.open("rb") as handle:
            frames, warnings = _walk(path, _reader(handle), size)
            if not frames:
                raise ValueError(f"{path}: no whole FFF frame in the file ({'; '.join(warnings)})")
            first = frames[0]
            for k, frame in enumerate(frames):
                if (frame.raw.height, frame.raw.width) != (first.raw.height, first.raw.width):
                    raise ValueError(
                        f"{path}: frame {k} is {frame.raw.width} x {frame.raw.height} px, frame 0 is "
                        f"{first.raw.width} x {first.raw.height} px; one recording must hold one frame size"
                    )
            raws, swapped = _checked_order(path, handle, [f.raw for f in frames])
    except OSError as err:
        raise ValueError(f"{path}: cannot read ({' '.join(str(err).split())})") from err
    planck = np.stack([f.camera.vector() for f in frames])
    ms = np.array([f.camera.capture_ms for f in frames], dtype=np.int64)
    return SequenceIndex(path, raws, planck, ms, first, warnings, swapped)


def _checked_order(path: Path, handle: BinaryIO, raws: list[RawImage]) -> tuple[list[RawImage], list[str]]:
    """The raw images, with the layouts whose first frame reads far smoother byte-swapped flipped."""
    flipped = []
    for layout in dict.fromkeys(_layout(r) for r in raws):
        raw = next(r for r in raws if _layout(r) == layout)
        handle.seek(raw.offset)
        if swapped_rougher(decode_counts(raw, handle.read(raw.length), where=str(path))):
            flipped.append(layout)
    if not flipped:
        return raws, []
    return [replace(r, swapped=not r.swapped) if _layout(r) in flipped else r for r in raws], flipped


# ------------------------------------------------------------------------------------------- frames
class FLIRFrames:
    """Temperatures (degC, float32) of a FLIR recording's frames, read and decoded on demand: a frame source
    like :class:`~anra_torch.video.lazy.LazyFrames` (see :class:`~anra_torch.video.lazy.FrameSource`).

    Args:
        index: the recording's :class:`SequenceIndex`.
        objects: object parameters that replace the file's (None keeps them).
        start: first frame of the view.
        stop: frame after the view's last (default the end).

    Shape:
        ``frames[a:b]`` -> ``numpy.ndarray`` ``(b - a, H, W)`` float32; ``shape`` ``(T, H, W)``.

    Raises:
        ValueError: ``start``/``stop`` outside the recording; on reading, a frame that cannot be decoded.
    """

    dtype = np.dtype(np.float32)

    def __init__(
        self,
        index: SequenceIndex,
        objects: ObjectParameters | None = None,
        *,
        start: int = 0,
        stop: int | None = None,
    ) -> None:
        total = len(index.raws)
        stop = total if stop is None else stop
        if not 0 <= start <= stop <= total:
            raise ValueError(
                f"start and stop must satisfy 0 <= start <= stop <= {total}, got {start}, {stop}"
            )
        self.index, self.objects = index, objects
        self.path = index.path
        self._start = start
        self.shape = (stop - start, *index.shape[1:])
        self._planck = index.planck.copy()
        for key, value in (objects.changes() if objects is not None else {}).items():
            self._planck[:, PLANCK_KEYS.index(key)] = value

    def __len__(self) -> int:
        return self.shape[0]

    def window(self, start: int, stop: int) -> FLIRFrames:
        """Frames ``start .. stop - 1`` of this view, still unread."""
        first, last, _ = slice(start, stop).indices(self.shape[0])
        return FLIRFrames(
            self.index, self.objects, start=self._start + first, stop=self._start + max(last, first)
        )

    def counts(self, index: slice) -> np.ndarray:
        """The raw counts of frames ``index`` (a slice of this view), undecoded.

        Shape:
            ``(n, H, W)`` ``uint16``.
        """
        start, stop = self._span(index)
        raws = self.index.raws[start:stop]
        _, h, w = self.shape
        with self.path.open("rb") as handle:
            block = _strided(handle, raws, h, w)
            if block is not None:
                return block
            out = np.empty((len(raws), h, w), dtype=np.uint16)
            for k, raw in enumerate(raws):  # compressed frames: one decode each
                handle.seek(raw.offset)
                out[k] = decode_counts(raw, handle.read(raw.length), where=str(self.path))
        return out

    def __getitem__(self, index: slice) -> np.ndarray:
        start, stop = self._span(index)
        counts = self.counts(index)
        rows = self._planck[start:stop]
        same = len(rows) and bool((rows == rows[0]).all())
        planck = {key: (rows[0, k] if same else rows[:, k]) for k, key in enumerate(PLANCK_KEYS)}
        return celsius(counts, planck).astype(np.float32)

    def _span(self, index: slice) -> tuple[int, int]:
        """Absolute frame numbers ``[start, stop)`` of a contiguous slice of this view."""
        if not isinstance(index, slice):
            raise TypeError(f"FLIRFrames supports slices of frames, got {type(index).__name__}")
        start, stop, step = index.indices(self.shape[0])
        if step != 1:
            raise ValueError(f"FLIRFrames reads contiguous frames only (step 1), got step {step}")
        return self._start + start, self._start + max(stop, start)


def _strided(handle: BinaryIO, raws: list[RawImage], h: int, w: int) -> np.ndarray | None:
    """uint16 frames evenly spaced in the file, read with one read and no per-frame loop; None otherwise."""
    if not raws or any(r.encoding != "uint16" or _layout(r) != _layout(raws[0]) for r in raws):
        return None
    if any(r.swapped != raws[0].swapped for r in raws):
        return None
    offsets = np.array([r.offset for r in raws], dtype=np.int64)
    steps = np.diff(offsets)
    if steps.size and ((steps != steps[0]).any() or steps[0] < 2 * h * w):
        return None
    stride = int(steps[0]) if steps.size else 2 * h * w
    size = stride * (len(raws) - 1) + 2 * h * w
    handle.seek(int(offsets[0]))
    data = handle.read(size)
    if len(data) < size:
        raise ValueError(f"{handle.name}: truncated: frames at byte {offsets[0]} are not all in the file")
    view = np.ndarray((len(raws), h, w), dtype=raws[0].order + "u2", buffer=data, strides=(stride, 2 * w, 2))
    counts = view.astype(np.uint16)
    return counts.byteswap() if raws[0].swapped else counts


# ------------------------------------------------------------------------------------------- loaders
def _meta(index: SequenceIndex, objects: ObjectParameters | None) -> dict[str, Any]:
    first = index.first
    varies = frozenset(
        k for j, k in enumerate(PLANCK_KEYS) if (index.planck[:, j] != index.planck[0, j]).any()
    )
    t0 = index.ms[0] / 1000.0
    layouts = sorted({_layout(r) for r in index.raws})
    camera = {
        **first.camera.camera,
        "creator": first.creator,
        "fff_version": first.version,
        "counts": layouts,
        "counts_byteswapped": index.swapped,
        "planck": {k: float(v) for k, v in first.camera.planck.items() if k.startswith(("planck_", "alpha"))},
        "constants_vary_by_frame": sorted(varies),
        "capture_local": _when(t0, first.camera.utc_offset_min),
    }
    return {
        "unit": "degC",
        "format": f"flir_{index.path.suffix.lower().lstrip('.')}",
        "t0_utc": _when(t0, 0),
        "t_resolution": T_RESOLUTION,
        "object_parameters": object_record(first.camera, objects, varies=varies),
        "camera": camera,
        "input_warnings": list(index.warnings),
    }


def _when(seconds: float, zone_minutes: int) -> str | None:
    """A capture time (Unix s) as ISO text in a time zone (minutes east of UTC); None when the header's
    values are no date (a damaged frame: a year past 9999, a zone of a day or more)."""
    try:
        zone = UTC if zone_minutes == 0 else timezone(timedelta(minutes=zone_minutes))
        return datetime.fromtimestamp(seconds, zone).isoformat(timespec="milliseconds")
    except (ValueError, OverflowError, OSError):
        return None


def open_flir_sequence(path: Path, objects: ObjectParameters | None = None) -> RawVideo:
    """A FLIR ``.seq`` / ``.csq`` / ``.fff`` recording indexed, its frames left unread (:class:`FLIRFrames`).

    Args:
        path: the file.
        objects: object parameters that replace the file's.

    Returns:
        A :class:`~anra_torch.video.core.RawVideo`: ``frames`` a :class:`FLIRFrames` (degC), ``t`` the
        capture times in s from the first frame's, ``meta`` with ``unit``, ``format``, ``t0_utc``,
        ``t_resolution``, ``object_parameters`` (what was used and where it came from), ``camera``
        (model, serial number, Planck constants, ...) and ``input_warnings``.

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.

    Raises:
        ValueError: see :func:`index_sequence`.
    """
    index = index_sequence(path)
    return RawVideo(frames=FLIRFrames(index, objects), t=index.t, meta=_meta(index, objects))


def load_flir_sequence(path: Path, objects: ObjectParameters | None = None) -> RawVideo:
    """A FLIR ``.seq`` / ``.csq`` / ``.fff`` recording read whole (see :func:`open_flir_sequence`).

    Shape:
        ``frames`` ``(T, H, W)`` float32 degC; ``t`` ``(T,)``.
    """
    raw = open_flir_sequence(path, objects)
    raw.frames = raw.frames[0 : len(raw.frames)]
    return raw


def load_flir_folder(folder: Path, objects: ObjectParameters | None = None) -> RawVideo:
    """A folder of FLIR ``.fff`` files (a camera streaming one FFF frame per file) as one video, its frames
    ordered by their capture times (names may be in any order); files of other kinds beside them (ExifTool's
    text dumps, notes) are ignored. Read whole (the frames are decoded as they are read).

    Args:
        folder: the folder.
        objects: object parameters that replace the files'.

    Returns:
        A :class:`~anra_torch.video.core.RawVideo` as :func:`open_flir_sequence`'s, ``meta["files"]`` the
        first and last file in time order and ``meta["ignored"]`` how many other files were left alone.

    Shape:
        ``frames`` ``(T, H, W)`` float32 degC; ``t`` ``(T,)``.

    Raises:
        ValueError: a file that is not an FFF recording, frames of different sizes, or two frames captured
            at the same millisecond (each names its files).
    """
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    frames = [p for p in files if p.suffix.lower() == ".fff"]
    indexes = [index_sequence(p) for p in frames]
    order = sorted((int(ms), k, j) for k, index in enumerate(indexes) for j, ms in enumerate(index.ms))
    for (ms, k, j), (before, k0, j0) in zip(order[1:], order, strict=False):
        if ms == before:
            raise ValueError(
                f"{folder}: duplicate timestamps: {_name(frames, indexes, k, j)} and "
                f"{_name(frames, indexes, k0, j0)} were captured at the same millisecond; one folder must "
                "hold one video"
            )
    views = [FLIRFrames(index, objects) for index in indexes]
    decoded = [views[k][j : j + 1][0] for _, k, j in order]
    names = [frames[k] for _, k, _ in order]
    whole = SequenceIndex(  # the frames of every file in time order, for the metadata
        folder,
        [indexes[k].raws[j] for _, k, j in order],
        np.stack([indexes[k].planck[j] for _, k, j in order]),
        np.array([ms for ms, _, _ in order], dtype=np.int64),
        indexes[order[0][1]].first,
        [f"{p.name}: {w}" for p, i in zip(frames, indexes, strict=True) for w in i.warnings],
    )
    meta = _meta(whole, objects)
    meta.update(format="flir_fff_folder", files=f"{names[0].name} .. {names[-1].name}")
    meta["ignored"] = len(files) - len(frames)
    return RawVideo(frames=stack_frames(decoded, names, folder), t=whole.t, meta=meta)


def _name(files: list[Path], indexes: list[SequenceIndex], k: int, j: int) -> str:
    """A frame's file name (and its place in the file when the file holds several)."""
    return files[k].name + (f" (frame {j})" if len(indexes[k].raws) > 1 else "")
