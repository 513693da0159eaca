"""The defects a map of contrasts shows: their outlines, depths and where they lie.

A defect is a connected region of candidate pixels (significantly shorter ``tau`` than the plate's) of at
least a given size whose peak (the 95 % quantile of its contrast ``ln(plate / tau)``) is above the sound
plate's own scatter. Its outline is where its contrast is above :data:`OUTLINE_SHARE` of that peak (and
significant at 2 sd), out to its edge and connected to it: any shape, running out of the frame or not. The
strongest defect is outlined first; a weaker region inside its outline is part of it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from anra_torch.flash.regions import components

__all__ = ["OUTLINE_SHARE", "FoundDefect", "Outlines", "outline_defects"]

OUTLINE_SHARE = 0.6
"""An outline's pixels are above this share of the peak (measured: the contrast's sideways spread puts the
true edge above half of it on most plates of ``experiments.flash_defect_map``)."""
_OUTLINE_SIGNIFICANCE = 2.0  # ... at this many standard deviations of their own fit
_PEAK = 0.95  # the quantile of a region's contrast that is its peak


@dataclass(frozen=True)
class FoundDefect:
    """One defect of a :class:`~anra_torch.flash.DefectMap`.

    Attributes:
        x: centroid in mm along the columns (from the frame's corner).
        y: centroid in mm along the rows.
        area: in mm^2 (inside the frame).
        depth_fraction: ``d / L``.
        touches_edge: the outline reaches the frame's edge (the defect may run out of it).
    """

    x: float
    y: float
    area: float
    depth_fraction: float
    touches_edge: bool


@dataclass(frozen=True)
class Outlines:
    """Output of :func:`outline_defects`.

    Attributes:
        mask: the defects' pixels, ``(H, W)`` booleans.
        depth_fraction: each defect's ``d / L`` over its outline, NaN elsewhere, ``(H, W)``.
        peaks: per defect, strongest first, its outline ``(H, W)`` and its peak contrast (a 0-d tensor).
        defects: per defect, its description.
    """

    mask: Tensor
    depth_fraction: Tensor
    peaks: list[tuple[Tensor, Tensor]]
    defects: list[FoundDefect]


def outline_defects(
    contrast: Tensor,
    candidate: Tensor,
    significance: Tensor,
    limits: tuple[float, int, float],
    depth_of: Callable[[Tensor, Tensor], float],
) -> Outlines:
    """Outline the defects among the candidate pixels' regions, the strongest first.

    Args:
        contrast: ``ln(plate / tau)`` per pixel, ``(H, W)``.
        candidate: the pixels that may belong to a defect, ``(H, W)`` booleans.
        significance: per pixel, how many sd of its own fit its ``tau`` is from the plate's, ``(H, W)``.
        limits: the least peak contrast, the fewest pixels of a region, the pixel size in mm.
        depth_of: a defect's ``d / L`` from its outline ``(H, W)`` and its peak contrast.
    """
    least, fewest, dx = limits
    labels, count = components(candidate)
    regions = []
    for k in range(1, count + 1):  # a few regions, each whole
        region = labels == k
        if int(region.sum()) >= fewest:
            peak = torch.quantile(contrast[region], _PEAK)
            if float(peak) >= least:  # above the sound plate's own scatter
                regions.append((float(peak), k, region, peak))
    mask = torch.zeros_like(candidate)
    fraction = torch.full_like(contrast, math.nan)
    peaks, found = [], []
    level = significance > _OUTLINE_SIGNIFICANCE
    for _, _, region, peak in sorted(regions, key=lambda r: (-r[0], r[1])):
        if bool((region & mask).any()):
            continue
        outline = _grown(region, (contrast >= OUTLINE_SHARE * peak) & level) & ~mask
        depth = depth_of(outline, peak)
        mask |= outline
        fraction[outline] = depth
        peaks.append((outline, peak))
        found.append(_describe(outline, depth, dx))
    return Outlines(mask, fraction, peaks, found)


def _grown(region: Tensor, level: Tensor) -> Tensor:
    """The connected parts of ``level`` ``(H, W)`` that overlap ``region`` (a defect's outline is where its
    contrast is above the level, out to its edge, not only where its own fit is significant)."""
    labels, _ = components(level)
    return torch.isin(labels, labels[region & level]) & level


def _describe(outline: Tensor, depth: float, dx: float) -> FoundDefect:
    rows, cols = torch.nonzero(outline, as_tuple=True)
    height, width = outline.shape
    edge = bool(
        (rows == 0).any() or (cols == 0).any() or (rows == height - 1).any() or (cols == width - 1).any()
    )
    return FoundDefect(
        x=float((cols.to(torch.float64) + 0.5).mean()) * dx,
        y=float((rows.to(torch.float64) + 0.5).mean()) * dx,
        area=len(rows) * dx**2,
        depth_fraction=depth,
        touches_edge=edge,
    )
