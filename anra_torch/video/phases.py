"""Phase segmentation: find from the data when a local heat source is on (heating) and off (cooling).

The hot-spot signal is the mean temperature of the 3 x 3 pixels around the pixel that rises most. The
source is taken as switched off at the last frame before the steepest fall after the signal's peak that
is still within ``onset`` of the total rise from the peak (a surface under a source keeps warming or
holds a plateau until the source stops; on a noisy plateau the peak itself can come seconds before the
switch-off), and as switched on at the last frame before the peak where the rise is still below
``onset`` of the total rise. Frames before the onset form a ``baseline`` phase, frames from the onset to
the switch-off ``heating``, frames from the switch-off on ``cooling``. Shared boundary frames belong
to both phases.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from anra_torch.balance import estimate_noise_sd

__all__ = ["Phase", "hot_spot_signal", "recording_phases", "segment_phases"]


_MATERIAL = 0.2  # a change of heat content counts when it is at least this share of its range ...
_NOISE_MULTIPLE = 10.0  # ... and this many times the noise of the frame-mean signal


@dataclass(frozen=True)
class Phase:
    """A run of frames with one heating state.

    Attributes:
        name: ``"baseline"``, ``"heating"`` or ``"cooling"``.
        start: first frame (index).
        stop: one past the last frame (index).
        t_start: time of the first frame in s.
        t_stop: time of the last frame in s.
    """

    name: str
    start: int
    stop: int
    t_start: float
    t_stop: float

    @property
    def frames(self) -> int:
        """Number of frames in the phase."""
        return self.stop - self.start


def hot_spot_signal(frames: Tensor) -> tuple[Tensor, tuple[int, int]]:
    """Mean of the 3 x 3 pixels around the pixel with the largest rise over the first frame.

    Shape:
        ``(T, H, W)`` -> ``(T,)`` and the (row, column) of that pixel.
    """
    x = frames.double()
    rise = (x - x[:1]).amax(dim=0)
    rise = torch.nan_to_num(rise, nan=-torch.inf)
    row, col = divmod(int(rise.argmax()), x.shape[2])
    window = x[:, max(row - 1, 0) : row + 2, max(col - 1, 0) : col + 2]
    return torch.nanmean(window.reshape(x.shape[0], -1), dim=1), (row, col)


def segment_phases(
    frames: Tensor, t: Tensor | None = None, *, onset: float = 0.05, smooth: int = 5
) -> list[Phase]:
    """Split a video into baseline / heating / cooling phases from its own hot-spot signal.

    Args:
        frames: temperatures.
        t: timestamps in s (default the frame index).
        onset: fraction of the total rise that marks the source switching on; also the band below
            the peak within which the source still counts as on before it switches off.
        smooth: length of the running median on the signal (frames; 1 = none), against sensor noise;
            applied only to videos of at least ``10 * smooth`` frames.

    Returns:
        The phases in time order (only those with at least 2 frames).

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.

    Raises:
        ValueError: fewer than 3 frames, or a signal with no rise (nothing heats).
    """
    if frames.ndim != 3 or frames.shape[0] < 3:
        raise ValueError(f"frames must have shape (T, H, W) with T >= 3, got {tuple(frames.shape)}")
    n = frames.shape[0]
    times = torch.arange(n, dtype=torch.float64) if t is None else torch.as_tensor(t, dtype=torch.float64)
    signal, _ = hot_spot_signal(frames)
    if smooth > 1 and n >= 10 * smooth:  # a short video keeps its peak frame
        pad = smooth // 2
        padded = torch.cat([signal[:1].expand(pad), signal, signal[-1:].expand(pad)])
        signal = padded.unfold(0, smooth, 1).median(dim=1).values
    peak = int(signal.argmax())
    base = signal[0]
    total = float(signal[peak] - base)
    if not total > 0:
        raise ValueError("no heating found: the hot-spot signal never rises above its first frame")
    below = torch.nonzero(signal[: peak + 1] - base <= onset * total).reshape(-1)
    start = int(below[-1]) if below.numel() else 0
    off = _switch_off(signal, peak, onset * total)
    bounds = [("baseline", 0, start + 1), ("heating", start, off + 1), ("cooling", off, n)]
    return [Phase(name, a, b, float(times[a]), float(times[b - 1])) for name, a, b in bounds if b - a >= 2]


def _pixel_noise(frames: Tensor) -> float:
    """The sensor noise of one pixel (:func:`~anra_torch.balance.estimate_noise_sd` of at most 64
    frames): an upper bound on the noise of a frame mean, whatever the noise's correlation.

    The frame mean's noise is first measured from its steps, which is right for frames a fraction of a
    second apart; for frames 30 s apart every step is signal, and a clear heating and cooling read as one
    steady phase (``tests/test_recording.py -k 30_s_apart``).
    """
    stride = max(1, frames.shape[0] // 64)
    return float(estimate_noise_sd(frames[::stride]))


def _heat_content(frames: Tensor) -> tuple[Tensor, Tensor, float]:
    """The frames in float64 with masked samples at their frame's mean (no signal is NaN), the frame-mean
    temperature ``(T,)`` and its noise (from its steps, at most one pixel's noise: :func:`_pixel_noise`)."""
    n = frames.shape[0]
    frames = frames.double()
    finite = torch.isfinite(frames)
    if not bool(finite.all()):
        fill = torch.where(finite, frames, 0.0).sum((1, 2)) / finite.sum((1, 2)).clamp_min(1)
        frames = torch.where(finite, frames, fill[:, None, None])
    content = frames.reshape(n, -1).mean(1)
    steps = content[1:] - content[:-1]
    noise = float((steps - steps.median()).abs().median()) * 1.4826 / 2**0.5 if n > 2 else 0.0
    if n > 2 and float(content.max() - content.min()) > 0:  # frames far apart: their steps are signal
        noise = min(noise, _pixel_noise(frames))
    return frames, content, noise


def recording_phases(frames: Tensor, t: Tensor | None = None) -> list[Phase]:
    """The phases of a recording that change what acts in it: baseline, heating, cooling, or one phase.

    :func:`segment_phases` places the source's switch-on and switch-off from the hot-spot signal; a boundary
    is kept only where the data say a source really switched: heating and cooling are separate phases only
    when the frame-mean temperature (the heat content) rises over the heating by at least a fifth of its range
    and ten times its noise (measured from its steps, at most one pixel's noise: :func:`_pixel_noise`), and
    over the cooling the hot spot falls by at least a fifth of its rise while the heat content no longer rises
    materially (a hot spot passing by, as in a flow, moves heat without adding any); a baseline only when it
    is flat (its heat content changes under a tenth as fast as during the heating's fastest rise). Otherwise
    the recording is one phase, named by its heat content: ``"heating"`` (rises materially), ``"cooling"``
    (falls) or ``"steady"`` (neither: diffusion alone, or a balance of input and loss). Unlike
    :func:`segment_phases`, heating and cooling share no frame: the interval in which the source switched off
    belongs to neither. Phases shorter than :data:`MIN_PHASE_FRAMES` are returned too; non-finite samples
    count as their frame's mean.

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.
    """
    n = frames.shape[0]
    times = torch.arange(n, dtype=torch.float64) if t is None else torch.as_tensor(t, dtype=torch.float64)
    frames, content, noise = _heat_content(frames)
    steps, span = content[1:] - content[:-1], float(content.max() - content.min())

    def material(change: float) -> bool:
        return abs(change) >= _MATERIAL * span and abs(change) >= _NOISE_MULTIPLE * noise and span > 0

    def change(phase: Phase) -> float:
        return float(content[phase.stop - 1] - content[phase.start])

    try:
        found = {p.name: p for p in segment_phases(frames, times)}
    except ValueError:  # nothing rises: one phase
        found = {}
    heating, cooling, baseline = found.get("heating"), found.get("cooling"), found.get("baseline")
    split = heating is not None and cooling is not None and change(heating) > 0 and material(change(heating))
    if split:  # the source is off: the hot spot falls materially while the heat content no longer rises
        assert heating is not None and cooling is not None
        spot, _ = hot_spot_signal(frames)
        rise = float(spot[heating.stop - 1] - spot[heating.start])
        fall = float(spot[cooling.start] - spot[cooling.stop - 1])
        split = fall >= _MATERIAL * rise and not (change(cooling) > 0 and material(change(cooling)))
    if not split:
        whole = change(Phase("whole", 0, n, 0.0, 0.0))
        kind = ("heating" if whole > 0 else "cooling") if material(whole) else "steady"
        return [Phase(kind, 0, n, float(times[0]), float(times[-1]))]
    assert heating is not None and cooling is not None
    # The interval in which the source switched off belongs to neither phase: cooling starts at the first
    # frame after the heating's last (no cooling interval holds seconds of heating).
    cooling = Phase("cooling", heating.stop, cooling.stop, float(times[heating.stop]), cooling.t_stop)
    phases = [heating, cooling]
    # The heating's fastest rise (a 5-frame running mean of the content's steps, against noise).
    rates = steps[heating.start : heating.stop - 1]
    fastest = float(rates.unfold(0, min(5, rates.numel()), 1).mean(1).max()) if rates.numel() else 0.0
    flat = baseline is not None and abs(change(baseline)) / max(baseline.frames - 1, 1) < 0.1 * fastest
    if flat:
        phases.insert(0, baseline)
    else:  # a rise from the first frame on: the heating phase starts there
        phases[0] = Phase("heating", 0, heating.stop, float(times[0]), heating.t_stop)
    return phases


def _switch_off(signal: Tensor, peak: int, band: float) -> int:
    """The last frame, up to the steepest fall after ``peak``, still within ``band`` of the peak value."""
    step = signal[1:] - signal[:-1]  # step[i]: from frame i to i + 1
    if peak >= step.numel() or not bool((step[peak:] < 0).any()):
        return peak
    fall = peak + int(step[peak:].argmin())
    near = torch.nonzero(signal[peak : fall + 1] >= signal[peak] - band).reshape(-1)
    return peak + int(near[-1])
