"""RTC attention: where the temperature changes fastest, per frame (stages IV and V of ANRA).

The paper's definition (El-Kebir et al., eq. RTC), per frame k over pixels (i, j)::

    RTC = exp(|dT/dt|);  RTC -= min RTC;  RTC /= sum RTC

computed here without overflow by factoring out the per-frame maximum, which cancels in the
normalisation: ``(exp(z - z_max) - exp(z_min - z_max)) / sum(...)``. For ``|dT/dt| = 1e4 K/s`` this gives the
exact limit (all weight on the fastest pixels) instead of ``inf / inf``.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["RTCAttention", "UniformAttention", "rtc_attention", "confidence_mask"]


def _rtc(rate: Tensor, sharpness: float, unit_invariant: bool, mask: Tensor | None) -> tuple[Tensor, Tensor]:
    """RTC weights and their diagonal derivative d w_ij / d rate_ij (same shapes)."""
    magnitude = rate.abs()
    valid = torch.isfinite(magnitude)
    if mask is not None:
        valid = valid & mask.to(torch.bool)
    magnitude = torch.where(valid, magnitude, torch.zeros_like(magnitude))
    scale = torch.ones_like(magnitude[..., :1, :1])
    if unit_invariant:
        peak = magnitude.amax(dim=(-2, -1), keepdim=True)
        scale = torch.where(peak > 0, peak, torch.ones_like(peak))
    z = sharpness * magnitude / scale
    z_max = torch.where(valid, z, torch.full_like(z, -torch.inf)).amax(dim=(-2, -1), keepdim=True)
    z_min = torch.where(valid, z, torch.full_like(z, torch.inf)).amin(dim=(-2, -1), keepdim=True)
    z_max = torch.where(torch.isfinite(z_max), z_max, torch.zeros_like(z_max))
    z_min = torch.where(torch.isfinite(z_min), z_min, z_max)
    grow = torch.exp(z - z_max)
    raw = torch.where(valid, (grow - torch.exp(z_min - z_max)).clamp_min(0), torch.zeros_like(z))
    total = raw.sum(dim=(-2, -1), keepdim=True)
    total = torch.where(total > 0, total, torch.ones_like(total))
    weights = raw / total
    slope = torch.where(valid, grow * sharpness * torch.sign(rate) / scale, torch.zeros_like(z))
    return weights, slope * (1 - weights) / total


def rtc_attention(
    rate: Tensor,
    *,
    sharpness: float = 1.0,
    unit_invariant: bool = False,
    mask: Tensor | None = None,
) -> Tensor:
    """Rate-of-temperature-change attention weights, summing to 1 over each frame's valid pixels.

    Args:
        rate: time derivative dT/dt (units of the data per s).
        sharpness: multiplies ``|dT/dt|`` inside the exponential (1/(K/s); 1 is the paper's choice).
        unit_invariant: divide ``|dT/dt|`` by its per-frame maximum first, so the weights do not depend
            on the units of T and t (the paper's form depends on them).
        mask: boolean, True where a pixel may receive weight; others get exactly 0.

    Returns:
        Weights of the same shape; a frame whose valid ``|dT/dt|`` is constant (no thermal activity)
        gets all-zero weights, never NaN.

    Shape:
        ``rate``: ``(..., H, W)``; ``mask``: broadcastable to it; output like ``rate``.
    """
    if not rate.is_floating_point():
        raise TypeError(f"rate must be a floating tensor, got dtype {rate.dtype}")
    if not (sharpness > 0):
        raise ValueError(f"sharpness must be a positive number, got {sharpness!r}")
    return _rtc(rate, sharpness, unit_invariant, mask)[0]


def confidence_mask(weights: Tensor, threshold: float) -> Tensor:
    """Stage V: keep pixels whose attention is at least ``threshold`` times the frame's maximum.

    Shape:
        ``weights`` ``(..., H, W)``; output boolean, same shape.
    """
    if not 0.0 <= threshold < 1.0:
        raise ValueError(f"threshold must be in [0, 1), got {threshold!r}")
    peak = weights.amax(dim=(-2, -1), keepdim=True)
    return (weights > 0) & (weights >= threshold * peak)


class RTCAttention(nn.Module):
    """Softmax-like attention on the rate of temperature change, with the stage-V confidence threshold.

    Args:
        sharpness: scale inside the exponential (see :func:`rtc_attention`).
        unit_invariant: make the weights independent of the units of T and t.
        threshold: stage V, drop pixels below ``threshold * max`` of the frame and renormalise (0 keeps all).

    Shape:
        Input ``(B, K, H, W)`` rates (and optional boolean mask); output weights, same shape, each frame
        summing to 1 over its kept pixels (or to 0 for a frame without activity).
    """

    def __init__(
        self, *, sharpness: float = 1.0, unit_invariant: bool = False, threshold: float = 0.0
    ) -> None:
        super().__init__()
        if not 0.0 <= threshold < 1.0:
            raise ValueError(f"threshold must be in [0, 1), got {threshold!r}")
        if not (sharpness > 0):
            raise ValueError(f"sharpness must be a positive number, got {sharpness!r}")
        self.sharpness, self.unit_invariant, self.threshold = sharpness, unit_invariant, threshold

    def forward(self, rate: Tensor, mask: Tensor | None = None) -> Tensor:
        return self.with_slope(rate, mask)[0]

    def with_slope(self, rate: Tensor, mask: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Weights and their diagonal sensitivity ``d w_ij / d rate_ij`` (per s / unit of the data).

        The weights depend on the noisy rate they later multiply; by Stein's identity that correlation
        biases a weighted regression by ``noise_var * sum(slope * regressor)``, which the estimator removes.
        Couplings through the per-frame normalisation and maximum are O(1/pixels) and left out.
        """
        if not rate.is_floating_point():
            raise TypeError(f"rate must be a floating tensor, got dtype {rate.dtype}")
        weights, slope = _rtc(rate, self.sharpness, self.unit_invariant, mask)
        if self.threshold > 0:
            kept = confidence_mask(weights, self.threshold)
            total = (weights * kept).sum(dim=(-2, -1), keepdim=True)
            total = torch.where(total > 0, total, torch.ones_like(total))
            weights, slope = weights * kept / total, slope * kept / total
        return weights, slope

    def extra_repr(self) -> str:
        return (
            f"sharpness={self.sharpness:g}, unit_invariant={self.unit_invariant}, "
            f"threshold={self.threshold:g}"
        )


class UniformAttention(nn.Module):
    """Equal weight on every valid pixel of a frame (summing to 1): the no-attention reference.

    Same interface as :class:`RTCAttention`; its slope is zero, so it adds no weighting bias.

    Shape:
        Input ``(B, K, H, W)``; output weights, same shape.
    """

    def forward(self, rate: Tensor, mask: Tensor | None = None) -> Tensor:
        return self.with_slope(rate, mask)[0]

    def with_slope(self, rate: Tensor, mask: Tensor | None = None) -> tuple[Tensor, Tensor]:
        if mask is None and bool(torch.isfinite(rate.sum((-2, -1))).all()):  # every pixel: one weight
            shape = (*rate.shape[:-2], 1, 1)
            weight = rate.new_full(shape, 1.0 / (rate.shape[-2] * rate.shape[-1]))
            return weight.expand_as(rate), rate.new_zeros(shape).expand_as(rate)  # broadcast, no memory
        valid = torch.isfinite(rate)
        if mask is not None:
            valid = valid & mask.to(torch.bool)
        weights = valid.to(rate.dtype)
        total = weights.sum(dim=(-2, -1), keepdim=True)
        weights = weights / torch.where(total > 0, total, torch.ones_like(total))
        return weights, torch.zeros_like(weights)
