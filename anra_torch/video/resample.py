"""Resampling a video with non-uniform timestamps onto a uniform time grid.

The estimator and the diagnosis assume one frame period. Hand-triggered cameras do not keep one (the
FLIR C3-X recordings here step 4-6 s; other cameras are triggered 5-60 s apart). :func:`resample_uniform`
makes the choice explicit: frames are interpolated in time onto ``t0, t0 + dt, ...`` (never past the last
measured frame), by a cubic through the samples whose slopes use their real timestamps, within each phase
of the recording, and the returned video says what it was resampled from in ``meta["resampled"]``. A
resampled frame between two samples of different phases blends them: across a source's switch it mixes
heating and cooling, so :func:`measured_part` keeps a phase on the frames interpolated from its own
samples only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import Tensor

from anra_torch.video.core import Video
from anra_torch.video.phases import Phase, hot_spot_signal, recording_phases

__all__ = ["FOREIGN_WEIGHT", "measured_frames", "measured_part", "resample_uniform"]

FOREIGN_WEIGHT = 0.1
"""The most a phase's resampled frame may take from another phase's samples (a timing jitter's blend)."""


def resample_uniform(video: Video, dt: float | None = None, *, method: str = "cubic") -> Video:
    """Interpolate ``video`` in time onto a uniform grid of step ``dt`` (s).

    ``"cubic"`` (default): within each phase (:func:`~anra_torch.video.phases.recording_phases` of the
    linear interpolant), a cubic Hermite curve through the samples whose slope at each sample is the
    derivative of the parabola through it and its neighbours at their real times (non-uniform three-point
    weights; one-sided at a phase's ends). Between two samples seconds apart a diffusing field is convex
    in time, and a straight line between them is biased: on frames 5-60 s apart the cooling diffusivity
    came out 1.3 % low and a loss was named; the cubic gives the value of frames simulated on the grid
    itself. Across a phase switch (a kink in time) and next to a masked sample the interpolation is
    linear. ``"linear"``: linear interpolation throughout.

    Args:
        video: a video with timestamps ``t`` (strictly increasing, s).
        dt: the new frame period in s; default the median measured step.
        method: ``"cubic"`` or ``"linear"``.

    Returns:
        A video with float64 frames on ``t = t0 + k dt`` (``k = 0 .. floor((t_end - t0) / dt)``), the same
        ``dx``, and ``meta["resampled"]`` = ``{"from_frames", "step_min", "step_max", "dt", "method"}``
        (steps in s). A video that is already uniform (or has no timestamps) is returned unchanged.

    Shape:
        ``video.frames`` ``(T, H, W)`` -> ``(T', H, W)``.

    Raises:
        ValueError: non-positive ``dt``, an unknown ``method``, or a new grid of fewer than 2 frames.
    """
    if method not in _METHODS:
        raise ValueError(f"method must be one of {', '.join(_METHODS)}, got {method!r}")
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

    def interpolate(frames: Tensor) -> Tensor:
        line = _linear(t, frames.double(), grid)
        if method == "linear" or t.numel() < 3:
            return line
        runs = _sample_phases(t, grid, line)
        return _cubic(t, frames.double(), grid, runs, line)

    meta = dict(video.meta)
    meta["resampled"] = {
        "from_frames": int(t.numel()),
        "step_min": float(steps.min()),
        "step_max": float(steps.max()),
        "dt": step,
        "method": _METHODS[method],
    }
    meta["dt_source"] = "resampled"
    meta["measured_t"] = tuple(float(x) for x in t)  # for :func:`measured_part`, not for the JSON
    return video.map_frames(interpolate, dt=step, t=grid, meta=meta)


_METHODS = {
    "cubic": "cubic Hermite in time within each phase (slopes from the real timestamps), linear across "
    "a phase switch",
    "linear": "linear interpolation in time",
}


def _linear(t: Tensor, frames: Tensor, grid: Tensor) -> Tensor:
    """Linear interpolation of the samples onto ``grid``; on a sample's own time the other side has no
    weight, so a masked (NaN) neighbour stays out.

    Shape:
        ``t`` ``(M,)``; ``frames`` ``(M, H, W)``; ``grid`` ``(K,)``; output ``(K, H, W)``.
    """
    left, right, weight = _brackets(t, grid)
    weight = weight.view(-1, 1, 1)
    blend = (1 - weight) * frames[left] + weight * frames[right]
    return torch.where(weight == 0, frames[left], torch.where(weight == 1, frames[right], blend))


def _sample_phases(t: Tensor, grid: Tensor, line: Tensor) -> Tensor:
    """Each sample's run: its phase (:func:`recording_phases` of the linear interpolant), by the phase of its
    nearest grid frame, split after the hot spot's peak sample (a source switched off between two samples
    puts the peak in the last sample before it; the phases may keep a sample within their onset band after
    it); a sample in no phase (the switch interval) is a run of its own.

    Shape:
        ``t`` ``(M,)``; output ``(M,)`` long.
    """
    nearest = _nearest_frame(grid, t)
    labels = torch.arange(t.numel()) + 2 * len(grid)  # unique: a sample in no phase is a run of its own
    try:
        phases = recording_phases(line, grid) if line.shape[0] >= 3 else []
    except ValueError:
        phases = []
    for index, phase in enumerate(phases):
        labels = torch.where((nearest >= phase.start) & (nearest < phase.stop), 2 * index, labels)
    spot, _ = hot_spot_signal(line)
    peak = int(torch.nan_to_num(spot[nearest], nan=-torch.inf).argmax())
    return labels + (torch.arange(t.numel()) > peak).long()


def _cubic(t: Tensor, frames: Tensor, grid: Tensor, runs: Tensor, line: Tensor) -> Tensor:
    """Cubic Hermite interpolation within runs of samples of one phase (``runs``: a label per sample);
    linear (``line``) across runs and wherever the cubic is not finite.

    The slope at a sample is the derivative of the parabola through it and its two neighbours of the same
    run: ``w s_right + (1 - w) s_left`` with ``w = h_left / (h_left + h_right)`` (``s`` the secants, ``h``
    the steps); at a run's end the parabola through its last three samples, evaluated there; a run of two
    samples: the secant.

    Shape:
        ``t`` ``(M,)``; ``frames`` ``(M, H, W)``; ``grid`` ``(K,)``; ``runs`` ``(M,)``; ``line`` and the
        output ``(K, H, W)``.
    """
    h = torch.diff(t)
    secant = (frames[1:] - frames[:-1]) / h.view(-1, 1, 1)  # (M - 1, H, W)
    same = runs[1:] == runs[:-1]  # interval i lies inside one run
    zero = torch.zeros_like(frames[:1])
    # Per sample: the secants and steps on each side (0 where there is no interval of the same run).
    s_left, s_right = torch.cat([zero, secant]), torch.cat([secant, zero])
    h_left, h_right = torch.cat([h[:1], h]), torch.cat([h, h[-1:]])
    left_in = torch.cat([torch.tensor([False]), same])
    right_in = torch.cat([same, torch.tensor([False])])
    w = (h_left / (h_left + h_right)).view(-1, 1, 1)
    centred = w * s_right + (1 - w) * s_left
    # One-sided: the parabola through the run's last (first) three samples, at the end sample.
    s_left2, h_left2 = torch.cat([zero, zero, secant[:-1]]), torch.cat([h[:1], h[:1], h[:-1]])
    s_right2, h_right2 = torch.cat([secant[1:], zero, zero]), torch.cat([h[1:], h[-1:], h[-1:]])
    left2_in = torch.cat([torch.tensor([False, False]), same[:-1]]) & left_in
    right2_in = torch.cat([same[1:], torch.tensor([False, False])]) & right_in
    end_right = s_left + (h_left / (h_left + h_left2)).view(-1, 1, 1) * (s_left - s_left2)
    end_left = s_right - (h_right / (h_right + h_right2)).view(-1, 1, 1) * (s_right2 - s_right)

    def pick(mask: Tensor, a: Tensor, b: Tensor) -> Tensor:
        return torch.where(mask.view(-1, 1, 1), a, b)

    slope = pick(
        left_in & right_in,
        centred,
        pick(left_in, pick(left2_in, end_right, s_left), pick(right2_in, end_left, s_right)),
    )
    left, right, u = _brackets(t, grid)
    step, u = h[left].view(-1, 1, 1), u.view(-1, 1, 1)
    cubic = (
        (2 * u**3 - 3 * u**2 + 1) * frames[left]
        + (u**3 - 2 * u**2 + u) * step * slope[left]
        + (3 * u**2 - 2 * u**3) * frames[right]
        + (u**3 - u**2) * step * slope[right]
    )
    inside = same[left].view(-1, 1, 1) & (u > 0) & (u < 1)
    return torch.where(inside & torch.isfinite(cubic), cubic, line)


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
