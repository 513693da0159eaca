"""An independent 3-D bioheat simulator: skin-like tissue under a laser, a sweeping tip or a contact burn.

:func:`simulate_bioheat` solves Pennes' equation for ``theta = T - T_body`` in a block of tissue,
``d theta / dt = a (d_xx + d_yy + d_zz) theta - b theta + s``, heated through its top face by a surface
flux or a hot contact probe, or below it by a near-infrared beam, and losing heat to the air. It returns
the camera's noiseless frames, the temperature of the top face averaged over each pixel, and as the truth
the Arrhenius damage and the peak temperature in depth. It shares no code with
:mod:`anra_torch.tissue.depth` nor with :mod:`anra_torch.simulation.integrator`. The discretisation:
``docs/architecture.md``, "The bioheat references".

Units: mm, s, C, mm^2/s, 1/s. Computed in NumPy float64; needs SciPy, from ``anra_torch[test]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from anra_torch.simulation.bioheat_setup import (
    BioheatResult,
    BioheatScene,
    Contact,
    DepthGrid,
    SurfaceFlux,
)

__all__ = [
    "camera_frames",
    "flux_centre",
    "simulate_bioheat",
]

_A_SKIN, _EA_SKIN, _R_GAS = 3.1e98, 6.28e5, 8.314462618  # Henriques-Moritz skin (1/s, J/mol, J/(mol K))
_HOT = 42.0  # C: below it the skin's Arrhenius rate is < 5e-6 1/s; cells never hotter add nothing
_GAMMA = 2.0 - math.sqrt(2.0)  # TR-BDF2's stage fraction


# ------------------------------------------------------------------------------------------ operators
def _lateral_factor(nx: int, ny: int, h: float, a: float, tau: float) -> np.ndarray:
    """``exp(tau a lambda)`` ``(ny, nx)`` of the 2-D finite-volume Laplacian with zero-flux edges on cells
    of ``h`` mm, on its eigenvectors, the DCT-II basis:
    ``lambda = -(2 / h)^2 (sin^2(pi p / 2 nx) + sin^2(pi q / 2 ny))``."""
    lx = (2.0 / h * np.sin(0.5 * np.pi * np.arange(nx) / nx)) ** 2
    ly = (2.0 / h * np.sin(0.5 * np.pi * np.arange(ny) / ny)) ** 2
    return np.exp(-tau * a * (ly[:, None] + lx[None, :]))


def _depth_operator(faces: np.ndarray, a: float, b: float, beta: float) -> np.ndarray:
    """The column operator ``A`` in band storage ``(3, Z)``: upper, diagonal, lower rows; with the
    surface's Robin coefficient ``beta`` in 1/mm and the bottom face held at 0."""
    size = np.diff(faces)
    centre = 0.5 * (faces[1:] + faces[:-1])
    gap = np.diff(centre)  # between neighbouring centres
    up = np.zeros_like(size)
    down = np.zeros_like(size)
    up[:-1] = a / gap / size[:-1]  # coupling of cell j to j + 1
    down[1:] = a / gap / size[1:]  # coupling of cell j to j - 1
    diagonal = -(up + down) - b
    half = 0.5 * size[0]
    diagonal[0] -= a * beta / (1.0 + beta * half) / size[0]
    diagonal[-1] -= a / (0.5 * size[-1]) / size[-1]
    band = np.zeros((3, len(size)))
    band[0, 1:] = up[:-1]
    band[1] = diagonal
    band[2, :-1] = down[1:]
    return band


class _Columns:
    """TR-BDF2 steps of ``du/dt = A u + f(t)`` for columns of one operator ``A``, a free surface or a
    probe in contact; the two stages' tridiagonal matrices are factorised once, for the Thomas algorithm."""

    def __init__(self, band: np.ndarray, h: float) -> None:
        self.band, self.h = band, h
        self.c1, self.c2 = 0.5 * _GAMMA, (1.0 - _GAMMA) / (2.0 - _GAMMA)
        self.lu = [self._factor(band, c * h) for c in (self.c1, self.c2)]

    @staticmethod
    def _factor(band: np.ndarray, ch: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Thomas factors of ``I - ch A``: lower multipliers, inverse pivots, upper diagonal."""
        upper, diagonal, lower = -ch * band[0], 1.0 - ch * band[1], -ch * band[2]
        n = len(diagonal)
        multiplier, pivot = np.zeros(n), np.zeros(n)
        pivot[0] = diagonal[0]
        for j in range(1, n):
            multiplier[j] = lower[j - 1] / pivot[j - 1]
            pivot[j] = diagonal[j] - multiplier[j] * upper[j]
        return multiplier, 1.0 / pivot, upper

    @staticmethod
    def _solve(factors: tuple[np.ndarray, np.ndarray, np.ndarray], rhs: np.ndarray) -> np.ndarray:
        multiplier, inverse, upper = factors
        x = rhs
        for j in range(1, len(x)):
            x[j] -= multiplier[j] * x[j - 1]
        x[-1] *= inverse[-1]
        for j in range(len(x) - 2, -1, -1):
            x[j] = (x[j] - upper[j + 1] * x[j + 1]) * inverse[j]
        return x

    def _apply(self, u: np.ndarray) -> np.ndarray:
        band = self.band
        out = band[1][:, None] * u
        out[:-1] += band[0][1:, None] * u[1:]
        out[1:] += band[2][:-1, None] * u[:-1]
        return out

    def step(self, u: np.ndarray, forcing: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
        """One step of size ``h`` for columns ``u`` ``(Z, N)``; ``forcing``: ``f`` at ``t``, ``t + gamma h``
        and ``t + h``, each ``(Z_f, N)`` for the top ``Z_f`` cells, the rest being 0."""
        f0, fg, f1 = forcing
        rhs = u + self.c1 * self.h * self._apply(u)
        rhs[: len(f0)] += self.c1 * self.h * (f0 + fg)
        u_gamma = self._solve(self.lu[0], rhs)
        g = _GAMMA * (2.0 - _GAMMA)
        rhs = u_gamma / g - (1.0 - _GAMMA) ** 2 / g * u
        rhs[: len(f1)] += self.c2 * self.h * f1
        return self._solve(self.lu[1], rhs)


# ------------------------------------------------------------------------------------------ the block
def _cell_average(edges: np.ndarray, centre: float, width: float) -> np.ndarray:
    """A unit-peak Gaussian of sd ``width`` averaged over the cells between ``edges``, exactly by erf."""
    from scipy.special import erf

    if math.isinf(width):
        return np.ones(len(edges) - 1)
    s = math.sqrt(2.0) * width
    return (erf((edges[1:] - centre) / s) - erf((edges[:-1] - centre) / s)) * (
        0.5 * math.sqrt(math.pi) * s / np.diff(edges)
    )


@dataclass(frozen=True)
class _Block:
    """The simulated tissue: fine cell edges in mm, in the camera frame's coordinates, and depth faces.
    Only a quarter or half is simulated when the scene is mirror symmetric about the frame's centre lines."""

    x: np.ndarray
    y: np.ndarray
    faces: np.ndarray
    mirror: tuple[bool, bool]  # (about x = centre, about y = centre)
    refine: int
    margin_px: int

    @property
    def cell(self) -> float:
        return float(self.x[1] - self.x[0])


def _symmetry(scene: BioheatScene) -> tuple[bool, bool]:
    """Whether every source is mirror symmetric about the frame's vertical / horizontal centre line."""
    h, w = scene.shape
    cx, cy = 0.5 * w * scene.dx, 0.5 * h * scene.dx
    near = lambda u, v: abs(u - v) < 1e-9  # noqa: E731
    about_x, about_y = w % 2 == 0, h % 2 == 0
    for s in scene.sources:
        points = (s.centre,) if isinstance(s, Contact) else (s.start, s.end)
        about_x &= all(near(p[0], cx) for p in points)
        about_y &= all(near(p[1], cy) for p in points)
    return about_x, about_y


def _block(scene: BioheatScene, refine: int, depth: DepthGrid) -> _Block:
    h, w = scene.shape
    m = math.ceil(scene.margin / scene.dx - 1e-9)
    mirror = _symmetry(scene)

    def edges(n: int, flip: bool) -> np.ndarray:
        cells = np.arange(-m * refine, (n + m) * refine + 1) * (scene.dx / refine)
        return cells[(n // 2 + m) * refine :] if flip else cells

    return _Block(edges(w, mirror[0]), edges(h, mirror[1]), depth.faces(), mirror, refine, m)


def flux_centre(s: SurfaceFlux, t: float) -> tuple[float, float]:
    """Where the beam or tip ``s`` is at time ``t`` in s: ``(x, y)`` in mm; at its ends outside its time."""
    f = min(max((t - s.t_on) / (s.t_off - s.t_on), 0.0), 1.0)
    return s.start[0] + (s.end[0] - s.start[0]) * f, s.start[1] + (s.end[1] - s.start[1]) * f


def _surface(scene: BioheatScene, block: _Block, t: float, on_at: float) -> tuple:
    """At time ``t``, with the sources on or off as at ``on_at``: the surface flux ``(Ny, Nx)`` in K mm/s,
    the probe's ``theta_ext`` and conductance where one touches, NaN elsewhere, and the volumetric
    ``(flux, mu)`` pairs."""
    ny, nx = len(block.y) - 1, len(block.x) - 1
    flux, contact, volume = np.zeros((ny, nx)), np.full((ny, nx), np.nan), []
    conductance = np.full((ny, nx), np.nan)
    xc, yc = 0.5 * (block.x[1:] + block.x[:-1]), 0.5 * (block.y[1:] + block.y[:-1])
    for s in scene.sources:
        if not s.t_on <= on_at < s.t_off:
            continue
        if isinstance(s, Contact):
            inside = (xc[None, :] - s.centre[0]) ** 2 + (yc[:, None] - s.centre[1]) ** 2 < s.radius**2
            contact[inside] = s.temperature - scene.tissue.body_temperature
            conductance[inside] = s.conductance
            continue
        cx, cy = flux_centre(s, t)
        q = s.power * np.outer(_cell_average(block.y, cy, s.width), _cell_average(block.x, cx, s.width))
        if s.absorption is None:
            flux += q
        else:
            volume.append((q, s.absorption))
    return flux, contact, conductance, volume


class _Stepper:
    """The split step ``Z(h / 2) L(h) Z(h / 2)`` of the block, and the face temperature the camera sees."""

    def __init__(self, scene: BioheatScene, block: _Block, h: float) -> None:
        tissue, a = scene.tissue, scene.tissue.diffusivity
        self.scene, self.block, self.h, self.a = scene, block, h, a
        self.size = np.diff(block.faces)
        self.half = 0.5 * self.size[0]
        self.theta_body = tissue.body_temperature
        conductances = sorted({s.conductance for s in scene.sources if isinstance(s, Contact)})
        self.betas = [tissue.air, *conductances]
        self.columns = [
            _Columns(_depth_operator(block.faces, a, tissue.perfusion, beta), 0.5 * h) for beta in self.betas
        ]
        self.lateral = _lateral_factor(len(block.x) - 1, len(block.y) - 1, block.cell, a, h)

    def _kind(self, conductance: np.ndarray) -> np.ndarray:
        """Index of each column's operator in ``betas``: 0 free, else its probe's conductance."""
        kind = np.zeros(conductance.shape, dtype=int)
        for k, beta in enumerate(self.betas[1:], 1):
            kind[conductance == beta] = k
        return kind

    def _forcing(self, t: float, on_at: float, kind: np.ndarray, beta: float) -> np.ndarray:
        """``f`` ``(Z, N)`` of the columns of operator ``beta`` at time ``t``, the sources as at ``on_at``."""
        flux, contact, _, volume = _surface(self.scene, self.block, t, on_at)
        mask = kind == self.betas.index(beta)
        top = flux[mask] + self.a * beta * np.nan_to_num(contact[mask])
        f = np.zeros((len(self.size) if volume else 1, top.size))
        f[0] = top / ((1.0 + beta * self.half) * self.size[0])
        for q, mu in volume:
            shape = -np.diff(np.exp(-mu * self.block.faces)) / self.size
            f += shape[:, None] * q[mask][None, :]  # all of it absorbed in the tissue
        return f

    def _depth_step(self, u: np.ndarray, t: float) -> np.ndarray:
        """Half a step, ``h / 2``, of every column from ``t``, each with its operator."""
        k = 0.5 * self.h
        mid = t + 0.5 * k
        kind = self._kind(_surface(self.scene, self.block, mid, mid)[2])
        flat = u.reshape(len(self.size), -1)
        for index, beta in enumerate(self.betas):
            mask = (kind == index).reshape(-1)
            if not mask.any():
                continue
            forcing = [self._forcing(s, mid, kind, beta) for s in (t, t + _GAMMA * k, t + k)]
            columns = flat if mask.all() else flat[:, mask]
            stepped = self.columns[index].step(columns, tuple(forcing))
            if mask.all():
                flat = stepped
            else:
                flat[:, mask] = stepped
        return flat.reshape(u.shape)

    def step(self, u: np.ndarray, t: float) -> np.ndarray:
        """``u`` ``(Z, Ny, Nx)`` from ``t`` to ``t + h``: ``Z(h / 2) L(h) Z(h / 2)``."""
        from scipy.fft import dctn, idctn

        u = self._depth_step(u, t)
        u = idctn(
            dctn(u, type=2, axes=(1, 2), norm="ortho") * self.lateral, type=2, axes=(1, 2), norm="ortho"
        )
        return self._depth_step(u, t + 0.5 * self.h)

    def face(self, u: np.ndarray, t: float, on_at: float) -> np.ndarray:
        """Temperature rise of the top face ``(Ny, Nx)``: the top cell plus its flux balance."""
        flux, contact, conductance, _ = _surface(self.scene, self.block, t, on_at)
        beta = np.asarray(self.betas)[self._kind(conductance)]
        ext = np.nan_to_num(contact)
        return u[0] + self.half * (beta * (ext - u[0]) + flux / self.a) / (1.0 + beta * self.half)


# ------------------------------------------------------------------------------------------ simulation
def _log_rate(theta: np.ndarray, body: float) -> np.ndarray:
    """``ln`` of the skin's Arrhenius rate in 1/s at ``theta + body`` C."""
    return math.log(_A_SKIN) - _EA_SKIN / (_R_GAS * (theta + body + 273.15))


class _Dose:
    """The peak rise of every cell and ``Omega``, by the trapezoid rule over the steps, computed only on
    the cells hotter than :data:`_HOT`."""

    def __init__(self, shape: tuple[int, ...], body: float, h: float) -> None:
        self.omega, self.peak = np.zeros(shape), np.zeros(shape)
        self.body, self.h, self.hot = body, h, _HOT - body

    def add(self, u: np.ndarray, weight: float) -> None:
        np.maximum(self.peak, u, out=self.peak)
        hot = u > self.hot
        columns = hot.any(0)
        if not columns.any():
            return
        rows, cols = np.flatnonzero(columns.any(1)), np.flatnonzero(columns.any(0))
        deep = np.flatnonzero(hot.any((1, 2)))[-1] + 1
        box = (slice(0, deep), slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        self.omega[box] += weight * self.h * np.exp(_log_rate(u[box], self.body))


def _column_depth(omega: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Deepest point in mm with ``Omega >= 1`` of each column of ``omega`` ``(Z, ...)``, 0 when none;
    ``ln Omega`` interpolated linearly between the cell centres around it."""
    damaged = omega >= 1.0
    last = len(centres) - 1 - np.argmax(damaged[::-1], axis=0)
    below = np.minimum(last + 1, len(centres) - 1)
    with np.errstate(divide="ignore"):
        here = np.log(np.take_along_axis(omega, last[None], 0)[0])
        there = np.log(np.maximum(np.take_along_axis(omega, below[None], 0)[0], 1e-300))
    fraction = np.where(below > last, here / np.maximum(here - there, 1e-300), 0.0)
    depth = centres[last] + np.clip(fraction, 0.0, 1.0) * (centres[below] - centres[last])
    return np.where(damaged.any(0), depth, 0.0)


def _unfold(field: np.ndarray, block: _Block) -> np.ndarray:
    """The whole block's ``(..., Ny, Nx)`` from a mirrored part."""
    if block.mirror[0]:
        field = np.concatenate([field[..., ::-1], field], -1)
    if block.mirror[1]:
        field = np.concatenate([field[..., ::-1, :], field], -2)
    return field


def _to_camera(field: np.ndarray, block: _Block, shape: tuple[int, int]) -> np.ndarray:
    """Pixel means of the unfolded fine ``field`` ``(..., Ny, Nx)`` over the camera view: ``(..., H, W)``."""
    full, r, m = _unfold(field, block), block.refine, block.margin_px * block.refine
    view = full[..., m : m + shape[0] * r, m : m + shape[1] * r]
    return view.reshape(*view.shape[:-2], shape[0], r, shape[1], r).mean((-3, -1))


def simulate_bioheat(
    scene: BioheatScene, *, refine: int = 2, depth: DepthGrid | None = None, step: float = 0.1
) -> BioheatResult:
    """Simulate ``scene``: the camera's noiseless frames and the damage in depth under each pixel.

    Args:
        scene: :class:`BioheatScene`.
        refine: fine cells per camera pixel side, an integer >= 1.
        depth: the depth cells; default :class:`DepthGrid`.
        step: largest time step in s; each frame period is split into equal steps no longer than this.

    Returns:
        :class:`BioheatResult`.

    Raises:
        ValueError: a ``refine`` that is not an integer >= 1, or a ``step`` that is not positive.

    Shape:
        ``frames`` ``(T, H, W)``, ``damage_depth`` ``(H, W)``, ``log_omega`` and ``peak`` ``(Z, H, W)``.
    """
    if not (isinstance(refine, int) and refine >= 1):
        raise ValueError(f"refine must be an integer >= 1, got {refine!r}")
    if not (step > 0):
        raise ValueError(f"step must be a positive time in s, got {step!r}")
    block = _block(scene, refine, depth or DepthGrid())
    frame_dt = 1.0 / scene.rate
    substeps = max(1, math.ceil(frame_dt / step - 1e-9))
    h = frame_dt / substeps
    stepper = _Stepper(scene, block, h)
    shape = (len(block.faces) - 1, len(block.y) - 1, len(block.x) - 1)
    u, dose = np.zeros(shape), _Dose(shape, scene.tissue.body_temperature, h)
    dose.add(u, 0.5)
    n_frames = round(scene.duration * scene.rate) + 1
    faces = [stepper.face(u, 0.0, -h)]
    for n in range(1, n_frames):
        for k in range(substeps):
            t = ((n - 1) * substeps + k) * h
            u = stepper.step(u, t)
            dose.add(u, 1.0)
        faces.append(stepper.face(u, n * frame_dt, n * frame_dt - 0.5 * h))
    dose.add(u, -0.5)
    body = scene.tissue.body_temperature
    centres = 0.5 * (block.faces[1:] + block.faces[:-1])
    fine_depth = _column_depth(dose.omega, centres)
    with np.errstate(divide="ignore"):
        log_omega = np.log(_to_camera(dose.omega, block, scene.shape))
    return BioheatResult(
        frames=body + _to_camera(np.stack(faces), block, scene.shape),
        dt=frame_dt,
        dx=scene.dx,
        damage_depth=_to_camera(fine_depth, block, scene.shape),
        depths=centres,
        log_omega=log_omega,
        peak=body + _to_camera(dose.peak, block, scene.shape),
        scene=scene,
        info={"step_s": h, "cells": shape, "mirror": block.mirror},
    )


def camera_frames(result: BioheatResult, noise: float, seed: int) -> np.ndarray:
    """The camera's frames: ``result.frames`` plus white Gaussian noise of sd ``noise`` K, seeded by ``seed``.

    Shape:
        ``(T, H, W)``.
    """
    rng = np.random.default_rng(seed)
    return result.frames + noise * rng.standard_normal(result.frames.shape)
