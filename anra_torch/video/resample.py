"""Resampling a video with non-uniform timestamps onto a uniform time grid (linear interpolation).

The estimator and the diagnosis assume one frame period. Hand-triggered cameras do not keep one (the
FLIR C3-X recordings here step 4-6 s). :func:`resample_uniform` makes the choice explicit: frames are
linearly interpolated in time onto ``t0, t0 + dt, ...`` (never past the last measured frame), and the
returned video says what it was resampled from in ``meta["resampled"]``. A resampled frame between two
samples blends them: across a source's switch it mixes heating and cooling, so :func:`measured_part` keeps
a phase on the frames interpolated from its own samples only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import Tensor

from anra_torch.video.core import Video
from anra_torch.video.phases import Phase

__all__ = ["FOREIGN_WEIGHT", "measured_frames", "measured_part", "resample_uniform"]

FOREIGN_WEIGHT = 0.1
"""The most a phase's resampled frame may take from another phase's samples (a timing jitter's blend)."""


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
    left, right, weight = _brackets(t, grid)
    weight = weight.view(-1, 1, 1)

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
    meta["measured_t"] = tuple(float(x) for x in t)  # for :func:`measured_part`, not for the JSON
    return video.map_frames(interpolate, dt=step, t=grid, meta=meta)


def measured_part(phase: Phase, t: Tensor, measured_t: Sequence[float] | Tensor) -> Phase:
    """``phase`` of a resampled recording without its edge frames blended from another phase's samples.

    Each measured sample belongs to the phase of its nearest resampled frame. A resampled frame near a
    phase's edge that takes more than :data:`FOREIGN_WEIGHT` of its value from a sample of another phase
    (or of the switch between phases) is dropped: across a source's switch, linear interpolation puts
    seconds of heating into a cooling frame. A frame within a sample's jitter of its own sample is kept.

    Args:
        phase: a phase in the resampled frames' indices.
        t: the resampled frames' times in s (uniform).
        measured_t: the measured samples' times in s, increasing (``Video.meta["measured_t"]`` after
            :func:`resample_uniform`).

    Returns:
        The phase on the frames it keeps (its name; the kept frames' indices and times); no frame when
        every frame is blended.

    Shape:
        ``t`` ``(T,)``; ``measured_t`` ``(M,)``.
    """
    grid = torch.as_tensor(t, dtype=torch.float64)
    samples = torch.as_tensor(measured_t, dtype=torch.float64)
    if phase.stop <= phase.start or grid.numel() < 2 or samples.numel() < 2:
        return phase
    nearest = _nearest_frame(grid, samples)
    own = (nearest >= phase.start) & (nearest < phase.stop)
    left, right, weight = _brackets(samples, grid[phase.start : phase.stop])
    foreign = (1 - weight) * (~own[left]).double() + weight * (~own[right]).double()
    kept = torch.nonzero(foreign <= FOREIGN_WEIGHT).reshape(-1)
    if kept.numel() == 0:
        return replace(phase, stop=phase.start, t_stop=phase.t_start)
    start, stop = phase.start + int(kept[0]), phase.start + int(kept[-1]) + 1
    return replace(phase, start=start, stop=stop, t_start=float(grid[start]), t_stop=float(grid[stop - 1]))


def measured_frames(t: Tensor, measured_t: Sequence[float] | Tensor) -> Tensor:
    """Which resampled frames stand for a measured sample: the frame nearest to each sample.

    A camera's timing jitter moves every sample by a fraction of a step: each frame still has its sample.
    Frames seconds apart leave gaps: the frames interpolated inside a gap, with no sample nearer to them
    than to another frame, are not measurements, and forecasts are not scored there
    (:func:`anra_torch.forecast.assess_gain`'s ``scored``).

    Args:
        t: the resampled frames' times in s (uniform).
        measured_t: the measured samples' times in s.

    Shape:
        ``t`` ``(T,)``; ``measured_t`` ``(M,)``; output ``(T,)`` bool.
    """
    grid = torch.as_tensor(t, dtype=torch.float64)
    samples = torch.as_tensor(measured_t, dtype=torch.float64)
    out = torch.zeros(grid.shape, dtype=torch.bool)
    if grid.numel() < 2:
        return ~out
    out[_nearest_frame(grid, samples)] = True
    return out


def _brackets(samples: Tensor, times: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """For each of ``times``, the samples before and after it and the linear weight of the later one.

    Shape:
        ``samples`` ``(M,)`` increasing, ``M >= 2``; ``times`` ``(K,)``; each output ``(K,)``.
    """
    right = torch.searchsorted(samples, times, right=True).clamp(1, samples.numel() - 1)
    left = right - 1
    return left, right, ((times - samples[left]) / (samples[right] - samples[left])).clamp(0, 1)


def _nearest_frame(grid: Tensor, samples: Tensor) -> Tensor:
    """Index of the uniform ``grid``'s frame nearest to each sample (clamped to the grid).

    Shape:
        ``grid`` ``(T,)``, ``T >= 2``; ``samples`` ``(M,)``; output ``(M,)`` long.
    """
    nearest = ((samples - grid[0]) / (grid[1] - grid[0])).round().long()
    return nearest.clamp(0, grid.numel() - 1)
