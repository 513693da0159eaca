"""Scenes and closed forms the depth model's tests share: a surface step, the half-space's ramp
responses (with and without perfusion), Omega by direct integration, a Gaussian burn and a beam on the
independent 3-D simulator."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from scipy.special import erfc

from anra_torch.simulation import BioheatScene, SurfaceFlux, Tissue, camera_frames, simulate_bioheat
from anra_torch.simulation.bioheat_scenes import flux_peak
from anra_torch.video import save_npz

F64 = torch.float64
A, BODY, RISE = 0.14, 37.0, 43.0
A_SKIN, EA_SKIN, R_GAS = 3.1e98, 6.28e5, 8.314462618


def step_video(n: int, dt: float, shape: tuple[int, int] = (6, 6), dtype: torch.dtype = F64) -> torch.Tensor:
    """A surface at 37 C stepping to 80 C at the second frame (a ramp over the first frame interval)."""
    frames = torch.full((n, *shape), BODY, dtype=dtype)
    frames[1:] = BODY + RISE
    return frames


def ramp_response(z: np.ndarray, t: np.ndarray, a: float, tau: float) -> np.ndarray:
    """Half-space response (fraction) to a surface rising linearly from 0 to 1 over ``[0, tau]`` and held:
    ``(R(t) - R(t - tau)) / tau`` with ``R(s) = int_0^s erfc(z / 2 sqrt(a u)) du = 4 s i2erfc(x)``."""

    def integral(s: np.ndarray) -> np.ndarray:
        s = np.maximum(s, 1e-300)
        x = z / (2 * np.sqrt(a * s))
        value = s * ((1 + 2 * x**2) * erfc(x) - 2 * x * np.exp(-(x**2)) / math.sqrt(math.pi))
        return np.where(s > 1e-200, value, 0.0)

    return (integral(t) - integral(t - tau)) / tau


def decaying_response(z: np.ndarray, t: float, a: float, c: float, tau: float) -> np.ndarray:
    """The same with a loss rate ``c`` (1/s): the step response ``(e^{-zk} erfc(x - sqrt(ct)) + e^{zk}
    erfc(x + sqrt(ct))) / 2``, ``k = sqrt(c / a)``, averaged over the ramp (Gauss-Legendre, 64 nodes)."""
    nodes, weights = np.polynomial.legendre.leggauss(64)
    s = t - tau * 0.5 * (nodes + 1.0)
    k = math.sqrt(c / a)
    x = z[:, None] / (2 * np.sqrt(a * s[None]))
    step = 0.5 * (
        np.exp(-z[:, None] * k) * erfc(x - np.sqrt(c * s)) + np.exp(z[:, None] * k) * erfc(x + np.sqrt(c * s))
    )
    return (step * weights).sum(1) / 2


def arrhenius_direct(history: np.ndarray, dt: float) -> np.ndarray:
    """Omega of piecewise-linear histories ``(T, ...)`` (C): every segment cut into 256 and Simpson's rule."""
    frac = np.linspace(0.0, 1.0, 257)
    simpson = np.ones(257)
    simpson[1:-1:2], simpson[2:-1:2] = 4.0, 2.0
    a, b = history[:-1, None], history[1:, None]
    temps = a + (b - a) * frac.reshape(1, -1, *([1] * (history.ndim - 1)))
    rate = A_SKIN * np.exp(-EA_SKIN / (R_GAS * (temps + 273.15)))
    return (np.tensordot(simpson, np.moveaxis(rate, 1, 0), axes=1) / (3 * 256) * dt).sum(0)


def burn_video() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    dt, dx = 0.25, 0.2
    y, x = torch.meshgrid(torch.arange(20, dtype=F64), torch.arange(20, dtype=F64), indexing="ij")
    spot = torch.exp(-((x - 9.5) ** 2 + (y - 9.5) ** 2) * dx**2 / (2 * 1.0**2))
    on = torch.zeros(33, dtype=F64)
    on[1:17] = 1.0
    return BODY + 48.0 * on.view(-1, 1, 1) * spot, dt, dx


def reference_scene(absorption: float | None) -> BioheatScene:
    """A 0.4 mm beam for 4 s at the centre of a 32 x 32 px view (0.2 mm), surface peak near 82 C."""
    tissue = Tissue(diffusivity=0.15, perfusion=0.004)
    centre = (3.2, 3.2)
    unit = SurfaceFlux(centre, centre, 0.4, 1.0, 0.5, 4.5)
    power = 45.0 / flux_peak(unit, tissue, np.array([centre]), np.array([4.5]))
    source = SurfaceFlux(centre, centre, 0.4, power * (1.5 if absorption else 1.0), 0.5, 4.5, absorption)
    return BioheatScene(tissue, (source,), 10.0, (32, 32), 0.2, 10.0, 1.5)


def beam_recording(folder: Path) -> dict:
    """A 0.4 mm beam for 3 s on skin-like tissue (the independent 3-D simulator), 3 s of cooling, 0.2 K
    noise, saved in ``folder``: ``video`` (``.npz`` with its spacings), ``no_dx`` (without a pixel size),
    ``frames`` and the simulator's ``result``."""
    tissue = Tissue(diffusivity=0.13, perfusion=0.003)
    centre = (2.8, 2.8)
    unit = SurfaceFlux(centre, centre, 0.4, 1.0, 0.5, 3.5)
    power = 45.0 / flux_peak(unit, tissue, np.array([centre]), np.array([3.5]))
    scene = BioheatScene(
        tissue, (SurfaceFlux(centre, centre, 0.4, power, 0.5, 3.5),), 7.0, (28, 28), 0.2, 10.0, 1.5
    )
    result = simulate_bioheat(scene)
    frames = camera_frames(result, 0.2, 5)
    return {
        "video": save_npz(folder / "burn.npz", frames, dt=result.dt, dx=result.dx),
        "no_dx": save_npz(folder / "no_dx.npz", frames, dt=result.dt, dx=None),
        "frames": torch.from_numpy(frames),
        "result": result,
    }
