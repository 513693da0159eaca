"""Regions of a map: connected components, dilation and erosion of booleans, a Gaussian average, the scatter
by distance from the frame's edge, as whole-map tensor operations."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as nnf
from torch import Tensor

__all__ = ["components", "dilate", "edge_scatter", "erode", "smooth"]


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
