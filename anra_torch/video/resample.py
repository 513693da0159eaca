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

__all__ = [
    "FOREIGN_WEIGHT",
    "MAX_FRAMES_PER_SAMPLE",
    "default_step",
    "measured_frames",
    "measured_part",
    "resample_uniform",
]

FOREIGN_WEIGHT = 0.1
"""The most a phase's resampled frame may take from another phase's samples (a timing jitter's blend)."""


def resample_uniform(video: Video, dt: float | None = None, *, method: str = "cubic") -> Video:
    """Interpolate ``video`` in time onto a uniform grid of step ``dt`` in s.

    ``"cubic"`` (default): within each phase (:func:`~anra_torch.video.recording_phases` of the
    linear interpolant), a cubic Hermite curve through the samples whose slope at each sample is the
    derivative of the parabola through it and its neighbours at their real times; linear across a phase
    switch, after a heating's peak sample and next to a masked sample (why: ``docs/results/sparse.md``).
    ``"linear"``: linear interpolation throughout.

    Args:
        video: a video with timestamps ``t`` (strictly increasing, s).
        dt: the new frame period in s; default :func:`default_step`: the median measured step when every
            sample keeps a frame of its own there, else a finer step.
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
    step = default_step(t) if dt is None else float(dt)
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


MAX_FRAMES_PER_SAMPLE = 8
"""The most frames per measured sample :func:`default_step` makes (a burst of close samples in a slow
recording would otherwise make thousands)."""


def default_step(t: Tensor) -> float:
    """The resampling step in s for timestamps ``t``: the median step, if every sample then falls nearest to
    a frame of its own (a camera's jitter around one period); otherwise the smallest step, but no finer
    than :data:`MAX_FRAMES_PER_SAMPLE` frames per sample.

    A hand-triggered camera samples densely while the scene changes fast (0, 5, 15, 20, 30, 60, 90 s ...):
    at the median step several early samples share a frame and only one is kept, and phases of 4-6 frames
    are too short to analyse. At the smallest step every sample keeps its frame; the frames between
    samples are interpolated and never scored (:func:`measured_frames`).

    Shape:
        ``t`` ``(T,)``, increasing, ``T >= 2``.
    """
    t = torch.as_tensor(t, dtype=torch.float64)
    steps = torch.diff(t)
    median = float(steps.median())
    frames = ((t - t[0]) / median).round()
    if bool((torch.diff(frames) > 0).all()):
        return median
    span = float(t[-1] - t[0])
    return max(float(steps.min()), span / (MAX_FRAMES_PER_SAMPLE * t.numel()))


_TINY = 1e-300  # s: a step that is never reached by increasing timestamps (guards a run of one sample)

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
    nearest grid frame; a heating phase followed by another is split after the hot spot's peak sample (a
    source switched off between two samples puts the peak in the last sample before it, and the heating
    may keep a sample within its onset band after it); a sample in no phase (the switch interval) is a run
    of its own.

    Shape:
        ``t`` ``(M,)``; output ``(M,)`` long.
    """
    nearest = _nearest_frame(grid, t)
    labels = torch.arange(t.numel()) + 2 * len(grid)  # unique: a sample in no phase is a run of its own
    try:
        phases = recording_phases(line, grid) if line.shape[0] >= 3 else []
    except ValueError:
        phases = []
    heating = torch.zeros(t.numel(), dtype=torch.bool)
    for index, phase in enumerate(phases):
        inside = (nearest >= phase.start) & (nearest < phase.stop)
        labels = torch.where(inside, 2 * index, labels)
        heating |= inside & (phase.name == "heating") & (len(phases) > 1)
    spot, _ = hot_spot_signal(line)
    peak = int(torch.nan_to_num(spot[nearest], nan=-torch.inf).argmax())
    if not bool(heating[peak]):  # no switch-off to keep out of a run
        return labels
    return labels + (torch.arange(t.numel()) > peak).long()


def _cubic(t: Tensor, frames: Tensor, grid: Tensor, runs: Tensor, line: Tensor) -> Tensor:
    """Cubic Hermite interpolation within runs of samples of one phase (``runs``: a label per sample);
    linear (``line``) across runs and wherever the cubic is not finite.

    Shape:
        ``t`` ``(M,)``; ``frames`` ``(M, H, W)``; ``grid`` ``(K,)``; ``runs`` ``(M,)``; ``line`` and the
        output ``(K, H, W)``.
    """
    slope = _slopes(t, frames, runs)
    same = runs[1:] == runs[:-1]  # interval i lies inside one run
    left, right, u = _brackets(t, grid)
    step, u = (t[right] - t[left]).view(-1, 1, 1), u.view(-1, 1, 1)
    cubic = (
        (2 * u**3 - 3 * u**2 + 1) * frames[left]
        + (u**3 - 2 * u**2 + u) * step * slope[left]
        + (3 * u**2 - 2 * u**3) * frames[right]
        + (u**3 - u**2) * step * slope[right]
    )
    inside = same[left].view(-1, 1, 1) & (u > 0) & (u < 1)
    return torch.where(inside & torch.isfinite(cubic), cubic, line)


def _slopes(t: Tensor, frames: Tensor, runs: Tensor) -> Tensor:
    """dT/dt at each sample: the derivative there of the parabola through three samples of its run at their
    real times (it and its neighbours; its run's first or last three at a run's end), in Newton's form
    ``f[i0, i1] + f[i0, i1, i2] ((t - t_i0) + (t - t_i1))``; the secant in a run of two samples.

    Shape:
        ``t`` ``(M,)``; ``frames`` ``(M, H, W)``; ``runs`` ``(M,)`` (contiguous labels); output ``(M, H, W)``.
    """
    index = torch.arange(t.numel())
    new_run = torch.cat([torch.tensor([True]), runs[1:] != runs[:-1]])
    first = torch.cummax(torch.where(new_run, index, 0), 0).values
    run_end = torch.cat([runs[1:] != runs[:-1], torch.tensor([True])])
    last = torch.flip(torch.cummin(torch.flip(torch.where(run_end, index, t.numel()), (0,)), 0).values, (0,))
    i0 = torch.minimum(torch.maximum(index - 1, first), (last - 2).clamp_min(first))
    i1, i2 = (i0 + 1).clamp_max(last), (i0 + 2).clamp_max(last)

    def divided(a: Tensor, b: Tensor) -> Tensor:  # a == b only in a run of one sample: its slope is unused
        return (frames[b] - frames[a]) / (t[b] - t[a]).clamp_min(_TINY).view(-1, 1, 1)

    first_order = divided(i0, i1)
    spread = (t[i2] - t[i0]).clamp_min(_TINY).view(-1, 1, 1)
    second_order = torch.where((i2 > i1).view(-1, 1, 1), (divided(i1, i2) - first_order) / spread, 0.0)
    offset = ((t - t[i0]) + (t - t[i1])).view(-1, 1, 1)
    return first_order + second_order * offset


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
