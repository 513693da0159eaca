"""FLIR radiometric JPEGs: the thermal image is embedded as raw sensor counts in an FFF record.

A radiometric JPEG (e.g. FLIR C3-X, 128 x 96 px thermal) carries, in its APP1 ``FLIR`` segments, an FFF
frame with a RawData record (the counts, PNG or uint16) and a CameraInfo record (Planck constants R1, R2,
B, F, O, emissivity, distance, reflected and atmospheric temperatures). The segments are joined here; the
frame is read (:mod:`~anra_torch.video.formats.flir_fff`) and its counts turned into temperatures
(:mod:`~anra_torch.video.formats.flir_planck`), as for ``.fff``, ``.seq`` and ``.csq`` files, with the object
parameters the camera set or the caller's :class:`~anra_torch.video.formats.flir_objects.ObjectParameters`;
the visible 640 x 480 picture is NOT the thermal data. Timestamps come from CameraInfo's DateTimeOriginal
(Unix seconds plus milliseconds), the EXIF capture time to the millisecond (EXIF ``DateTimeOriginal``
alone has whole seconds).

A folder of such JPEGs is one video: frames ordered by file name (natural order), times relative to the
first frame in s; unsorted or duplicate times are a one-line error naming both files.
"""

from __future__ import annotations

import re
import struct
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from anra_torch.video.core import RawVideo, stack_frames
from anra_torch.video.formats.flir_counts import decode_counts
from anra_torch.video.formats.flir_fff import Frame, read_frame
from anra_torch.video.formats.flir_objects import ObjectParameters, object_record
from anra_torch.video.formats.flir_planck import celsius

__all__ = ["flir_timestamp", "load_flir_jpeg", "load_flir_jpeg_folder"]


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


def _frame(path: Path) -> tuple[Frame, bytes]:
    """The FFF frame of a radiometric JPEG and the FFF bytes it was read from."""
    fff = _fff(path, path.read_bytes())
    return read_frame(lambda offset, size: fff[offset : offset + size], 0, where=str(path)), fff


def flir_timestamp(path: Path | str) -> float:
    """Capture time of a FLIR radiometric JPEG as Unix time in s, to the millisecond.

    Raises:
        ValueError: not a JPEG, no FLIR thermal data, or a truncated record.
    """
    path = Path(path)
    return _capture_time(_frame(path)[0], path)


def _capture_time(frame: Frame, path: Path) -> float:
    stamp = frame.camera.capture_time
    if stamp < 1:
        raise ValueError(f"{path}: FLIR capture time missing or invalid ({stamp:.3f} s)")
    return stamp


def _celsius(path: Path, objects: ObjectParameters | None) -> tuple[np.ndarray, Frame]:
    """Temperatures (degC, (H, W)) of one JPEG by the Planck formula, and its FFF frame."""
    frame, fff = _frame(path)
    raw = frame.raw
    counts = decode_counts(raw, fff[raw.offset : raw.offset + raw.length], where=str(path))
    camera = objects.apply(frame.camera) if objects is not None else frame.camera
    return celsius(counts, camera.planck), frame


def _meta(frame: Frame, t0: float, objects: ObjectParameters | None) -> dict:
    meta = {f"flir_{k}": v for k, v in frame.camera.planck.items() if k in ("emissivity", "object_distance")}
    meta.update(
        unit="degC",
        format="flir_jpeg",
        t0_utc=datetime.fromtimestamp(t0, UTC).isoformat(timespec="milliseconds"),
        object_parameters=object_record(frame.camera, objects),
        camera={**frame.camera.camera, "planck": frame.camera.planck},
    )
    return meta


def load_flir_jpeg(path: Path, objects: ObjectParameters | None = None) -> RawVideo:
    """One FLIR radiometric JPEG as a one-frame video (degC; ``t`` = its capture time, 0 s)."""
    celsius_, frame = _celsius(path, objects)
    t0 = _capture_time(frame, path)
    return RawVideo(frames=celsius_[None], t=np.zeros(1), meta=_meta(frame, t0, objects))


def _natural(path: Path) -> list:
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


def load_flir_jpeg_folder(folder: Path, objects: ObjectParameters | None = None) -> RawVideo:
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
    decoded = [_celsius(p, objects) for p in files]
    frames = stack_frames([c for c, _ in decoded], files, folder)
    meta = _meta(decoded[0][1], stamps[0], objects)
    meta["files"] = f"{files[0].name} .. {files[-1].name}"
    return RawVideo(frames=frames, t=np.asarray(stamps) - stamps[0], meta=meta)
