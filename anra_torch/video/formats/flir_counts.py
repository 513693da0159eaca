"""The raw counts of a FLIR frame: its image decoded (``uint16`` in the record's byte order, PNG or JPEG-LS)
and the byte order judged from the counts themselves. FLIR's PNGs hold their counts byte-swapped
(ExifTool's note; flyr and Thermimage swap them)."""

from __future__ import annotations

from typing import Any

import numpy as np

from anra_torch.checks import one_line
from anra_torch.video.formats.flir_fff import RawImage, TruncatedFrame

__all__ = ["decode_counts", "swapped_rougher"]


def _imagecodecs() -> Any:
    try:
        import imagecodecs
    except ImportError as err:
        raise ImportError(
            "decoding FLIR PNG or JPEG-LS counts needs imagecodecs: pip install anra_torch[formats]"
        ) from err
    return imagecodecs


def decode_counts(raw: RawImage, data: bytes, *, where: str = "FFF") -> np.ndarray:
    """The raw counts of one frame from its image ``data`` (``raw.length`` bytes at ``raw.offset``).

    ``uint16`` counts are read in the record's byte order; PNG and JPEG-LS images are decoded by
    ``imagecodecs`` (its CharLS JPEG-LS decoder), PNG counts then byte-swapped as FLIR stores them.

    Shape:
        ``(raw.height, raw.width)``, ``uint16``.

    Raises:
        ValueError: the data do not decode to ``raw.height x raw.width`` counts.
        ImportError: a PNG or JPEG-LS image without imagecodecs (the ``formats`` extra).
    """
    if raw.encoding == "uint16":
        count = raw.width * raw.height
        if len(data) < 2 * count:
            raise TruncatedFrame(f"{where}: truncated: the raw counts at byte {raw.offset} are cut off")
        counts = np.frombuffer(data, dtype=raw.order + "u2", count=count).reshape(raw.height, raw.width)
    else:
        codecs = _imagecodecs()
        decoder = codecs.png_decode if raw.encoding == "png" else codecs.jpegls_decode
        try:
            counts = np.asarray(decoder(data))
        except Exception as err:  # the codecs raise their own error types on damaged data
            raise ValueError(
                f"{where}: cannot decode the {raw.encoding} counts at byte {raw.offset} "
                f"({one_line(err, kind=True)}); the file may be corrupt"
            ) from err
        if counts.shape != (raw.height, raw.width) or counts.dtype.kind not in "ui":
            raise ValueError(
                f"{where}: the {raw.encoding} image at byte {raw.offset} is {counts.shape} {counts.dtype}, "
                f"not the {raw.height} x {raw.width} counts its RawData record gives"
            )
    counts = counts.astype(np.uint16, copy=False)
    return counts.byteswap() if raw.swapped else counts.astype("=u2", copy=False)


def swapped_rougher(counts: np.ndarray) -> bool:
    """Whether ``counts`` read byte-swapped would be far smoother than as given (stored in the other byte
    order than documented: a scene varies by a few counts between neighbours, swapped its noisy low byte
    steps by hundreds). Only on overwhelming evidence (a mean step along rows 16x smaller swapped, and of
    at least one count); a flat frame keeps the documented order.

    Shape:
        ``(..., H, W)`` ``uint16``.
    """
    if counts.shape[-1] < 2:  # one column: no step to judge by
        return False
    given = np.abs(np.diff(counts.astype(np.int32), axis=-1)).mean()
    other = np.abs(np.diff(counts.byteswap().astype(np.int32), axis=-1)).mean()
    return bool(given >= 16 * max(other, 1.0))
