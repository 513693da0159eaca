"""The naive estimators the paper compares ANRA against, built with kornia.

Both use the paper's RTC-weighted ratio ``a[k] = sum RTC * (dT/dt / Laplacian)`` with classical image
processing operators instead of noise-robust ones: a backward difference in time, paired with the newest
frame, and a Laplacian of Gaussian in space; the second variant also blurs every frame with a Gaussian first.
The paper reports -7.9 and -41.9 on its simulated case (truth 0.2): physically infeasible.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from anra_torch.checks import as_spacing, as_video
from anra_torch.layers import rtc_attention

__all__ = ["log_kernel", "backward_log_estimate", "BASELINES"]


def log_kernel(sigma: float, *, truncate: float = 4.0) -> Tensor:
    """Laplacian-of-Gaussian kernel for unit spacing, calibrated to be exact on quadratics.

    Sampled ``(r^2 - 2 s^2) / s^4 * G``, shifted to sum to 0 (constants give 0) and scaled so that
    ``x^2 + y^2`` gives 4 (kornia's own ``laplacian`` is not calibrated).

    Shape:
        Output ``(2 R + 1, 2 R + 1)``, float64, ``R = ceil(truncate * sigma)``.
    """
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ValueError(f"log sigma must be a positive number of pixels, got {sigma!r}")
    radius = max(1, math.ceil(truncate * sigma))
    offsets = torch.arange(-radius, radius + 1, dtype=torch.float64)
    yy, xx = torch.meshgrid(offsets, offsets, indexing="ij")
    r2 = xx**2 + yy**2
    kernel = (r2 - 2 * sigma**2) / sigma**4 * torch.exp(-r2 / (2 * sigma**2))
    kernel = kernel - kernel.mean()
    return kernel * (4.0 / float((kernel * r2).sum()))


def backward_log_estimate(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    *,
    log_sigma: float = 1.0,
    blur_sigma: float | None = None,
) -> Tensor:
    """Paper baseline: backward difference + Laplacian of Gaussian (+ optional Gaussian blur), RTC ratio.

    Args:
        frames: video ``(T, H, W)`` or ``(B, T, H, W)``.
        dt: frame period in s; dx: pixel size in mm; floats or ``(B,)``.
        log_sigma: LoG scale in px.
        blur_sigma: Gaussian blur of every frame first in px, None for none.

    Returns:
        Diffusivity in mm^2/s per video, the mean over frames of the paper's weighted ratio; may be
        negative or huge: that is the point of the baseline. Pixels where the LoG is exactly 0 are skipped.

    Shape:
        ``(B, T, H, W)`` -> ``(B,)``; ``(T, H, W)`` -> 0-d.
    """
    import kornia  # here, not at the top: 0.2 s CPU at every start of every command that never uses it

    video, batched = as_video(frames, min_frames=2)
    b, t, h, w = video.shape
    dt_ = as_spacing(dt, name="dt", unit="s", batch=b, like=video).view(b, 1, 1, 1)
    dx_ = as_spacing(dx, name="dx", unit="mm", batch=b, like=video).view(b, 1, 1, 1)
    flat = video.reshape(b * t, 1, h, w)
    if blur_sigma is not None:
        k = 2 * math.ceil(3 * blur_sigma) + 1
        flat = kornia.filters.gaussian_blur2d(flat, (k, k), (blur_sigma, blur_sigma), border_type="replicate")
    kernel = log_kernel(log_sigma).to(video.dtype)[None]
    lap = kornia.filters.filter2d(flat, kernel, border_type="replicate").reshape(b, t, h, w)
    smoothed = flat.reshape(b, t, h, w)
    rate = (smoothed[:, 1:] - smoothed[:, :-1]) / dt_
    lap = lap[:, 1:] / dx_**2
    weights = rtc_attention(rate)
    safe = torch.where(lap == 0, torch.ones_like(lap), lap)
    ratio = torch.where(lap == 0, torch.zeros_like(lap), weights * rate / safe)
    estimate = ratio.sum((-2, -1)).mean(1)
    return estimate if batched else estimate[0]


BASELINES = {
    "backward+LoG": lambda frames, dt, dx: backward_log_estimate(frames, dt, dx),
    "backward+LoG+blur": lambda frames, dt, dx: backward_log_estimate(frames, dt, dx, blur_sigma=2.0),
}
"""The paper's two naive baselines by name: callables ``(frames, dt, dx) -> (B,)`` diffusivities."""
