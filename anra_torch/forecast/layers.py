"""A flash plate's layers through its thickness: the model :class:`LayeredPlate` and one frame's step.

The layers are graded from the surface (:data:`LAYERS`), in the depth ``zeta = z / L`` where the
diffusion into depth is ``(1 / (L^2 / a_z)) d^2 T / d zeta^2`` (front-face data fix only ``L^2 / a_z``,
and nothing else is needed). :class:`Layers` steps them one frame ahead: the diffusion into depth exactly
(each step's propagator; over a defect's disc each pixel through its own face, which passes a share of
the intact conductance), then the lateral diffusion and the plate's other terms explicitly, the frame's
outermost pixel ring following the measured frames. :mod:`anra_torch.forecast.layered` builds the plate
from a diagnosis and forecasts with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as nnf
from torch import Tensor

from anra_torch.effects import Effect, Grid, step_rates

__all__ = ["LAYERS", "LayeredPlate", "Layers", "definite", "depth_faces", "surface"]

LAYERS = (0.004, 1.2, 0.08)
"""The layers through the thickness, as shares of it: the top one's, the growth from one to the next, the
thickest (24 layers, :func:`depth_faces`; the profile 0.07 s after the flash on a 1 mm plate at 0.45 mm^2/s
spans about 10)."""

_F64 = torch.float64
_STABLE = 0.8  # an explicit lateral step's share of its stability limit
_LEVELS = 16  # a defect face's share of the heat it stops, in steps of 1/16 (one propagator a step)


@dataclass(frozen=True)
class LayeredPlate:
    """A diagnosed flash plate's model through its thickness.

    Attributes:
        lateral: ``(a_x, a_y, a_xy)`` in mm^2/s.
        plate_time: ``L^2 / a_z`` in s.
        t_heat: the flash's time relative to the first frame in s (< 0).
        t_ref: the temperature before the flash (data units).
        defect: the delamination's ``(x, y, radius, d / L, strength)`` (mm, mm, mm, 1, 1; ``strength`` the
            share of the intact conductance its face stops), or None.
        others: the model's other effects, each acting on every layer.
        measured: the defect map's lateral diffusivities ``(a_x, a_y, a_xy)`` in mm^2/s, the anisotropy's
            other candidate (:func:`~anra_torch.forecast.layered.fitted_plate`), or None.
    """

    lateral: tuple[float, float, float]
    plate_time: float
    t_heat: float
    t_ref: float
    defect: tuple[float, float, float, float, float] | None
    others: tuple[Effect, ...]
    measured: tuple[float, float, float] | None = None


def definite(lateral: tuple[float, float, float]) -> bool:
    """Whether the lateral diffusivities ``(a_x, a_y, a_xy)`` are positive definite (can be simulated)."""
    a_x, a_y, a_xy = lateral
    return a_x > 0 and a_y > 0 and a_x * a_y > a_xy**2


class Layers:
    """The layered model of ``plate`` on the frames' grid, one frame ahead at a time: each step the exact
    diffusion into depth (the layers' propagator), then an explicit lateral step with the other terms."""

    def __init__(self, plate: LayeredPlate, frames: Tensor, dt: float, dx: float, forcing: Tensor | None):
        self.plate, self.frames, self.dt, self.dx, self.forcing = plate, frames, dt, dx, forcing
        height, width = frames.shape[1:]
        self.block, self.fraction = _block(plate, (height, width), dx, frames.device)
        self.faces = depth_faces(self.fraction).to(frames.device)
        grid = Grid((height, width), dx)
        self.terms = [e.spec.build(e.params, grid) for e in plate.others]
        low, high = float(frames.min()) + plate.t_ref, float(frames.max()) + plate.t_ref
        _, speed, decay = step_rates(0.0, plate.others, low, high, frames.shape[0] * dt)
        a_x, a_y, a_xy = plate.lateral
        fastest = 2 * (a_x + a_y + abs(a_xy)) / dx**2 + speed / dx + decay
        self.substeps = max(1, math.ceil(dt * fastest / _STABLE))
        h = dt / self.substeps
        self.intact = torch.linalg.matrix_exp(_depth_operator(self.faces, plate.plate_time, None) * h)
        self.last: tuple[int, Tensor] | None = None
        self.over, self.cut = _face_steps(self.faces, plate.plate_time, self.fraction, self.block, h)

    def profiles(self, elapsed: float) -> Tensor:
        """Each pixel's temperature through the thickness ``elapsed`` s after the flash over its surface's,
        ``(layers, H, W)``: the plate's, blended over a defect (the share its face stops) with the layer's
        above the face (nothing below it)."""
        plate, block = self.plate, self.block
        profile = _profile(self.faces, elapsed, plate.plate_time)[:, None, None] * (1 - block)[None]
        if self.fraction is None:
            return profile
        f = self.fraction
        upper = self.faces[self.faces <= f + 1e-12] / f
        shallow = torch.zeros_like(self.faces[1:])
        shallow[: len(upper) - 1] = _profile(upper, elapsed, plate.plate_time * f**2)
        return profile + shallow[:, None, None] * block[None]

    def advance(self, state: Tensor, k: int) -> Tensor:
        """The layers at frame ``k + 1`` from those at frame ``k``; the edge ring follows the frames."""
        h = self.dt / self.substeps
        elapsed = -self.plate.t_heat + k * self.dt
        start = self._ring(k, elapsed)  # the ring's layers at both frames
        end = self._ring(k + 1, elapsed + self.dt)
        t_ref = self.plate.t_ref
        for s in range(self.substeps):
            t = torch.tensor(k * self.dt + s * h, dtype=_F64, device="cpu")
            state = self.into_depth(state, torch.einsum("ij,jhw->ihw", self.intact, state))
            rhs = _lateral(state, self.plate.lateral, self.dx)
            for term in self.terms:
                rhs = rhs + term(t, state + t_ref)
            if self.forcing is not None:
                rhs = rhs + self.forcing
            w = (s + 1) / self.substeps
            state = _edges(state + h * rhs, (1 - w) * start + w * end)
        return state

    def _ring(self, k: int, elapsed: float) -> Tensor:
        """Frame ``k``'s surface times the profiles at ``elapsed`` s, ``(layers, H, W)``; the last one kept
        (a frame's end is the next frame's start)."""
        if self.last is None or self.last[0] != k:
            self.last = (k, self.profiles(elapsed) * self.frames[k][None])
        return self.last[1]

    def into_depth(self, state: Tensor, intact: Tensor) -> Tensor:
        """One step of the diffusion into depth: ``intact``, the intact plate's, with the pixels over a defect
        stepped through their own face (:func:`_face_steps`)."""
        if self.cut is None:
            return intact
        out = intact.clone()
        out[:, self.over] = torch.bmm(self.cut, state[:, self.over].T[:, :, None])[:, :, 0].T
        return out


def _face_steps(
    faces: Tensor, plate_time: float, fraction: float | None, block: Tensor, h: float
) -> tuple[Tensor, Tensor | None]:
    """The pixels over a defect ``(H, W)`` bool and each one's propagator of the diffusion into depth over
    ``h`` s ``(pixels, n, n)``: its face at ``fraction`` passing ``1 - block`` of the intact conductance
    (``block`` in steps of :data:`_LEVELS`; one matrix exponential per step present)."""
    level = (block * _LEVELS).round()
    over = level > 0
    if fraction is None or not bool(over.any()):
        return over, None
    steps, which = torch.unique(level[over], return_inverse=True)
    device = block.device
    propagators = torch.stack(
        [
            torch.linalg.matrix_exp(_depth_operator(faces, plate_time, fraction, 1 - float(s) / _LEVELS) * h)
            for s in steps.cpu()
        ]
    ).to(device)
    return over, propagators[which]


def depth_faces(cut: float | None = None) -> Tensor:
    """The layers' faces through the thickness as shares of it, 0 to 1, graded (:data:`LAYERS`), with a face
    at ``cut`` (a defect's ``d / L``) where given (moved there from the nearest, as a mesher puts a node on a
    crack), ``(layers + 1,)`` float64 on the CPU."""
    first, growth, thickest = LAYERS
    faces, size = [0.0], first
    while faces[-1] + 0.5 * size < 1.0:
        faces.append(faces[-1] + size)
        size = min(size * growth, thickest)
    faces[-1] = 1.0
    grid = torch.tensor(faces, dtype=_F64, device="cpu")
    if cut is not None:
        nearest = int((grid[1:-1] - cut).abs().argmin()) + 1
        grid[nearest] = cut
    return grid


def _depth_operator(faces: Tensor, plate_time: float, cut: float | None, passed: float = 0.0) -> Tensor:
    """The finite-volume operator of ``dT/dt = (1 / (L^2 / a_z)) d^2 T / d zeta^2`` on the layers between
    ``faces`` ``(n + 1,)``, both faces insulated, the face at ``cut`` passing ``passed`` of its conductance
    (0: no heat), ``(n, n)``."""
    size = faces.diff()
    centres = (faces[1:] + faces[:-1]) / 2
    g = 1 / (plate_time * centres.diff())  # the conductance between neighbouring centres
    if cut is not None:
        g = torch.where((faces[1:-1] - cut).abs() < 1e-12, g * passed, g)
    n = len(size)
    k = torch.arange(n - 1, device=faces.device)
    operator = torch.zeros(n, n, dtype=faces.dtype, device=faces.device)
    operator[k, k + 1] += g / size[:-1]
    operator[k, k] -= g / size[:-1]
    operator[k + 1, k] += g / size[1:]
    operator[k + 1, k + 1] -= g / size[1:]
    return operator


def _block(
    plate: LayeredPlate, shape: tuple[int, int], dx: float, device: torch.device
) -> tuple[Tensor, float | None]:
    """The share of the heat the defect's face stops per pixel ``(H, W)`` and the face's ``d / L``."""
    height, width = shape
    if plate.defect is None:
        return torch.zeros(shape, dtype=_F64, device=device), None
    x, y, radius, fraction, strength = plate.defect
    xs = (torch.arange(width, dtype=_F64, device=device) + 0.5) * dx
    ys = (torch.arange(height, dtype=_F64, device=device) + 0.5) * dx
    r = torch.sqrt((xs[None, :] - x) ** 2 + (ys[:, None] - y) ** 2)
    disc = 0.5 * (1 + torch.tanh((radius - r) / dx))  # the delamination's disc, its tanh edge 1 px wide
    return strength * disc, min(max(fraction, 0.02), 0.98)


def _profile(faces: Tensor, elapsed: float, plate_time: float) -> Tensor:
    """An insulated plate's temperature through its thickness ``elapsed`` s after a flash at its surface,
    averaged over each layer between ``faces`` (shares of the thickness, 0 to 1), over its surface value,
    ``(len(faces) - 1,)``."""
    s = max(elapsed, 1e-9) * math.pi**2 / plate_time
    terms = min(4000, max(8, math.ceil(math.sqrt(40 / s))))
    n = torch.arange(1, terms + 1, dtype=faces.dtype, device=faces.device)[:, None]
    sines = torch.sin(n * math.pi * faces)
    decay = torch.exp(-(n**2) * s)
    average = 1 + 2 * (decay * (sines[:, 1:] - sines[:, :-1]) / (n * math.pi * faces.diff())).sum(0)
    return average / (1 + 2 * decay.sum())


def surface(state: Tensor, faces: Tensor) -> Tensor:
    """The surface temperature of layers ``(n, ...)`` between ``faces``: the top two layers' values
    extrapolated linearly to the surface (as a camera sees a plate's top cells)."""
    c0, c1 = float(faces[1]) / 2, float(faces[1] + faces[2]) / 2
    return state[0] - c0 * (state[1] - state[0]) / (c1 - c0)


def _lateral(state: Tensor, lateral: tuple[float, float, float], dx: float) -> Tensor:
    """``a_x T_xx + a_y T_yy + 2 a_xy T_xy`` on every layer (central differences; the ring is reset after)."""
    a_x, a_y, a_xy = lateral
    p = nnf.pad(state[None], (1, 1, 1, 1), mode="replicate")[0]
    t_xx = p[:, 1:-1, 2:] - 2 * state + p[:, 1:-1, :-2]
    t_yy = p[:, 2:, 1:-1] - 2 * state + p[:, :-2, 1:-1]
    out = a_x * t_xx + a_y * t_yy
    if a_xy != 0.0:
        t_xy = (p[:, 2:, 2:] - p[:, 2:, :-2] - p[:, :-2, 2:] + p[:, :-2, :-2]) / 4
        out = out + 2 * a_xy * t_xy
    return out / dx**2


def _edges(state: Tensor, ring: Tensor) -> Tensor:
    """The frame's outermost pixel ring of every layer set to ``ring``'s (the measured surface times its
    profile through the thickness), ``(layers, H, W)``."""
    state = state.clone()
    state[:, 0], state[:, -1] = ring[:, 0], ring[:, -1]
    state[:, :, 0], state[:, :, -1] = ring[:, :, 0], ring[:, :, -1]
    return state
