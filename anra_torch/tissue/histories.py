"""Temperature histories as the dose functions of :mod:`~anra_torch.tissue.dose` read them: the units
checked and turned into Celsius (:func:`to_celsius`), the shapes and the rule checked, masked (non-finite)
samples counted (:func:`count_masked`) and left out of every sum, and the in-place arithmetic the doses use
where no gradient is tracked.

Computation is in float64 whatever the input dtype; gradients flow to the temperatures.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from anra_torch.checks import as_spacing

__all__ = [
    "KELVIN_AT_ZERO_CELSIUS",
    "RULES",
    "UNITS",
    "Step",
    "as_history",
    "check_rule",
    "count_masked",
    "counted",
    "divided",
    "masked",
    "prepare",
    "stepper",
    "to_celsius",
]

KELVIN_AT_ZERO_CELSIUS = 273.15

UNITS: dict[str, float] = {"C": 0.0, "K": -KELVIN_AT_ZERO_CELSIUS}
"""Temperature units accepted and the offset that turns them into Celsius."""

RULES = ("hold", "linear")
"""How a frame history of ``T`` frames is integrated: ``"hold"``, each frame held for ``dt``, over ``T dt``;
``"linear"``, the frames joined by straight lines over ``(T - 1) dt``."""

_IMPLAUSIBLE_CELSIUS = 200.0
"""A dose computation where every value is at least this many Celsius (or below this many kelvin,
i.e. colder than -73 C) was given the wrong unit: living tissue is neither."""

_F64 = torch.float64


def as_history(temperatures: object) -> tuple[Tensor, tuple[int, ...]]:
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
    values = x.detach()
    finite = torch.isfinite(values)
    if bool(finite.any()):
        if bool(finite.all()):
            low, high = (float(v) for v in torch.aminmax(values))
        else:
            low = float(torch.where(finite, values, torch.inf).amin())
            high = float(torch.where(finite, values, -torch.inf).amax())
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
    return x if UNITS[units] == 0.0 and x is not temperatures else x + UNITS[units]  # always a new tensor


def count_masked(temperatures: Tensor) -> Tensor:
    """Number of non-finite samples per pixel (they add nothing to any dose).

    Shape:
        Like the dose functions: ``(T,)`` -> ``()``, ``(T, H, W)`` -> ``(H, W)``,
        ``(B, T, H, W)`` -> ``(B, H, W)``.
    """
    x, shape = as_history(temperatures)
    return (~torch.isfinite(x)).sum(1).reshape(shape)


def check_rule(rule: str) -> None:
    if rule not in RULES:
        raise ValueError(f"rule must be one of {', '.join(map(repr, RULES))}, got {rule!r}")


def prepare(temperatures: object, dt: object, units: str, rule: str) -> tuple[Tensor, Tensor, tuple]:
    check_rule(rule)
    x, shape = as_history(temperatures)
    if x.shape[1] < (2 if rule == "linear" else 1):
        raise ValueError(
            f"rule={rule!r} needs at least {2 if rule == 'linear' else 1} frames, got {x.shape[1]}"
        )
    step = as_spacing(dt, name="dt", unit="s", batch=x.shape[0], like=x)  # the one spacing check
    return to_celsius(x, units), step.reshape(-1, 1, 1), shape


def masked(x: Tensor, rule: str, finite: Tensor | None = None) -> tuple[Tensor, Tensor | None]:
    """Histories with masked samples at 43 C (finite, so that no branch makes a NaN) and the weights (1 or 0)
    of the frames (``"hold"``) or segments (``"linear"``) that count; None when every one counts."""
    finite = torch.isfinite(x) if finite is None else finite
    if bool(finite.all()):
        return x, None
    keep = finite if rule == "hold" else finite[:, :-1] & finite[:, 1:]
    return torch.nan_to_num(x, nan=43.0, posinf=43.0, neginf=43.0), keep.to(_F64)


def counted(values: Tensor, weights: Tensor | None, step: Step) -> Tensor:
    """``values`` summed over frames or segments ``(B, S, P) -> (B, P)``, the masked ones left out."""
    return (values if weights is None else step(values, "mul", weights)).sum(1)


Step = Callable[..., Tensor]


def stepper(x: Tensor) -> Step:
    """``step(t, "mul", y)``: ``t.mul_(y)`` where no gradient is tracked through ``x``, ``t.mul(y)``
    otherwise; why: ``docs/architecture.md``, "Choices in the hot paths". Only for temporaries the caller
    made itself."""
    inplace = not (torch.is_grad_enabled() and x.requires_grad)

    def step(t: Tensor, name: str, *args: object) -> Tensor:
        return getattr(t, name + "_")(*args) if inplace else getattr(t, name)(*args)

    return step


def divided(change: Tensor, rise: Tensor, limit: Tensor, scale: float, step: Step) -> Tensor:
    """``change / rise`` where ``|rise|`` is well above ``scale``, ``limit`` (its value as ``rise -> 0``)
    well below: ``(change rise + scale^2 limit) / (rise^2 + scale^2)``, smooth, without a branch. Consumes
    ``change`` and ``limit``."""
    square = scale * scale
    top = step(step(change, "mul", rise), "add", step(limit, "mul", square))
    return step(top, "div", step(rise * rise, "add", square))
