"""The standard errors of the depth maps: the perturbed copies of a depth problem (``a + se``, ``b + se``,
seeded noise videos) and the spread of their results.

The maps are solved for the base problem and every copy at once (:func:`anra_torch.tissue.damage_in_depth`);
the standard error is the root sum of squares of the copies' changes, the noise draws' entering as their
mean square.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["NOISE_DRAWS", "perturbed_copies", "spread"]

_F64 = torch.float64

NOISE_DRAWS = 8
"""Seeded white-noise videos whose changes give the noise's part of the standard errors (their mean square):
one draw gives a standard error with one degree of freedom, whose +-2 band holds the truth only 70 % of the
time (``2 / pi * atan(2)``) where the noise dominates; eight give about 92 % (Student's t, 8 degrees)."""


def perturbed_copies(
    rise: Tensor, a: Tensor, b: Tensor, errors: tuple[Tensor, Tensor, Tensor], seed: int
) -> tuple[Tensor, Tensor, Tensor, int]:
    """The base problem and the perturbed copies of each non-zero standard error (``a + se``, ``b + se``, the
    surface plus :data:`NOISE_DRAWS` seeded noise videos of the measured sd), stacked along the batch:
    ``(rise, a, b, weights)``, ``weights`` (``V - 1``) the weight of each copy's squared change in the
    variance (1 for ``a`` and ``b``, ``1 / NOISE_DRAWS`` for each noise draw: their mean square)."""
    sa, sb, sn = errors
    rises, rates, losses, weights = [rise], [a], [b], []
    if bool((sa > 0).any()):
        rises, rates, losses, weights = [*rises, rise], [*rates, a + sa], [*losses, b], [*weights, 1.0]
    if bool((sb > 0).any()):
        rises, rates, losses, weights = [*rises, rise], [*rates, a], [*losses, b + sb], [*weights, 1.0]
    if bool((sn > 0).any()):
        generator = torch.Generator().manual_seed(seed)
        shape = (NOISE_DRAWS, *rise.shape)
        noise = torch.randn(shape, generator=generator, dtype=_F64, device="cpu").to(rise.device, rise.dtype)
        rises.extend(rise + sn.view(-1, 1, 1, 1) * noise)
        rates, losses = [*rates, *[a] * NOISE_DRAWS], [*losses, *[b] * NOISE_DRAWS]
        weights = [*weights, *[1.0 / NOISE_DRAWS] * NOISE_DRAWS]
    as_tensor = torch.tensor(weights, dtype=_F64, device="cpu").to(rise.device, rise.dtype)
    return torch.cat(rises), torch.cat(rates), torch.cat(losses), as_tensor


def spread(values: Tensor, weights: Tensor, other: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """The base value and the root of the perturbed copies' weighted squared changes (``weights``, ``(V -
    1,)``: see :func:`perturbed_copies`), from ``(V B, ...)``; with ``other`` (the base's depth from its dose
    by the other integration rule, ``(B, ...)``), half the two rules' difference is added in quadrature: the
    frames' sampling in time."""
    stacked = values.reshape(len(weights) + 1, -1, *values.shape[1:])
    base = stacked[0]
    change = (stacked[1:] - base) ** 2
    variance = (weights.to(change.dtype).view(-1, *[1] * base.ndim) * change).sum(0)
    if other is not None:
        variance = variance + (0.5 * (other - base)) ** 2
    return base, variance.sqrt()
