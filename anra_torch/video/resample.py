"""Resampling a video with non-uniform timestamps onto a uniform time grid (linear interpolation).

The estimator and the diagnosis assume one frame period. Hand-triggered cameras do not keep one (the
FLIR C3-X recordings here step 4-6 s). :func:`resample_uniform` makes the choice explicit: frames are
linearly interpolated in time onto ``t0, t0 + dt, ...`` (never past the last measured frame), and the
returned video says what it was resampled from in ``meta["resampled"]``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from anra_torch.video.core import Video

__all__ = ["resample_uniform"]


def resample_uniform(video: Video, dt: float | None = None) -> Video:
    """Interpolate ``video`` linearly in time onto a uniform grid of step ``dt`` (s).

    Args:
        video: a video with timestamps ``t`` (strictly increasing, s).
        dt: the new frame period in s; default the median measured step.

    Returns:
        A video with float64 frames on ``t = t0 + k dt`` (``k = 0 .. floor((t_end - t0) / dt)``), the same
        ``dx``, and ``meta["resampled"]`` = ``{"from_frames", "step_min", "step_max", "dt", "method"}``
        (steps in s). A video that is already uniform (or has no timestamps) is returned unchanged.

    Shape:
        ``video.frames`` ``(T, H, W)`` -> ``(T', H, W)``.

    Raises:
        ValueError: non-positive ``dt``, or a new grid of fewer than 2 frames.
    """
    if video.t is None or (video.uniform and dt is None):
        return video
    t = video.t.double()
    steps = torch.diff(t)
    step = float(steps.median()) if dt is None else float(dt)
    if not step > 0:
        raise ValueError(f"dt must be a positive number in s, got {dt!r}")
    n = int((float(t[-1] - t[0]) + 1e-9 * step) // step) + 1
    if n < 2:
        raise ValueError(f"{video.name}: resampling at dt = {step:g} s leaves {n} frame; choose a smaller dt")
    grid = t[0] + step * torch.arange(n, dtype=torch.float64)
    right = torch.searchsorted(t, grid, right=True).clamp(1, t.numel() - 1)
    left = right - 1
    weight = ((grid - t[left]) / (t[right] - t[left])).clamp(0, 1).view(-1, 1, 1)

    def interpolate(frames: Tensor) -> Tensor:
        frames = frames.double()
        blend = (1 - weight) * frames[left] + weight * frames[right]
        # On a sample's own time the other side has no weight: a masked (NaN) neighbour stays out.
        return torch.where(weight == 0, frames[left], torch.where(weight == 1, frames[right], blend))

    meta = dict(video.meta)
    meta["resampled"] = {
        "from_frames": int(t.numel()),
        "step_min": float(steps.min()),
        "step_max": float(steps.max()),
        "dt": step,
        "method": "linear interpolation in time",
    }
    meta["dt_source"] = "resampled"
    return video.map_frames(interpolate, dt=step, t=grid, meta=meta)
