"""Slow, obvious NumPy/SciPy oracles, written from REFERENCE.md and the paper without using anra_torch.

Tables are typed in as exact rationals (so a wrong transcription in the package cannot hide behind
rounding); filters are explicit loops, ``np.correlate``, ``scipy.signal.correlate2d`` or
``scipy.ndimage.correlate1d``; RTC attention follows the paper's three lines in float64.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
from scipy import ndimage, signal


def _taps(numerators: tuple[int, ...], denominator: int) -> tuple[Fraction, ...]:
    return tuple(Fraction(n, denominator) for n in numerators)


def _outer(column: tuple[Fraction, ...], row: tuple[Fraction, ...]) -> list[list[Fraction]]:
    """``column (x) row``: entry ``[i][j] = column[i] * row[j]`` (column along y/H, row along x/W)."""
    return [[c * r for r in row] for c in column]


def _embed(kernel: list[list[Fraction]], size: int) -> list[list[Fraction]]:
    """Zero-pad a small rational kernel to ``size x size``, centred."""
    h, w = len(kernel), len(kernel[0])
    top, left = (size - h) // 2, (size - w) // 2
    out = [[Fraction(0)] * size for _ in range(size)]
    for i in range(h):
        for j in range(w):
            out[top + i][left + j] = kernel[i][j]
    return out


def _plus_transpose(kernel: list[list[Fraction]]) -> list[list[Fraction]]:
    n = len(kernel)
    return [[kernel[i][j] + kernel[j][i] for j in range(n)] for i in range(n)]


def as_array(table: tuple[Fraction, ...] | list[list[Fraction]]) -> np.ndarray:
    """A rational table as a float64 array."""
    return np.array(table, dtype=object).astype(np.float64)


# ------------------------------------------------------------------------------ tables (REFERENCE.md)
BINOMIAL = {2: _taps((1, 2, 1), 4), 4: _taps((1, 4, 6, 4, 1), 16)}
"""``B_n = binomial(n) / 2**n``."""

FIRST_DERIVATIVE = {
    5: _taps((-1, -2, 0, 2, 1), 8),
    7: _taps((-1, -4, -5, 0, 5, 4, 1), 32),
    9: _taps((-1, -6, -14, -14, 0, 14, 14, 6, 1), 128),
    11: _taps((-1, -8, -27, -48, -42, 0, 42, 48, 27, 8, 1), 512),
}
"""Centred smooth first derivative, correlation order, unit spacing."""

FIRST_DERIVATIVE_GAIN = {3: 0.71, 5: 0.40, 7: 0.29, 9: 0.23, 11: 0.19}
"""White-noise gains (3 is the plain central difference)."""

SMOOTH_ONE_SIDED = {
    4: _taps((-1, -1, 1, 1), 4),
    5: _taps((-1, -2, 0, 2, 1), 8),
    6: _taps((-1, -3, -2, 2, 3, 1), 16),
}
"""One-sided smooth family, oldest frame first; estimates the derivative at the window centre."""

HYBRID_NEWEST_FIRST = {
    4: _taps((2, -1, -2, 1), 2),
    5: _taps((7, 1, -10, -1, 3), 10),
    6: _taps((16, 1, -10, -10, -6, 9), 28),
    7: _taps((12, 5, -8, -6, -10, 1, 6), 28),
    8: _taps((22, 7, -6, -11, -14, -9, -2, 13), 60),
}
"""One-sided hybrid family, NEWEST frame first as published; derivative at the newest frame."""

HYBRID_8_GAIN = {0.1: 1.04, 0.2: 1.16}
"""Amplitude response / ideal of the L=8 hybrid differentiator (overshoot +4 % and +16 %)."""

SECOND_DERIVATIVE = {
    5: _taps((1, 0, -2, 0, 1), 4),
    7: _taps((1, 2, -1, -4, -1, 2, 1), 16),
    9: _taps((1, 4, 4, -4, -10, -4, 4, 4, 1), 64),
}
"""Centred smooth second derivative, unit spacing."""

SECOND_DERIVATIVE_GAIN = {3: 2.45, 5: 0.61, 7: 0.33, 9: 0.22}
"""White-noise gains (3 is the plain ``[1, -2, 1]``)."""

CENTRAL_SECOND_5 = _taps((-1, 16, -30, 16, -1), 12)
"""Fourth-order central second difference."""

GRADIENT_X = {
    5: _embed(_outer(BINOMIAL[2], FIRST_DERIVATIVE[5]), 5),
    7: _embed(_outer(BINOMIAL[4], FIRST_DERIVATIVE[7]), 7),
}
"""Holoborodko d/dx masks (3x5 and 5x7, embedded square); rows are y, columns x."""

LAPLACIAN = {
    5: _plus_transpose(_embed(_outer(BINOMIAL[2], SECOND_DERIVATIVE[5]), 5)),
    7: _plus_transpose(_embed(_outer(BINOMIAL[4], SECOND_DERIVATIVE[7]), 7)),
}
"""``L_N = D2_N (x) B along the other axis + transpose``."""

FIVE_POINT = [[Fraction(v) for v in row] for row in ((0, 1, 0), (1, -4, 1), (0, 1, 0))]

LAPLACIAN_GAIN = {3: 4.47, 5: 0.64, 7: 0.29}
"""White-noise gains of L5, L7 and the 5-point stencil."""


# ------------------------------------------------------------------------------------------ filters
def correlate1d_loops(x: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Valid correlation ``out[k] = sum_i taps[i] x[k + i]`` of a 1D array, by explicit loops."""
    n = len(x) - len(taps) + 1
    out = np.zeros(n)
    for k in range(n):
        for i, tap in enumerate(taps):
            out[k] += tap * x[k + i]
    return out


def time_filter(video: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Valid correlation of ``(B, T, H, W)`` with ``taps`` along T (oldest frame first)."""
    return np.apply_along_axis(lambda s: np.correlate(s, taps, mode="valid"), 1, video)


NUMPY_PAD = {"reflect": "reflect", "replicate": "edge", "circular": "wrap", "zeros": "constant"}
"""The package's border names as ``np.pad`` modes (``"crop"`` pads nothing)."""

NDIMAGE_MODE = {"reflect": "mirror", "replicate": "nearest", "circular": "wrap", "zeros": "constant"}
"""The package's border names as ``scipy.ndimage`` modes."""


def filter2d(image: np.ndarray, kernel: np.ndarray, border: str) -> np.ndarray:
    """Correlate each ``(H, W)`` image of ``(..., H, W)`` with ``kernel`` by ``scipy.signal.correlate2d``."""
    kh, kw = kernel.shape
    flat = image.reshape(-1, *image.shape[-2:])
    results = []
    for img in flat:
        if border != "crop":
            img = np.pad(img, ((kh // 2, kh // 2), (kw // 2, kw // 2)), mode=NUMPY_PAD[border])
        results.append(signal.correlate2d(img, kernel, mode="valid"))
    out = np.stack(results)
    return out.reshape(*image.shape[:-2], *out.shape[-2:])


def gaussian_smooth(image: np.ndarray, taps: np.ndarray, border: str) -> np.ndarray:
    """Separable smoothing of ``(..., H, W)`` with ``taps`` along W and H by ``scipy.ndimage.correlate1d``.

    ``"crop"`` keeps only the pixels whose whole window lies inside the image.
    """
    r = len(taps) // 2
    mode = NDIMAGE_MODE.get(border, "constant")
    out = ndimage.correlate1d(image, taps, axis=-1, mode=mode)
    out = ndimage.correlate1d(out, taps, axis=-2, mode=mode)
    if border == "crop":
        out = out[..., r : out.shape[-2] - r, r : out.shape[-1] - r]
    return out


def response(taps: np.ndarray, omega: float, centre: float) -> complex:
    """Frequency response ``sum_k taps[k] exp(i omega (k - centre))`` of correlation taps about ``centre``.

    For a differentiator, ``response / (i omega)`` is 1 where it is ideal.
    """
    k = np.arange(len(taps), dtype=np.float64)
    return complex(np.sum(np.asarray(taps) * np.exp(1j * omega * (k - centre))))


def response2d(kernel: np.ndarray, omega_x: float, omega_y: float) -> complex:
    """Frequency response of a centred 2D correlation kernel (rows y, columns x)."""
    r_y, r_x = kernel.shape[0] // 2, kernel.shape[1] // 2
    y = np.arange(kernel.shape[0])[:, None] - r_y
    x = np.arange(kernel.shape[1])[None, :] - r_x
    return complex(np.sum(kernel * np.exp(1j * (omega_x * x + omega_y * y))))


# ---------------------------------------------------------------------------------------- attention
def rtc(rate: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """The paper's RTC per frame over the last two axes, in float64, over the pixels where ``mask`` is True.

    ``RTC = exp(|dT/dt|); RTC -= min RTC; RTC /= sum RTC``; pixels outside the mask get 0.
    """
    rate = np.asarray(rate, dtype=np.float64)
    valid = np.ones(rate.shape, dtype=bool) if mask is None else np.broadcast_to(mask, rate.shape)
    out = np.zeros_like(rate)
    frames = rate.reshape(-1, *rate.shape[-2:])
    masks = valid.reshape(-1, *rate.shape[-2:])
    result = out.reshape(-1, *rate.shape[-2:])
    for k, (frame, ok) in enumerate(zip(frames, masks, strict=True)):
        values = np.exp(np.abs(frame[ok]))
        values = values - values.min()
        values = values / values.sum()
        result[k][ok] = values
    return out


# ---------------------------------------------------------------------------------------- thermal dose
A_SKIN, EA_SKIN = 3.1e98, 6.28e5
"""Arrhenius constants of skin, 1/s and J/mol (Henriques & Moritz)."""

R_GAS = 8.314462618
"""The gas constant in J/(mol K), the SI value."""


def cem43_constant(celsius: float, seconds: float) -> float:
    """CEM43 (min) of ``seconds`` at a constant ``celsius``: ``R^(43 - T) t / 60``, R = 0.5 at or above
    43 C, 0.25 below."""
    return (0.5 if celsius >= 43.0 else 0.25) ** (43.0 - celsius) * seconds / 60.0


def omega_constant(celsius: float, seconds: float) -> float:
    """Arrhenius Omega (skin constants) of ``seconds`` at a constant ``celsius``: ``A exp(-Ea / R T_K) t``."""
    return A_SKIN * math.exp(-EA_SKIN / (R_GAS * (celsius + 273.15))) * seconds
