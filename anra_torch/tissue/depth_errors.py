"""The depth where a dose crosses its threshold, and the standard errors of the depth maps.

:func:`threshold_depth` finds that depth and :func:`threshold_variance` its variance from the doses'
noise. :func:`perturbed_copies` stacks the copies of a depth problem with ``a + se`` and ``b + se``, and
:func:`spread` turns their results into the parameters' part of a standard error.
:func:`noise_correlation` gives the temperature noise that a white surface noise puts at every depth node.
The derivations: ``docs/architecture.md``, "The depth model". Units: mm, s, K, mm^2/s, 1/s.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = [
    "BETWEEN_WEIGHT",
    "between_frames",
    "noise_correlation",
    "perturbed_copies",
    "spread",
    "threshold_depth",
    "threshold_variance",
]

BETWEEN_WEIGHT = 1.0 / 3.0
"""The weight of the surface between the frames (:func:`between_frames`) in a variance: the truth lies
anywhere between the frames joined by straight lines and that surface (a switch-off anywhere between two
frames), the mean square of an error spread evenly between none and the copy's change."""
_F64 = torch.float64
_BINS = 48  # radial bins of |k|^2 (the transfer function depends on |k| only)
_FREQUENCIES = 512  # quadrature points over |w| < _ALIASES pi / dt
_ALIASES = 8


def perturbed_copies(
    rise: Tensor, a: Tensor, b: Tensor, errors: tuple[Tensor, Tensor], *, switch: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The base problem and its perturbed copies, stacked along the batch.

    One copy of weight 1 per non-zero standard error: ``a + se``, then ``b + se``. With ``switch``, each
    video's last frame before its switch-off ``(B,)``, one more copy of weight :data:`BETWEEN_WEIGHT`: the
    surface of :func:`between_frames`.

    Returns:
        ``(rise, a, b, weights)``: rises ``(V B, T, H, W)``, rates ``(V B,)``, the copies' weights
        ``(V - 1,)``.
    """
    sa, sb = errors
    rises, rates, losses = [rise], [a], [b]
    weights: list[float] = []
    if bool((sa > 0).any()):
        rises, rates, losses, weights = [*rises, rise], [*rates, a + sa], [*losses, b], [*weights, 1.0]
    if bool((sb > 0).any()):
        rises, rates, losses, weights = [*rises, rise], [*rates, a], [*losses, b + sb], [*weights, 1.0]
    if switch is not None and rise.shape[1] > 2:
        late = between_frames(rise, switch)
        rises, rates, losses, weights = [*rises, late], [*rates, a], [*losses, b], [*weights, BETWEEN_WEIGHT]
    weights_ = torch.tensor(weights, dtype=_F64, device="cpu").to(rise.device, rise.dtype)
    return torch.cat(rises), torch.cat(rates), torch.cat(losses), weights_


def between_frames(rise: Tensor, switch: Tensor) -> Tensor:
    """The surface between the frames as high as the frames allow: each frame moved by
    ``-(g_(n+1) - 2 g_n + g_(n-1)) / 12``, and the frame after ``switch`` raised to at least the heating's
    own continuation ``2 g_s - g_(s-1)``. ``switch``: each video's last frame before its switch-off.

    Shape:
        ``rise`` ``(B, T, H, W)`` with ``T > 2``, ``switch`` ``(B,)`` -> ``(B, T, H, W)``.
    """
    bend = torch.zeros_like(rise)
    bend[:, 1:-1] = rise[:, 2:] - 2 * rise[:, 1:-1] + rise[:, :-2]
    late = rise - bend / 12.0
    at = switch.clamp(1, rise.shape[1] - 2).view(-1, 1, 1, 1).expand(-1, 1, *rise.shape[2:])
    heating = 2 * rise.gather(1, at) - rise.gather(1, at - 1)
    return late.scatter(1, at + 1, torch.maximum(late.gather(1, at + 1), heating))


def spread(values: Tensor, weights: Tensor, other: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """The base value and its standard error: the root of the copies' weighted squared changes.

    ``values`` ``(V B, ...)`` holds the base, then each copy; ``weights`` ``(V - 1,)`` are the copies'
    weights from :func:`perturbed_copies`. With ``other``, the base's depth by the other integration rule
    ``(B, ...)``, half the two rules' difference is added in quadrature. Returns two ``(B, ...)``."""
    stacked = values.reshape(len(weights) + 1, -1, *values.shape[1:])
    base = stacked[0]
    change = (stacked[1:] - base) ** 2
    variance = (weights.to(change.dtype).view(-1, *[1] * base.ndim) * change).sum(0)
    if other is not None:
        variance = variance + (0.5 * (other - base)) ** 2
    return base, variance.sqrt()


def noise_correlation(
    depths: Tensor, a: Tensor, b: Tensor, dt: Tensor, dx: Tensor, size: tuple[int, int], noise: Tensor
) -> tuple[Tensor, Tensor]:
    """The temperature noise a white surface noise puts at each depth node, in float64.

    Args:
        depths: node depths in mm, ``(Z,)``.
        a, b, dt, dx, noise: diffusivity in mm^2/s, loss rate in 1/s, frame period in s, pixel size in mm
            and the frames' noise sd in K, each ``(B,)``.
        size: the frame ``(H, W)`` whose cosine modes carry the noise.

    Returns:
        The variance in K^2 and the frame-to-frame correlation of an exponential autocovariance.

    Shape:
        ``(Z,)`` -> ``(B, Z)``, ``(B, Z)``.
    """
    like = {"device": a.device, "dtype": _F64}
    a, b, dt, dx, noise = (x.detach().to(**like).view(-1, 1, 1, 1) for x in (a, b, dt, dx, noise))
    h, w = size
    ky = (math.pi / h) * torch.arange(h, **like)
    kx = (math.pi / w) * torch.arange(w, **like)
    k2 = (ky[:, None] ** 2 + kx[None, :] ** 2).flatten() / dx.view(-1, 1) ** 2  # (B, N)
    edges = torch.linspace(0.0, 1.0, _BINS + 1, **like) ** 2 * k2.amax(1, keepdim=True) * (1 + 1e-9)
    index = torch.searchsorted(edges.contiguous(), k2.contiguous(), right=True).clamp(1, _BINS) - 1
    count = torch.zeros(k2.shape[0], _BINS, **like).scatter_add(1, index, torch.ones_like(k2))
    total = torch.zeros_like(count).scatter_add(1, index, k2)
    centre = (total / count.clamp_min(1.0)).view(-1, _BINS, 1, 1)  # (B, bins, 1, 1)
    weight = (count / (h * w)).view(-1, _BINS, 1, 1)
    z = depths.detach().to(**like).view(1, 1, -1, 1)
    # The frames joined by straight lines: the noise's spectrum is sigma^2 dt sinc^4(w dt / 2) at every w
    # (its aliases included), integrated here up to 8 times the frames' Nyquist frequency.
    fraction = (torch.arange(_FREQUENCIES, **like) + 0.5) / _FREQUENCIES * _ALIASES
    omega = (math.pi * fraction / dt.view(-1, 1)).view(-1, 1, 1, _FREQUENCIES)
    hat = torch.sinc(fraction / 2) ** 4 * _ALIASES  # sinc(x) = sin(pi x) / (pi x)
    rate = (a * centre + b) / a  # 1/mm^2
    root = torch.sqrt(torch.complex(rate.expand_as(omega + rate), omega / a))  # (B, bins, 1, F)
    power = torch.exp(-2.0 * z * root.real) * hat  # |H|^2 sinc^4, (B, bins, Z, F)
    variance = noise.view(-1, 1) ** 2 * (weight * power.mean(-1, keepdim=True)).sum(1)[..., 0]
    variance = torch.where(z.view(1, -1) == 0, noise.view(-1, 1) ** 2, variance)  # the frames themselves
    zero = noise.view(-1, 1) ** 2 * (weight * torch.exp(-2.0 * z * rate.sqrt())).sum(1)[..., 0]
    rho = ((zero - variance) / (zero + variance).clamp_min(1e-300)).clamp(0.0, 1.0 - 1e-9)
    return variance, rho


def threshold_depth(values: Tensor, depths: Tensor, threshold: float | Tensor) -> Tensor:
    """Deepest point along the depth axis where ``values >= threshold``, with ``log(values)``
    interpolated linearly between the nodes around it; 0 where no node reaches it. Differentiable in
    ``values``.

    Args:
        values: a positive dose at every node, such as Omega or CEM43, ``(..., Z, H, W)``.
        depths: node depths in mm, increasing, ``(Z,)``.
        threshold: the dose, positive.

    Returns:
        Depth in mm, ``(..., H, W)``.

    Shape:
        ``(..., Z, H, W)`` -> ``(..., H, W)``.

    Example:
        >>> omega = torch.tensor([8.0, 2.0, 0.5]).view(3, 1, 1)  # ln: 2.08, 0.69, -0.69
        >>> round(float(threshold_depth(omega, torch.tensor([0.0, 0.1, 0.2]), 1.0)), 6)
        0.15
    """
    z = depths.to(device=values.device, dtype=values.dtype)
    above = values >= threshold
    n = values.shape[-3]
    index = torch.arange(n, device=values.device).view(-1, 1, 1)
    last = torch.where(above, index, -1).amax(-3, keepdim=True)  # deepest node at or above
    here = last.clamp_min(0)
    below = (here + 1).clamp_max(n - 1)
    log_here = torch.log(values.gather(-3, here).clamp_min(1e-300) / threshold)
    log_below = torch.log(values.gather(-3, below).clamp_min(1e-300) / threshold)
    span = (log_here - log_below).clamp_min(1e-12)
    fraction = torch.where(below > here, (log_here / span).clamp(0.0, 1.0), torch.zeros_like(span))
    depth = z[here] + fraction * (z[below] - z[here])
    return torch.where(last >= 0, depth, torch.zeros_like(depth)).squeeze(-3)


def threshold_variance(values: Tensor, variance: Tensor, depths: Tensor, threshold: float) -> Tensor:
    """The variance in mm^2 of :func:`threshold_depth` from the dose's noise variance ``variance`` at every
    node: ``Var(ln D)`` interpolated to the crossing, over the squared slope of ``ln D`` there.

    Shape:
        ``values``, ``variance`` ``(..., Z, H, W)`` -> ``(..., H, W)``.
    """
    z = depths.to(device=values.device, dtype=values.dtype)
    n = values.shape[-3]
    index = torch.arange(n, device=values.device).view(-1, 1, 1)
    last = torch.where(values >= threshold, index, -1).amax(-3, keepdim=True)
    here = last.clamp_min(0)
    below = (here + 1).clamp_max(n - 1)
    log_here = torch.log(values.gather(-3, here).clamp_min(1e-300) / threshold)
    log_below = torch.log(values.gather(-3, below).clamp_min(1e-300) / threshold)
    span = (log_here - log_below).clamp_min(1e-12)
    fraction = (log_here / span).clamp(0.0, 1.0)
    relative = variance / values.clamp_min(1e-300) ** 2  # Var(ln D) at every node
    mixed = (1 - fraction) * relative.gather(-3, here) + fraction * relative.gather(-3, below)
    slope = span / (z[below] - z[here]).clamp_min(1e-12)
    out = torch.where((last >= 0) & (below > here), mixed / slope**2, torch.zeros_like(mixed))
    return out.squeeze(-3)
