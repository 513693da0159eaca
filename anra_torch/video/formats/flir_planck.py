"""FLIR counts to temperatures: the Planck formula with the atmosphere's and the IR window's transmission,
as Thermimage's ``raw2temp``, flirpy and flyr compute it (:func:`celsius`).

Emissivity, reflected apparent temperature, object distance, atmospheric temperature and relative humidity
can be replaced after capture (:mod:`~anra_torch.video.formats.flir_objects`, which also states the values
used and where each came from).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from anra_torch.video.formats.flir_fff import PLANCK_KEYS

__all__ = ["celsius"]

_KELVIN = 273.15


def celsius(counts: np.ndarray, planck: Mapping[str, Any]) -> np.ndarray:
    """Object temperatures in degC from raw counts by the Planck formula with the atmosphere's and the IR
    window's transmission (Thermimage ``raw2temp``; flyr): the counts are corrected for the radiance the
    object reflects (at the reflected temperature, weight ``1 - E``), the atmosphere's emission on either
    side of the window (transmission ``tau`` each, over half the object distance) and the window's
    emission, then inverted through ``T = B / ln(R1 / (R2 (S + O)) + F)``.

    Args:
        counts: raw counts, any integer or float dtype.
        planck: the :data:`PLANCK_KEYS` values (temperatures degC, distance m, humidity a fraction), each a
            scalar or, for ``(T, H, W)`` counts, a ``(T,)`` vector of per-frame values.

    Returns:
        float64 temperatures; NaN where the counts lie outside the formula's range (no object radiance).

    Shape:
        ``(H, W)`` or ``(T, H, W)`` -> the same.

    Example:
        >>> values = [1, 0, 20, 20, 20, 1, 0.5, 21106.77, 1501, 1, -7340, 0.012545258, 0.006569, 0.01262]
        >>> p = dict(zip(PLANCK_KEYS, values + [-0.002276, -0.00667, 1.9]))  # Thermimage's defaults
        >>> round(float(celsius(np.array([[18109]]), p)[0, 0]), 2)
        23.62
    """
    with np.errstate(all="ignore"):  # damaged constants (an emissivity of 0, ...): NaN, masked below
        return _celsius(counts, planck)


def _celsius(counts: np.ndarray, planck: Mapping[str, Any]) -> np.ndarray:
    ndim = np.ndim(counts)

    def value(key: str) -> Any:
        v = np.asarray(planck[key], dtype=np.float64)
        return v.reshape(v.shape + (1,) * (ndim - v.ndim)) if v.ndim else np.float64(v)  # numpy: errstate

    e, od, rt, at, wt, wtr, rh = (value(k) for k in PLANCK_KEYS[:7])
    r1, b, f, o, r2, a1, a2, b1, b2, x = (value(k) for k in PLANCK_KEYS[7:])
    h2o = rh * np.exp(1.5587 + 0.06939 * at - 0.00027816 * at**2 + 0.00000068455 * at**3)
    half = np.sqrt(od / 2)
    tau = x * np.exp(-half * (a1 + b1 * np.sqrt(h2o))) + (1 - x) * np.exp(-half * (a2 + b2 * np.sqrt(h2o)))

    def radiance(temp_c: Any) -> Any:
        return r1 / (r2 * (np.exp(b / (temp_c + _KELVIN)) - f)) - o

    atmosphere = radiance(at)
    stray = (
        (1 - e) / e * radiance(rt)  # reflected by the object
        + (1 - tau) / e / tau * atmosphere  # the atmosphere between object and window
        + (1 - wtr) / e / tau / wtr * radiance(wt)  # the window's own emission
        + (1 - tau) / e / tau / wtr / tau * atmosphere  # the atmosphere between window and camera
    )
    # r2 (S + O) with S = counts / (e tau wtr tau) - stray, in one multiply and one subtraction
    signal = np.multiply(counts, r2 / (e * tau * wtr * tau), dtype=np.float64)
    signal -= (stray - o) * r2
    np.divide(r1, signal, out=signal)
    signal += f
    np.log(signal, out=signal)
    np.divide(b, signal, out=signal)
    signal -= _KELVIN
    signal[~((signal >= -_KELVIN) & (signal < np.inf))] = np.nan  # NaN, infinities, below 0 K
    return signal
