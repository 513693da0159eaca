"""FLIR FFF frames: the record directory, the camera record and where the raw image lies.

An FFF frame is the container of every radiometric FLIR format: a ``.fff`` file is one, a ``.seq`` is
several one after another, a ``.csq`` the same with JPEG-LS counts, a radiometric JPEG carries one in its
APP1 segments. The layout read is ExifTool's, byte by byte in ``docs/guides/research-camera.md``, section
"The FFF layout". The raw image becomes counts in :mod:`~anra_torch.video.formats.flir_counts`, counts
become temperatures in :mod:`~anra_torch.video.formats.flir_planck`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "CAMERA_INFO",
    "PLANCK_KEYS",
    "RAW_DATA",
    "MAGIC",
    "CameraInfo",
    "Frame",
    "RawImage",
    "TruncatedFrame",
    "read_frame",
]

RAW_DATA = 0x01
"""FFF record type of the raw counts."""
CAMERA_INFO = 0x20
"""FFF record type of the camera parameters."""

HEADER_SIZE = 0x40
_ENTRY = 0x20
MAGIC = (b"FFF\x00", b"AFF\x00")
"""The first four bytes of an FFF frame."""
_KELVIN = 273.15
_TIME = 0x384  # DateTimeOriginal: int32u s, int32u (low 16 bits ms), int16s minutes west of UTC
_CAMERA_MIN = _TIME + 10  # shortest camera record that holds every field the temperatures and times need


class TruncatedFrame(ValueError):
    """An FFF frame whose header, directory or records run past the end of the data."""


class IncompleteFrame(ValueError):
    """A whole FFF frame without a RawData or CameraInfo record (``end``: where the next frame begins)."""

    def __init__(self, message: str, end: int) -> None:
        super().__init__(message)
        self.end = end


# ------------------------------------------------------------------------------------------ records
@dataclass(frozen=True)
class RawImage:
    """Where a frame's raw counts lie and how they are stored.

    Attributes:
        width: columns in px, from the RawData record.
        height: rows in px.
        order: the record's byte order, ``"<"`` or ``">"`` (that of ``uint16`` counts).
        encoding: ``"uint16"``, ``"png"`` or ``"jpeg-ls"``.
        offset: byte offset of the image data in the file (or buffer) it was read from.
        length: bytes of image data.
        swapped: the counts are byte-swapped against ``order`` (FLIR's PNGs), as documented.

    Shape:
        Decoded counts ``(height, width)``.
    """

    width: int
    height: int
    order: str
    encoding: str
    offset: int
    length: int
    swapped: bool = False


@dataclass(frozen=True)
class CameraInfo:
    """A frame's CameraInfo record (ExifTool's names).

    Attributes:
        planck: the :data:`PLANCK_KEYS` values the temperatures need: ``emissivity`` (0-1],
            ``object_distance`` (m), ``reflected_temp``, ``atmospheric_temp``, ``ir_window_temp`` (degC),
            ``ir_window_transmission``, ``relative_humidity`` (a fraction), the camera's calibration
            ``planck_r1``, ``planck_b``, ``planck_f``, ``planck_o``, ``planck_r2`` and the atmosphere's
            transmission constants ``alpha1``, ``alpha2``, ``beta1``, ``beta2``, ``x``.
        capture_ms: Unix time of the capture in ms (an integer: exact differences between frames).
        utc_offset_min: the camera's time zone, minutes east of UTC.
        camera: the other fields (model, serial number, lens, temperature range in degC, ...).

    Shape:
        Scalars.
    """

    planck: dict[str, float]
    capture_ms: int
    utc_offset_min: int
    camera: dict[str, Any]

    @property
    def capture_time(self) -> float:
        """Unix time of the capture in s."""
        return self.capture_ms / 1000.0

    def vector(self) -> np.ndarray:
        """The :data:`PLANCK_KEYS` values as one float64 vector (a row of a sequence's table).

        Shape:
            ``(len(PLANCK_KEYS),)``.
        """
        return np.array([self.planck[key] for key in PLANCK_KEYS], dtype=np.float64)


@dataclass(frozen=True)
class Frame:
    """One FFF frame as found: its extent, its raw image and its camera record.

    Attributes:
        start: byte offset of its header; end: the byte after its last record (a sequence's next frame).
        raw: the raw image (offsets from the start of the file or buffer); camera: the CameraInfo record.
        creator: the header's creator software; version: its format version.

    Shape:
        No tensors.
    """

    start: int
    end: int
    raw: RawImage
    camera: CameraInfo
    creator: str
    version: int


Reader = Callable[[int, int], bytes]
"""``read(offset, size)``: up to ``size`` bytes from ``offset`` (fewer at the end of the data)."""


def _order(data: bytes, offset: int, low: int, high: int) -> str | None:
    """The byte order in which the ``int32u`` at ``offset`` lies in ``[low, high)``, None in neither."""
    for order in (">", "<"):
        if low <= struct.unpack_from(order + "I", data, offset)[0] < high:
            return order
    return None


def _record_order(data: bytes, frame_order: str) -> str:
    """ExifTool's rule: the frame's order, toggled when the record's first ``int16u`` reads >= 0x100."""
    if struct.unpack_from(frame_order + "H", data, 0)[0] < 0x100:
        return frame_order
    return "<" if frame_order == ">" else ">"


def _text(data: bytes, offset: int, size: int) -> str | None:
    if offset + size > len(data):
        return None
    return data[offset : offset + size].split(b"\x00", 1)[0].decode("latin-1").strip()


def _directory(
    read: Reader, start: int, where: str
) -> tuple[str, list[tuple[int, int, int, int]], int, bytes]:
    """The frame's byte order, its non-empty records ``(type, subtype, offset, length)`` (offsets from
    the frame's first byte), the end of its directory (from the frame's first byte) and its header."""
    header = read(start, HEADER_SIZE)
    if header[:4] not in MAGIC:
        raise ValueError(f"{where}: no FFF frame header (got {header[:4]!r} at byte {start})")
    if len(header) < HEADER_SIZE:
        raise TruncatedFrame(f"{where}: truncated: the FFF header at byte {start} is cut off")
    order = _order(header, 0x14, 100, 200)
    if order is None:
        raise ValueError(f"{where}: unsupported FFF format version at byte {start} (expected 100-199)")
    index, count = struct.unpack_from(order + "II", header, 0x18)
    if count > 4096 or index < HEADER_SIZE:
        raise ValueError(
            f"{where}: corrupt FFF record directory ({count} entries at {index}) at byte {start}"
        )
    table = read(start + index, count * _ENTRY)
    if len(table) < count * _ENTRY:
        raise TruncatedFrame(
            f"{where}: truncated: the FFF record directory at byte {start + index} is cut off"
        )
    entries = []
    for k in range(count):
        kind, subtype, _, _, offset, length = struct.unpack_from(order + "HHIIII", table, k * _ENTRY)
        if kind:
            entries.append((kind, subtype, offset, length))
    return order, entries, index + count * _ENTRY, header


def read_frame(read: Reader, start: int = 0, *, where: str = "FFF") -> Frame:
    """The FFF frame whose header is at byte ``start``: its records walked through its directory.

    Args:
        read: ``read(offset, size)`` of the file or buffer (:data:`Reader`).
        start: byte offset of the frame's header (64-bit: any size of file).
        where: the file's name, for the messages.

    Returns:
        :class:`Frame` (its ``end`` is the byte after its last record or directory).

    Shape:
        No tensors.

    Raises:
        TruncatedFrame: the header, the directory or a record runs past the end of the data.
        IncompleteFrame: a whole frame without a RawData or CameraInfo record.
        ValueError: no FFF header at ``start``, an unknown format version, or a record too short for its
            fields.
    """
    order, entries, directory_end, header = _directory(read, start, where)
    end = start + directory_end
    found: dict[int, tuple[int, int]] = {}
    for kind, _, offset, length in entries:
        end = max(end, start + offset + length)
        found.setdefault(kind, (start + offset, length))
    missing = [
        name for kind, name in ((RAW_DATA, "RawData"), (CAMERA_INFO, "CameraInfo")) if kind not in found
    ]
    if len(read(end - 1, 1)) < 1:
        found, end = _whole_records(read, found, [(start + e[2], e[3]) for e in entries], order)
        if not found:
            raise TruncatedFrame(
                f"{where}: truncated: the FFF frame at byte {start} runs past the end of the data"
            )
    if missing:
        text = f"{where}: the FFF frame at byte {start} has no {' or '.join(missing)} record"
        raise IncompleteFrame(text, end)
    camera = _camera_info(read(*found[CAMERA_INFO]), order, where, start)
    creator = header[4:20].split(b"\x00", 1)[0].decode("latin-1")
    version = struct.unpack_from(order + "I", header, 0x14)[0]
    return Frame(start, end, _raw_image(read, *found[RAW_DATA], order, where), camera, creator, version)


_PNG_END = b"IEND\xaeB`\x82"  # the IEND chunk and its CRC: the last bytes of a whole PNG


def _whole_records(
    read: Reader, found: dict[int, tuple[int, int]], records: list[tuple[int, int]], frame_order: str
) -> tuple[dict[int, tuple[int, int]], int]:
    """A frame cut by the end of the data, kept when what its temperatures need is all there: the
    CameraInfo record whole and the image whole (a JPEG-LS stream up to its end-of-image marker, a PNG up
    to its IEND chunk, or every uint16 count), as a last frame whose record was stored shorter than its
    directory says. Returns ``found`` with the RawData record cut to the image and the end of the data
    (where the frame ends), or ``({}, 0)`` when the image or the CameraInfo record is cut."""
    if RAW_DATA not in found or CAMERA_INFO not in found:
        return {}, 0
    camera_at, camera_length = found[CAMERA_INFO]
    if len(read(camera_at, camera_length)) < camera_length:
        return {}, 0
    raw_at, raw_length = found[RAW_DATA]
    data = read(raw_at, raw_length)
    body = data[0x20:].rstrip(b"\x00")  # zero padding after the image's end
    if body.startswith(b"\xff\xd8\xff") and body.endswith(b"\xff\xd9"):  # no FF D9 inside JPEG-LS data
        kept = 0x20 + len(body)
    elif body.startswith(b"\x89PNG\r\n\x1a\n") and body.endswith(_PNG_END):
        kept = 0x20 + len(body)
    elif len(data) >= 6 and 0 < 2 * math.prod(_size(data, frame_order)) <= len(data) - 0x20:
        kept = len(data)
    else:
        return {}, 0
    end = max(offset + len(read(offset, length)) for offset, length in records)
    return {**found, RAW_DATA: (raw_at, kept)}, end


def _size(head: bytes, frame_order: str) -> tuple[int, int]:
    """Width and height in px of a RawData record from its first bytes."""
    return struct.unpack_from(_record_order(head, frame_order) + "HH", head, 2)


def _raw_image(read: Reader, offset: int, length: int, frame_order: str, where: str) -> RawImage:
    head = read(offset, 0x20 + 8)
    if length < 0x20 + 8 or len(head) < 0x20 + 8:
        raise ValueError(f"{where}: RawData record at byte {offset} too short ({length} bytes)")
    order = _record_order(head, frame_order)
    width, height = struct.unpack_from(order + "HH", head, 2)
    body = head[0x20:]
    size = length - 0x20
    if body.startswith(b"\x89PNG\r\n\x1a\n"):
        encoding = "png"
    elif body.startswith(b"\xff\xd8\xff"):
        encoding = "jpeg-ls"
    elif size >= 2 * width * height > 0:
        encoding = "uint16"
    else:
        raise ValueError(
            f"{where}: RawData record at byte {offset}: {size} bytes are not {width} x {height} uint16 "
            "counts, a PNG or a JPEG-LS image"
        )
    if width < 1 or height < 1:
        raise ValueError(f"{where}: RawData record at byte {offset} gives a {width} x {height} px image")
    return RawImage(width, height, order, encoding, offset + 0x20, size, swapped=encoding == "png")


_FORMULA_TAGS: dict[str, tuple[int, str]] = {
    # ExifTool's CameraInfo offsets and formats ("K": a float in K, read in degC)
    "emissivity": (0x20, "f"),
    "object_distance": (0x24, "f"),
    "reflected_temp": (0x28, "K"),
    "atmospheric_temp": (0x2C, "K"),
    "ir_window_temp": (0x30, "K"),
    "ir_window_transmission": (0x34, "f"),
    "relative_humidity": (0x3C, "f"),
    "planck_r1": (0x58, "f"),
    "planck_b": (0x5C, "f"),
    "planck_f": (0x60, "f"),
    "planck_o": (0x308, "i"),
    "planck_r2": (0x30C, "f"),
    "alpha1": (0x70, "f"),
    "alpha2": (0x74, "f"),
    "beta1": (0x78, "f"),
    "beta2": (0x7C, "f"),
    "x": (0x80, "f"),
}
PLANCK_KEYS = tuple(_FORMULA_TAGS)
"""The CameraInfo values :func:`celsius` uses, in the order of :meth:`CameraInfo.vector`."""
_CAMERA_TAGS: dict[str, tuple[int, str | int]] = {
    # the rest, for the metadata (an int: a string of that many bytes); None beyond a short record
    **{
        f"camera_temperature_{name}": (0x90 + 4 * k, "K")
        for k, name in enumerate(
            ("range_max", "range_min", "max_clip", "min_clip", "max_warn", "min_warn", "max_saturated")
        )
    },
    "camera_temperature_min_saturated": (0xAC, "K"),
    "camera_model": (0xD4, 32),
    "camera_part_number": (0xF4, 16),
    "camera_serial_number": (0x104, 16),
    "camera_software": (0x114, 16),
    "lens_model": (0x170, 32),
    "lens_part_number": (0x190, 16),
    "lens_serial_number": (0x1A0, 16),
    "field_of_view": (0x1B4, "f"),
    "filter_model": (0x1EC, 16),
    "filter_part_number": (0x1FC, 32),
    "filter_serial_number": (0x21C, 32),
    "raw_value_range_min": (0x310, "H"),
    "raw_value_range_max": (0x312, "H"),
    "raw_value_median": (0x338, "H"),
    "raw_value_range": (0x33C, "H"),
    "focus_step_count": (0x390, "H"),
    "focus_distance": (0x45C, "f"),
    "frame_rate": (0x464, "H"),
}


def _tag(data: bytes, order: str, offset: int, kind: str | int) -> Any:
    if isinstance(kind, int):
        return _text(data, offset, kind)
    fmt = "f" if kind == "K" else kind
    if offset + struct.calcsize(fmt) > len(data):
        return None
    value = struct.unpack_from(order + fmt, data, offset)[0]
    return round(float(value) - _KELVIN, 6) if kind == "K" else value


def _camera_info(data: bytes, frame_order: str, where: str, start: int) -> CameraInfo:
    if len(data) < _CAMERA_MIN:
        raise ValueError(
            f"{where}: CameraInfo record of the frame at byte {start} too short ({len(data)} bytes, "
            f"need {_CAMERA_MIN}); the file may be corrupt"
        )
    order = _record_order(data, frame_order)
    values = {
        name: float(struct.unpack_from(order + ("f" if k == "K" else k), data, at)[0])
        for name, (at, k) in _FORMULA_TAGS.items()
    }
    for name, (_, kind) in _FORMULA_TAGS.items():
        values[name] -= _KELVIN if kind == "K" else 0.0
    if values["relative_humidity"] > 2:  # ExifTool: a percentage in some files
        values["relative_humidity"] /= 100
    seconds, sub, zone = struct.unpack_from(order + "IIh", data, _TIME)
    camera = {name: _tag(data, order, at, kind) for name, (at, kind) in _CAMERA_TAGS.items()}
    return CameraInfo(values, 1000 * seconds + (sub & 0xFFFF), -zone, camera)
