"""Thermal dose of a temperature history: CEM43, the Arrhenius damage integral, time above a threshold.

* CEM43 of Sapareto and Dewey, cumulative equivalent minutes at 43 C::

      CEM43 = integral R^(43 - T(t)) dt / 60,   R = 0.5 for T >= 43 C, 0.25 below   (minutes)

* The Arrhenius damage integral of Henriques and Moritz::

      Omega = integral A exp(-Ea / (R_gas T_K(t))) dt

  with the skin constants :data:`SKIN` by default; ``Omega >= 1`` marks irreversible damage, 63 % of
  the cells.

The frames ``T_0 .. T_{N-1}``, period ``dt``, become a history ``T(t)`` by ``rule``, one of :data:`RULES`:

* ``"hold"``, the default and the Sapareto-Dewey sum: frame ``k`` holds for ``[k dt, (k + 1) dt)``, so
  the history lasts ``N dt`` and every integral is the sum ``sum_k f(T_k) dt``.
* ``"linear"``: the piecewise-linear interpolant of the frames, lasting ``(N - 1) dt``, integrated
  exactly on each segment.

Non-finite samples contribute nothing: with ``"hold"`` their frame, with ``"linear"`` the segments they
end; :func:`count_masked` counts them. Computation is in float64 whatever the input dtype; gradients flow
to the temperatures. How each rule integrates and how exactly: ``docs/guides/tissue-damage.md``, section
"How the doses are integrated".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from anra_torch.tissue.histories import (
    KELVIN_AT_ZERO_CELSIUS,
    RULES,
    UNITS,
    Step,
    count_masked,
    counted,
    divided,
    masked,
    prepare,
    stepper,
    to_celsius,
)

__all__ = [
    "CEM43_R",
    "GAS_CONSTANT",
    "RULES",
    "SKIN",
    "UNITS",
    "ArrheniusConstants",
    "arrhenius_omega",
    "cem43",
    "count_masked",
    "time_above",
    "to_celsius",
]

GAS_CONSTANT = 8.314462618
"""Molar gas constant in J/(mol K)."""

_F64 = torch.float64
_GL = tuple(v.tolist() for v in np.polynomial.legendre.leggauss(8))  # nodes, weights on [-1, 1]
_MAX_EXPONENT_STEP = 1.0  # largest change of Ea / (R T) over one Gauss-Legendre piece
_SERIES_TERMS = 10  # terms of the Arrhenius antiderivative's series: relative error 11! y^10
_BLOCK_VALUES = 1 << 18  # samples per block of dose_maps (2 MiB of float64)
_SERIES_REACH = 0.02  # ... used up to T_K = 0.02 Ea / R_gas (4e-10; 1237 C with the skin constants)


@dataclass(frozen=True)
class ArrheniusConstants:
    """Constants of the Arrhenius damage integral.

    Attributes:
        frequency: frequency factor ``A`` in 1/s.
        activation_energy: ``Ea`` in J/mol.
    """

    frequency: float
    activation_energy: float

    def __post_init__(self) -> None:
        for name in ("frequency", "activation_energy"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                unit = "1/s" if name == "frequency" else "J/mol"
                raise ValueError(f"{name} must be a positive finite number in {unit}, got {value!r}")


SKIN = ArrheniusConstants(frequency=3.1e98, activation_energy=6.28e5)
"""Henriques & Moritz skin constants (``A = 3.1e98 1/s``, ``Ea = 6.28e5 J/mol``)."""


# ------------------------------------------------------------------------------------------ CEM43
CEM43_R: tuple[float, float] = (0.5, 0.25)
"""Sapareto-Dewey ``R`` at or above 43 C and below it."""
_LOG_R_HIGH, _LOG_R_LOW = -math.log(CEM43_R[0]), -math.log(CEM43_R[1])  # R^(43 - T) = exp(c (T - 43))
_CEM_STEP = 1e-5  # K: segments flatter than this take the mean of their end rates (error below 1e-10)


def _log_r(x: Tensor) -> Tensor:
    """``-ln R``: ln 2 at or above 43 C, ln 4 below (float64)."""
    return _LOG_R_LOW + (_LOG_R_HIGH - _LOG_R_LOW) * (x >= 43.0).to(_F64)


def cem43(temperatures: Tensor, dt: float | Tensor, *, units: str = "C", rule: str = "hold") -> Tensor:
    """Cumulative equivalent minutes at 43 C of each pixel's history, by Sapareto and Dewey.

    Args:
        temperatures: history or video in ``units``.
        dt: frame period in s, a number or ``(B,)``.
        units: ``"C"`` or ``"K"``.
        rule: ``"hold"``, the Sapareto-Dewey sum, or ``"linear"``, exact for the piecewise-linear
            interpolant; see :data:`RULES`.

    Returns:
        CEM43 in minutes, float64.

    Raises:
        ValueError: bad shape, ``dt``, ``rule`` or ``units``, as :func:`to_celsius` checks them.

    Shape:
        ``(T,)`` -> ``()``; ``(T, H, W)`` -> ``(H, W)``; ``(B, T, H, W)`` -> ``(B, H, W)``.

    Example:
        >>> float(cem43(torch.full((300,), 44.0), 1.0))  # 5 min at 44 C
        10.0
    """
    x, period, shape = prepare(temperatures, dt, units, rule)
    return (_cem43(*masked(x, rule), rule) * period[:, 0] / 60.0).reshape(shape)


def _cem43(x: Tensor, weights: Tensor | None, rule: str, rise: Tensor | None = None) -> Tensor:
    """CEM43 seconds per unit ``dt`` of Celsius histories ``(B, T, P)`` (see :func:`masked`; ``rise`` the
    segments' ``x[:, 1:] - x[:, :-1]`` when known)."""
    step = stepper(x)
    c = step(step((x >= 43.0).to(_F64), "mul", _LOG_R_HIGH - _LOG_R_LOW), "add", _LOG_R_LOW)  # -ln R
    rate = step(step(x - 43.0, "mul", c), "exp")  # R^(43 - T)
    if rule == "hold":
        return counted(rate, weights, step)
    # The antiderivative (rate - 1) / c is continuous (0 at 43 C): each segment's mean rate is its change
    # over the segment's rise, the constant part (1 / c) changing only on segments that cross 43 C.
    inverse = c.reciprocal()
    scaled = rate * inverse
    change = step(step(scaled[:, 1:] - scaled[:, :-1], "sub", inverse[:, 1:]), "add", inverse[:, :-1])
    rise = x[:, 1:] - x[:, :-1] if rise is None else rise
    middle = step(rate[:, 1:] + rate[:, :-1], "mul", 0.5)
    mean = divided(change, rise, middle, _CEM_STEP, step)
    return counted(mean, weights, step)


# --------------------------------------------------------------------------------------- Arrhenius
_OMEGA_STEP = 1e-5  # K: segments flatter than this take the slope of P at their start (error 1e-10)


def _check_constants(constants: ArrheniusConstants) -> None:
    if not isinstance(constants, ArrheniusConstants):
        raise TypeError(f"constants must be ArrheniusConstants, got {type(constants).__name__}")


def _omega_series(kelvin: Tensor, theta: float, terms: int, step: Step) -> Tensor:
    """``S(y) = sum_n (n + 1)! (-y)^n`` at ``y = T_K / theta`` (Horner), ``terms`` terms."""
    minus_y = kelvin / -theta
    total = step(minus_y * float(math.factorial(terms)), "add", float(math.factorial(terms - 1)))
    for n in range(terms - 2, 0, -1):
        total = step(step(total, "mul", minus_y), "add", float(math.factorial(n)))
    return total


def _series_terms(hottest: float, theta: float) -> int:
    """Fewest terms of :func:`_omega_series` whose error ``(N + 1)! y^N`` is below 1e-12 up to ``hottest`` K
    (8 for the skin constants up to 100 C), at most :data:`_SERIES_TERMS`."""
    y = hottest / theta
    for terms in range(2, _SERIES_TERMS):
        if math.factorial(terms + 1) * y**terms < 1e-12:
            return terms
    return _SERIES_TERMS


def _omega_segments(x: Tensor, constants: ArrheniusConstants, terms: int, rise: Tensor | None) -> Tensor:
    """Mean Arrhenius rate in 1/s over the linear segments of Celsius histories ``(B, T, P)``,
    ``(B, T - 1, P)``, exact to rounding (``rise`` the segments' ``x[:, 1:] - x[:, :-1]`` when known).

    With ``K`` the kelvin temperature and ``theta = Ea / R_gas``, ``integral exp(-theta / K) dK =
    exp(-theta / K) P(K)``, ``P(K) = K^2 / theta S(K / theta)`` (asymptotic series, relative error
    ``(N + 1)! y^N`` with ``N`` terms). The mean over a segment from ``K0`` to ``K1 = K0 + d`` is
    ``(F(K1) - F(K0)) / d``, written without cancellation as ``r0 ((K1 / K0) S(y1) phi(lam) + (P1 - P0) / d)``
    with ``r0`` the rate at ``K0``, ``lam = theta / K0 - theta / K1`` the change of the exponent,
    ``phi(z) = expm1(z) / z``, and ``(P1 - P0) / d -> P'(K) = 1 - S(y)`` as ``d -> 0``.
    """
    step = stepper(x)
    log_a = math.log(constants.frequency)
    theta = constants.activation_energy / GAS_CONSTANT  # K
    kelvin = x + KELVIN_AT_ZERO_CELSIUS  # per frame: shared by the segments either side
    exponent = step(kelvin.reciprocal(), "mul", theta)
    rate = step(log_a - exponent, "exp")
    series = _omega_series(kelvin, theta, terms, step)
    antiderivative = step(step(kelvin * kelvin, "mul", series), "div", theta)  # P(K)
    lam = exponent[:, :-1] - exponent[:, 1:]
    # phi(lam) = expm1(lam) / lam, blended into 1 + lam / 2 below |lam| ~ 1e-50 (flat segments: lam = 0).
    phi = divided(torch.expm1(lam), lam, step(lam * 0.5, "add", 1.0), 1e-50, step)
    growth = step(step(kelvin[:, 1:] / kelvin[:, :-1], "mul", series[:, 1:]), "mul", phi)
    change = antiderivative[:, 1:] - antiderivative[:, :-1]
    rise = x[:, 1:] - x[:, :-1] if rise is None else rise
    slope = divided(change, rise, 1.0 - series[:, :-1], _OMEGA_STEP, step)
    return step(step(growth, "add", slope), "mul", rate[:, :-1])


def _omega_quadrature(t0: Tensor, t1: Tensor, constants: ArrheniusConstants) -> Tensor:
    """Mean Arrhenius rate over linear segments by composite 8-node Gauss-Legendre, each segment cut into
    pieces over which ``Ea / (R_gas T_K)`` changes by at most 1: for temperatures beyond the series'
    reach (:func:`_omega_segments`)."""
    log_a = math.log(constants.frequency)
    theta = constants.activation_energy / GAS_CONSTANT  # K
    k0, k1 = t0 + KELVIN_AT_ZERO_CELSIUS, t1 + KELVIN_AT_ZERO_CELSIUS
    pieces = torch.ceil(theta * (1.0 / k0 - 1.0 / k1).abs() / _MAX_EXPONENT_STEP).clamp_min(1).flatten()
    start, delta = t0.flatten(), (t1 - t0).flatten()
    total = torch.zeros_like(start)
    gl_nodes, gl_weights = (torch.tensor(v, dtype=_F64, device=t0.device) for v in _GL)
    nodes, weights = 0.5 * (gl_nodes + 1.0), 0.5 * gl_weights  # on [0, 1]
    # Piece j of every segment that has more than j pieces; the active set shrinks quickly.
    active = torch.arange(start.numel(), device=start.device)
    j = 0
    while active.numel():
        n = pieces[active]
        left = (j + nodes[:, None]) / n  # (8, A) fractions of the segment
        celsius = start[active] + delta[active] * left
        rate = torch.exp(log_a - theta / (celsius + KELVIN_AT_ZERO_CELSIUS))
        total[active] += (weights[:, None] * rate).sum(0) / n
        j += 1
        active = active[pieces[active] > j]
    return total.reshape(t0.shape)


def _omega_linear(x: Tensor, constants: ArrheniusConstants, rise: Tensor | None = None) -> Tensor:
    """Mean Arrhenius rate over the linear segments of Celsius histories ``(B, T, P)``: the closed form
    where its series is exact, else quadrature (above :data:`_SERIES_REACH` of ``Ea / R_gas`` in kelvin: no
    tissue with published constants)."""
    theta = constants.activation_energy / GAS_CONSTANT
    hottest = float(x.detach().amax()) + KELVIN_AT_ZERO_CELSIUS if x.numel() else theta * _SERIES_REACH
    if hottest > _SERIES_REACH * theta:
        return _omega_quadrature(x[:, :-1], x[:, 1:], constants)
    return _omega_segments(x, constants, _series_terms(hottest, theta), rise)


def arrhenius_omega(
    temperatures: Tensor,
    dt: float | Tensor,
    *,
    units: str = "C",
    constants: ArrheniusConstants = SKIN,
    rule: str = "hold",
) -> Tensor:
    """Arrhenius damage integral ``Omega = integral A exp(-Ea / (R_gas T_K)) dt`` of each pixel.

    Args:
        temperatures: history or video in ``units``.
        dt: frame period in s, a number or ``(B,)``.
        units: ``"C"`` or ``"K"``.
        constants: ``A`` and ``Ea``, :data:`SKIN` by default.
        rule: ``"hold"`` or ``"linear"``, see :data:`RULES`.

    Returns:
        Omega, dimensionless, float64; ``>= 1`` is irreversible damage.

    Raises:
        ValueError: bad shape, ``dt``, ``rule`` or ``units``.
        TypeError: ``constants`` not :class:`ArrheniusConstants`.

    Shape:
        ``(T,)`` -> ``()``; ``(T, H, W)`` -> ``(H, W)``; ``(B, T, H, W)`` -> ``(B, H, W)``.

    Example:
        >>> omega = arrhenius_omega(torch.full((60,), 60.0), 1.0)  # one minute at 60 C
        >>> round(float(omega), 2)
        64.15
    """
    _check_constants(constants)
    x, period, shape = prepare(temperatures, dt, units, rule)
    return (_omega(*masked(x, rule), constants, rule) * period[:, 0]).reshape(shape)


def _omega(
    x: Tensor, weights: Tensor | None, constants: ArrheniusConstants, rule: str, rise: Tensor | None = None
) -> Tensor:
    """Omega per unit ``dt`` of Celsius histories ``(B, T, P)`` (see :func:`masked`)."""
    step = stepper(x)
    if rule == "hold":
        log_a = math.log(constants.frequency)
        theta = constants.activation_energy / GAS_CONSTANT
        exponent = step(step((x + KELVIN_AT_ZERO_CELSIUS).reciprocal(), "mul", -theta), "add", log_a)
        return counted(step(exponent, "exp"), weights, step)
    return counted(_omega_linear(x, constants, rise), weights, step)


# -------------------------------------------------------------------------------- time above
def time_above(
    temperatures: Tensor, dt: float | Tensor, threshold: float, *, units: str = "C", rule: str = "hold"
) -> Tensor:
    """Time in s each pixel spends at or above ``threshold`` in Celsius.

    Args:
        temperatures: history or video in ``units``.
        dt: frame period in s, a number or ``(B,)``.
        threshold: temperature in Celsius, whatever ``units`` is.
        units: ``"C"`` or ``"K"``.
        rule: ``"hold"``, the frames at or above times ``dt``, or ``"linear"``, exact for the
            interpolant; see :data:`RULES`.

    Returns:
        Seconds, float64.

    Raises:
        ValueError: bad shape, ``dt``, ``rule``, ``units`` or a non-finite ``threshold``.

    Shape:
        ``(T,)`` -> ``()``; ``(T, H, W)`` -> ``(H, W)``; ``(B, T, H, W)`` -> ``(B, H, W)``.
    """
    if not (isinstance(threshold, int | float) and math.isfinite(threshold)):
        raise ValueError(f"threshold must be a finite temperature in Celsius, got {threshold!r}")
    x, period, shape = prepare(temperatures, dt, units, rule)
    return (_above(*masked(x, rule), (float(threshold),), rule)[0] * period[:, 0]).reshape(shape)


def _above(
    x: Tensor, weights: Tensor | None, thresholds: tuple[float, ...], rule: str, rise: Tensor | None = None
) -> list[Tensor]:
    """Time above each threshold per unit ``dt`` of Celsius histories ``(B, T, P)`` (see :func:`masked`)."""
    step = stepper(x)
    if rule == "hold":
        return [counted((x >= t).to(_F64), weights, step) for t in thresholds]
    rise = x[:, 1:] - x[:, :-1] if rise is None else rise
    high = torch.maximum(x[:, :-1], x[:, 1:])
    # The fraction of a segment above t, (high - t) / |rise| clipped to [0, 1]; a flat one is wholly above or
    # below (1e-30 K, far below a float64 temperature's resolution, settles t itself: above).
    scale = step(step(rise.abs(), "clamp_min", 1e-30), "reciprocal")
    scale = scale if weights is None else step(scale, "mul", weights)
    return [
        step(step(step(high - t, "add", 1e-30), "mul", scale), "clamp", 0.0, 1.0).sum(1) for t in thresholds
    ]


# ------------------------------------------------------------------------------------ all doses
def dose_maps(
    celsius: Tensor,
    dt: Tensor,
    *,
    thresholds: tuple[float, ...],
    constants: ArrheniusConstants = SKIN,
    rule: str = "hold",
    finite: Tensor | None = None,
) -> dict[str, Tensor]:
    """Every dose of checked Celsius histories at once: what :func:`time_above`, :func:`cem43` and
    :func:`arrhenius_omega` give, sharing one pass over the frames.

    Args:
        celsius: float64 temperatures in Celsius, non-finite where masked, ``(B, T, H, W)``.
        finite: the samples that count, ``(B, T, H, W)`` bool (default: the finite ones).
        dt: frame periods in s, ``(B,)``.
        thresholds: Celsius thresholds of the times above.
        constants: Arrhenius constants.
        rule: ``"hold"`` or ``"linear"``.

    Returns:
        ``time_above_<t>`` (s, one per threshold, named with ``{t:g}``), ``cem43_minutes`` and ``omega``,
        each ``(B, H, W)`` float64.

    Shape:
        ``celsius`` ``(B, T, H, W)``; maps ``(B, H, W)``.
    """
    b, t, h, w = celsius.shape
    x, mask = celsius.reshape(b, t, h * w), None if finite is None else finite.reshape(b, t, h * w)
    # Pixel by pixel, in blocks whose temporaries (a few dozen) stay in the cache: ~25 % faster than the
    # whole video at once on a CPU (video-sized float64 temporaries go to memory at every pass).
    block = max(1, _BLOCK_VALUES // max(b * t, 1))
    parts = [
        _doses(
            x[..., i : i + block],
            None if mask is None else mask[..., i : i + block],
            thresholds,
            constants,
            rule,
        )
        for i in range(0, h * w, block)
    ]
    period = dt.to(_F64).reshape(b, 1)
    names = [f"time_above_{t:g}" for t in thresholds] + ["cem43_minutes", "omega"]
    scale = [1.0] * len(thresholds) + [1.0 / 60.0, 1.0]
    return {
        name: (torch.cat([part[n] for part in parts], -1) * period * k).reshape(b, h, w)
        for n, (name, k) in enumerate(zip(names, scale, strict=True))
    }


def _doses(
    x: Tensor, finite: Tensor | None, thresholds: tuple[float, ...], constants: ArrheniusConstants, rule: str
) -> list[Tensor]:
    """The times above, CEM43 in s and Omega per unit ``dt`` of histories ``(B, T, P)``, each ``(B, P)``."""
    x, weights = masked(x, rule, finite)
    rise = x[:, 1:] - x[:, :-1] if rule == "linear" else None  # shared by every dose
    return [
        *_above(x, weights, thresholds, rule, rise),
        _cem43(x, weights, rule, rise),
        _omega(x, weights, constants, rule, rise),
    ]
