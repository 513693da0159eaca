"""Input checks shared by every public entry point: one place for each kind of check and its message.

Every check raises a one-line ``ValueError`` (bad value or shape) or ``TypeError`` (not a number or array)
that names the argument, the requirement and what was received.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "MAX_NON_FINITE",
    "SPACING_RANGE",
    "VALUE_LIMIT",
    "as_fields",
    "as_spacing",
    "as_video",
    "check_choice",
    "check_dtype",
    "check_int",
    "check_shape",
    "in_range_values",
    "join_messages",
    "mostly_finite",
    "number",
    "one_line",
    "positive",
    "spacing_in_range",
    "uniform_step",
]

VALUE_LIMIT = 1e6
"""Largest magnitude in data units of a sample that can be a measurement: above any temperature in K, C or F
(the sun's surface is 5.8e3 K) and above any 16-bit raw sensor count (65535), far below where float32
squares overflow. Samples beyond it, and non-finite ones, are masked by :func:`in_range_values`."""

MAX_NON_FINITE = 0.05
"""Largest fraction of non-finite samples :func:`mostly_finite` lets through: a few are artefacts to repair,
more is a broken recording."""

SPACING_RANGE = (1e-6, 1e6)
"""Frame periods in s and pixel sizes in mm :func:`spacing_in_range` accepts: 1 MHz to one frame every 11
days, 1 nm to 1 km per pixel; outside, dx^2 / dt and the derivatives' scales leave the float range."""


def number(
    value: object, name: str, unit: str, *, positive: bool = False, minimum: float | None = None
) -> float:
    """``value`` as a finite float (a number or a one-element tensor or array); positive or ``>= minimum``
    when asked.

    Raises:
        TypeError: not a number.
        ValueError: not finite, not positive, or below ``minimum``.
    """
    if isinstance(value, bool):
        raise TypeError(f"{name} must be a number in {unit}, got {value!r}")
    try:
        scalar = value.item() if isinstance(value, Tensor | np.ndarray) else value  # type: ignore[union-attr]
        result = float(scalar)  # type: ignore[arg-type]
    except (TypeError, ValueError, RuntimeError) as err:
        raise TypeError(f"{name} must be a number in {unit}, got {value!r}") from err
    if positive and not (math.isfinite(result) and result > 0):
        raise ValueError(f"{name} must be a positive finite number in {unit}, got {value!r}")
    if not math.isfinite(result):
        raise ValueError(f"{name} must be a finite number in {unit}, got {value!r}")
    if minimum is not None and result < minimum:
        raise ValueError(f"{name} must be a finite number >= {minimum:g} in {unit}, got {value!r}")
    return result


def one_line(err: BaseException, *, kind: bool = False) -> str:
    """The message of ``err`` on one line (its type name when it has none).

    Args:
        err: the exception.
        kind: prefix the type name (``"BadZipFile: ..."``), for quoting another library's error inside ours.

    Shape:
        No tensors.

    Example:
        >>> one_line(ValueError("no   such  file")), one_line(KeyError(), kind=True)
        ('no such file', 'KeyError: KeyError')
    """
    text = " ".join(str(err).split()) or type(err).__name__
    return f"{type(err).__name__}: {text}" if kind else text


def join_messages(parts: Iterable[object]) -> str:
    """The non-empty ``parts``, ``"; "``-joined, each once, in order: one message cell from several lines.

    Example:
        >>> join_messages(["masked", "", None, "negative a", "masked"])
        'masked; negative a'
    """
    return "; ".join(dict.fromkeys(str(p) for p in parts if p))


def positive(value: object, name: str, unit: str) -> float:
    """``value`` as a positive finite float (see :func:`number`)."""
    return number(value, name, unit, positive=True)


def check_int(value: object, name: str, minimum: int) -> int:
    """``value`` as an integer (not a bool) ``>= minimum``.

    Raises:
        ValueError: not such an integer.
    """
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return value


def check_choice(value: object, name: str, choices: Sequence[str]) -> str:
    """``value`` if it is one of ``choices``.

    Raises:
        ValueError: unknown value, listing the choices.
    """
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"unknown {name} {value!r}; expected one of: {', '.join(choices)}")
    return value


def check_dtype(dtype: object) -> torch.dtype:
    """``dtype`` if it is float32 or float64.

    Raises:
        TypeError: another dtype.
    """
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    return dtype  # type: ignore[return-value]


def check_shape(shape: object) -> tuple[int, int]:
    """A frame size ``(H, W)`` of positive integers.

    Raises:
        ValueError: anything else.
    """
    if (
        not isinstance(shape, Sequence)
        or len(shape) != 2
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in shape)
    ):
        raise ValueError(f"shape must be (H, W) with positive integers, got {shape!r}")
    return int(shape[0]), int(shape[1])


def as_fields(initial: object, *, name: str = "initial") -> tuple[Tensor, bool]:
    """Return finite frames as a floating ``(B, H, W)`` tensor and whether the input was batched.

    Raises:
        TypeError: not real numbers.
        ValueError: not ``(H, W)`` or ``(B, H, W)``, or non-finite values.
    """
    if not isinstance(initial, Tensor):
        try:
            initial = torch.as_tensor(initial, device="cpu")
        except (TypeError, ValueError, RuntimeError) as err:
            raise TypeError(f"{name} must be a tensor or array, got {type(initial).__name__}") from err
    if initial.dtype == torch.bool or initial.is_complex():
        raise TypeError(f"{name} must hold real temperatures, got dtype {initial.dtype}")
    if not initial.is_floating_point():
        initial = initial.to(torch.get_default_dtype())
    elif initial.dtype not in (torch.float32, torch.float64):
        initial = initial.to(torch.float32)
    if initial.ndim not in (2, 3) or initial.numel() == 0:
        raise ValueError(f"{name} must have shape (H, W) or (B, H, W), got {tuple(initial.shape)}")
    if not bool(torch.isfinite(initial).all()):
        bad = int((~torch.isfinite(initial)).sum())
        raise ValueError(f"{name} must be finite, got {bad} non-finite values; mask or fill them first")
    batched = initial.ndim == 3
    return (initial if batched else initial.unsqueeze(0)), batched


def own_tensor(value: object, dtype: torch.dtype | None = None) -> Tensor:
    """``value`` as a tensor on its own device: a tensor stays where it is, an array or a list goes to the
    CPU (never to the default device), in ``dtype`` when given.

    Shape:
        Any; the output has ``value``'s shape.
    """
    tensor = value if isinstance(value, Tensor) else torch.as_tensor(value, device="cpu")
    return tensor if dtype is None else tensor.to(dtype)


def as_video(frames: object, *, name: str = "frames", min_frames: int = 1) -> tuple[Tensor, bool]:
    """Return ``frames`` as a floating ``(B, T, H, W)`` tensor and whether the input was batched.

    Integer raw counts are converted to the default floating dtype; float32/float64 are kept.

    Raises:
        TypeError: not array-like.
        ValueError: wrong number of dimensions or too few frames.
    """
    if not isinstance(frames, Tensor):
        try:
            frames = torch.as_tensor(frames, device="cpu")  # arrays live on the CPU
        except (TypeError, ValueError, RuntimeError) as err:
            raise TypeError(f"{name} must be a tensor or array, got {type(frames).__name__}") from err
    if frames.dtype == torch.bool or frames.is_complex():
        raise TypeError(f"{name} must hold real temperatures, got dtype {frames.dtype}")
    if not frames.is_floating_point():
        frames = frames.to(torch.get_default_dtype())
    elif frames.dtype not in (torch.float32, torch.float64):
        frames = frames.to(torch.float32)
    if frames.ndim not in (3, 4):
        raise ValueError(f"{name} must have shape (T, H, W) or (B, T, H, W), got {tuple(frames.shape)}")
    batched = frames.ndim == 4
    video = frames if batched else frames.unsqueeze(0)
    if video.shape[1] < min_frames:
        raise ValueError(f"{name} needs at least {min_frames} frames for these filters, got {video.shape[1]}")
    return video, batched


def as_spacing(value: object, *, name: str, unit: str, batch: int, like: Tensor) -> Tensor:
    """Return a positive finite spacing (``dt`` in s, ``dx`` in mm) as a ``(B,)`` tensor.

    Raises:
        ValueError: non-positive or non-finite value, or a tensor of the wrong length.
    """
    if isinstance(value, Tensor):
        spacing = value.detach().to(like.dtype).reshape(-1)
    else:
        try:
            spacing = torch.as_tensor(value, dtype=like.dtype, device=like.device).reshape(-1)
        except (TypeError, ValueError, RuntimeError) as err:
            raise ValueError(f"{name} must be a positive number in {unit}, got {value!r}") from err
    if spacing.numel() == 1:
        spacing = spacing.expand(batch)
    if spacing.numel() != batch:
        raise ValueError(
            f"{name} must be a number or have shape ({batch},), got shape {tuple(spacing.shape)}"
        )
    if not bool(torch.isfinite(spacing).all()) or bool((spacing <= 0).any()):
        shown = value if not isinstance(value, Tensor) else (value.tolist() if value.ndim else value.item())
        raise ValueError(f"{name} must be a positive finite number in {unit}, got {shown}")
    return spacing.to(like.device)


def uniform_step(times: object, *, name: str = "t", rtol: float = 1e-3, atol: float = 0.0) -> float:
    """Return the constant step of increasing, uniform timestamps in s: every step within ``rtol`` of their
    mean, or within ``atol`` s (the clock's resolution: times kept to the millisecond step by 33 and 34 ms
    at 30 Hz).

    Raises:
        ValueError: fewer than two stamps, non-finite, not strictly increasing, or non-uniform.
    """
    t = torch.as_tensor(times, dtype=torch.float64, device="cpu").reshape(-1)
    if t.numel() < 2:
        raise ValueError(f"{name} needs at least 2 timestamps, got {t.numel()}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} must be finite timestamps in s, got non-finite values")
    steps = torch.diff(t)
    if bool((steps <= 0).any()):
        k = int(torch.nonzero(steps <= 0)[0])
        raise ValueError(
            f"{name} must be strictly increasing, got t[{k}]={t[k].item():g} s "
            f"then t[{k + 1}]={t[k + 1].item():g} s"
        )
    mean = float(steps.mean())
    spread = float((steps - mean).abs().max())
    if spread > max(rtol * mean, atol):
        raise ValueError(
            f"{name} must be uniformly spaced, got steps from {float(steps.min()):g} "
            f"to {float(steps.max()):g} s; resample the video first"
        )
    if not math.isfinite(mean):
        raise ValueError(f"{name} must be finite timestamps in s")
    return mean


def in_range_values(
    frames: Tensor, *, name: str = "frames", limit: float = VALUE_LIMIT
) -> tuple[Tensor, dict]:
    """Mask the samples that cannot be measurements: non-finite, or beyond ``+-limit`` in data units.

    The one policy for input values (every command reads its video through
    :func:`anra_torch.video.prepare_video`, which calls this): such samples are set to NaN, counted, and
    left to the analyses' masks; a video with no sample left is refused.

    Args:
        frames: the samples, any shape and real dtype (integers are kept unless a sample is masked, then
            they become float64).
        name: the argument's name, for the message.
        limit: largest magnitude accepted in data units, default :data:`VALUE_LIMIT`.

    Returns:
        The frames with the masked samples (infinities too) set to NaN, and a record ``{"non_finite",
        "beyond_limit", "samples"`` (counts), ``"limit"`` in data units, ``"largest"`` (the largest finite
        magnitude masked, or None)``}``.

    Shape:
        Any shape, kept.

    Raises:
        ValueError: no sample (an empty array) or none finite within ``+-limit``.

    Example:
        >>> masked, found = in_range_values(torch.tensor([1.0, float("nan"), 3e30, -2.0]))
        >>> masked.tolist()[::3], found["non_finite"], found["beyond_limit"]
        ([1.0, -2.0], 1, 1)
    """
    total = frames.numel()
    values = frames if frames.is_floating_point() else frames.to(torch.float64)  # int16 abs would wrap
    finite = torch.isfinite(values)
    beyond = finite & (values.abs() > limit)
    n_bad, n_beyond = total - int(finite.sum()), int(beyond.sum())
    found = {
        "non_finite": n_bad,
        "beyond_limit": n_beyond,
        "samples": total,
        "limit": limit,
        "largest": float(values[beyond].abs().max()) if n_beyond else None,
    }
    if total == 0 or n_bad + n_beyond == total:
        raise ValueError(
            f"{name} must hold finite values within +-{limit:g} (data units), got none: {n_bad} non-finite "
            f"and {n_beyond} beyond the limit of {total} samples"
        )
    if n_bad or n_beyond:  # every masked sample is NaN (an infinity too), so one test finds them all
        frames = torch.where(finite & ~beyond, values, torch.full_like(values, torch.nan))
    return frames, found


def spacing_in_range(value: float, name: str, unit: str) -> float:
    """``value`` if it lies in :data:`SPACING_RANGE` (a frame period in s or a pixel size in mm).

    Raises:
        ValueError: outside the range, with the likely unit mix-up when there is one.
    """
    low, high = SPACING_RANGE
    if not low <= value <= high:
        raise ValueError(
            f"{name} must be between {low:g} and {high:g} {unit}, got {value:g}; check its unit "
            f"(dt in s, dx in mm)"
        )
    return value


def mostly_finite(frames: Tensor, *, name: str = "frames") -> Tensor:
    """``frames`` if at most :data:`MAX_NON_FINITE` of their samples are non-finite (analyses that repair a
    few, such as the diagnosis, cannot work around more).

    Raises:
        ValueError: more non-finite samples, with their true count.
    """
    bad = int((~torch.isfinite(frames)).sum())
    if bad > MAX_NON_FINITE * frames.numel():
        raise ValueError(
            f"{name} must be mostly finite, got {bad} non-finite values of {frames.numel()} (more than "
            f"{100 * MAX_NON_FINITE:g} %); crop or fill them first"
        )
    return frames
