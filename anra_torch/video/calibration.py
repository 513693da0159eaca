"""Units and calibration: apparent -> true temperature tables, Celsius/Kelvin, pixel size with uncertainty.

A calibration table (e.g. ``flir_csv/calibration_og.csv``: ``T,IR`` rows, true temperature then the
camera's apparent reading, degC) is measured as true -> apparent; :meth:`CalibrationTable.to_true`
inverts it by piecewise-linear interpolation of the monotone table (linear extrapolation beyond its ends,
counted in :attr:`CalibrationResult.outside`). The diffusivity scales as ``dx^2``, so an uncertain pixel
size becomes an interval on ``a`` (:meth:`PixelSize.diffusivity_interval`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from anra_torch.video.core import Video

__all__ = ["CalibrationTable", "PixelSize", "apply_calibration", "load_calibration", "to_unit"]

_KELVIN = 273.15
UNITS = {"degC": 0.0, "C": 0.0, "K": _KELVIN}


@dataclass(frozen=True)
class CalibrationTable:
    """Measured pairs of true and apparent temperature (same unit), both strictly increasing.

    Attributes:
        true: true temperatures ``(N,)``.
        apparent: the camera's readings at those temperatures ``(N,)``.
        source: where the table came from (for messages).
    """

    true: np.ndarray
    apparent: np.ndarray
    source: str = "<memory>"

    def __post_init__(self) -> None:
        t, a = np.asarray(self.true, np.float64), np.asarray(self.apparent, np.float64)
        if t.ndim != 1 or t.shape != a.shape or t.size < 2:
            raise ValueError(
                f"{self.source}: a calibration table needs >= 2 (true, apparent) pairs, "
                f"got {t.shape} and {a.shape}"
            )
        if not (np.isfinite(t).all() and np.isfinite(a).all()):
            raise ValueError(f"{self.source}: calibration values must be finite")
        if (np.diff(t) <= 0).any() or (np.diff(a) <= 0).any():
            raise ValueError(
                f"{self.source}: calibration must be strictly increasing in both columns to be inverted, "
                f"got true {t.tolist()} apparent {a.tolist()}"
            )

    def to_true(self, apparent: Tensor) -> Tensor:
        """Map apparent readings to true temperatures (piecewise linear, extrapolated linearly).

        Shape:
            any -> same shape, float64.
        """
        xp = torch.as_tensor(np.ascontiguousarray(self.apparent), dtype=torch.float64)
        fp = torch.as_tensor(np.ascontiguousarray(self.true), dtype=torch.float64)
        x = apparent.double()
        k = torch.searchsorted(xp, x.reshape(-1).contiguous()).clamp(1, xp.numel() - 1).reshape(x.shape)
        slope = (fp[k] - fp[k - 1]) / (xp[k] - xp[k - 1])
        return fp[k - 1] + slope * (x - xp[k - 1])

    def outside(self, apparent: Tensor) -> float:
        """Fraction of readings outside the table's apparent range (extrapolated)."""
        lo, hi = float(self.apparent[0]), float(self.apparent[-1])
        return float(((apparent < lo) | (apparent > hi)).double().mean())


def load_calibration(path: str | os.PathLike[str]) -> CalibrationTable:
    """Read a two-column CSV (optional header row): true temperature, apparent reading.

    Raises:
        ValueError: missing file, non-numeric rows, fewer than 2 rows, non-monotone columns.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such calibration file")
    rows = []
    for number, line in enumerate(path.read_text(encoding="utf-8-sig").splitlines(), start=1):
        cells = [c.strip() for c in line.split(",")]
        if not line.strip():
            continue
        try:
            rows.append((float(cells[0]), float(cells[1])))
        except (ValueError, IndexError):
            if rows or number > 1:
                raise ValueError(
                    f"{path}: line {number}: expected 'true,apparent' numbers, got {line!r}"
                ) from None
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 2)
    return CalibrationTable(true=table[:, 0], apparent=table[:, 1], source=str(path))


def apply_calibration(video: Video, table: CalibrationTable) -> Video:
    """The video in true temperatures; ``meta["calibration"]`` records the table and the extrapolated
    fraction.

    Shape:
        ``video.frames`` ``(T, H, W)`` -> same, float64.
    """
    frames = video.frames.double()
    meta = dict(video.meta)
    meta["calibration"] = {"table": table.source, "outside_fraction": table.outside(frames)}
    return video.map_frames(table.to_true, meta=meta)


def to_unit(video: Video, unit: str) -> Video:
    """Convert between Celsius (``"degC"``) and Kelvin (``"K"``); the diffusivity does not change.

    Raises:
        ValueError: unknown target unit, or a video whose unit is not Celsius or Kelvin.
    """
    if unit not in UNITS:
        raise ValueError(f"unit must be one of {', '.join(UNITS)}, got {unit!r}")
    if video.unit not in UNITS:
        raise ValueError(f"{video.name}: cannot convert {video.unit!r} to {unit}; set the video's unit first")
    shift = UNITS[unit] - UNITS[video.unit]
    return video.map_frames(
        lambda frames: frames.double() + shift if shift else frames,
        meta={**video.meta, "unit": "K" if unit == "K" else "degC"},
    )


@dataclass(frozen=True)
class PixelSize:
    """A pixel size in mm known only within ``[low, high]`` mm.

    Attributes:
        value: the nominal size in mm.
        low: the smallest plausible size in mm.
        high: the largest plausible size in mm.
    """

    value: float
    low: float
    high: float

    def __post_init__(self) -> None:
        if not 0 < self.low <= self.value <= self.high:
            raise ValueError(
                f"pixel size needs 0 < low <= value <= high in mm, got {self.low}, {self.value}, {self.high}"
            )

    def diffusivity_interval(self, a: float) -> tuple[float, float]:
        """The interval of a diffusivity ``a`` (mm^2/s, estimated at :attr:`value`) over ``[low, high]``.

        ``a`` scales as ``dx^2`` (the Laplacian divides by ``dx^2``, time does not change).

        Example:
            >>> PixelSize(0.55, 0.5, 0.6).diffusivity_interval(0.121)
            (0.1, 0.144)
        """
        lo, hi = a * (self.low / self.value) ** 2, a * (self.high / self.value) ** 2
        return (round(min(lo, hi), 12), round(max(lo, hi), 12))
