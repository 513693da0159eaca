"""Conduction into a plate below the imaged surface, solved exactly for the independent simulator.

A plate of thickness ``L`` and through-thickness diffusivity ``a_z``, insulated on both faces and heated
at its surface at ``t_heat``, has at its surface the lateral solution times the depth factor

    theta(t - t_heat) = 1 + 2 sum_n exp(-n^2 pi^2 (t - t_heat) / depth_time),   depth_time = L^2 / a_z

(the cosine series of the 1-D heat equation), for any lateral pattern, lateral anisotropy, advection or
lateral heterogeneity: the lateral and the depth problem separate. Summed here directly (400 terms), not
with the Poisson-summed form the library's :mod:`anra_torch.effects.depth_conduction` uses, so the two
check each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

__all__ = ["FlashPlate", "flash_plate_video", "plate_factor", "with_depth"]


def plate_factor(elapsed: np.ndarray, depth_time: float, terms: int = 400) -> np.ndarray:
    """``theta`` at ``elapsed`` s (> 0) after the heating of a plate with ``depth_time`` (s) ``L^2 / a_z``.

    Shape:
        ``elapsed`` any shape -> the same.
    """
    n = np.arange(1, terms + 1, dtype=np.float64)
    exponent = np.multiply.outer(np.asarray(elapsed, np.float64), n**2) * (math.pi**2 / depth_time)
    return 1.0 + 2.0 * np.exp(-exponent).sum(-1)


def with_depth(clean: Tensor, times: np.ndarray, depth: tuple[float, float, float, float]) -> Tensor:
    """``T_ref + (theta(t - t_heat) / theta(-t_heat))^strength (clean - T_ref)``.

    Args:
        clean: the video of the rest of the model, ``(T, H, W)``.
        times: frame times in s, ``(T,)``.
        depth: ``(strength, t_heat, depth_time, T_ref)``.
    """
    strength, t_heat, depth_time, t_ref = depth
    theta = plate_factor(times - t_heat, depth_time) / plate_factor(np.array(-t_heat), depth_time)
    return t_ref + torch.from_numpy(theta**strength)[:, None, None] * (clean - t_ref)


@dataclass(frozen=True)
class FlashPlate:
    """The plate of :func:`flash_plate_video`: its diffusivities, thickness, layers and delamination.

    Attributes:
        diffusivity: ``(a_x, a_y, a_z)`` in mm^2/s (lateral x, y and through the thickness).
        thickness: plate thickness in mm.
        layers: finite volumes through the thickness.
        defect: ``(x, y, radius, depth)`` in mm of a delamination, or None.
    """

    diffusivity: tuple[float, float, float] = (7.3, 1.1, 0.45)
    thickness: float = 3.0
    layers: int = 30
    defect: tuple[float, float, float, float] | None = None


def flash_plate_video(
    *,
    size: int = 100,
    dx: float = 0.2,
    n_frames: int = 380,
    rate: float = 31.0,
    plate: FlashPlate | None = None,
    t_heat: float = -0.05,
    rise: float = 2.0,
    noise_sd: float = 0.02,
    seed: int = 0,
    pad: int | None = None,
) -> tuple[Tensor, float, float]:
    """Flash thermography of a plate, solved in 3-D independently of the library's operators.

    A :class:`FlashPlate` insulated on both faces, heated at its surface at ``t_heat`` s by a flash brighter
    towards one side (0.6 + 0.4 x a 3 mm Gaussian): lateral flow on a periodic domain ``pad`` px wider than
    the frame (exact per Fourier mode), ``layers`` finite volumes through the thickness (exact per column),
    Strang-split two steps per frame. No heat crosses a ``defect``'s plane inside its disc. The camera sees
    the top cell with white noise.

    Args:
        size: frame side in px.
        dx: pixel size in mm.
        n_frames: frames.
        rate: frame rate in Hz.
        plate: the plate (:class:`FlashPlate`); default ``FlashPlate()``, intact, 3 mm thick.
        t_heat: time of the flash in s relative to the first frame (< 0).
        rise: the first frame's largest excess over the temperature before the flash (20 C), K.
        noise_sd: camera noise sd in K.
        seed: noise seed.
        pad: px of lateral domain beyond each frame edge; default the frame size.

    Returns:
        ``(frames (n_frames, size, size) float32 in C, dt s, dx mm)``.
    """
    if not t_heat < 0:
        raise ValueError(f"t_heat must be before the first frame (< 0 s), got {t_heat!r}")
    plate = FlashPlate() if plate is None else plate
    a_x, a_y, a_z = plate.diffusivity
    pad = size if pad is None else pad
    side = size + 2 * pad
    dz, dt = plate.thickness / plate.layers, 1.0 / rate
    state, broken, cut = _flashed(plate, size, dx, pad)
    kx = 2 * math.pi * np.fft.rfftfreq(side, dx)[None, :]
    ky = 2 * math.pi * np.fft.fftfreq(side, dx)[:, None]
    symbol, column_rate, flat = a_x * kx**2 + a_y * ky**2, a_z / dz**2, broken.ravel()
    first = -t_heat / 4  # four Strang steps from the flash to the first frame, then two per frame
    state = _strang(
        state,
        4,
        _column_propagators(plate.layers, cut, column_rate, first / 2),
        np.exp(-symbol * first),
        flat,
    )
    columns, lateral = _column_propagators(plate.layers, cut, column_rate, dt / 4), np.exp(-symbol * dt / 2)
    frames = _filmed(state, n_frames, size, pad, columns, lateral, flat)
    frames *= rise / frames[0].max()
    noisy = 20.0 + frames + noise_sd * np.random.default_rng(seed).standard_normal(frames.shape)
    return torch.from_numpy(noisy.astype(np.float32)), dt, dx


def _filmed(
    state: np.ndarray,
    n_frames: int,
    size: int,
    pad: int,
    columns: tuple[np.ndarray, np.ndarray],
    lateral: np.ndarray,
    broken: np.ndarray,
) -> np.ndarray:
    """The top layer in the frame, ``(n_frames, size, size)``, two Strang steps (:func:`_strang`) apart."""
    frames = np.empty((n_frames, size, size))
    for index in range(n_frames):
        frames[index] = state[0, pad : pad + size, pad : pad + size]
        if index + 1 < n_frames:
            state = _strang(state, 2, columns, lateral, broken)
    return frames


def _flashed(plate: FlashPlate, size: int, dx: float, pad: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The plate just after the flash ``(layers, side, side)``, its delaminated columns ``(side, side)`` and
    the interface cut below layer ``cut - 1`` (``layers``: none), on the frame padded by ``pad`` px."""
    side, layers = size + 2 * pad, plate.layers
    centres = (np.arange(side) - pad + 0.5) * dx
    x, y = np.meshgrid(centres, centres)  # (side, side): y along rows
    spot = np.exp(-((x - 0.35 * size * dx) ** 2 + (y - 0.45 * size * dx) ** 2) / (2 * 3.0**2))
    state = np.zeros((layers, side, side))
    state[0] = 0.6 + 0.4 * spot  # the flash's energy in the top layer
    broken = np.zeros((side, side), bool)
    cut = layers  # no defect: no interface is cut
    if plate.defect is not None:
        cx, cy, radius, depth = plate.defect
        broken = np.hypot(x - cx, y - cy) <= radius
        cut = min(
            max(round(depth / (plate.thickness / layers)), 1), layers - 1
        )  # the interface below cut - 1
    return state, broken, cut


def _column_propagators(layers: int, cut: int, rate: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """``exp(h A)`` of the finite volumes through the thickness (``rate = a_z / dz^2`` 1/s, zero flux at
    both faces), for an intact column and for one with no conductance below layer ``cut - 1``."""

    def propagator(open_cut: bool) -> np.ndarray:
        operator = np.zeros((layers, layers))
        for k in range(layers - 1):  # conductance between layers k and k + 1
            if k == cut - 1 and not open_cut:
                continue
            operator[k, k] -= 1.0
            operator[k + 1, k + 1] -= 1.0
            operator[k, k + 1] += 1.0
            operator[k + 1, k] += 1.0
        values, vectors = np.linalg.eigh(operator * rate)
        return (vectors * np.exp(values * h)) @ vectors.T

    return propagator(True), propagator(False)


def _strang(
    state: np.ndarray,
    steps: int,
    columns: tuple[np.ndarray, np.ndarray],
    lateral: np.ndarray,
    broken: np.ndarray,
) -> np.ndarray:
    """``steps`` Strang steps: half a step through the thickness (``columns``: intact and cut propagators,
    the cut ones where ``broken``), a whole lateral step (``lateral`` per Fourier mode), half a step again."""
    intact, split = columns
    cut = bool(broken.any())
    for _ in range(steps):
        for half in range(2):
            flat = state.reshape(state.shape[0], -1)
            through = np.where(broken, split @ flat, intact @ flat) if cut else intact @ flat
            state = through.reshape(state.shape)
            if half == 0:
                state = np.fft.irfft2(np.fft.rfft2(state) * lateral, s=state.shape[-2:])
    return state
