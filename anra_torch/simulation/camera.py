"""What real infrared cameras add to a thermal video, planted with a record of what was planted.

A simulated video carries white noise only; a microbolometer or photon-counting camera adds more. Each
planter here takes a video ``(T, H, W)`` and returns a new one with one kind of artefact and a JSON-ready
record of exactly what it put where (the artefacts' truth), so that a diagnosis can be tested on videos
with artefacts it must survive or mask:

- :func:`bad_elements`: single-sample spikes of +-30-300 K, dead elements stuck at a constant and hot
  elements stuck high or strongly offset;
- :func:`fixed_pattern`: a static per-pixel offset (a few temporal-noise sds, non-uniformity left after
  the correction) plus column stripes (the read-out's column amplifiers);
- :func:`correlated_noise`: noise correlated over ~1.5 px and ~3 frames (Gaussian-filtered white noise);
- :func:`offset_steps`: global offset steps at a few frames (shutter recalibration) plus a slow drift.

Every planter draws from ``numpy.random.default_rng(seed)`` (or a given ``Generator``), leaves its input
untouched and returns a copy in the input's dtype. :data:`ARTEFACTS` lists them by kind and
:func:`plant` applies one with the levels of the diagnosis benchmark (:func:`default_levels`).
Temperatures are in K (any unit of the data: the spike and step sizes are in it); time in s.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import as_video, check_choice, check_int, number

__all__ = [
    "ARTEFACTS",
    "bad_elements",
    "correlated_noise",
    "default_levels",
    "fixed_pattern",
    "offset_steps",
    "plant",
]

Record = dict[str, Any]


def _inputs(frames: object, seed: int | np.random.Generator) -> tuple[Tensor, np.random.Generator, Record]:
    """A copy of ``frames`` ``(T, H, W)``, the generator and the record's common part.

    Raises:
        TypeError: ``seed`` neither an integer nor a ``numpy.random.Generator``.
        ValueError: not one video ``(T, H, W)``, or non-finite values.
    """
    video, batched = as_video(frames, name="frames")
    if batched:
        raise ValueError(f"frames must have shape (T, H, W): one video, got {tuple(video.shape)}")
    if not bool(torch.isfinite(video).all()):
        raise ValueError("frames must be finite before artefacts are planted, got non-finite values")
    if isinstance(seed, np.random.Generator):
        return video[0].clone(), seed, {"seed": None}
    seed = check_int(seed, "seed", 0)
    return video[0].clone(), np.random.default_rng(seed), {"seed": seed}


def _pixels(rng: np.random.Generator, count: int, shape: tuple[int, int], name: str) -> list[tuple[int, int]]:
    """``count`` distinct pixels ``(row, col)``, uniformly over the frame."""
    height, width = shape
    if count > height * width:
        raise ValueError(f"{name} must be at most the {height * width} pixels of the frame, got {count}")
    flat = rng.choice(height * width, size=count, replace=False)
    return [(int(i) // width, int(i) % width) for i in flat]


# ------------------------------------------------------------------------------------ bad elements
def bad_elements(
    frames: Tensor,
    *,
    seed: int | np.random.Generator,
    spikes: int = 8,
    dead: int = 3,
    hot: int = 3,
    spike_range: tuple[float, float] = (30.0, 300.0),
    hot_range: tuple[float, float] = (10.0, 50.0),
) -> tuple[Tensor, Record]:
    """Single-sample spikes, dead elements and hot elements.

    Spikes: ``spikes`` samples at distinct (frame, pixel), each ``+-U(spike_range)`` K added to one sample.
    Dead: ``dead`` pixels stuck at a constant drawn uniformly in the video's range. Hot: ``hot`` pixels
    stuck at the video's maximum plus ``U(hot_range)`` (``"stuck"``) or offset by ``U(hot_range)``
    (``"offset"``), a fair coin each. Dead, hot and spiked pixels are distinct.

    Args:
        frames: one video.
        seed: seed or generator of the draws.
        spikes: number of spiked samples, >= 0.
        dead: number of dead elements, >= 0.
        hot: number of hot elements, >= 0.
        spike_range: ``(low, high)`` spike size in K (``0 <= low <= high``).
        hot_range: ``(low, high)`` of a hot element's excess in K.

    Returns:
        The video with the bad elements, and ``{"kind": "bad_elements", "seed", "spikes": [{"frame", "row",
        "col", "size"}], "dead": [{"row", "col", "value"}], "hot": [{"row", "col", "mode", "value"}]}``.

    Shape:
        ``frames`` ``(T, H, W)``; output like it.

    Raises:
        ValueError: bad video, counts or ranges.
    """
    video, rng, record = _inputs(frames, seed)
    n_frames, height, width = video.shape
    counts = {n: check_int(c, n, 0) for n, c in (("spikes", spikes), ("dead", dead), ("hot", hot))}
    spike_lo, spike_hi = _range(spike_range, "spike_range")
    hot_lo, hot_hi = _range(hot_range, "hot_range")
    low, high = float(video.min()), float(video.max())
    total = counts["dead"] + counts["hot"] + counts["spikes"]
    chosen = _pixels(rng, total, (height, width), "dead + hot + spikes")
    record.update(kind="bad_elements", spikes=[], dead=[], hot=[])
    for row, col in chosen[: counts["dead"]]:
        value = float(rng.uniform(low, high))
        video[:, row, col] = value
        record["dead"].append({"row": row, "col": col, "value": value})
    for row, col in chosen[counts["dead"] : counts["dead"] + counts["hot"]]:
        excess, stuck = float(rng.uniform(hot_lo, hot_hi)), bool(rng.uniform() < 0.5)
        value = high + excess if stuck else excess
        video[:, row, col] = value if stuck else video[:, row, col] + excess
        record["hot"].append({"row": row, "col": col, "mode": "stuck" if stuck else "offset", "value": value})
    for row, col in chosen[counts["dead"] + counts["hot"] :]:
        frame = int(rng.integers(n_frames))
        size = float(rng.uniform(spike_lo, spike_hi)) * (1.0 if rng.uniform() < 0.5 else -1.0)
        video[frame, row, col] += size
        record["spikes"].append({"frame": frame, "row": row, "col": col, "size": size})
    return video, record


def _range(value: object, name: str) -> tuple[float, float]:
    """``(low, high)`` with ``0 <= low <= high`` in K."""
    try:
        low, high = (number(v, name, "K", minimum=0.0) for v in value)  # type: ignore[attr-defined]
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be (low, high) with 0 <= low <= high in K, got {value!r}") from err
    if low > high:
        raise ValueError(f"{name} must be (low, high) with 0 <= low <= high in K, got {value!r}")
    return low, high


# ----------------------------------------------------------------------------------- fixed pattern
def fixed_pattern(
    frames: Tensor, *, seed: int | np.random.Generator, sd: float, stripe_sd: float | None = None
) -> tuple[Tensor, Record]:
    """A static fixed pattern: per-pixel offsets plus column stripes, the same in every frame.

    Args:
        frames: one video.
        seed: seed or generator of the draws.
        sd: sd of the per-pixel offsets in K (e.g. 3 times the temporal noise sd).
        stripe_sd: sd of the per-column offsets in K (default ``sd / 2``).

    Returns:
        The video plus the pattern, and ``{"kind": "fixed_pattern", "seed", "pixel_sd", "stripe_sd"
        (requested), "pixel_sd_realised", "stripe_sd_realised", "pattern_sd_realised" (sds of the drawn
        offsets, the columns' and their sum's)}``; the pattern is ``output[k] - frames[k]`` for any ``k``.

    Shape:
        ``frames`` ``(T, H, W)``; output like it.

    Raises:
        ValueError: bad video or negative levels.
    """
    video, rng, record = _inputs(frames, seed)
    _, height, width = video.shape
    sd = number(sd, "sd", "K", minimum=0.0)
    stripe_sd = 0.5 * sd if stripe_sd is None else number(stripe_sd, "stripe_sd", "K", minimum=0.0)
    pixel = rng.standard_normal((height, width)) * sd
    stripes = rng.standard_normal(width) * stripe_sd
    pattern = pixel + stripes[None, :]
    record.update(
        kind="fixed_pattern",
        pixel_sd=sd,
        stripe_sd=stripe_sd,
        pixel_sd_realised=float(pixel.std()),
        stripe_sd_realised=float(stripes.std()),
        pattern_sd_realised=float(pattern.std()),
    )
    return video + torch.from_numpy(pattern).to(video.dtype), record


# -------------------------------------------------------------------------------- correlated noise
def _gaussian_taps(sigma: float) -> np.ndarray:
    """A normalised Gaussian kernel of sd ``sigma`` taps (cut at 4 sd); ``[1.]`` for ``sigma == 0``."""
    if sigma <= 0:
        return np.ones(1)
    radius = max(1, math.ceil(4.0 * sigma))
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    return taps / taps.sum()


def _filter(noise: np.ndarray, taps: np.ndarray, axis: int) -> np.ndarray:
    """``noise`` correlated with ``taps`` along ``axis``, 'valid' (shorter by ``len(taps) - 1``)."""
    length = noise.shape[axis] - taps.size + 1
    out = np.zeros_like(np.take(noise, np.arange(length), axis=axis))
    for k, tap in enumerate(taps):
        out += tap * np.take(noise, np.arange(k, k + length), axis=axis)
    return out


def correlated_noise(
    frames: Tensor,
    *,
    seed: int | np.random.Generator,
    sd: float,
    length_px: float = 1.5,
    length_frames: float = 3.0,
) -> tuple[Tensor, Record]:
    """Noise correlated in space and time: white noise through a Gaussian filter, scaled to ``sd``.

    The correlation length ``l`` is that of the noise itself: its autocorrelation falls as
    ``exp(-d^2 / (2 l^2))`` with the lag ``d`` (px or frames), which a Gaussian filter of sd ``l / sqrt(2)``
    gives. The noise is drawn on a frame and a time span extended by the filter's reach (no edge effects)
    and scaled so that its sample sd is exactly ``sd``.

    Args:
        frames: one video.
        seed: seed or generator of the draws.
        sd: sd of the added noise in K (e.g. twice the white noise sd).
        length_px: spatial correlation length in px (>= 0; 0: white in space).
        length_frames: temporal correlation length in frames, >= 0.

    Returns:
        The noisy video, and ``{"kind": "correlated_noise", "seed", "sd", "length_px", "length_frames",
        "filter_sigma_px", "filter_sigma_frames"}``.

    Shape:
        ``frames`` ``(T, H, W)``; output like it.

    Raises:
        ValueError: bad video or negative levels.
    """
    video, rng, record = _inputs(frames, seed)
    n_frames, height, width = video.shape
    sd = number(sd, "sd", "K", minimum=0.0)
    length_px = number(length_px, "length_px", "px", minimum=0.0)
    length_frames = number(length_frames, "length_frames", "frames", minimum=0.0)
    space, time = _gaussian_taps(length_px / math.sqrt(2.0)), _gaussian_taps(length_frames / math.sqrt(2.0))
    white = rng.standard_normal((n_frames + time.size - 1, height + space.size - 1, width + space.size - 1))
    noise = _filter(_filter(_filter(white, time, 0), space, 1), space, 2)
    noise *= sd / max(float(noise.std()), 1e-300)
    record.update(
        kind="correlated_noise",
        sd=sd,
        length_px=length_px,
        length_frames=length_frames,
        filter_sigma_px=length_px / math.sqrt(2.0),
        filter_sigma_frames=length_frames / math.sqrt(2.0),
    )
    return video + torch.from_numpy(noise).to(video.dtype), record


# ------------------------------------------------------------------------------------ offset steps
def offset_steps(
    frames: Tensor,
    *,
    seed: int | np.random.Generator,
    dt: float,
    steps: int = 3,
    step_range: tuple[float, float] = (0.05, 0.3),
    drift: float | None = None,
) -> tuple[Tensor, Record]:
    """Global offset steps at a few frames (recalibration) plus a slow linear drift of the whole frame.

    Args:
        frames: one video.
        seed: seed or generator of the draws.
        dt: frame period in s.
        steps: number of steps, >= 0, at distinct frames ``1 .. T - 1``: the offset changes between frame
            ``k - 1`` and frame ``k``.
        step_range: ``(low, high)`` size of a step in K, each of either sign.
        drift: drift rate in K/s; default drawn, ``+-U(0.02, 0.1)`` K/s.

    Returns:
        The video, and ``{"kind": "offset_steps", "seed", "steps": [{"frame", "size"}], "drift_rate"
        (K/s), "offsets" (the offset of each frame, K)}``: frame ``k`` gained ``offsets[k]`` everywhere.

    Shape:
        ``frames`` ``(T, H, W)``; output like it.

    Raises:
        ValueError: bad video, ``dt``, ranges, or more steps than frames after the first.
    """
    video, rng, record = _inputs(frames, seed)
    n_frames = video.shape[0]
    dt = number(dt, "dt", "s", positive=True)
    steps = check_int(steps, "steps", 0)
    low, high = _range(step_range, "step_range")
    if steps > n_frames - 1:
        raise ValueError(f"steps must be at most the {n_frames - 1} frames after the first, got {steps}")
    where = sorted(int(k) for k in rng.choice(np.arange(1, n_frames), size=steps, replace=False))
    sizes = [float(rng.uniform(low, high)) * (1.0 if rng.uniform() < 0.5 else -1.0) for _ in where]
    if drift is None:
        drift = float(rng.uniform(0.02, 0.1)) * (1.0 if rng.uniform() < 0.5 else -1.0)
    drift = number(drift, "drift", "K/s")
    offsets = drift * dt * np.arange(n_frames, dtype=np.float64)
    for frame, size in zip(where, sizes, strict=True):
        offsets[frame:] += size
    record.update(
        kind="offset_steps",
        steps=[{"frame": k, "size": s} for k, s in zip(where, sizes, strict=True)],
        drift_rate=drift,
        offsets=offsets.tolist(),
    )
    return video + torch.from_numpy(offsets).to(video.dtype)[:, None, None], record


# --------------------------------------------------------------------------------------- registry
ARTEFACTS: dict[str, Callable[..., tuple[Tensor, Record]]] = {
    "bad_elements": bad_elements,
    "fixed_pattern": fixed_pattern,
    "correlated_noise": correlated_noise,
    "offset_steps": offset_steps,
}
"""The planters by kind."""


def default_levels(kind: str, *, noise_sd: float, dt: float) -> dict[str, float]:
    """The levels the diagnosis benchmark plants a ``kind`` at, for a video of white-noise sd ``noise_sd``
    (K) and frame period ``dt`` in s: a fixed pattern of 3 noise sds (stripes 1.5), correlated noise of 2
    noise sds over 1.5 px and 3 frames; the other kinds' own defaults.

    Shape:
        No tensors.

    Raises:
        ValueError: unknown kind, negative ``noise_sd``, non-positive ``dt``.
    """
    check_choice(kind, "artefact kind", list(ARTEFACTS))
    noise_sd = number(noise_sd, "noise_sd", "K", minimum=0.0)
    dt = number(dt, "dt", "s", positive=True)
    levels: dict[str, dict[str, float]] = {
        "bad_elements": {},
        "fixed_pattern": {"sd": 3.0 * noise_sd, "stripe_sd": 1.5 * noise_sd},
        "correlated_noise": {"sd": 2.0 * noise_sd, "length_px": 1.5, "length_frames": 3.0},
        "offset_steps": {"dt": dt},
    }
    return levels[kind]


def plant(
    frames: Tensor, kind: str, *, seed: int | np.random.Generator, noise_sd: float, dt: float
) -> tuple[Tensor, Record]:
    """Plant one kind of artefact at the levels of :func:`default_levels`.

    Args:
        frames: one video.
        kind: a key of :data:`ARTEFACTS`.
        seed: seed or generator of the draws.
        noise_sd: the video's white-noise sd in K (sets the fixed pattern's and correlated noise's level).
        dt: frame period in s.

    Returns:
        ``(video, record)`` of the planter.

    Shape:
        ``frames`` ``(T, H, W)``; output like it.

    Raises:
        ValueError: unknown kind, or as the planter.

    Example:
        >>> video = torch.full((5, 8, 8), 30.0)
        >>> out, record = plant(video, "offset_steps", seed=0, noise_sd=0.1, dt=0.04)
        >>> record["kind"], len(record["steps"]), bool(torch.equal(video, torch.full((5, 8, 8), 30.0)))
        ('offset_steps', 3, True)
    """
    levels = default_levels(kind, noise_sd=noise_sd, dt=dt)
    return ARTEFACTS[kind](frames, seed=seed, **levels)
