"""Regions of a map: connected components, dilation and erosion of booleans, a Gaussian average, the scatter
by distance from the frame's edge, the sound plate's level, as whole-map tensor operations."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as nnf
from torch import Tensor

__all__ = ["components", "dilate", "edge_scatter", "erode", "plate_level", "smooth", "tile_standard_error"]


def components(mask: Tensor) -> tuple[Tensor, int]:
    """Label the 4-connected components of ``mask``.

    Every pixel of ``mask`` takes the largest index of its component by repeated 3 x 3 cross maxima
    (as many rounds as the longest path inside a component), then the labels are renumbered.

    Args:
        mask: ``(H, W)`` booleans.

    Returns:
        Labels ``(H, W)`` int64 (0 outside ``mask``, components 1 .. n in the order of their first pixel
        in row-major order) and ``n``.
    """
    height, width = mask.shape
    index = torch.arange(1, height * width + 1, device=mask.device, dtype=torch.float64).view(height, width)
    labels = torch.where(mask, index, torch.zeros_like(index))
    while True:
        padded = nnf.pad(labels[None, None], (1, 1, 1, 1))[0, 0]
        neighbours = torch.stack(
            [labels, padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]]
        ).amax(0)
        grown = torch.where(mask, neighbours, labels)
        if torch.equal(grown, labels):
            break
        labels = grown
    values, inverse = torch.unique(labels.flatten(), return_inverse=True)
    # unique sorts by the largest index: renumber by each component's first pixel instead
    first = torch.full((len(values),), height * width, device=mask.device, dtype=torch.long)
    first.scatter_reduce_(0, inverse, torch.arange(height * width, device=mask.device), "amin")
    start = 1 if bool((values == 0).any()) else 0
    order = torch.argsort(first[start:])
    rank = torch.zeros(len(values), dtype=torch.long, device=mask.device)
    rank[start + order] = torch.arange(1, len(order) + 1, device=mask.device)
    return rank[inverse].view(height, width), len(order)


def dilate(mask: Tensor, radius: int) -> Tensor:
    """``mask`` ``(H, W)`` grown by a square of ``radius`` px on each side (nothing beyond the frame)."""
    grown = nnf.max_pool2d(mask[None, None].to(torch.float32), 2 * radius + 1, stride=1, padding=radius)
    return grown[0, 0] > 0


def erode(mask: Tensor, radius: int) -> Tensor:
    """``mask`` ``(H, W)`` shrunk by a square of ``radius`` px (pixels off the frame count as in ``mask``)."""
    return ~dilate(~mask, radius)


def smooth(values: Tensor, sigma: float) -> Tensor:
    """``values`` ``(H, W)`` averaged by a Gaussian of ``sigma`` px over the frame (normalised at its edges:
    a constant map stays constant)."""
    radius = int(math.ceil(3 * sigma))
    k = torch.arange(-radius, radius + 1, dtype=values.dtype, device=values.device)
    taps = torch.exp(-(k**2) / (2 * sigma**2))

    def blur(x: Tensor) -> Tensor:
        x = nnf.conv2d(x[None, None], taps.view(1, 1, 1, -1), padding=(0, radius))
        return nnf.conv2d(x, taps.view(1, 1, -1, 1), padding=(radius, 0))[0, 0]

    return blur(values) / blur(torch.ones_like(values))


def edge_scatter(values: Tensor, sound: Tensor, rings: int, min_pixels: int) -> Tensor:
    """Per pixel, the robust sd of ``values`` ``(H, W)`` over the pixels as far from the frame's edge (up to
    ``rings`` px; estimates from one-sided filters are noisier near the edge), from their deviations below
    the ring's median (a defect only raises the values; a cut to the ``sound`` pixels would hide the edge's
    scatter); beyond ``rings`` px, over the ``sound`` pixels (if at least ``min_pixels``)."""
    height, width = values.shape
    rows = torch.arange(height, device=values.device)[:, None]
    cols = torch.arange(width, device=values.device)[None, :]
    ring = torch.minimum(torch.minimum(rows, height - 1 - rows), torch.minimum(cols, width - 1 - cols))
    ring = ring.clamp(max=rings)
    spread = torch.zeros(rings + 1, dtype=values.dtype, device=values.device)
    for k in range(int(ring.max()) + 1):  # a few rings, each whole
        chosen = values[ring == k]
        if k == rings and int(((ring == k) & sound).sum()) >= min_pixels:
            chosen = values[(ring == k) & sound]
            spread[k] = 1.4826 * (chosen - chosen.median()).abs().median()
        else:
            middle = chosen.median()
            spread[k] = 1.4826 * (middle - chosen[chosen <= middle]).median()
    return spread[ring]


def plate_level(
    log_tau: Tensor, odd: float, *, sigma: float, share: float, longest: float
) -> tuple[Tensor, Tensor]:
    """The sound plate's level in a map of ``ln tau`` ``(H, W)`` and its pixels (within ``odd`` of it).

    The level is the median of the pixels within ``odd`` of it, iterated from the map's median. A defect only
    shortens ``tau``: where a connected region of the map smoothed by ``sigma`` px (one pixel's fit scatters;
    a region does not) lies more than ``odd`` above that level, covers at least ``share`` of the frame and
    its median is at most ``longest`` (the recording reaches its back wall), the level is that region's
    (a defect larger than the sound plate left in the frame; measured on the noisiest plates of
    experiments.flash_defect_map the largest such region covers 0.19 of the frame, where the recording ends
    before the back wall).
    """
    level, sound = _level(log_tau, log_tau.median(), odd)
    labels, count = components(smooth(log_tau, sigma) > level + odd)
    if count:
        sizes = torch.bincount(labels.flatten(), minlength=count + 1)[1:]
        region = labels == int(sizes.argmax()) + 1
        median = log_tau[region].median()
        if float(sizes.max()) >= share * log_tau.numel() and float(median) <= longest:
            level, sound = _level(log_tau, median, odd)
    return level, sound


def _level(log_tau: Tensor, level: Tensor, odd: float) -> tuple[Tensor, Tensor]:
    for _ in range(3):
        sound = (log_tau - level).abs() < odd
        level = log_tau[sound].median()
    return level, sound


def tile_standard_error(log_tau: Tensor, sound: Tensor) -> float:
    """Standard error of the median of ``log_tau`` ``(H, W)`` over its ``sound`` pixels from the spread of the
    medians of 4 x 4 tiles (those with at least 8 sound pixels; inf with fewer than 2 such tiles)."""
    height, width = log_tau.shape
    rows = torch.arange(height, device=log_tau.device) * 4 // height
    cols = torch.arange(width, device=log_tau.device) * 4 // width
    tile = (rows[:, None] * 4 + cols[None, :])[sound]
    values = log_tau[sound]
    medians = torch.stack([values[tile == k].median() for k in range(16) if int((tile == k).sum()) >= 8])
    if len(medians) < 2:
        return math.inf
    return float(medians.std() / math.sqrt(len(medians)))
