"""Checks shared by the public entry points: video shapes, spacings, timestamps."""

from __future__ import annotations

import math

import torch
from torch import Tensor


def as_video(frames: object, *, name: str = "frames", min_frames: int = 1) -> tuple[Tensor, bool]:
    """Return ``frames`` as a floating ``(B, T, H, W)`` tensor and whether the input was batched.

    Integer raw counts are converted to the default floating dtype; float32/float64 are kept.

    Raises:
        TypeError: not array-like.
        ValueError: wrong number of dimensions or too few frames.
    """
    if not isinstance(frames, Tensor):
        try:
            frames = torch.as_tensor(frames)
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
            spacing = torch.as_tensor(value, dtype=like.dtype).reshape(-1)
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


def uniform_step(times: object, *, name: str = "t", rtol: float = 1e-3) -> float:
    """Return the constant step of increasing, uniform timestamps (s).

    Raises:
        ValueError: fewer than two stamps, non-finite, not strictly increasing, or non-uniform.
    """
    t = torch.as_tensor(times, dtype=torch.float64).reshape(-1)
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
    if spread > rtol * mean:
        raise ValueError(
            f"{name} must be uniformly spaced, got steps from {float(steps.min()):g} "
            f"to {float(steps.max()):g} s; resample the video first"
        )
    if not math.isfinite(mean):
        raise ValueError(f"{name} must be finite timestamps in s")
    return mean
