"""Camera artefacts found in the video itself: repaired or neutralised before the balance, never named as
effects.

Real infrared cameras add more than white noise. What is found here, and what is done about it:

==========================  ====================================================  ==========================
artefact                    how it is found                                        what is done
==========================  ====================================================  ==========================
non-finite samples          ``isfinite``                                          replaced (below), counted
dead and hot elements       a pixel constant in time while the scene changes, or  replaced by the median of
                            whose time mean is far from the quadratic through its  its good neighbours
                            24 neighbours (an isolated impulse)
single-sample spikes        a sample far from the median of its five-frame         replaced by that median
                            window, unlike its neighbours in space
static fixed pattern        spatial fourth differences of the time-mean frame     per-pixel fixed effects in
                            far above what the temporal noise leaves in it         the balance (exact); its
                                                                                   parts measured and stated
global offset steps, drift  jumps in the frames' median change                    per-frame fixed effects in
                                                                                   the balance (exact)
==========================  ====================================================  ==========================

A static pattern and a global offset (a recalibration step, a drift) are removed exactly, whatever their
size, by per-pixel and per-frame fixed effects in every term of the balance, each only when found, so a
clean video is analysed exactly as before. A source held still over the whole video is removed with a
pattern. In a video shorter than :data:`PIXEL_EFFECTS_FRAMES` the pattern's measured parts
(:func:`~anra_torch.balance.measure_noise`) are the noise model's static part instead. Why, and what
was measured: ``docs/results/artefacts.md``.

The thresholds are robust z-scores against the median absolute deviation of the same statistic over the
whole video (:data:`OUTLIER_Z`), far above what Gaussian noise reaches in a camera-sized video.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance.robust import (
    PixelStats,
    pixel_stats,
    robust_sd,
    row_medians,
    sampled_fourth_difference,
)

__all__ = ["OUTLIER_Z", "PIXEL_EFFECTS_FRAMES", "RESOLUTION", "Artefacts", "find_artefacts", "stuck_pixels"]

OUTLIER_Z = 12.0
"""Robust z-score above which a sample, a pixel or a frame step is an artefact (the largest of 10^7
Gaussian samples is at about 5.3)."""

RESOLUTION = 1e-3
"""Smallest artefact looked for, as a fraction of the video's range: below it an artefact cannot matter to
the balance, and a noiseless video (whose only "noise" is rounding) finds nothing in its own curvature."""

PIXEL_EFFECTS_FRAMES = 20
"""Fewest frames for per-pixel fixed effects: in a shorter video (a phase of a few frames, a split inside
one) each pixel's own changes carry too little of the balance, and a fixed pattern is measured as the
noise's static part instead."""

_MAX_STUCK_FRACTION = 0.01  # more constant pixels than this is a static region, not dead elements
_PATTERN_RATIO = 4.0  # static spatial roughness over what the temporal noise leaves: a fixed pattern


@dataclass(frozen=True)
class Artefacts:
    """What :func:`find_artefacts` found in one video and what was done.

    Attributes:
        bad_pixels: ``(row, column)`` of dead or hot elements, replaced by their neighbours' median.
        spikes: number of single samples replaced by their neighbourhood's median.
        non_finite: number of non-finite samples replaced.
        fixed_pattern: whether a static pattern was found (per-pixel fixed effects; the noise model
            measures its parts).
        pattern_sd: its standard deviation estimated from the time-median frame in data units.
        steps: frames (index of the later frame) where the whole frame jumped (per-frame fixed effects).
        step_sizes: the jumps in data units.
        global_offsets: whether per-frame fixed effects are used (steps found).
        pixel_effects: whether per-pixel fixed effects are used (a fixed pattern in a video of at least
            :data:`PIXEL_EFFECTS_FRAMES` frames).
    """

    bad_pixels: tuple[tuple[int, int], ...] = ()
    spikes: int = 0
    non_finite: int = 0
    fixed_pattern: bool = False
    pattern_sd: float = 0.0
    steps: tuple[int, ...] = ()
    step_sizes: tuple[float, ...] = ()
    global_offsets: bool = False
    notes: tuple[str, ...] = field(default=())
    pixel_effects: bool = False

    @property
    def any(self) -> bool:
        """Whether anything was found."""
        return bool(self.bad_pixels or self.spikes or self.non_finite or self.fixed_pattern or self.steps)

    @property
    def within(self) -> tuple[str, ...]:
        """The fixed effects the balance must use: ``"pixel"`` with a fixed pattern (in a video of at least
        :data:`PIXEL_EFFECTS_FRAMES` frames), ``"frame"`` after offset steps (none for a clean video)."""
        return ("pixel",) * self.pixel_effects + ("frame",) * self.global_offsets

    def to_record(self) -> dict:
        """The JSON ``"artefacts"`` object."""
        return {
            "bad_pixels": [list(p) for p in self.bad_pixels],
            "spikes": self.spikes,
            "non_finite": self.non_finite,
            "fixed_pattern": self.fixed_pattern,
            "pattern_sd": self.pattern_sd,
            "steps": list(self.steps),
            "step_sizes": list(self.step_sizes),
            "fixed_effects": list(self.within),
        }


def _neighbour_median(image: Tensor, good: Tensor) -> Tensor:
    """Median of the good pixels among each pixel's 8 neighbours (NaN where none is good).

    Shape:
        ``image`` ``(..., H, W)``; ``good`` ``(H, W)``; output like ``image``.
    """
    lead, (h, w) = image.shape[:-2], image.shape[-2:]
    values = torch.where(good, image, torch.full_like(image, torch.nan)).reshape(-1, 1, h, w)
    patches = F.unfold(F.pad(values, (1, 1, 1, 1), value=torch.nan), 3)  # (N, 9, H W)
    patches = torch.cat([patches[:, :4], patches[:, 5:]], 1)  # without the centre
    return patches.nanmedian(1).values.reshape(*lead, h, w)


def _bad_pixels(frames: Tensor, finite: Tensor | None, floor: float = 0.0) -> Tensor:
    """Dead (constant while the scene changes, or never finite) and hot (an isolated impulse in the
    time-mean frame) elements, ``(H, W)`` bool.

    ``frames`` must be free of spikes (they would move a pixel's mean); ``finite`` None: all finite.
    """
    t = frames.shape[0]
    if finite is None or bool(finite.all()):  # the usual case: no masked copies of the video
        never = torch.zeros(frames.shape[1:], dtype=torch.bool, device=frames.device)
        low, high = frames.amin(0), frames.amax(0)  # two reductions: 10x faster than aminmax(dim=0)
        constant = high == low
        mean = frames.sum(0) / t
    else:
        never = ~finite.any(0)
        high = torch.where(finite, frames, -torch.inf).amax(0)
        low = torch.where(finite, frames, torch.inf).amin(0)
        constant = (high == low) & finite.all(0)
        mean = torch.where(finite, frames, 0.0).sum(0) / finite.sum(0).clamp_min(1)
    if float(constant.float().mean()) > _MAX_STUCK_FRACTION or t < 3:
        constant = torch.zeros_like(constant)
    good = ~(never | constant)
    if not bool(good.all()):
        mean = torch.where(good, mean, _neighbour_median(mean, good).nan_to_num(float(mean[good].mean())))
    # An isolated impulse: far from the quadratic that its 24 neighbours fit (a smooth field, even at a
    # sharp peak, is close to it), by more than half its neighbourhood's range (the neighbours of an
    # impulse are pulled by it, but their range holds it).
    padded = F.pad(mean[None, None], (2, 2, 2, 2), mode="replicate")
    excess = mean - F.conv2d(padded, _QUADRATIC_PREDICTOR.to(mean)[None, None])[0, 0]
    scale = robust_sd(excess[good], sample=None)
    big = excess.abs() > max(OUTLIER_Z * scale, floor)
    if bool(big.any()):  # the neighbourhoods' ranges of the few candidates only
        rows, cols = big.nonzero(as_tuple=True)
        five = torch.arange(5, device=mean.device)
        patches = padded[0, 0][(rows[:, None] + five)[:, :, None], (cols[:, None] + five)[:, None, :]]
        patches = torch.cat([patches.reshape(-1, 25)[:, :12], patches.reshape(-1, 25)[:, 13:]], 1)
        spread = torch.zeros_like(mean)
        spread[rows, cols] = patches.amax(1) - patches.amin(1)
        big = big & (excess.abs() > 0.5 * spread)
    hot = big if scale > 0 else ~good
    return never | constant | (hot & good)


def _quadratic_predictor() -> Tensor:
    """5 x 5 weights (zero centre) of the least-squares quadratic through the 24 neighbours, at the centre."""
    offsets = [(i, j) for i in range(-2, 3) for j in range(-2, 3) if (i, j) != (0, 0)]
    design = torch.tensor(
        [[1, j, i, j * j, i * j, i * i] for i, j in offsets], dtype=torch.float64, device="cpu"
    )
    weights = torch.linalg.pinv(design)[0]
    kernel = torch.zeros(5, 5, dtype=torch.float64, device="cpu")
    for (i, j), w in zip(offsets, weights, strict=True):
        kernel[i + 2, j + 2] = w
    return kernel


_QUADRATIC_PREDICTOR = _quadratic_predictor()


def _repair_pixels(frames: Tensor, bad: Tensor) -> Tensor:
    """Bad pixels replaced, frame by frame, by the median of their good neighbours (repeated outward)."""
    if not bool(bad.any()):  # nothing to replace: the frames as they are
        return frames
    out = frames.clone()
    good = ~bad
    for _ in range(4):  # a cluster of bad pixels fills from its rim inwards
        if bool(good.all()):
            break
        fill = _neighbour_median(out, good)
        reachable = ~good & torch.isfinite(fill).all(0)
        out = torch.where(reachable, fill, out)
        good = good | reachable
    return torch.where(good, out, out.nanmean() if bool(torch.isfinite(out).any()) else 0.0)


def _floor(frames: Tensor, *, sample: int = 50_000) -> float:
    """:data:`RESOLUTION` times the range between the 0.1 and 99.9 percentiles of the finite values."""
    flat = frames.reshape(-1)
    flat = flat[:: max(1, flat.numel() // sample)]
    flat = flat[torch.isfinite(flat)].double()
    if flat.numel() < 2:
        return 0.0
    return RESOLUTION * (_quantile(flat, 0.999) - _quantile(flat, 0.001))


def _quantile(flat: Tensor, q: float) -> float:
    """``torch.quantile(flat, q)`` (linear interpolation) by selection instead of a full sort."""
    position = q * (flat.numel() - 1)
    below = int(position)
    values = flat.detach().cpu().numpy()
    ranks = [below, below + 1] if below + 1 < values.shape[0] else [below]
    chosen = np.partition(values, ranks)[ranks]
    if len(ranks) == 1:
        return float(chosen[0])
    return float(chosen[0]) + (position - below) * (float(chosen[1]) - float(chosen[0]))


def _spikes(frames: Tensor, floor: float = 0.0) -> tuple[Tensor, Tensor]:
    """Single-sample spikes: their indices ``(N, 3)`` and the values without them ``(N,)``.

    Candidates are samples whose second difference in time is far above its robust scale (a spike
    leaves itself there; a smooth history its curvature); a candidate is a spike if it is also far from
    the median of its five-frame window and unlike its neighbours in space (a fast but real change is
    shared by the neighbouring pixels). Only the candidates are examined closely, so the cost is a few
    passes over the video.
    """
    t, h, w = frames.shape
    none = torch.zeros(0, 3, dtype=torch.long, device=frames.device), frames.new_zeros(0)
    if t < 5:
        return none
    second = torch.add(frames[:-2], frames[2:]).mul_(-0.5).add_(frames[1:-1])  # one temporary
    scale = robust_sd(second, nonzero=True)
    if scale == 0:
        return none
    threshold = max(OUTLIER_Z * scale, floor)
    if not float(torch.linalg.vector_norm(second, ord=float("inf"))) > threshold:
        return none  # the usual case, told by one pass: no sample is a candidate
    over = second.abs() > threshold
    flagged = over.nonzero()
    if flagged.numel() == 0:
        return none
    # A single-sample spike is alone: no neighbour in the same frame is flagged (a moving edge or a fast
    # peak flags its neighbours too). Counted at the flagged samples only: they are few.
    marks = F.pad(over, (1, 1, 1, 1))
    k0, i0, j0 = flagged.unbind(1)
    crowd = sum(marks[k0, i0 + di, j0 + dj].long() for di in range(3) for dj in range(3))
    candidates = flagged[crowd == 1]
    if candidates.numel() == 0:
        return none
    k, i, j = candidates[:, 0] + 1, candidates[:, 1], candidates[:, 2]
    window = torch.stack([frames[(k + d).clamp(0, t - 1), i, j] for d in (-2, -1, 1, 2)], 1)
    without = window.median(1).values
    # Unlike its neighbours in space: its second difference departs from the quadratic through its 24
    # neighbours' (a smooth field's second differences are smooth too, even at a sharp, fast-changing
    # peak), by most of its own size.
    padded = F.pad(second[:, None], (2, 2, 2, 2), mode="replicate")[:, 0]
    five = torch.arange(5, device=frames.device)
    rows, cols = i[:, None] + five, j[:, None] + five
    patch = padded[(k - 1)[:, None, None], rows[:, :, None], cols[:, None, :]]  # (N, 5, 5)
    own = patch[:, 2, 2]
    isolated = (own - (patch * _QUADRATIC_PREDICTOR.to(frames.dtype)).sum((1, 2))).abs()
    isolated = torch.where(isolated > 0.5 * own.abs(), isolated, torch.zeros_like(isolated))
    jump = (frames[k, i, j] - without).abs()
    spike = (jump > threshold) & (isolated > threshold)
    return torch.stack([k, i, j], 1)[spike], without[spike]


def _fixed_pattern(frames: Tensor, floor: float = 0.0, stats: PixelStats | None = None) -> tuple[bool, float]:
    """Whether the time-mean frame is spatially rough compared with a single frame's deviation from it
    (a static pattern), and the pattern's sd in data units.

    Spatial fourth differences remove the smooth thermal field; what is left in the time-mean frame is
    the static pattern plus the temporal noise averaged over the frames (at most about ``sqrt(pi / 2)``
    of one frame's, when the noise is correlated over many frames; ``sqrt(pi / 2T)`` for white noise).
    ``stats``: the frames' :class:`~anra_torch.balance.robust.PixelStats` when the caller has them.
    """
    t = frames.shape[0]
    if t < 5 or min(frames.shape[1:]) < 5:
        return False, 0.0
    # Over the quieter half of the pixels: a camera's pattern covers the whole sensor, while the static
    # structure of the scene (a heated spot, a source) sits where the temperature changes.
    stats = pixel_stats(frames) if stats is None else stats
    mean, quiet = stats.mean, stats.quiet

    def roughness(x: Tensor) -> float:
        axes = []
        for d in (-2, -1):  # the differences at the sampled quiet pixels only
            centre = quiet.narrow(d, 2, x.shape[d] - 4)
            axes.append(robust_sd(sampled_fourth_difference(x, d, where=centre), sample=None))
        return float(torch.tensor(axes, device="cpu").median()) / 70**0.5

    static, moving = roughness(mean), roughness(frames[:: max(1, t // 16)] - mean)
    found = static > _PATTERN_RATIO * moving * (torch.pi / (2 * t)) ** 0.5 and static > 0.85 * moving
    found = found and static > floor and moving > 1e-3 * floor  # a static video: no temporal noise
    return found, static


def _steps(frames: Tensor, floor: float = 0.0) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """Frames where the whole frame jumps: outliers of the frames' median change against its local trend."""
    t = frames.shape[0]
    if t < 8:
        return (), ()
    stride = max(1, math.ceil((frames[0].numel() / 20_000) ** 0.5 - 1e-9))  # 20,000 pixels or fewer
    sub = frames[:, ::stride, ::stride]
    change = row_medians((sub[1:] - sub[:-1]).flatten(1))  # (T - 1,)
    padded = F.pad(change[None, None], (3, 3), mode="replicate")[0, 0]
    trend = padded.unfold(0, 7, 1).median(-1).values
    jump = change - trend
    scale = robust_sd(jump, sample=None)
    noise = robust_sd(sampled_fourth_difference(sub, 0), sample=None) / 70**0.5 / sub[0].numel() ** 0.5
    threshold = max(OUTLIER_Z * max(scale, noise), floor)
    index = (jump.abs() > threshold).nonzero().flatten().tolist()
    return tuple(k + 1 for k in index), tuple(float(jump[k]) for k in index)


def find_artefacts(frames: Tensor, *, stats: PixelStats | None = None) -> tuple[Tensor, Artefacts]:
    """Find the camera artefacts of one video, repair what can be repaired, and say what was done.

    Args:
        frames: temperatures ``(T, H, W)`` (any real dtype; computed in the frames' floating dtype).
        stats: the frames' :class:`~anra_torch.balance.robust.PixelStats`, where the caller has them
            (:func:`~anra_torch.balance.robust.pixel_stats`; used while nothing is repaired).

    Returns:
        The repaired frames (non-finite samples, dead and hot elements and spikes replaced; finite
        everywhere; ``frames`` itself, not a copy, where nothing was repaired) and :class:`Artefacts`
        (with the fixed effects the balance must use).

    Shape:
        ``frames`` ``(T, H, W)``; output the same.
    """
    video = frames if frames.is_floating_point() else frames.double()
    # One sum tells a video without non-finite samples (inf and NaN carry through it): no masks then.
    everywhere = bool(torch.isfinite(video.sum()))
    finite = None if everywhere else torch.isfinite(video)
    non_finite = 0 if finite is None else int((~finite).sum())
    repaired = torch.where(finite, video, torch.nan) if non_finite else video  # copied where changed
    floor = _floor(video)
    spike_at, without = _spikes(torch.where(finite, video, 0.0) if non_finite else video, floor)
    if finite is not None:
        keep = finite[spike_at[:, 0], spike_at[:, 1], spike_at[:, 2]]
        spike_at, without = spike_at[keep], without[keep]
    if spike_at.shape[0]:
        repaired = repaired.clone() if repaired is video else repaired
        repaired[spike_at[:, 0], spike_at[:, 1], spike_at[:, 2]] = without
    bad = _bad_pixels(repaired, torch.isfinite(repaired) if non_finite else None, floor)
    repaired = _repair_pixels(repaired, bad)
    # Samples still non-finite in good pixels: their pixel's mean.
    holes = None if everywhere else ~torch.isfinite(repaired)
    if holes is not None and bool(holes.any()):
        local = repaired.nanmean(0, keepdim=True).expand_as(repaired)
        repaired = torch.where(holes, local, repaired).nan_to_num(float(repaired.nanmean()))
    pattern, pattern_sd = _fixed_pattern(repaired, floor, stats if repaired is frames else None)
    steps, sizes = _steps(repaired, floor)
    rows, cols = bad.nonzero(as_tuple=True)
    found = Artefacts(
        bad_pixels=tuple(zip(rows.tolist(), cols.tolist(), strict=True)),
        spikes=len(spike_at),
        non_finite=non_finite,
        fixed_pattern=pattern,
        pattern_sd=pattern_sd if pattern else 0.0,
        steps=steps,
        step_sizes=sizes,
        global_offsets=bool(steps),
        pixel_effects=pattern and video.shape[0] >= PIXEL_EFFECTS_FRAMES,
    )
    return repaired, found


def stuck_pixels(video: Tensor, finite: Tensor | None) -> Tensor:
    """Dead elements: finite pixels constant in time while the rest of the frame changes, ``(B, T, H, W)``.

    A real scene seen through sensor noise never holds a pixel exactly constant; a few such pixels are
    dead or saturated elements whose Laplacian spikes would otherwise dominate the fit. Many constant
    pixels (a noiseless static background) are left alone. ``finite`` None: every sample is finite.
    """
    if finite is None:
        detached = video.detach()
        low, high = detached.amin(1), detached.amax(1)
        constant = high == low
    else:
        big = torch.finfo(video.dtype).max
        high = torch.where(finite, video, torch.full_like(video, -big)).amax(1)
        low = torch.where(finite, video, torch.full_like(video, big)).amin(1)
        constant = (high == low) & finite.all(1)  # (B, H, W)
    fraction = constant.flatten(1).float().mean(1)
    dead = constant & (fraction <= _MAX_STUCK_FRACTION).view(-1, 1, 1)
    return dead.unsqueeze(1).expand_as(video)
