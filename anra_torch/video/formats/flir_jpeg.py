"""FLIR radiometric JPEGs: the thermal image is embedded as raw sensor counts in an FFF record.

A radiometric JPEG (e.g. FLIR C3-X, 128 x 96 px thermal) carries, in its APP1 ``FLIR`` segments, an FFF
file with a RawData record (the counts, PNG or uint16) and a CameraInfo record (Planck constants R1, R2,
B, F, O, emissivity, distance, reflected and atmospheric temperatures). Temperatures are decoded by the
PyPI package ``flyr`` (Planck formula with atmospheric transmission, as the camera set it); the visible
640 x 480 picture is NOT the thermal data. Timestamps come from CameraInfo's DateTimeOriginal (Unix
seconds plus milliseconds), the EXIF capture time to the millisecond (EXIF ``DateTimeOriginal`` alone
has whole seconds).

A folder of such JPEGs is one video: frames ordered by file name (natural order), times relative to the
first frame in s; unsorted or duplicate times are a one-line error naming both files.
"""

from __future__ import annotations

import re
import struct
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from anra_torch.checks import one_line
from anra_torch.video.core import RawVideo, stack_frames

__all__ = ["flir_timestamp", "load_flir_jpeg", "load_flir_jpeg_folder"]

_CAMERA_INFO = 0x20  # FFF record type of the camera parameters
_TIME_OFFSET = 0x384  # DateTimeOriginal in CameraInfo: uint32 Unix s, uint32 ms, int16 tz minutes


def _fff(path: Path, data: bytes) -> bytes:
    """The FFF file assembled from the JPEG's APP1 ``FLIR`` segments (in chunk order)."""
    if data[:2] != b"\xff\xd8":
        raise ValueError(f"{path}: not a JPEG (no start-of-image marker); the file may be corrupt")
    chunks: dict[int, bytes] = {}
    pos = 2
    while pos + 4 <= len(data) and data[pos] == 0xFF:
        marker = data[pos + 1]
        if marker in (0xDA, 0xD9):  # start of scan / end of image: no more metadata segments
            break
        (length,) = struct.unpack(">H", data[pos + 2 : pos + 4])
        segment = data[pos + 4 : pos + 2 + length]
        if marker == 0xE1 and segment[:5] == b"FLIR\x00" and len(segment) > 8:
            chunks[segment[6]] = segment[8:]
        pos += 2 + length
    if not chunks:
        raise ValueError(
            f"{path}: no FLIR thermal data (no FFF record in the JPEG's APP1 segments); "
            "expected a radiometric FLIR JPEG"
        )
    fff = b"".join(chunks[k] for k in sorted(chunks))
    if fff[:4] != b"FFF\x00" or len(fff) < 0x20:
        raise ValueError(f"{path}: corrupt FLIR record (no FFF header); the file may be truncated")
    return fff


def _record(fff: bytes, kind: int, path: Path) -> bytes:
    order = ">" if struct.unpack(">I", fff[0x14:0x18])[0] < 1000 else "<"
    index, count = struct.unpack(order + "II", fff[0x18:0x20])
    for k in range(count):
        entry = fff[index + 32 * k : index + 32 * k + 20]
        if len(entry) < 20:
            break
        record_type, _, _, _, offset, length = struct.unpack(order + "HHIIII", entry)
        if record_type == kind and offset + length <= len(fff):
            return fff[offset : offset + length]
    raise ValueError(f"{path}: FLIR record type {kind:#x} missing or cut off; the file may be truncated")


def flir_timestamp(path: Path | str) -> float:
    """Capture time of a FLIR radiometric JPEG as Unix time in s, to the millisecond.

    Raises:
        ValueError: not a JPEG, no FLIR thermal data, or a truncated record.
    """
    path = Path(path)
    info = _record(_fff(path, path.read_bytes()), _CAMERA_INFO, path)
    order = "<" if struct.unpack("<H", info[:2])[0] == 2 else ">"
    if len(info) < _TIME_OFFSET + 8:
        raise ValueError(f"{path}: FLIR camera record too short for a capture time; the file may be corrupt")
    seconds, millis = struct.unpack(order + "II", info[_TIME_OFFSET : _TIME_OFFSET + 8])
    if seconds == 0 or millis >= 1000:
        raise ValueError(f"{path}: FLIR capture time missing or invalid ({seconds} s, {millis} ms)")
    return seconds + millis / 1000.0


def _celsius(path: Path) -> tuple[np.ndarray, dict]:
    """Temperatures (degC, (H, W)) and the camera's object parameters, decoded by flyr."""
    try:
        import flyr
    except ImportError as err:
        raise ImportError(
            "reading FLIR radiometric JPEGs needs flyr: pip install anra_torch[formats]"
        ) from err
    try:
        thermogram = flyr.unpack(str(path))
        celsius = np.asarray(thermogram.celsius, dtype=np.float64)
        params = dict(thermogram.metadata)
    except Exception as err:  # flyr raises many kinds on a damaged file
        raise ValueError(
            f"{path}: cannot decode the FLIR thermal image ({one_line(err, kind=True)})"
        ) from err
    if celsius.ndim != 2 or not np.isfinite(celsius).all():
        raise ValueError(f"{path}: the decoded thermal image is not a finite 2D matrix")
    return celsius, params


def _meta(params: dict, t0: float) -> dict:
    keep = ("emissivity", "object_distance", "reflected_apparent_temperature", "atmospheric_temperature")
    meta = {f"flir_{k}": float(params[k]) for k in keep if k in params}
    meta.update(
        unit="degC",
        format="flir_jpeg",
        t0_utc=datetime.fromtimestamp(t0, UTC).isoformat(timespec="milliseconds"),
    )
    return meta


def load_flir_jpeg(path: Path) -> RawVideo:
    """One FLIR radiometric JPEG as a one-frame video (degC; ``t`` = its capture time, 0 s)."""
    t0 = flir_timestamp(path)
    celsius, params = _celsius(path)
    return RawVideo(frames=celsius[None], t=np.zeros(1), meta=_meta(params, t0))


def _natural(path: Path) -> list:
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


def load_flir_jpeg_folder(folder: Path) -> RawVideo:
    """A folder of FLIR radiometric JPEGs as one video (degC; ``t`` in s from the first frame)."""
    files = sorted(
        (p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in (".jpg", ".jpeg")), key=_natural
    )
    stamps = [flir_timestamp(p) for p in files]
    for k in range(1, len(files)):
        if stamps[k] <= stamps[k - 1]:
            kind = "duplicate" if stamps[k] == stamps[k - 1] else "unsorted"
            raise ValueError(
                f"{folder}: {kind} timestamps: {files[k].name} was taken at {stamps[k]:.3f} s, not after "
                f"{files[k - 1].name} at {stamps[k - 1]:.3f} s (Unix time); frames are ordered by file name"
            )
    decoded = [_celsius(p) for p in files]
    frames = stack_frames([c for c, _ in decoded], files, folder)
    meta = _meta(decoded[0][1], stamps[0])
    meta["files"] = f"{files[0].name} .. {files[-1].name}"
    return RawVideo(frames=frames, t=np.asarray(stamps) - stamps[0], meta=meta)
