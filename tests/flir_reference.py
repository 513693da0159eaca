"""An independent decoder of FLIR radiometric JPEGs for tests: FFF records by hand, Planck by hand.

Written from the published record layout (ExifTool's FLIR tags: CameraInfo offsets 0x20 emissivity,
0x24 object distance, 0x28 reflected, 0x2c atmospheric, 0x30 IR window temperature (K), 0x34 window
transmission, 0x3c relative humidity, 0x58 R1, 0x5c B, 0x60 F, 0x70-0x80 atmospheric constants,
0x308 O, 0x30c R2, 0x384 DateTimeOriginal) and the raw -> temperature formula with atmospheric
transmission (as in ExifTool's documentation and R's Thermimage::raw2temp). Shares no code with flyr or
anra_torch.video.
"""

from __future__ import annotations

import io
import math
import struct
from pathlib import Path

import numpy as np


def fff_bytes(path: Path) -> bytes:
    data = Path(path).read_bytes()
    pos, chunks = 2, {}
    while data[pos] == 0xFF and data[pos + 1] not in (0xDA, 0xD9):
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        seg = data[pos + 4 : pos + 2 + length]
        if data[pos + 1] == 0xE1 and seg.startswith(b"FLIR\x00"):
            chunks[seg[6]] = seg[8:]
        pos += 2 + length
    return b"".join(v for _, v in sorted(chunks.items()))


def records(fff: bytes) -> dict[int, bytes]:
    index, count = struct.unpack(">II", fff[0x18:0x20])
    out = {}
    for k in range(count):
        kind, _, _, _, off, length = struct.unpack(">HHIIII", fff[index + 32 * k : index + 32 * k + 20])
        out.setdefault(kind, fff[off : off + length])
    return out


def decode(path: Path) -> tuple[np.ndarray, float]:
    """Temperatures in degC ``(H, W)`` and the capture time (Unix s) of one radiometric JPEG."""
    from PIL import Image

    rec = records(fff_bytes(path))
    raw_rec, cam = rec[1], rec[0x20]
    width, height = struct.unpack("<HH", raw_rec[2:6])
    body = raw_rec[0x20:]
    if body[:4] == b"\x89PNG":
        raw = np.asarray(Image.open(io.BytesIO(body)), dtype=np.uint16)
        raw = ((raw >> 8) | ((raw & 0xFF) << 8)).astype(np.float64)  # stored byte-swapped
    else:
        raw = np.frombuffer(body[: 2 * width * height], "<u2").reshape(height, width).astype(np.float64)
    f = lambda off: struct.unpack("<f", cam[off : off + 4])[0]  # noqa: E731
    e, od, rt, at, iwt, iwtr, rh = f(0x20), f(0x24), f(0x28), f(0x2C), f(0x30), f(0x34), f(0x3C)
    r1, b, pf, r2 = f(0x58), f(0x5C), f(0x60), f(0x30C)
    po = struct.unpack("<i", cam[0x308:0x30C])[0]
    a1, a2, b1, b2, x = f(0x70), f(0x74), f(0x78), f(0x7C), f(0x80)
    seconds, millis = struct.unpack("<II", cam[0x384:0x38C])
    atc = at - 273.15
    h2o = rh * math.exp(1.5587 + 0.06939 * atc - 0.00027816 * atc**2 + 0.00000068455 * atc**3)
    tau = x * math.exp(-math.sqrt(od / 2) * (a1 + b1 * math.sqrt(h2o))) + (1 - x) * math.exp(
        -math.sqrt(od / 2) * (a2 + b2 * math.sqrt(h2o))
    )

    def radiance(kelvin: float) -> float:
        return r1 / (r2 * (math.exp(b / kelvin) - pf)) - po

    # one atmosphere layer on each side of the window (the camera splits the distance), window transparent
    refl = (1 - e) / e * radiance(rt)
    atm1 = (1 - tau) / e / tau * radiance(at)
    wind = (1 - iwtr) / e / tau / iwtr * radiance(iwt)
    atm2 = (1 - tau) / e / tau / iwtr / tau * radiance(at)
    obj = raw / e / tau / iwtr / tau - atm1 - atm2 - wind - refl
    kelvin = b / np.log(r1 / (r2 * (obj + po)) + pf)
    return kelvin - 273.15, seconds + millis / 1000
