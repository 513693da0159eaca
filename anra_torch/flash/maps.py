"""A flash recording's maps: the defect map and the standard contrasts beside it, from the whole video.

:func:`flash_maps` finds the flash (the frame whose mean is highest: the first after it), maps the cooling
from there (:func:`~anra_torch.flash.defects.defect_map`) and computes TSR, PCT and PPT on the same
frames (:mod:`~anra_torch.flash.contrasts`; TSR against the fitted ``T_ref`` at the fitted times since the
flash). :meth:`FlashMaps.arrays` are what ``anra diagnose --maps`` writes, :meth:`FlashMaps.record` what
its JSON says (docs/reference/outputs.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import as_video
from anra_torch.flash.contrasts import pct, ppt, tsr
from anra_torch.flash.defects import DefectMap, defect_map

__all__ = ["TSR_FRAMES", "FlashMaps", "flash_maps"]

TSR_FRAMES = 16
"""Frames at which the TSR second derivative is kept, evenly spaced in ``ln t`` over the cooling."""

_MIN_COOLING = 8


@dataclass(frozen=True)
class FlashMaps:
    """Output of :func:`flash_maps`.

    Attributes:
        defects: the defect map of the cooling.
        flash_frame: the first frame after the flash (the cooling starts there).
        tsr_d2: TSR's ``d^2 ln (T - T_ref) / d (ln t)^2`` at :data:`TSR_FRAMES` frames, ``(F, H, W)``.
        tsr_times: those frames' times since the flash in s, ``(F,)``.
        pct: PCT's first six spatial components, ``(6, H, W)``.
        ppt: PPT's phase at the eight lowest frequencies in rad, ``(8, H, W)``.
        ppt_frequencies: those frequencies in Hz, ``(8,)``.
    """

    defects: DefectMap
    flash_frame: int
    tsr_d2: Tensor
    tsr_times: Tensor
    pct: Tensor
    ppt: Tensor
    ppt_frequencies: Tensor

    def arrays(self) -> dict[str, np.ndarray]:
        """The maps as NumPy arrays by their names in the ``--maps`` file."""
        d = self.defects
        out = {
            "defect_score": d.defect_score,
            "defect_mask": d.defect_mask,
            "depth_fraction": d.depth_fraction,
            "depth_time": d.depth_time,
            "tsr_d2": self.tsr_d2,
            "tsr_times": self.tsr_times,
            "pct": self.pct,
            "ppt": self.ppt,
            "ppt_frequencies": self.ppt_frequencies,
        }
        return {k: v.detach().cpu().numpy() for k, v in out.items()}

    def record(self) -> dict[str, Any]:
        """The defect map's numbers (JSON-ready; ``inf`` and NaN as None)."""
        d = self.defects

        def finite(value: float) -> float | None:
            return value if math.isfinite(value) else None

        return {
            "plate_time": finite(d.plate_time),
            "plate_time_std_error": finite(d.plate_time_se),
            "back_wall_reached": d.back_wall_reached,
            "flash_frame": self.flash_frame,
            "first_frame_time": d.first_time,
            "T_ref": d.t_ref,
            "lateral_diffusivity": list(d.lateral),
            "noise_sd": d.noise_sd,
            "defect_pixels": int(d.defect_mask.sum()),
            "defects": [
                {
                    "x": f.x,
                    "y": f.y,
                    "area": f.area,
                    "depth_fraction": f.depth_fraction,
                    "touches_edge": f.touches_edge,
                }
                for f in d.defects
            ],
        }


def flash_maps(frames: Tensor, dt: float, dx: float, *, noise_sd: float | None = None) -> FlashMaps:
    """The defect map and the contrasts of a flash recording.

    Args:
        frames: the recording in C or K, frames before the flash allowed, ``(T, H, W)``.
        dt: frame period in s.
        dx: pixel size in mm.
        noise_sd: the camera's white noise sd (default: measured).

    Returns:
        :class:`FlashMaps`.

    Raises:
        ValueError: as :func:`~anra_torch.flash.defects.defect_map`, or fewer than 8 frames after the
            flash (the warmest frame).

    Shape:
        ``frames`` ``(T, H, W)``; maps ``(H, W)``.
    """
    video, batched = as_video(frames, name="frames", min_frames=_MIN_COOLING)
    if batched:
        raise ValueError(f"frames must be one recording (T, H, W), got {tuple(video.shape)}")
    video = video[0]
    means = video.double().mean((1, 2))
    start = int(torch.argmax(torch.nan_to_num(means, nan=-math.inf)))
    if len(video) - start < _MIN_COOLING:
        raise ValueError(
            f"frames must hold at least {_MIN_COOLING} frames after the flash (the warmest frame), got "
            f"{len(video) - start} after frame {start}"
        )
    cooling = video[start:]
    found = defect_map(cooling, dt, dx, noise_sd=noise_sd)
    times = found.first_time + dt * torch.arange(len(cooling), dtype=torch.float64, device=video.device)
    reconstruction = tsr(cooling.double(), times, baseline=found.t_ref)
    picks = torch.unique(
        torch.round(torch.logspace(0, math.log10(len(cooling)), TSR_FRAMES, device=video.device) - 1).long()
    )
    picks = picks.to(video.device)
    phase = ppt(cooling, dt)
    return FlashMaps(
        defects=found,
        flash_frame=start,
        tsr_d2=reconstruction.second[picks],
        tsr_times=times[picks],
        pct=pct(cooling).maps,
        ppt=phase.phase,
        ppt_frequencies=phase.frequencies,
    )
