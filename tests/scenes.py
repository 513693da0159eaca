"""Synthetic videos and recordings that several test files share.

The recordings of explicit finite-difference heat equations (:func:`heated_then_cooled`) and the small
boxes are written here in NumPy, independent of the package's simulators. The camera scene is the
package's pure-diffusion :func:`~anra_torch.effects.hidden_effect_video`, on which
:mod:`anra_torch.simulation.camera` plants artefacts; it is built once per test process
(:func:`functools.cache`), so callers must not change it in place (every test builds new tensors from it).
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from anra_torch.effects import HiddenEffectVideo, hidden_effect_video
from anra_torch.recording import PhaseDiagnosis, diagnose_recording
from anra_torch.simulation import gaussian_blob
from anra_torch.simulation.camera import correlated_noise, plant
from anra_torch.video import Video

DT, DX, A = 0.1, 0.25, 0.3
"""Frame period (s), pixel size (mm) and diffusivity (mm^2/s) of the finite-difference recordings."""


def heated_then_cooled(
    off: int = 60, n: int = 110, size: int = 40, noise: float = 0.01, seed: int = 0
) -> np.ndarray:
    """Explicit FTCS heat equation (zero-flux edges) with a Gaussian source on for frames < ``off``.

    Shape:
        ``(n, size, size)``, spacing :data:`DT`, :data:`DX`, diffusivity :data:`A`.
    """
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:size, :size] * DX
    c = (size - 1) * DX / 2
    q = 4.0 * np.exp(-((x - c) ** 2 + (y - c) ** 2) / (2 * 1.0**2))  # K/s
    u = np.full((size, size), 20.0)
    sub = 10
    h = DT / sub
    frames = []
    for k in range(n):
        frames.append(u.copy())
        for _ in range(sub):
            p = np.pad(u, 1, mode="edge")
            lap = (p[1:-1, 2:] + p[1:-1, :-2] + p[2:, 1:-1] + p[:-2, 1:-1] - 4 * u) / DX**2
            u = u + h * (A * lap + (q if k < off else 0.0))
    return np.asarray(frames) + rng.normal(0, noise, (n, size, size))


@functools.cache
def short_heating_phases(off: int) -> tuple[PhaseDiagnosis, ...]:
    """:func:`~anra_torch.recording.diagnose_recording` of ``heated_then_cooled(off, n=30)``: a heating of
    ``off + 1`` frames and its cooling, analysed once per process (read only)."""
    return tuple(diagnose_recording(torch.as_tensor(heated_then_cooled(off=off, n=30)), DT, DX))


def quasi_steady_box(n: int = 300, size: int = 8, seed: int = 1, noise: float = 0.01) -> np.ndarray:
    """An 8 x 8 px box whose interior is, at every frame, the steady state for its drifting edges plus a
    stationary source's particular solution (conduction far faster than a frame), plus noise.

    Shape:
        ``(n, size, size)``, spacing :data:`DT`, :data:`DX`.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    y, x = np.mgrid[:size, :size].astype(float)
    frames = np.empty((n, size, size))
    for k in range(n):  # edges: a drifting, tilting plane (harmonic), so the steady interior is the plane
        frames[k] = 30 + 2 * np.sin(0.05 * t[k]) + 0.1 * t[k] * (x - y) / size
    inner = np.zeros((size, size))
    inner[1:-1, 1:-1] = np.exp(-((x[1:-1, 1:-1] - 3.5) ** 2 + (y[1:-1, 1:-1] - 3.5) ** 2) / 2.0)
    return frames + 1.5 * inner + rng.normal(0, noise, frames.shape)


def still_box(seed: int, n: int = 160, size: int = 12, noise: float = 0.1) -> torch.Tensor:
    """A box that does not change over its frames (a baseline): a constant plus white noise.

    Shape:
        ``(n, size, size)`` float64.
    """
    return torch.as_tensor(20.0 + np.random.default_rng(seed).normal(0, noise, (n, size, size)))


def spot_video(
    on: int = 30, off: int = 120, n: int = 200, noise: float = 0.05, tau: float = 30.0
) -> torch.Tensor:
    """A Gaussian spot heated from frame ``on`` to ``off`` (exponential approach over ``tau`` frames), then
    cooling.

    Shape:
        ``(n, 24, 24)`` float64.
    """
    k = np.arange(n, dtype=float)
    rise = np.where(k < on, 0, 1 - np.exp(-(np.minimum(k, off) - on) / tau))
    rise = np.where(k > off, rise[off] * np.exp(-(k - off) / 40), rise)
    y, x = np.mgrid[:24, :24]
    shape = np.exp(-((x - 12) ** 2 + (y - 10) ** 2) / 18)
    rng = np.random.default_rng(0)
    return torch.from_numpy(20 + 10 * rise[:, None, None] * shape + noise * rng.normal(size=(n, 24, 24)))


def blob_video(frames: int, size: int, *, noise: float = 0.0, sigma: float = 0.6, seed: int = 0) -> Video:
    """The exact solution for a Gaussian spot (a = 0.2 mm^2/s, 0.1 mm, 30 Hz, initial sd ``sigma`` mm) plus
    white noise, float32.

    Shape:
        ``frames`` ``(frames, size, size)``.
    """
    t = torch.arange(frames, dtype=torch.float64) / 30
    clean = gaussian_blob(t, shape=(size, size), dx=0.1, a=0.2, peak=3.0, sigma=sigma, background=20.0)
    generator = torch.Generator().manual_seed(seed)
    noisy = clean + noise * torch.randn(clean.shape, generator=generator, dtype=torch.float64)
    return Video(frames=noisy.float(), dt=1 / 30, dx=0.1)


def random_frames(t: int = 8, h: int = 6, w: int = 7, dtype: type = np.float64) -> np.ndarray:
    """Uniform random values in [0, 100) (seed 0): a video file's content, ``(t, h, w)``."""
    rng = np.random.default_rng(0)
    return (100 * rng.random((t, h, w))).astype(dtype)


@functools.cache
def camera_scene(seed: int = 0, size: int = 96, frames: int = 61) -> HiddenEffectVideo:
    """A pure-diffusion video (0.05 mm px, 30 Hz) for planting camera artefacts; built once per process."""
    fps = 30.0
    return hidden_effect_video([], seed=seed, size=size, dx=0.05, fps=fps, duration=(frames - 1) / fps)


def with_artefacts(video: HiddenEffectVideo, kind: str, seed: int = 1) -> tuple[torch.Tensor, dict]:
    """``video``'s frames with artefacts of ``kind`` planted (new tensors) and their record."""
    return plant(video.frames, kind, seed=seed, noise_sd=video.noise_sd, dt=video.dt)


def white_beside_correlated(video: HiddenEffectVideo, seed: int) -> torch.Tensor:
    """The camera benchmark's correlated noise (2 noise sds, 1.5 px, 3 frames) beside white noise of one
    noise sd, both drawn anew for ``seed``."""
    generator = torch.Generator().manual_seed(1000 + seed)
    white = video.clean + video.noise_sd * torch.randn(
        video.clean.shape, generator=generator, dtype=torch.float64
    )
    return correlated_noise(white, seed=seed, sd=2 * video.noise_sd, length_px=1.5, length_frames=3.0)[0]
