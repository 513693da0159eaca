"""Region of interest and pixel masks: crop a video, flag dead pixels and reflections.

A masked pixel becomes NaN in every frame; the estimator drops non-finite pixels explicitly and reports
how many (``n_masked``), so a stuck pixel or a reflection cannot pose as temperature.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from anra_torch.video.core import Video

__all__ = ["ROI", "apply_mask", "crop", "dead_pixel_mask", "parse_roi", "reflection_mask"]

ROI = tuple[int, int, int, int]
"""``(x0, y0, width, height)`` in px: columns x0 .. x0 + width - 1, rows y0 .. y0 + height - 1."""


def parse_roi(text: str) -> ROI:
    """``"X0,Y0,W,H"`` in px -> :data:`ROI`.

    Raises:
        ValueError: not four integers, or a negative origin or non-positive size.
    """
    try:
        x0, y0, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"roi must be X0,Y0,W,H in px (four integers), got {text!r}") from None
    if x0 < 0 or y0 < 0 or w < 1 or h < 1:
        raise ValueError(f"roi needs X0, Y0 >= 0 and W, H >= 1 px, got {text!r}")
    return x0, y0, w, h


def crop(video: Video, roi: ROI) -> Video:
    """Keep the region ``roi`` = (x0, y0, width, height) px; ``meta["roi"]`` records it.

    Shape:
        ``(T, H, W)`` -> ``(T, height, width)``.

    Raises:
        ValueError: a region outside the frame.
    """
    x0, y0, w, h = roi
    _, height, width = video.frames.shape
    if x0 + w > width or y0 + h > height:
        raise ValueError(
            f"{video.name}: roi {x0},{y0},{w},{h} (x0,y0,W,H px) does not fit in the "
            f"{width} x {height} px frame"
        )
    return video.map_frames(
        lambda frames: frames[:, y0 : y0 + h, x0 : x0 + w].contiguous(),
        meta={**video.meta, "roi": [x0, y0, w, h]},
    )


def dead_pixel_mask(frames: Tensor, *, spike: float = 8.0) -> Tensor:
    """Pixels that are stuck (exactly constant in time while the frame changes) or isolated spikes.

    A spike is a pixel whose time-median differs from the median of its 3 x 3 neighbours by more than
    ``spike`` robust standard deviations of that difference over the frame.

    Shape:
        ``(T, H, W)`` -> bool ``(H, W)``.
    """
    x = frames.double()
    stuck = (x == x[:1]).all(dim=0) & (x.amax(dim=(1, 2)) != x.amin(dim=(1, 2))).any()
    median = x.median(dim=0).values
    padded = torch.nn.functional.pad(median[None, None], (1, 1, 1, 1), mode="replicate")[0, 0]
    patches = padded.unfold(0, 3, 1).unfold(1, 3, 1).reshape(*median.shape, 9)
    neighbours = torch.cat([patches[..., :4], patches[..., 5:]], dim=-1).median(dim=-1).values
    diff = median - neighbours
    scale = 1.4826 * (diff - diff.median()).abs().median()
    spikes = (diff - diff.median()).abs() > spike * scale if scale > 0 else torch.zeros_like(stuck)
    return stuck | spikes


def reflection_mask(frames: Tensor, hot: Tensor, *, margin_px: int = 2) -> Tensor:
    """Warm pixels not connected to the heated region ``hot``: mirror images, e.g. a weigh boat's walls.

    A pixel is flagged when its peak rise over the first frame exceeds 20 % of the largest rise but it lies
    more than ``margin_px`` px outside the connected warm region grown from ``hot``.

    Shape:
        ``frames`` ``(T, H, W)``, ``hot`` bool ``(H, W)`` -> bool ``(H, W)``.
    """
    rise = (frames.double() - frames[0].double()).amax(dim=0)
    warm = rise > 0.2 * rise.max()
    region = hot & warm
    kernel = torch.ones(1, 1, 3, 3, dtype=torch.float64)
    for _ in range(max(frames.shape[1:])):  # grow through warm pixels until it stops
        grown = (torch.nn.functional.conv2d(region[None, None].double(), kernel, padding=1)[0, 0] > 0) & warm
        if bool((grown == region).all()):
            break
        region = grown
    near = region[None, None].double()
    for _ in range(margin_px):
        near = (torch.nn.functional.conv2d(near, kernel, padding=1) > 0).double()
    return warm & ~near[0, 0].bool()


def apply_mask(video: Video, mask: Tensor) -> Video:
    """Set the masked pixels to NaN in every frame (float64); ``meta["masked_px"]`` counts them.

    Shape:
        ``video.frames`` ``(T, H, W)``, ``mask`` bool ``(H, W)``.

    Raises:
        ValueError: a mask of another shape.
    """
    if tuple(mask.shape) != tuple(video.frames.shape[1:]):
        raise ValueError(
            f"mask must have the frame shape {tuple(video.frames.shape[1:])}, got {tuple(mask.shape)}"
        )
    frames = video.frames.double().masked_fill(mask.bool(), float("nan"))
    return replace(video, frames=frames, meta={**video.meta, "masked_px": int(mask.sum())})
