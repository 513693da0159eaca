"""A flash plate's layers through its thickness: the model :class:`LayeredPlate` and one frame's step.

The layers are graded from the surface (:data:`LAYERS`), in the depth ``zeta = z / L`` where the
diffusion into depth is ``(1 / (L^2 / a_z)) d^2 T / d zeta^2`` (front-face data fix only ``L^2 / a_z``,
and nothing else is needed). :class:`Layers` steps them one frame ahead: the diffusion into depth exactly
(each step's propagator; over a defect's disc each pixel through its own face, which passes a share of
the intact conductance; each defect a face at its own depth), split around the lateral diffusion, stepped
exactly in the sine basis of the frame's interior (:class:`_Across`), with the mixed derivative ``a_xy``
and the plate's other terms held over the step; the frame's outermost pixel ring follows the measured
frames.
:mod:`anra_torch.forecast.layered` builds the plate from a diagnosis and forecasts with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from anra_torch.effects import Effect, Grid, step_rates

__all__ = ["LAYERS", "LayeredPlate", "Layers", "definite", "depth_faces", "surface"]

LAYERS = (0.004, 1.2, 0.08)
"""The layers through the thickness, as shares of it: the top one's, the growth from one to the next, the
thickest (24 layers, :func:`depth_faces`; the profile 0.07 s after the flash on a 1 mm plate at 0.45 mm^2/s
spans about 10)."""

_F64 = torch.float64
_STABLE = 0.8  # an explicit substep's rate times its length at most this (a_xy, the other terms)
_LEVELS = 16  # a defect face's share of the heat it stops, in steps of 1/16 (one propagator a step)

Defect = tuple[float, float, float, float, float]


@dataclass(frozen=True)
class LayeredPlate:
    """A diagnosed flash plate's model through its thickness.

    Attributes:
        lateral: ``(a_x, a_y, a_xy)`` in mm^2/s.
        plate_time: ``L^2 / a_z`` in s.
        t_heat: the flash's time relative to the first frame in s (< 0).
        t_ref: the temperature before the flash (data units).
        defects: each delamination's ``(x, y, radius, d / L, strength)`` (mm, mm, mm, 1, 1; ``strength`` the
            share of the intact conductance its face stops), each a face at its own depth; none, one or more.
        others: the model's other effects, each acting on every layer.
        measured: the defect map's lateral diffusivities ``(a_x, a_y, a_xy)`` in mm^2/s, the anisotropy's
            other candidate (:func:`~anra_torch.forecast.layered.fitted_plate`), or None.
    """

    lateral: tuple[float, float, float]
    plate_time: float
    t_heat: float
    t_ref: float
    defects: tuple[Defect, ...]
    others: tuple[Effect, ...]
    measured: tuple[float, float, float] | None = None


def definite(lateral: tuple[float, float, float]) -> bool:
    """Whether the lateral diffusivities ``(a_x, a_y, a_xy)`` are positive definite (can be simulated)."""
    a_x, a_y, a_xy = lateral
    return a_x > 0 and a_y > 0 and a_x * a_y > a_xy**2


class Layers:
    """The layered model of ``plate`` on the frames' grid, one frame ahead at a time: each substep half the
    diffusion into depth (the layers' propagator), the lateral step, the other half; substeps only as the
    explicit rates (``a_xy``, the other terms) need them."""

    def __init__(self, plate: LayeredPlate, frames: Tensor, dt: float, dx: float, forcing: Tensor | None):
        self.plate, self.frames, self.dt, self.dx, self.forcing = plate, frames, dt, dx, forcing
        height, width = frames.shape[1:]
        self.block, self.which, fractions = _block(plate, (height, width), dx, frames.device)
        faces, self.cuts = _graded(fractions)
        self.faces = faces.to(frames.device)
        grid = Grid((height, width), dx)
        self.terms = [e.spec.build(e.params, grid) for e in plate.others]
        low, high = float(frames.min()) + plate.t_ref, float(frames.max()) + plate.t_ref
        _, speed, decay = step_rates(0.0, plate.others, low, high, frames.shape[0] * dt)
        explicit = 2 * abs(plate.lateral[2]) / dx**2 + speed / dx + decay  # what is stepped explicitly
        self.substeps = max(1, math.ceil(dt * explicit / _STABLE))
        h = dt / self.substeps
        self.across = _Across(plate.lateral, (height, width), dx, h, frames.device)
        self.intact = torch.linalg.matrix_exp(_depth_operator(self.faces, plate.plate_time, None) * h / 2)
        self.last: tuple[int, Tensor] | None = None
        self.over, self.cut = _face_steps(
            self.faces, plate.plate_time, self.cuts, (self.block, self.which), h / 2
        )

    def profiles(self, elapsed: float) -> Tensor:
        """Each pixel's temperature through the thickness ``elapsed`` s after the flash over its surface's,
        ``(layers, H, W)``: the plate's, blended over each defect (the share its face stops, where it is the
        pixel's defect) with the layer's above its face (nothing below it)."""
        plate, block = self.plate, self.block
        profile = _profile(self.faces, elapsed, plate.plate_time)[:, None, None] * (1 - block)[None]
        for j, cut in enumerate(self.cuts):
            f = float(self.faces[cut])
            shallow = torch.zeros_like(self.faces[1:])
            shallow[:cut] = _profile(self.faces[: cut + 1] / f, elapsed, plate.plate_time * f**2)
            profile = profile + shallow[:, None, None] * (block * (self.which == j))[None]
        return profile

    def advance(self, state: Tensor, k: int) -> Tensor:
        """The layers at frame ``k + 1`` from those at frame ``k``; the edge ring follows the frames. Each
        substep: half the diffusion into depth, the lateral step (:class:`_Across`), the other half."""
        h = self.dt / self.substeps
        elapsed = -self.plate.t_heat + k * self.dt
        start = self._ring(k, elapsed)  # the ring's layers at both frames
        end = self._ring(k + 1, elapsed + self.dt)
        t_ref = self.plate.t_ref
        for s in range(self.substeps):
            t = torch.tensor(k * self.dt + s * h, dtype=_F64, device="cpu")
            before = _edges(self._into_depth(state), start + s / self.substeps * (end - start))
            after = start + (s + 1) / self.substeps * (end - start)
            rhs = _mixed(before, self.plate.lateral[2], self.dx)
            for term in self.terms:
                rhs = _plus(rhs, term(t, before + t_ref)[:, 1:-1, 1:-1])
            if self.forcing is not None:
                rhs = _plus(rhs, self.forcing[1:-1, 1:-1].expand_as(before[:, 1:-1, 1:-1]))
            state = self._into_depth(self.across(before, rhs, after))
        return _edges(state, end)

    def _ring(self, k: int, elapsed: float) -> Tensor:
        """Frame ``k``'s surface times the profiles at ``elapsed`` s, ``(layers, H, W)``; the last one kept
        (a frame's end is the next frame's start)."""
        if self.last is None or self.last[0] != k:
            self.last = (k, self.profiles(elapsed) * self.frames[k][None])
        return self.last[1]

    def _into_depth(self, state: Tensor) -> Tensor:
        """Half a substep of the diffusion into depth: the intact plate's propagator, the pixels over a defect
        stepped through their own face (:func:`_face_steps`)."""
        out = torch.einsum("ij,jhw->ihw", self.intact, state)
        if self.cut is not None:
            out[:, self.over] = torch.bmm(self.cut, state[:, self.over].T[:, :, None])[:, :, 0].T
        return out


class _Across:
    """The lateral diffusion ``a_x T_xx + a_y T_yy`` on every layer over ``h`` s, exactly for a ring that
    changes linearly over the step and an explicit rate held over it: in the sine basis of the frame's
    interior (the ring fixed), where the second differences are diagonal, ``u(h) = e^{hA} u + h phi_1(hA)
    (b_0 + f) + h phi_2(hA) (b_1 - b_0)`` (``b`` what the ring adds at the step's start and end, ``f`` the
    explicit rate). An explicit lateral step needed 14-18 substeps a frame on the flash plates."""

    def __init__(self, lateral: tuple[float, float, float], shape: tuple[int, int], dx: float, h: float,
                 device: torch.device):  # fmt: skip
        (a_x, a_y, _), (height, width) = lateral, shape
        self.a_x, self.a_y, self.dx = a_x, a_y, dx
        self.rows, lam_y = _sines(height - 2, dx, device)
        self.cols, lam_x = _sines(width - 2, dx, device)
        z = h * (a_y * lam_y[:, None] + a_x * lam_x[None, :])  # (H - 2, W - 2), < 0
        small = z.abs() < 1e-6
        safe = torch.where(small, -torch.ones_like(z), z)
        self.decay = torch.exp(z)
        self.phi1 = h * torch.where(small, 1 + z / 2, torch.expm1(safe) / safe)
        self.phi2 = h * torch.where(small, 0.5 + z / 6, (torch.expm1(safe) - safe) / safe**2)

    def __call__(self, state: Tensor, rate: Tensor | None, after: Tensor) -> Tensor:
        """``state`` ``(layers, H, W)`` (its ring the step's start) ``h`` s later, with the explicit ``rate``
        ``(layers, H - 2, W - 2)`` (or None) held over the interior and the ring moving linearly to
        ``after``'s."""
        held = self._from_ring(state)
        if rate is not None:
            held = held + self._sine(rate)
        stepped = self.decay * self._sine(state[:, 1:-1, 1:-1]) + self.phi1 * held
        out = after.clone()
        out[:, 1:-1, 1:-1] = self._sine(stepped + self.phi2 * self._from_ring(after - state))
        return out

    def _sine(self, values: Tensor) -> Tensor:
        """The sine transform of ``values`` ``(..., H - 2, W - 2)`` (its own inverse)."""
        return self.rows @ values @ self.cols

    def _from_ring(self, state: Tensor) -> Tensor:
        """The sine transform of what the ring of ``state`` ``(layers, H, W)`` adds to the interior's second
        differences (it sits on the interior's outer rows and columns: a sum of outer products)."""
        scale = 1 / self.dx**2
        top, bottom = self.a_y * scale * state[:, 0, 1:-1], self.a_y * scale * state[:, -1, 1:-1]
        left, right = self.a_x * scale * state[:, 1:-1, 0], self.a_x * scale * state[:, 1:-1, -1]
        rows, cols = self.rows, self.cols
        out = rows[:, :1] * (top @ cols)[:, None, :] + rows[:, -1:] * (bottom @ cols)[:, None, :]
        return out + (left @ rows)[:, :, None] * cols[:1] + (right @ rows)[:, :, None] * cols[-1:]


def _sines(n: int, dx: float, device: torch.device) -> tuple[Tensor, Tensor]:
    """The orthonormal sine transform of ``n`` points between fixed ends ``(n, n)`` (symmetric, its own
    inverse) and the eigenvalues of the second difference over ``dx`` mm there ``(n,)`` in 1/mm^2."""
    k = torch.arange(1, n + 1, dtype=_F64, device=device)
    basis = math.sqrt(2 / (n + 1)) * torch.sin(math.pi * k[:, None] * k[None, :] / (n + 1))
    return basis, -4 * torch.sin(math.pi * k / (2 * (n + 1))) ** 2 / dx**2


def _face_steps(
    faces: Tensor, plate_time: float, cuts: tuple[int, ...], shares: tuple[Tensor, Tensor], h: float
) -> tuple[Tensor, Tensor | None]:
    """The pixels over a defect ``(H, W)`` bool and each one's propagator of the diffusion into depth over
    ``h`` s ``(pixels, n, n)``: the face ``faces[cuts[j]]`` of its defect ``j`` (``shares``: the share of
    the heat stopped and which defect, each ``(H, W)``) passing ``1 - share`` of the intact conductance
    (the share in steps of :data:`_LEVELS`; one matrix exponential per defect and step present)."""
    block, which = shares
    level = (block * _LEVELS).round()
    over = level > 0
    if not cuts or not bool(over.any()):
        return over, None
    steps, index = torch.unique(which[over] * (_LEVELS + 1) + level[over].long(), return_inverse=True)
    operators = [
        _depth_operator(
            faces, plate_time, cuts[int(s) // (_LEVELS + 1)], 1 - (int(s) % (_LEVELS + 1)) / _LEVELS
        )
        for s in steps.cpu()
    ]
    propagators = torch.stack([torch.linalg.matrix_exp(operator * h) for operator in operators])
    return over, propagators.to(block.device)[index]


def depth_faces(*cuts: float) -> Tensor:
    """The layers' faces through the thickness as shares of it, 0 to 1, graded (:data:`LAYERS`), with a face
    at each of ``cuts`` (each defect's ``d / L``; moved there from the nearest, as a mesher puts a node on a
    crack; of two cuts nearest the same face, the first's), ``(layers + 1,)`` float64 on the CPU."""
    return _graded(cuts)[0]


def _graded(cuts: tuple[float, ...]) -> tuple[Tensor, tuple[int, ...]]:
    """:func:`depth_faces` of ``cuts`` and the index of each cut's face in them."""
    first, growth, thickest = LAYERS
    faces, size = [0.0], first
    while faces[-1] + 0.5 * size < 1.0:
        faces.append(faces[-1] + size)
        size = min(size * growth, thickest)
    faces[-1] = 1.0
    grid = torch.tensor(faces, dtype=_F64, device="cpu")
    nearest = tuple(int((grid[1:-1] - cut).abs().argmin()) + 1 for cut in cuts)
    for cut, face in reversed(list(zip(cuts, nearest, strict=True))):  # the first cut at a face placed last
        grid[face] = cut
    return grid, nearest


def _depth_operator(faces: Tensor, plate_time: float, cut: int | None, passed: float = 0.0) -> Tensor:
    """The finite-volume operator of ``dT/dt = (1 / (L^2 / a_z)) d^2 T / d zeta^2`` on the layers between
    ``faces`` ``(n + 1,)``, both faces insulated, the face ``faces[cut]`` (an inner one) passing ``passed``
    of its conductance (0: no heat), ``(n, n)``."""
    size = faces.diff()
    centres = (faces[1:] + faces[:-1]) / 2
    g = 1 / (plate_time * centres.diff())  # the conductance between neighbouring centres
    if cut is not None:
        g = g.clone()
        g[cut - 1] = g[cut - 1] * passed
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
) -> tuple[Tensor, Tensor, tuple[float, ...]]:
    """The share of the heat the defects' faces stop per pixel ``(H, W)``, which defect's face it is per pixel
    ``(H, W)`` int64 (where discs overlap, the one that stops more), and each face's ``d / L``."""
    height, width = shape
    xs = (torch.arange(width, dtype=_F64, device=device) + 0.5) * dx
    ys = (torch.arange(height, dtype=_F64, device=device) + 0.5) * dx
    shares = [torch.zeros(shape, dtype=_F64, device=device)]
    for x, y, radius, _, strength in plate.defects:
        r = torch.sqrt((xs[None, :] - x) ** 2 + (ys[:, None] - y) ** 2)
        shares.append(strength * 0.5 * (1 + torch.tanh((radius - r) / dx)))  # its disc, the edge 1 px wide
    block, which = torch.stack(shares).max(0)
    fractions = tuple(min(max(d[3], 0.02), 0.98) for d in plate.defects)
    return block, (which - 1).clamp(min=0), fractions


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


def _mixed(state: Tensor, a_xy: float, dx: float) -> Tensor | None:
    """``2 a_xy T_xy`` over the interior of every layer ``(layers, H - 2, W - 2)`` (central differences), or
    None where ``a_xy`` is 0."""
    if a_xy == 0.0:
        return None
    t_xy = (state[:, 2:, 2:] - state[:, 2:, :-2] - state[:, :-2, 2:] + state[:, :-2, :-2]) / (4 * dx**2)
    return 2 * a_xy * t_xy


def _plus(total: Tensor | None, rate: Tensor) -> Tensor:
    return rate if total is None else total + rate


def _edges(state: Tensor, ring: Tensor) -> Tensor:
    """The frame's outermost pixel ring of every layer set to ``ring``'s (the measured surface times its
    profile through the thickness), ``(layers, H, W)``."""
    state = state.clone()
    state[:, 0], state[:, -1] = ring[:, 0], ring[:, -1]
    state[:, :, 0], state[:, :, -1] = ring[:, :, 0], ring[:, :, -1]
    return state
