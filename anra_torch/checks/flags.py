"""Plausibility and model-failure flags: the warnings a result carries, worded once for every command.

A number can be valid and still wrong: a diffusivity no material has (a pixel size in metres where mm were
meant reads 1e6 times too small), a negative one (heat gathering instead of spreading), or a model whose
forecast stays far above the noise floor. :class:`~anra_torch.estimation.ANRAResult` and
:class:`~anra_torch.forecast.GainResult` keep these lines in their ``warnings``; ``anra estimate``,
``diagnose`` and ``batch`` print them.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence

    from torch import Tensor

__all__ = [
    "MIN_RELIABILITY",
    "MIN_SIGNIFICANCE",
    "MODEL_FAILURE_RATIO",
    "PLAUSIBLE_DIFFUSIVITY",
    "DEPTH_BIAS",
    "POOR_FIT",
    "depth_bias",
    "diffusivity_warnings",
    "extended_diffusivity_warning",
    "implausible_diffusivity",
    "model_failure",
    "poor_fit",
    "verdicts",
]

PLAUSIBLE_DIFFUSIVITY = (1e-3, 2e3)
"""Diffusivities of known materials, mm^2/s: aerogels and foams ~0.01-0.03, tissue and polymers ~0.1,
metals 10-170, diamond and pyrolytic graphite ~1e3; a wide margin on each side."""

MODEL_FAILURE_RATIO = 3.0
"""A forecast RMSE above this multiple of the noise floor is a model that does not explain the data."""

_MIXUPS = (
    # (spacing, the unit it was probably given in, factor from that unit to mm or s)
    ("dx", "m", 1e3),
    ("dx", "cm", 10.0),
    ("dx", "um", 1e-3),
    ("dt", "ms", 1e-3),
    ("dt", "min", 60.0),
)
"""Unit mix-ups :func:`diffusivity_warnings` names as the likely cause (a scales as dx^2 / dt)."""


def _likely_cause(a: float, dt: float, dx: float) -> str:
    """The unit mix-up that brings ``|a|`` into :data:`PLAUSIBLE_DIFFUSIVITY` closest to 1 mm^2/s."""
    low, high = PLAUSIBLE_DIFFUSIVITY
    best = None
    for name, unit, factor in _MIXUPS:
        fixed = abs(a) * (factor**2 if name == "dx" else 1 / factor)
        if low <= fixed <= high and (best is None or abs(math.log10(fixed)) < abs(math.log10(best[0]))):
            best = (fixed, name, unit, factor)
    # Too small can also be the data's: frames that change by something other than lateral conduction.
    still = ", or frames that hardly change by lateral conduction (a flat baseline, a drift, a loss)"
    still = still if abs(a) < low else ""
    if best is None:
        return f"; check that dt is in s, dx in mm and the frames are temperatures{still}"
    fixed, name, unit, factor = best
    value = dx if name == "dx" else dt
    wanted = "mm" if name == "dx" else "s"
    return (
        f"; likely cause: {name} = {value:g} given in {unit} instead of {wanted} "
        f"({name} = {value * factor:g} {wanted} would give {math.copysign(fixed, a):.3g} mm^2/s){still}"
    )


def diffusivity_warnings(a: float, *, dt: float, dx: float, z: float | None = None) -> list[str]:
    """The warnings a diffusivity deserves: negative, or outside every known material.

    Args:
        a: the diffusivity, mm^2/s (a non-finite value gets no warning: it is reported as no estimate).
        dt: frame period, s (for the likely unit mix-up).
        dx: pixel size, mm.
        z: ``a`` in standard errors, when known: a negative ``a`` is then flagged only below -3.

    Returns:
        Zero, one or two lines.

    Shape:
        No tensors.

    Example:
        >>> diffusivity_warnings(6e-9, dt=0.04, dx=0.0001)[0].split("; ")[1].split(", or")[0]
        'likely cause: dx = 0.0001 given in m instead of mm (dx = 0.1 mm would give 0.006 mm^2/s)'
        >>> diffusivity_warnings(0.15, dt=0.04, dx=0.1)
        []
    """
    if not math.isfinite(a):
        return []
    found = []
    if z is not None and z < -3.0:
        how = f"{z:.1f} standard errors below 0" if math.isfinite(z) else "noise-free: a zero standard error"
        found.append(
            f"the diffusivity is significantly negative ({how}): heat is added "
            "faster than it spreads (a source?), the plain heat equation does not describe these frames; "
            "see anra diagnose"
        )
    elif z is None and a < 0:
        found.append(
            "the diffusivity is negative: heat gathers instead of spreading (a source, or frames in "
            "reverse order?), the plain heat equation does not describe these frames"
        )
    outside = implausible_diffusivity(a, dt=dt, dx=dx)
    return found + ([outside] if outside else [])


def implausible_diffusivity(a: float, *, dt: float, dx: float) -> str | None:
    """The warning for a diffusivity ``a`` in mm^2/s outside every known material
    (:data:`PLAUSIBLE_DIFFUSIVITY`), with the likely unit mix-up of ``dt`` in s or ``dx`` in mm; None inside
    the range or for a non-finite ``a``.

    Shape:
        No tensors.

    Example:
        >>> implausible_diffusivity(0.15, dt=0.04, dx=0.1) is None
        True
    """
    low, high = PLAUSIBLE_DIFFUSIVITY
    if not math.isfinite(a) or low <= abs(a) <= high:
        return None
    return (
        f"the diffusivity {a:.3g} mm^2/s is outside every known material (about {low:g} to {high:g} "
        f"mm^2/s in magnitude){_likely_cause(a, dt, dx)}"
    )


def extended_diffusivity_warning(a: float, plain: float, effects: Sequence[str]) -> str | None:
    """The warning for an extended model whose own diffusivity ``a`` (its coefficient of ``Lap T``; outside
    a named disc, ``a_outside``) is outside every known material while the plain model's ``plain`` is not:
    the named ``effects`` have taken up the lateral conduction itself, so the extension may forecast without
    describing the material (more terms than the frames support, or a missing one). None otherwise.

    Shape:
        No tensors.

    Example:
        >>> extended_diffusivity_warning(0.00082, 0.101, ["linear_loss", "heterogeneity"])[:60]
        "the extended model's diffusivity 0.00082 mm^2/s is outside e"
        >>> extended_diffusivity_warning(0.12, 0.101, ["linear_loss"]) is None
        True
    """
    low, high = PLAUSIBLE_DIFFUSIVITY
    if not effects or not math.isfinite(a) or low <= abs(a) <= high or not low <= abs(plain) <= high:
        return None
    return (
        f"the extended model's diffusivity {a:.3g} mm^2/s is outside every known material (the plain "
        f"fit's: {plain:.3g}): its effects ({', '.join(effects)}) take up the conduction itself; more "
        "terms than these frames support, or a missing one"
    )


def model_failure(rmse: float, floor: float, *, what: str = "forecast") -> str | None:
    """The warning for a model whose ``what`` RMSE stays above :data:`MODEL_FAILURE_RATIO` noise floors.

    Args:
        rmse: the model's error in data units.
        floor: the least error a perfect model would reach in data units.
        what: the error's name in the message.

    Returns:
        One line naming the ratio to the floor, or None when the model explains the data.

    Shape:
        No tensors.

    Example:
        >>> model_failure(0.03, 0.001)[:72]
        'the model does not explain the data: its forecast RMSE 0.03 is 30 times '
        >>> model_failure(0.002, 0.001) is None
        True
    """
    if not math.isfinite(rmse):
        return f"the model does not explain the data: its {what} is not finite (the simulation diverged)"
    if not math.isfinite(floor) or floor < 0 or rmse <= MODEL_FAILURE_RATIO * floor:
        return None
    ratio = f"{rmse / floor:.3g} times" if floor > 0 else "infinitely above"
    return (
        f"the model does not explain the data: its {what} RMSE {rmse:.3g} is {ratio} the noise floor "
        f"{floor:.3g} (more than {MODEL_FAILURE_RATIO:g}: an effect not modelled, a camera artefact, or "
        "wrong spacing)"
    )


POOR_FIT = 0.9
"""Share of ``dT/dt`` that ``a Lap T`` must explain (:attr:`ANRAResult.explained
<anra_torch.estimation.ANRAResult.explained>`) not to be flagged."""

MIN_RELIABILITY = 0.05
"""Below this fraction of signal in the regressor energy, nothing is measurable."""

MIN_SIGNIFICANCE = 3.0
"""``|a| / std_error`` below this is indistinguishable from noise."""


DEPTH_BIAS = 1.25
"""Ratio of the plain to a consistent depth-aware diffusivity above which the plain one is flagged."""


def depth_bias(plain: float | None, depth_aware: dict | None) -> list[str]:
    """The warning of a plain diffusivity more than :data:`DEPTH_BIAS` times (or under 1 / DEPTH_BIAS of)
    the depth-aware one (a ``depth_aware`` record of
    :meth:`~anra_torch.selection.DepthAwareFit.to_record` that is consistent); none otherwise.

    Shape:
        No tensors.

    Example:
        >>> depth_bias(0.25, {"diffusivity": 0.13, "consistent": True})[0][:58]
        'the plain diffusivity 0.25 mm^2/s is 1.9x the depth-aware '
        >>> depth_bias(0.25, {"diffusivity": 0.13, "consistent": False})
        []
    """
    if plain is None or not depth_aware or not depth_aware.get("consistent"):
        return []
    a = depth_aware["diffusivity"]
    if not (a > 0 and plain > 0 and max(plain / a, a / plain) > DEPTH_BIAS):
        return []
    return [
        f"the plain diffusivity {plain:.3g} mm^2/s is {plain / a:.2g}x the depth-aware {a:.3g} mm^2/s (a "
        "loss rate free in each frame, the same at every smoothing): heat flowing into depth reads as "
        "lateral spreading; the depth-aware value is the better estimate of the lateral diffusivity"
    ]


def poor_fit(explained: float) -> tuple[str, ...]:
    """The warning of an estimate whose plain heat equation explains less than :data:`POOR_FIT` of
    ``dT/dt`` (none at or above it)."""
    if not explained < POOR_FIT:
        return ()
    return (
        f"the plain heat equation explains only {100 * explained:.0f} % of dT/dt (below "
        f"{100 * POOR_FIT:.0f} %): the diffusivity is the best fit of a model that does not describe these "
        "frames (heat flowing into depth, a loss or a source); see anra diagnose",
    )


def verdicts(
    valid: Tensor,
    moving: Tensor,
    reliability: Tensor,
    estimate: Tensor,
    std_error: Tensor,
    dt: Tensor,
    dx: Tensor,
) -> tuple[tuple[str, ...], tuple[tuple[str, ...], ...]]:
    """Per video, the result's line (why it is not valid, else "") and its warnings
    (:func:`anra_torch.checks.diffusivity_warnings`; none for an invalid video)."""
    messages, warnings = [], []
    z = estimate / std_error
    rows = zip(
        *(v.tolist() for v in (valid, moving, reliability, z, estimate, std_error, dt, dx)), strict=True
    )
    for ok, changing, signal, zz, a, error, step, size in rows:
        found = tuple(diffusivity_warnings(a, dt=step, dx=size, z=zz)) if ok else ()
        warnings.append(found)
        if not changing:
            messages.append("frames are constant: no thermal activity, no diffusivity estimated")
        elif not ok and signal == 0 and not math.isfinite(zz):  # 0 / 0: no pixel left to balance
            messages.append(
                "no pixel has a filter window free of masked samples and with signal (too many masked "
                "samples or too small a frame); no diffusivity estimated"
            )
        elif not ok and not all(
            math.isfinite(x) for x in (signal, zz, a, error)
        ):  # a / inf is 0, not a result
            messages.append(
                "the balance of dT/dt and the Laplacian is not finite (an overflow: check that dt is in s, "
                "dx in mm and the frames' values are temperatures); no diffusivity estimated"
            )
        elif not ok:
            messages.append(
                f"frames show no thermal activity above the noise (signal fraction {signal:.3f}, estimate "
                f"{abs(zz):.1f} standard errors from 0; need >= {MIN_RELIABILITY} and >= "
                f"{MIN_SIGNIFICANCE:g}); no diffusivity estimated"
            )
        else:
            messages.append("")  # a valid video's flags are its warnings (joined once by their readers)
    return tuple(messages), tuple(warnings)
