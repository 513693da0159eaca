"""Synthetic thermal videos of known diffusivity, from the exact solutions of :mod:`anra_torch.simulation`.

- :func:`paper_video`: the simulation case of El-Kebir, Lee and Bentsman (arXiv 2203.13148).
- :func:`blobs_video`: several Gaussian blobs at random positions on a warm background.

Both are exact solutions of ``dT/dt = a (d_xx + d_yy) T`` on the infinite plane sampled at the pixel
centres (no discretisation error), plus independent zero-mean Gaussian noise on every pixel of
every frame.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import check_dtype, check_int, number, positive
from anra_torch.simulation.analytic import gaussian_blob, gaussian_blobs
from anra_torch.video import save_npz

__all__ = ["Blobs", "PaperSpot", "SyntheticVideo", "blobs_video", "paper_video"]

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
"""Full width at half maximum of a Gaussian in units of its standard deviation (2.3548...)."""


@dataclass(frozen=True)
class SyntheticVideo:
    """A synthetic thermal video and the truth it was made from.

    Attributes:
        frames: noisy temperatures.
        clean: the noise-free field (shared by all videos when it has no batch dimension).
        dt: frame period in s.
        dx: pixel size in mm.
        a: true diffusivity in mm^2/s.
        times: frame times in s, ``k dt``.

    Shape:
        ``frames`` ``(B, T, H, W)``; ``clean`` ``(T, H, W)`` or ``(B, T, H, W)``;
        ``times`` ``(T,)``.
    """

    frames: Tensor
    clean: Tensor
    dt: float
    dx: float
    a: float
    times: Tensor

    def to_npz(self, path: str | os.PathLike[str]) -> None:
        """Save as ``.npz`` with keys ``frames``, ``dt``, ``dx``, ``t`` and ``a_true``.

        ``frames`` is ``(T, H, W)`` when B == 1, else ``(B, T, H, W)``.

        ``numpy.savez`` appends ``.npz`` to a path without that suffix.
        """
        frames = self.frames[0] if self.frames.shape[0] == 1 else self.frames
        save_npz(path, frames, dt=self.dt, dx=self.dx, t=self.times, batch=True, a_true=np.float64(self.a))


@dataclass(frozen=True)
class PaperSpot:
    """The initial hot spot of the paper's case and the frame it lies in.

    Attributes:
        peak: initial peak temperature (above a background of 0).
        diameter_px: initial full width at half maximum in pixels.
        extent: frame side in mm (the paper's "units"): ``dx = extent / size``.
    """

    peak: float = 3.8
    diameter_px: float = 50.0
    extent: float = 10.0

    def checked(self) -> PaperSpot:
        """This spot checked (``extent`` and ``diameter_px`` positive, ``peak`` finite).

        Raises:
            ValueError: a non-positive extent or diameter, a peak that is not a finite number.
        """
        extent = positive(self.extent, "extent", "mm")
        peak = number(self.peak, "peak", "units of temperature")
        return PaperSpot(
            peak=peak, diameter_px=positive(self.diameter_px, "diameter_px", "px"), extent=extent
        )


def paper_video(
    *,
    n_videos: int = 1,
    seed: int = 0,
    noise_sd: float = 0.01,
    fps: float = 27.0,
    duration: float = 1.0,
    size: int = 224,
    a: float = 0.2,
    spot: PaperSpot | None = None,
    crop: int | None = None,
    dtype: torch.dtype = torch.float64,
) -> SyntheticVideo:
    """The simulation case of El-Kebir et al. (arXiv 2203.13148), computed exactly.

    A Gaussian spot (:class:`PaperSpot`) centred in a ``size x size`` frame, diffusing with ``a``, sampled
    at ``fps`` for ``duration`` s (``round(duration * fps) + 1`` frames from t = 0), plus Gaussian noise of
    sd ``noise_sd``: the clean field computed once, ``n_videos`` noise draws seeded by ``seed``.

    Args:
        n_videos: number of independent noise realisations B.
        seed: seed of the noise.
        noise_sd: noise standard deviation, units of temperature, >= 0.
        fps: frame rate in Hz.
        duration: recording length in s.
        size: frame side in pixels.
        a: diffusivity in mm^2/s.
        spot: the initial spot and the frame's side in mm (:class:`PaperSpot`); default the paper's.
        crop: keep only the central ``crop x crop`` pixels (those of the uncropped video, same seed).
        dtype: floating dtype of the frames.

    Returns:
        A :class:`SyntheticVideo` with ``clean`` shared across videos.

    Shape:
        ``frames`` ``(B, T, S, S)`` and ``clean`` ``(T, S, S)`` with ``S = crop or size``.

    Raises:
        ValueError: non-positive sizes, rates or durations, negative noise, ``crop`` outside ``[1, size]``.

    Example:
        >>> tuple(paper_video(n_videos=2, size=64, crop=32).frames.shape)  # 1 s at 27 fps: 28 frames
        (2, 28, 32, 32)
    """
    n_videos, seed = check_int(n_videos, "n_videos", 1), check_int(seed, "seed", 0)
    size = check_int(size, "size", 1)
    noise_sd = number(noise_sd, "noise_sd", "units of temperature", minimum=0.0)
    fps, duration = positive(fps, "fps", "Hz"), positive(duration, "duration", "s")
    a = number(a, "a", "mm^2/s", minimum=0.0)
    spot = (PaperSpot() if spot is None else spot).checked()
    crop = None if crop is None else _checked_crop(crop, size)
    check_dtype(dtype)
    times = torch.arange(round(duration * fps) + 1, dtype=torch.float64, device="cpu") / fps
    clean, dx = _spot_field(times, size, a, spot, dtype)
    generator = torch.Generator().manual_seed(seed)
    noise = torch.randn((n_videos, *clean.shape), generator=generator, dtype=dtype, device="cpu")
    frames = clean + noise_sd * noise
    if crop is not None:
        frames, clean = _centre(frames, crop), _centre(clean, crop)
    return SyntheticVideo(frames=frames, clean=clean, dt=1.0 / fps, dx=dx, a=a, times=times.to(dtype))


def _spot_field(
    times: Tensor, size: int, a: float, spot: PaperSpot, dtype: torch.dtype
) -> tuple[Tensor, float]:
    """The clean field ``(T, size, size)`` of ``spot`` diffusing with ``a`` at ``times`` in s; ``dx`` in
    mm."""
    dx = spot.extent / size
    sigma = spot.diameter_px / FWHM_PER_SIGMA * dx
    return gaussian_blob(times, shape=(size, size), dx=dx, a=a, peak=spot.peak, sigma=sigma).to(dtype), dx


def _checked_crop(crop: int, size: int) -> int:
    """``crop`` an integer in ``[1, size]``."""
    crop = check_int(crop, "crop", 1)
    if crop > size:
        raise ValueError(f"crop must be at most size={size} px, got {crop}")
    return crop


def _centre(frames: Tensor, crop: int) -> Tensor:
    """The central ``crop x crop`` pixels of ``(..., S, S)`` frames, contiguous."""
    start = (frames.shape[-1] - crop) // 2
    return frames[..., start : start + crop, start : start + crop].contiguous()


@dataclass(frozen=True)
class Blobs:
    """The hot spots :func:`blobs_video` draws on each video.

    Attributes:
        n_blobs: hot spots per video.
        background: uniform temperature under the blobs.
        peak_range: ``(low, high)`` initial peak above the background.
        sigma_range_px: ``(low, high)`` initial standard deviation in pixels; ``high < size / 4``.
    """

    n_blobs: int = 3
    background: float = 30.0
    peak_range: tuple[float, float] = (3.0, 10.0)
    sigma_range_px: tuple[float, float] = (4.0, 12.0)


def blobs_video(
    *,
    n_videos: int = 1,
    seed: int = 0,
    blobs: Blobs | None = None,
    size: int = 96,
    dx: float = 0.5,
    fps: float = 30.0,
    n_frames: int = 40,
    a: float = 0.15,
    noise_sd: float = 0.02,
    dtype: torch.dtype = torch.float64,
) -> SyntheticVideo:
    """Gaussian hot spots at random positions on a warm uniform background, computed exactly.

    Each video draws its own peaks, initial standard deviations in px and centres (at least two of them
    inside the frame), then its noise, all uniform from ``torch.Generator().manual_seed(seed)``.

    Args:
        n_videos: number of videos B, each with its own geometry and noise.
        seed: seed of geometry and noise.
        blobs: the hot spots drawn (:class:`Blobs`); default ``Blobs()``.
        size: frame side in pixels.
        dx: pixel size in mm.
        fps: frame rate in Hz.
        n_frames: number of frames T (frame k at ``t = k / fps``).
        a: diffusivity in mm^2/s.
        noise_sd: noise standard deviation, units of temperature, >= 0.
        dtype: floating dtype of the frames.

    Returns:
        A :class:`SyntheticVideo` with a per-video ``clean`` field.

    Shape:
        ``frames`` and ``clean`` ``(B, T, size, size)``.

    Raises:
        ValueError: non-positive sizes or rates, bad ranges, blobs too wide to fit in the frame.
    """
    blobs = Blobs() if blobs is None else blobs
    n_videos, seed = check_int(n_videos, "n_videos", 1), check_int(seed, "seed", 0)
    n_blobs, size = check_int(blobs.n_blobs, "n_blobs", 1), check_int(size, "size", 1)
    n_frames, dx = check_int(n_frames, "n_frames", 1), positive(dx, "dx", "mm")
    fps = positive(fps, "fps", "Hz")
    a = number(a, "a", "mm^2/s", minimum=0.0)
    background = number(blobs.background, "background", "units of temperature")
    noise_sd = number(noise_sd, "noise_sd", "units of temperature", minimum=0.0)
    peaks_range = _check_range(blobs.peak_range, "peak_range", "units of temperature", minimum=-math.inf)
    sigmas_range = _check_sigma_range(blobs.sigma_range_px, size)
    check_dtype(dtype)

    generator = torch.Generator().manual_seed(seed)
    peaks, sigma_px, centre_px = _draw_blobs(generator, n_videos, n_blobs, size, peaks_range, sigmas_range)
    times = torch.arange(n_frames, dtype=torch.float64, device="cpu") / fps
    shape, sigmas, centres = (size, size), sigma_px * dx, centre_px * dx
    clean = gaussian_blobs(
        times, shape=shape, dx=dx, a=a, peaks=peaks, sigmas=sigmas, centres=centres, background=background
    ).to(dtype)
    frames = clean + noise_sd * torch.randn(clean.shape, generator=generator, dtype=dtype, device="cpu")
    return SyntheticVideo(frames=frames, clean=clean, dt=1.0 / fps, dx=dx, a=a, times=times.to(dtype))


# ------------------------------------------------------------------------------------- validation
def _check_range(value: object, name: str, unit: str, *, minimum: float) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in value)  # type: ignore[attr-defined]
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a pair (low, high) in {unit}, got {value!r}") from err
    if not (math.isfinite(low) and math.isfinite(high)) or low > high or low < minimum:
        raise ValueError(f"{name} must be a finite pair with low <= high in {unit}, got {value!r}")
    return low, high


def _check_sigma_range(value: object, size: int) -> tuple[float, float]:
    """``sigma_range_px`` checked: positive, and small enough for the blobs to fit in the frame."""
    low, high = _check_range(value, "sigma_range_px", "px", minimum=0.0)
    if low <= 0:
        raise ValueError(f"sigma_range_px must be positive, got {tuple(value)}")  # type: ignore[arg-type]
    if 4 * high >= size:
        raise ValueError(
            f"sigma_range_px must stay below size / 4 = {size / 4:g} px to keep blobs inside the "
            f"frame, got {high:g}"
        )
    return low, high


def _draw_blobs(
    generator: torch.Generator,
    n_videos: int,
    n_blobs: int,
    size: int,
    peak_range: tuple[float, float],
    sigma_range: tuple[float, float],
) -> tuple[Tensor, Tensor, Tensor]:
    """Peaks, sigmas in px and centres in px of each video's blobs, centres two sigmas inside the frame.

    Shape:
        ``(B, N)``, ``(B, N)``, ``(B, N, 2)``.
    """
    draws = torch.rand((n_videos, n_blobs, 4), generator=generator, dtype=torch.float64, device="cpu")
    peaks = peak_range[0] + (peak_range[1] - peak_range[0]) * draws[..., 0]
    sigma_px = sigma_range[0] + (sigma_range[1] - sigma_range[0]) * draws[..., 1]
    margin = 2.0 * sigma_px  # centres at least two initial sd from every edge
    centre_px = margin[..., None] + (size - 2.0 * margin[..., None]) * draws[..., 2:]
    return peaks, sigma_px, centre_px
