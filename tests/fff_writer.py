"""A small writer of FLIR FFF frames, ``.seq`` and ``.csq`` files for the tests, and an independent Planck.

Written from ExifTool's FLIR tag tables (header: "FFF\\0", creator at 0x04, version at 0x14, directory offset
and count at 0x18 / 0x1c; 0x20-byte directory entries: type, subtype, version, index id, offset, length;
CameraInfo offsets 0x20 emissivity ... 0x384 DateTimeOriginal; RawData: 2, width, height, then the image at
0x20) and Thermimage's ``raw2temp``. Shares no code with anra_torch: the PNG is written by hand (zlib), the
JPEG-LS by imagecodecs' encoder.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

CONSTANTS = {  # a FLIR T420's (the little-endian sample frame's) calibration
    "r1": 16125.788,
    "b": 1420.1,
    "f": 1.0,
    "o": -5588,
    "r2": 0.010903412,
    "a1": 0.006569,
    "a2": 0.01262,
    "b1": -0.002276,
    "b2": -0.00667,
    "x": 1.9,
}


@dataclass
class Camera:
    """CameraInfo values: temperatures in K as stored, humidity a fraction, time Unix s + ms."""

    emissivity: float = 0.95
    distance: float = 1.0
    reflected_k: float = 293.15
    atmospheric_k: float = 293.15
    window_k: float = 293.15
    window_transmission: float = 1.0
    humidity: float = 0.5
    seconds: int = 1_700_000_000
    millis: int = 0
    tz_minutes: int = -60  # minutes west of UTC, as stored (-60: UTC+01:00)
    model: str = "Test Camera"
    constants: dict = field(default_factory=lambda: dict(CONSTANTS))


def camera_record(cam: Camera, order: str) -> bytes:
    data = bytearray(0x480)
    c = cam.constants
    struct.pack_into(order + "H", data, 0, 2)
    pack = lambda fmt, off, *v: struct.pack_into(order + fmt, data, off, *v)  # noqa: E731
    pack("fffff", 0x20, cam.emissivity, cam.distance, cam.reflected_k, cam.atmospheric_k, cam.window_k)
    pack("f", 0x34, cam.window_transmission)
    pack("f", 0x3C, cam.humidity)
    pack("fff", 0x58, c["r1"], c["b"], c["f"])
    pack("fffff", 0x70, c["a1"], c["a2"], c["b1"], c["b2"], c["x"])
    data[0xD4 : 0xD4 + len(cam.model)] = cam.model.encode()
    pack("if", 0x308, c["o"], c["r2"])
    pack("IIh", 0x384, cam.seconds, cam.millis, cam.tz_minutes)
    pack("H", 0x464, 30)
    return bytes(data)


def png_gray16(counts: np.ndarray) -> bytes:
    """A 16-bit greyscale PNG of ``counts`` (big-endian samples, as PNG stores them), filter 0 rows."""
    h, w = counts.shape
    rows = b"".join(b"\x00" + counts[r].astype(">u2").tobytes() for r in range(h))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(rows))
        + chunk(b"IEND", b"")
    )


def raw_record(counts: np.ndarray, order: str, encoding: str = "uint16") -> bytes:
    """The RawData record: ``encoding`` "uint16" (in ``order``), "png" (byte-swapped, as FLIR stores it),
    "png-plain" (not swapped), "jpeg-ls" or "uint16-swapped" (stored in the other order)."""
    h, w = counts.shape
    head = bytearray(0x20)
    struct.pack_into(order + "HHH", head, 0, 2, w, h)
    if encoding == "uint16":
        body = counts.astype(order + "u2").tobytes()
    elif encoding == "uint16-swapped":
        body = counts.astype(("<" if order == ">" else ">") + "u2").tobytes()
    elif encoding == "png":
        body = png_gray16(counts.astype(np.uint16).byteswap())
    elif encoding == "png-plain":
        body = png_gray16(counts.astype(np.uint16))
    else:
        import imagecodecs

        body = imagecodecs.jpegls_encode(np.ascontiguousarray(counts, dtype=np.uint16))
    return bytes(head) + body


def frame(
    records: list[tuple[int, bytes]],
    order: str,
    *,
    empty: int = 2,
    creator: bytes = b"TestWriter",
    version: int = 100,
    gap: int = 0,
) -> bytes:
    """One FFF frame: header, directory (records then ``empty`` empty entries), the records in the given
    order, ``gap`` zero bytes between the directory and the first record."""
    count = len(records) + empty
    header = bytearray(0x40)
    header[:4] = b"FFF\x00"
    header[4 : 4 + len(creator)] = creator
    struct.pack_into(order + "III", header, 0x14, version, 0x40, count)
    offset = 0x40 + 0x20 * count + gap
    directory, body = bytearray(), bytearray(gap)
    for kind, data in records:
        directory += struct.pack(order + "HHIIIIIII", kind, 1, 100, 1, offset, len(data), 0, 0, 0)
        body += data
        offset += len(data)
    directory += bytes(0x20 * empty)
    return bytes(header) + bytes(directory) + bytes(body)


def simple_frame(
    counts: np.ndarray,
    cam: Camera,
    order: str = "<",
    encoding: str = "uint16",
    record_order: str | None = None,
) -> bytes:
    """A frame with RawData and CameraInfo (records in ``record_order``, default the frame's)."""
    inner = record_order or order
    return frame([(0x01, raw_record(counts, inner, encoding)), (0x20, camera_record(cam, inner))], order)


# ------------------------------------------------------------------------------------------ Planck
def radiance(kelvin: float, c: dict) -> float:
    return c["r1"] / (c["r2"] * (math.exp(c["b"] / kelvin) - c["f"])) - c["o"]


def planck_celsius(raw: float, cam: Camera, *, emissivity: float | None = None) -> float:
    """Thermimage's raw2temp for one count, in plain floats (the constants rounded to float32 as stored)."""
    f32 = lambda v: float(np.float32(v))  # noqa: E731
    c = {k: f32(v) if k != "o" else v for k, v in cam.constants.items()}
    e = f32(cam.emissivity) if emissivity is None else emissivity
    od, rt, at, wt = (f32(v) for v in (cam.distance, cam.reflected_k, cam.atmospheric_k, cam.window_k))
    irt, rh = f32(cam.window_transmission), f32(cam.humidity)
    atc = at - 273.15
    h2o = rh * math.exp(1.5587 + 0.06939 * atc - 0.00027816 * atc**2 + 0.00000068455 * atc**3)
    tau = c["x"] * math.exp(-math.sqrt(od / 2) * (c["a1"] + c["b1"] * math.sqrt(h2o))) + (
        1 - c["x"]
    ) * math.exp(-math.sqrt(od / 2) * (c["a2"] + c["b2"] * math.sqrt(h2o)))
    refl1 = (1 - e) / e * radiance(rt, c)
    atm1 = (1 - tau) / e / tau * radiance(at, c)
    wind = (1 - irt) / e / tau / irt * radiance(wt, c)
    atm2 = (1 - tau) / e / tau / irt / tau * radiance(at, c)
    obj = raw / e / tau / irt / tau - atm1 - atm2 - wind - refl1
    return c["b"] / math.log(c["r1"] / (c["r2"] * (obj + c["o"])) + c["f"]) - 273.15


def counts_for(celsius: np.ndarray, cam: Camera) -> np.ndarray:
    """Blackbody counts (emissivity 1, no atmosphere) of temperatures ``celsius``, rounded to uint16."""
    c = cam.constants
    kelvin = np.asarray(celsius, dtype=np.float64) + 273.15
    return np.round(c["r1"] / (c["r2"] * (np.exp(c["b"] / kelvin) - c["f"])) - c["o"]).astype(np.uint16)
