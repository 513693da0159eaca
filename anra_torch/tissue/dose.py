"""Thermal dose of a temperature history: CEM43, the Arrhenius damage integral, time above a threshold.

* CEM43 (Sapareto & Dewey 1984), cumulative equivalent minutes at 43 C::

      CEM43 = integral R^(43 - T(t)) dt / 60,   R = 0.5 for T >= 43 C, 0.25 below   (minutes)

* Arrhenius damage integral (Henriques & Moritz)::

      Omega = integral A exp(-Ea / (R_gas T_K(t))) dt

  with the skin constants :data:`SKIN` by default (``A = 3.1e98 1/s``, ``Ea = 6.28e5 J/mol``);
  ``Omega >= 1`` marks irreversible damage (63 % of the cells).

How a sampled frame history ``T_0 .. T_{N-1}`` (period ``dt``) becomes ``T(t)``, by ``rule``
(:data:`RULES`):

* ``"hold"`` (default; the Sapareto-Dewey sum): frame ``k`` holds for ``[k dt, (k + 1) dt)``, so the
  history lasts ``N dt`` and every integral is the exact sum ``sum_k f(T_k) dt``. Exact for constant and
  step histories: 600 frames at 43 C with ``dt = 1 s`` give 10.0 min.
* ``"linear"``: ``T(t)`` is the piecewise-linear interpolant of the frames, lasting ``(N - 1) dt``.
  CEM43 and the time above a threshold are integrated exactly on each segment (closed forms, the
  segment split where it crosses 43 C or the threshold); Omega by composite 8-node Gauss-Legendre with
  each segment cut into pieces over which ``Ea / (R_gas T_K)`` changes by at most 1 (relative error
  below 1e-12 per piece).

Non-finite samples (dropped frames, masked pixels) contribute nothing: with ``"hold"`` their frame, with
``"linear"`` the segments they end. :func:`count_masked` says how many there were.

Computation is in float64 whatever the input dtype; gradients flow to the temperatures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

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

KELVIN_AT_ZERO_CELSIUS = 273.15

UNITS: dict[str, float] = {"C": 0.0, "K": -KELVIN_AT_ZERO_CELSIUS}
"""Temperature units accepted and the offset that turns them into Celsius."""

RULES = ("hold", "linear")
"""How a frame history is integrated (see the module docstring)."""

_IMPLAUSIBLE_CELSIUS = 200.0
"""A dose computation where every value is at least this many Celsius (or below this many kelvin,
i.e. colder than -73 C) was given the wrong unit: living tissue is neither."""

_F64 = torch.float64
_GL_NODES, _GL_WEIGHTS = (
    torch.tensor(v, dtype=_F64, device="cpu") for v in np.polynomial.legendre.leggauss(8)
)
_MAX_EXPONENT_STEP = 1.0  # largest change of Ea / (R T) over one Gauss-Legendre piece


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


# ------------------------------------------------------------------------------------- validation
def _as_history(temperatures: object) -> tuple[Tensor, tuple[int, ...]]:
    """``(B, T, P)`` float64 view of a history or video, and the output shape (time axis dropped)."""
    if not isinstance(temperatures, Tensor):
        try:
            temperatures = torch.as_tensor(temperatures, device="cpu")
        except (TypeError, ValueError, RuntimeError) as err:
            raise TypeError(
                f"temperatures must be a tensor or array, got {type(temperatures).__name__}"
            ) from err
    if temperatures.dtype == torch.bool or temperatures.is_complex():
        raise TypeError(f"temperatures must be real numbers, got dtype {temperatures.dtype}")
    x = temperatures.to(_F64)  # gradients flow (the depth maps differentiate through the doses)
    if x.ndim == 1:
        return x.reshape(1, -1, 1), ()
    if x.ndim == 3:
        return x.reshape(1, x.shape[0], -1), tuple(x.shape[1:])
    if x.ndim == 4:
        return x.reshape(x.shape[0], x.shape[1], -1), (x.shape[0], *x.shape[2:])
    raise ValueError(
        f"temperatures must have shape (T,), (T, H, W) or (B, T, H, W), got {tuple(temperatures.shape)}"
    )


def _as_dt(dt: object, batch: int, device: torch.device) -> Tensor:
    """Frame period(s) as a ``(B, 1, 1)`` float64 tensor on ``device``."""
    try:
        step = torch.as_tensor(dt.detach() if isinstance(dt, Tensor) else dt, dtype=_F64, device=device)
        step = step.reshape(-1)
    except (TypeError, ValueError, RuntimeError) as err:
        raise ValueError(f"dt must be a positive number in s, got {dt!r}") from err
    if step.numel() == 1:
        step = step.expand(batch)
    if step.numel() != batch:
        raise ValueError(f"dt must be a number or have shape ({batch},), got shape {tuple(step.shape)}")
    if not bool(torch.isfinite(step).all()) or bool((step <= 0).any()):
        raise ValueError(f"dt must be a positive finite number in s, got {step.tolist()}")
    return step.reshape(batch, 1, 1)


def to_celsius(temperatures: Tensor, units: str = "C") -> Tensor:
    """Temperatures in Celsius (float64), after checking that ``units`` fits the values.

    Args:
        temperatures: any shape, in ``units``.
        units: ``"C"`` or ``"K"`` (:data:`UNITS`).

    Returns:
        The values in Celsius, same shape; non-finite values stay non-finite.

    Raises:
        ValueError: unknown ``units``; a finite value below absolute zero for ``units``; or a range only
            plausible in the other unit (every finite value >= 200 declared Celsius, or every finite value
            below 200 K declared kelvin).

    Shape:
        Any; output like the input.
    """
    if units not in UNITS:
        raise ValueError(f"units must be one of {', '.join(map(repr, UNITS))}, got {units!r}")
    x = temperatures.to(_F64)
    finite = x.detach()[torch.isfinite(x.detach())]
    if finite.numel():
        low, high = float(finite.min()), float(finite.max())
        zero = -KELVIN_AT_ZERO_CELSIUS if units == "C" else 0.0
        other = "K" if units == "C" else "C"
        if low < zero:
            raise ValueError(
                f"units={units!r} (--units {units}) but temperatures go down to {low:.6g}, below absolute "
                f"zero ({zero:g} {units}); pass the unit the data is in"
            )
        wrong = low >= _IMPLAUSIBLE_CELSIUS if units == "C" else high < _IMPLAUSIBLE_CELSIUS
        if wrong:
            raise ValueError(
                f"units={units!r} (--units {units}) but every temperature lies in {low:.4g}-{high:.4g}, "
                f"a range that only makes sense in {other} for tissue; pass units={other!r} "
                f"(--units {other})"
            )
    return x + UNITS[units]


def count_masked(temperatures: Tensor) -> Tensor:
    """Number of non-finite samples per pixel (they add nothing to any dose).

    Shape:
        Like the dose functions: ``(T,)`` -> ``()``, ``(T, H, W)`` -> ``(H, W)``,
        ``(B, T, H, W)`` -> ``(B, H, W)``.
    """
    x, shape = _as_history(temperatures)
    return (~torch.isfinite(x)).sum(1).reshape(shape)


def _check_rule(rule: str) -> None:
    if rule not in RULES:
        raise ValueError(f"rule must be one of {', '.join(map(repr, RULES))}, got {rule!r}")


def _prepare(temperatures: object, dt: object, units: str, rule: str) -> tuple[Tensor, Tensor, tuple]:
    _check_rule(rule)
    x, shape = _as_history(temperatures)
    if x.shape[1] < (2 if rule == "linear" else 1):
        raise ValueError(
            f"rule={rule!r} needs at least {2 if rule == 'linear' else 1} frames, got {x.shape[1]}"
        )
    return to_celsius(x, units), _as_dt(dt, x.shape[0], x.device), shape


def _segments(x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Segment ends ``(B, T-1, P)`` with non-finite segments set to 43 and flagged False."""
    start, end = x[:, :-1], x[:, 1:]
    ok = torch.isfinite(start) & torch.isfinite(end)
    return torch.where(ok, start, 43.0), torch.where(ok, end, 43.0), ok


def _phi(z: Tensor) -> Tensor:
    """``expm1(z) / z`` with its limit 1 at 0."""
    small = z.abs() < 1e-12
    return torch.where(small, 1.0 + 0.5 * z, torch.expm1(z) / torch.where(small, 1.0, z))


# ------------------------------------------------------------------------------------------ CEM43
CEM43_R: tuple[float, float] = (0.5, 0.25)
"""Sapareto-Dewey ``R`` at or above 43 C and below it."""
_LOG_R_HIGH, _LOG_R_LOW = -math.log(CEM43_R[0]), -math.log(CEM43_R[1])  # R^(43 - T) = exp(c (T - 43))


def _cem_rate(x: Tensor) -> Tensor:
    """``R^(43 - T)`` for T in Celsius."""
    return torch.exp(_log_r(x) * (x - 43.0))


def _log_r(x: Tensor) -> Tensor:
    """``-ln R``: ln 2 at or above 43 C, ln 4 below (float64)."""
    return _LOG_R_LOW + (_LOG_R_HIGH - _LOG_R_LOW) * (x >= 43.0).to(_F64)


def cem43(temperatures: Tensor, dt: float | Tensor, *, units: str = "C", rule: str = "hold") -> Tensor:
    """Cumulative equivalent minutes at 43 C (Sapareto-Dewey) of each pixel's history.

    Args:
        temperatures: history or video in ``units``.
        dt: frame period in s, a number or ``(B,)``.
        units: ``"C"`` or ``"K"``.
        rule: ``"hold"`` (the Sapareto-Dewey sum) or ``"linear"`` (exact for the piecewise-linear
            interpolant); see the module docstring.

    Returns:
        CEM43 in minutes (float64).

    Raises:
        ValueError: bad shape, ``dt``, ``rule`` or ``units`` (see :func:`to_celsius`).

    Shape:
        ``(T,)`` -> ``()``; ``(T, H, W)`` -> ``(H, W)``; ``(B, T, H, W)`` -> ``(B, H, W)``.

    Example:
        >>> float(cem43(torch.full((300,), 44.0), 1.0))  # 5 min at 44 C
        10.0
    """
    x, step, shape = _prepare(temperatures, dt, units, rule)
    if rule == "hold":
        rate = torch.where(torch.isfinite(x), _cem_rate(torch.nan_to_num(x, nan=43.0)), 0.0)
        seconds = (rate * step).sum(1)
    else:
        t0, t1, ok = _segments(x)
        high0, high1 = t0 >= 43.0, t1 >= 43.0
        c = _log_r(t0)
        # Same side of 43 C: exp(c x0) * expm1(c (x1 - x0)) / (c (x1 - x0)), stable for x1 ~ x0.
        same = _cem_rate(t0) * _phi(c * (t1 - t0))

        def antiderivative(v: Tensor) -> Tensor:  # continuous, 0 at 43 C
            cv = _log_r(v)
            return torch.expm1(cv * (v - 43.0)) / cv

        span = torch.where(high0 == high1, 1.0, t1 - t0)  # crossing segments never have t1 == t0
        crossing = (antiderivative(t1) - antiderivative(t0)) / span
        mean_rate = torch.where(high0 == high1, same, crossing)
        seconds = torch.where(ok, mean_rate, 0.0).sum(1) * step[:, 0]
    return (seconds / 60.0).reshape(shape)


# --------------------------------------------------------------------------------------- Arrhenius
def _check_constants(constants: ArrheniusConstants) -> None:
    if not isinstance(constants, ArrheniusConstants):
        raise TypeError(f"constants must be ArrheniusConstants, got {type(constants).__name__}")


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
        constants: ``A`` and ``Ea`` (default :data:`SKIN`).
        rule: ``"hold"`` or ``"linear"`` (see the module docstring).

    Returns:
        Omega (dimensionless, float64); ``>= 1`` is irreversible damage.

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
    x, step, shape = _prepare(temperatures, dt, units, rule)
    log_a = math.log(constants.frequency)
    theta = constants.activation_energy / GAS_CONSTANT  # K

    def rate(celsius: Tensor) -> Tensor:
        return torch.exp(log_a - theta / (celsius + KELVIN_AT_ZERO_CELSIUS))

    if rule == "hold":
        values = torch.where(torch.isfinite(x), rate(torch.nan_to_num(x, nan=0.0)), 0.0)
        return (values * step).sum(1).reshape(shape)
    t0, t1, ok = _segments(x)
    k0, k1 = t0 + KELVIN_AT_ZERO_CELSIUS, t1 + KELVIN_AT_ZERO_CELSIUS
    pieces = torch.ceil(theta * (1.0 / k0 - 1.0 / k1).abs() / _MAX_EXPONENT_STEP).clamp_min(1)
    pieces = torch.where(ok, pieces, 0.0).flatten()
    start, delta = t0.flatten(), (t1 - t0).flatten()
    total = torch.zeros_like(start)
    nodes, weights = 0.5 * (_GL_NODES.to(x.device) + 1.0), 0.5 * _GL_WEIGHTS.to(x.device)  # on [0, 1]
    # Piece j of every segment that has more than j pieces; the active set shrinks quickly.
    active = torch.nonzero(pieces > 0).flatten()
    j = 0
    while active.numel():
        n = pieces[active]
        left = (j + nodes[:, None]) / n  # (8, A) fractions of the segment
        celsius = start[active] + delta[active] * left
        total[active] += (weights[:, None] * rate(celsius)).sum(0) / n
        j += 1
        active = active[pieces[active] > j]
    mean_rate = total.reshape(t0.shape)
    return (mean_rate.sum(1) * step[:, 0]).reshape(shape)


# -------------------------------------------------------------------------------- time above
def time_above(
    temperatures: Tensor, dt: float | Tensor, threshold: float, *, units: str = "C", rule: str = "hold"
) -> Tensor:
    """Time (s) each pixel spends at or above ``threshold`` (Celsius).

    Args:
        temperatures: history or video in ``units``.
        dt: frame period in s, a number or ``(B,)``.
        threshold: temperature in Celsius (whatever ``units`` is).
        units: ``"C"`` or ``"K"``.
        rule: ``"hold"`` (frames at or above, times dt) or ``"linear"`` (exact for the interpolant).

    Returns:
        Seconds (float64).

    Raises:
        ValueError: bad shape, ``dt``, ``rule``, ``units`` or a non-finite ``threshold``.

    Shape:
        ``(T,)`` -> ``()``; ``(T, H, W)`` -> ``(H, W)``; ``(B, T, H, W)`` -> ``(B, H, W)``.
    """
    if not (isinstance(threshold, int | float) and math.isfinite(threshold)):
        raise ValueError(f"threshold must be a finite temperature in Celsius, got {threshold!r}")
    x, step, shape = _prepare(temperatures, dt, units, rule)
    if rule == "hold":
        above = (torch.isfinite(x) & (x >= threshold)).to(_F64)
        return (above * step).sum(1).reshape(shape)
    t0, t1, ok = _segments(x)
    low, high = torch.minimum(t0, t1), torch.maximum(t0, t1)
    span = torch.where(high > low, high - low, 1.0)
    fraction = torch.where(high > low, ((high - threshold) / span).clamp(0, 1), (low >= threshold).to(_F64))
    return (torch.where(ok, fraction, 0.0).sum(1) * step[:, 0]).reshape(shape)
