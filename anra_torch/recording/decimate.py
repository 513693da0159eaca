"""A camera-sized recording diagnosed on a block-averaged copy, read chunk by chunk.

Above :data:`DIAGNOSE_VALUES` pixel values a recording is diagnosed on a copy averaged over blocks of
``k x k`` pixels and ``m`` frames (:func:`decimation` keeps ``a dt / dx^2`` near its value, with at least
:data:`MIN_FRAMES` frames), built while the recording is read a chunk of frames at a time, each chunk's
spikes and dead or hot elements repaired first at full resolution. :func:`camera_copy` makes the copy
again from the part of the frame whose temperature changes (:func:`signal_box`) when that covers at most
half the frame. Only whole blocks are kept (:func:`decimated_video`'s record says what was dropped). Why
the physics survives the averaging: ``docs/architecture.md`` ("Recordings larger than memory").
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance import find_artefacts
from anra_torch.video import ROI, Video

__all__ = ["DIAGNOSE_VALUES", "MIN_FRAMES", "camera_copy", "decimated_video", "decimation", "signal_box"]

DIAGNOSE_VALUES = 2**22
"""Pixel values above which a recording is diagnosed on a block-averaged copy of at most this many (about
1.4 GB of peak memory for the diagnosis)."""

MIN_FRAMES = 64
"""Frames the copy keeps at least (fewer when the recording has fewer)."""

_MIN_SIDE = 16  # px: the copy's frames keep at least this many pixels on each side
_CHUNK_VALUES = 2**24  # pixel values read (and repaired) at once: 64 MB in float32


def decimation(shape: tuple[int, int, int], budget: int = DIAGNOSE_VALUES) -> tuple[int, int]:
    """The block sizes ``(k, m)`` (pixels per side, frames) of the copy a recording is diagnosed on.

    ``(1, 1)`` when the recording has at most ``budget`` pixel values. Otherwise, among the pairs whose
    copy has at most ``budget`` values, at least :data:`MIN_FRAMES` frames (or all, for fewer) and
    frames of at least 16 px a side, the one whose change of the diffusion per frame, ``m / k^2``, is
    nearest 1 (on a log scale).

    Args:
        shape: the recording's ``(T, H, W)``.
        budget: most pixel values of the copy (positive).

    Raises:
        ValueError: a non-positive budget or shape, or no pair fits the budget.
    """
    t, h, w = (int(n) for n in shape)
    if budget < 1 or min(t, h, w) < 1:
        raise ValueError(f"budget and shape must be positive, got budget {budget} and shape {tuple(shape)}")
    if t * h * w <= budget:
        return 1, 1
    frames_needed = min(MIN_FRAMES, t)
    best: tuple[float, int, int] | None = None
    for k in range(1, max(1, min(h, w) // _MIN_SIDE) + 1):
        allowed = budget // ((h // k) * (w // k))
        m = math.ceil(t / max(allowed, 1))
        if allowed < 1 or t // m < frames_needed:
            continue
        score = abs(math.log(m / k**2))
        if best is None or score < best[0]:
            best = (score, k, m)
    if best is None:
        raise ValueError(
            f"a recording of {t} frames of {h} x {w} px cannot be averaged down to {budget} pixel values "
            f"with at least {frames_needed} frames of {_MIN_SIDE} px a side; diagnose a region (--roi)"
        )
    return best[1], best[2]


def _chunk(frames: Any, start: int, stop: int) -> Tensor:
    """Frames ``start .. stop - 1`` as a float tensor (float32 unless the recording is float64)."""
    part = torch.as_tensor(np.ascontiguousarray(frames[start:stop]))
    return part if part.dtype == torch.float64 else part.float()


def _block_means(frames: Any, box: tuple[int, int, int, int], k: int, m: int) -> tuple[Tensor, int, int]:
    """The ``box`` ``(x0, y0, width, height)`` px of ``frames`` averaged over ``k x k`` px and ``m`` frames,
    read a chunk at a time and repaired first; with the spikes and the distinct elements repaired."""
    x0, y0, w, h = box
    out_t, out_h, out_w = frames.shape[0] // m, h // k, w // k
    step = m * max(1, _CHUNK_VALUES // (m * h * w))  # whole blocks per chunk
    parts, spikes, elements = [], 0, torch.zeros(h, w, dtype=torch.bool)
    for start in range(0, out_t * m, step):
        chunk = _chunk(frames, start, min(start + step, out_t * m))[:, y0 : y0 + h, x0 : x0 + w]
        repaired, found = find_artefacts(chunk)
        spikes += found.spikes
        if found.bad_pixels:
            elements[tuple(torch.tensor(found.bad_pixels).T)] = True
        cut = repaired[:, : out_h * k, : out_w * k]
        parts.append(F.avg_pool3d(cut.double()[None, None], (m, k, k))[0, 0])
        del chunk, repaired, cut
    return torch.cat(parts), spikes, int(elements.sum())


def decimated_video(video: Video, k: int, m: int, region: ROI | None = None) -> tuple[Video, dict[str, Any]]:
    """The recording averaged over blocks of ``k x k`` pixels and ``m`` frames, its camera artefacts
    repaired at full resolution first, and what was done.

    The frames are read a chunk at a time (a :class:`~anra_torch.video.LazyFrames` is never read
    whole), so memory holds one chunk and the copy.

    Args:
        video: the recording (frames in memory or lazily read), uniform in time.
        k: pixels per block side, >= 1.
        m: frames per block, >= 1.
        region: ``(x0, y0, width, height)`` in px (as ``--roi``): only this part of each frame is read
            into the copy (default the whole frame).

    Returns:
        The copy in float64 (pixel size ``k dx``, frame period ``m dt``, timestamps the blocks' mean times,
        no truth) and its record: ``space_px`` (k), ``time_frames`` (m), ``shape`` (the copy's ``[T, H, W]``),
        ``dropped_frames`` / ``dropped_rows`` / ``dropped_columns`` (beyond the last whole block),
        ``repaired_spikes`` and ``repaired_elements`` (dead or hot elements, distinct pixels), and
        ``region`` (``[x0, y0, width, height]`` px of the recording, or null for the whole frame).

    Shape:
        frames ``(T, H, W)`` -> ``(T // m, H // k, W // k)`` (``H, W`` those of ``region`` when given).

    Raises:
        ValueError: a factor below 1 or larger than the recording.
    """
    t, h, w = video.frames.shape
    full = (w, h)
    x0, y0, w, h = region if region is not None else (0, 0, w, h)
    if x0 < 0 or y0 < 0 or w < 1 or h < 1 or x0 + w > full[0] or y0 + h > full[1]:
        raise ValueError(f"region must lie inside the {full[0]} x {full[1]} px frame, got {region}")
    if k < 1 or m < 1 or k > min(h, w) or m > t:
        raise ValueError(f"k and m must be in [1, min(H, W)] and [1, T], got k={k}, m={m} for {t}x{h}x{w}")
    out_t, out_h, out_w = t // m, h // k, w // k
    frames, spikes, elements = _block_means(video.frames, (x0, y0, w, h), k, m)
    t_in = video.t.double() if video.t is not None else torch.arange(t, dtype=torch.float64) * video.dt
    times = t_in[: out_t * m].reshape(out_t, m).mean(1)
    record = {
        "space_px": k,
        "time_frames": m,
        "shape": [out_t, out_h, out_w],
        "dropped_frames": t - out_t * m,
        "dropped_rows": h - out_h * k,
        "dropped_columns": w - out_w * k,
        "repaired_spikes": spikes,
        "repaired_elements": elements,
        "region": None if region is None else [x0, y0, w, h],
    }
    dx = None if video.dx is None else video.dx * k
    meta = {**video.meta, "decimated": record}
    copy = replace(video, frames=frames, dt=video.dt * m, dx=dx, t=times, meta=meta, truth=None)
    return copy, record


SIGNAL_SHARE = 0.01
"""A pixel is part of the signal when its temperature range over the recording is at least this share of
the largest (each frame's median removed first, so a global drift or offset step is no signal)."""

_MARGIN = 0.25  # the signal's box grows by this share of its size on each side (plus 4 px of the copy)


def signal_box(frames: Tensor) -> tuple[int, int, int, int] | None:
    """The box ``(x0, y0, width, height)`` px around the part of the frames whose temperature changes,
    with a margin; None when it covers more than half the frame (nothing to gain by cutting).

    The range is taken over 8-frame means of a 3 x 3 px box-smoothed copy, each frame's median removed,
    so neither noise nor a global offset counts as change; the signal is every pixel whose range is at
    least :data:`SIGNAL_SHARE` of the largest. The box grows by a quarter of its size on each side, plus
    4 px, for the heat that spreads beyond it and the filters' reach.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    t, h, w = frames.shape
    smooth = F.avg_pool2d(frames.double()[:, None], 3, stride=1, padding=1, count_include_pad=False)[:, 0]
    smooth = smooth - smooth.flatten(1).median(1).values[:, None, None]
    blocks = F.avg_pool1d(smooth.permute(1, 2, 0).reshape(h * w, 1, t), min(8, t))[:, 0]  # (H W, T / 8)
    change = (blocks.amax(1) - blocks.amin(1)).reshape(h, w)
    rows, cols = (change >= SIGNAL_SHARE * change.max()).nonzero(as_tuple=True)
    if rows.numel() == 0 or not bool(change.max() > 0):
        return None
    r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
    grow_r, grow_c = int(_MARGIN * (r1 - r0)) + 4, int(_MARGIN * (c1 - c0)) + 4
    r0, r1, c0, c1 = max(0, r0 - grow_r), min(h, r1 + grow_r), max(0, c0 - grow_c), min(w, c1 + grow_c)
    if (r1 - r0) * (c1 - c0) > 0.5 * h * w:
        return None
    return c0, r0, c1 - c0, r1 - r0


def camera_copy(video: Video, budget: int = DIAGNOSE_VALUES) -> tuple[Video, dict[str, Any] | None]:
    """The copy a recording of more than ``budget`` pixel values is diagnosed on, and its record (see
    :func:`decimated_video`); the recording itself and None within the budget.

    A first copy with :func:`decimation`'s factors locates the signal (:func:`signal_box`). When the
    signal covers at most half the frame, the copy is made again from that region only, at the finer
    factors it allows: a laser spot in a camera-sized frame keeps its resolution (a spot only a few pixels
    wide is where the balance's stencils and the forecast's grid are least exact).

    Args:
        video: the recording (frames in memory or lazily read), uniform in time.
        budget: most pixel values of the copy.

    Shape:
        frames ``(T, H, W)`` -> the copy's ``record["shape"]``.
    """
    k, m = decimation(video.frames.shape, budget)
    if (k, m) == (1, 1):
        return video, None
    copy, record = decimated_video(video, k, m)
    box = signal_box(copy.frames)
    if box is None:
        return copy, record
    x0, y0, w, h = (k * n for n in box)
    finer = decimation((video.frames.shape[0], h, w), budget)
    if finer[0] >= k:
        return copy, record
    return decimated_video(video, *finer, region=(x0, y0, w, h))
