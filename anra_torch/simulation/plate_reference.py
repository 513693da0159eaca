"""An independent 3-D flash-thermography plate: finite volumes on an irregular mesh, solved in one piece.

The package's own plate (:mod:`anra_torch.simulation.plate`) solves the lateral flow exactly per Fourier mode
on a periodic domain, the depth by finite volumes of equal thickness, and splits the two (Strang). This
module shares none of it, so that the flash analysis (:mod:`anra_torch.flash`) can be checked on plates it
was not built on:

- **mesh**: a tensor grid of cells that are irregular laterally (the cell edges inside the frame jittered
  by up to a third of a cell, then growing geometrically into a margin where the heat never arrives) and
  graded through the thickness (thin cells under the surface, growing towards the back wall), with a cell
  face at every defect's depth, as a mesher puts a node on a crack;
- **anisotropy**: two-point fluxes between cell centres with the diagonal conductivity ``(a_x, a_y, a_z)``
  (mm^2/s with ``rho c = 1``), every face its own conductance ``a A / distance``;
- **defects** (:class:`Defect`: ellipses, rectangles, polygons, any depth, inside the frame or running out
  of it): the faces at the defect's depth lose the share of their conductance that the defect covers
  (measured on 8 x 8 points per cell), down to ``transmission`` of it (0: no heat crosses);
- **time**: Crank-Nicolson with a fixed step, started by four implicit-Euler half steps (Rannacher's
  start, which damps the flash's stiff modes), every step solved exactly: the intact plate's operator is
  separable and inverted by the fast diagonalisation method (a generalised eigenproblem per axis), the
  cut faces added by the Woodbury identity through a capacitance matrix of the cut faces;
- **flash**: an instantaneous surface heating of ``energy`` K mm (the absorbed energy per area over
  ``rho c``), not uniform across the frame (:func:`default_flash`), put into the top cell of each column
  with a relative error of ``mesh_noise`` per cell (an element-wise quadrature of the flash), which fades
  within the first frames as the heat spreads;
- **camera**: the surface temperature extrapolated linearly from the two top cells (the earliest frames,
  where the heat has not crossed the top cells, carry the mesh's error), interpolated bilinearly from the
  cell centres and averaged over each pixel, plus white noise ``noise_sd`` (20 mK).

All faces are insulated. Units: mm, s, K (frames in C around ``T_ref`` 20 C). NumPy float64, no SciPy.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from anra_torch.simulation.plate_solver import PlateSolver, centres

__all__ = ["DEFECT_KINDS", "Defect", "PlateSetup", "ReferencePlate", "default_flash", "reference_plate_video"]

DEFECT_KINDS = ("ellipse", "rectangle", "polygon")
"""Shapes of :class:`Defect`."""

_T_REF = 20.0


@dataclass(frozen=True)
class Defect:
    """A planar defect parallel to the surface (a delamination, a flat-bottom void): no heat crosses it.

    Attributes:
        kind: ``"ellipse"`` (semi-axes ``size``), ``"rectangle"`` (half sides ``size``) or ``"polygon"``
            (``vertices``).
        centre: ``(x, y)`` in mm in the frame's coordinates (x along columns, y along rows, the frame's
            corner at 0); may lie outside the frame.
        size: ``(along x, along y)`` in mm before the rotation (ellipse, rectangle).
        depth: below the imaged surface in mm, in ``(0, thickness)``.
        angle: rotation in degrees, counter-clockwise from x (ellipse, rectangle).
        vertices: ``((x, y), ...)`` in mm (polygon).
        transmission: share of the intact conductance that still crosses, in ``[0, 1)``.
    """

    kind: str
    centre: tuple[float, float] = (0.0, 0.0)
    size: tuple[float, float] = (1.0, 1.0)
    depth: float = 1.0
    angle: float = 0.0
    vertices: tuple[tuple[float, float], ...] = ()
    transmission: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in DEFECT_KINDS:
            raise ValueError(f"kind must be one of {', '.join(DEFECT_KINDS)}, got {self.kind!r}")
        if self.kind == "polygon" and len(self.vertices) < 3:
            raise ValueError(f"a polygon needs at least 3 vertices, got {len(self.vertices)}")
        if self.kind != "polygon" and not (min(self.size) > 0):
            raise ValueError(f"size must be two positive lengths in mm, got {self.size!r}")
        if not self.depth > 0:
            raise ValueError(f"depth must be positive in mm, got {self.depth!r}")
        if not 0 <= self.transmission < 1:
            raise ValueError(f"transmission must be in [0, 1), got {self.transmission!r}")

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether points ``(x, y)`` (mm, any shape, broadcast) lie in the defect's outline."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        if self.kind == "polygon":
            return _in_polygon(x, y, np.asarray(self.vertices, np.float64))
        angle = math.radians(self.angle)
        dx, dy = x - self.centre[0], y - self.centre[1]
        u = dx * math.cos(angle) + dy * math.sin(angle)  # in the defect's own axes
        v = -dx * math.sin(angle) + dy * math.cos(angle)
        if self.kind == "ellipse":
            return (u / self.size[0]) ** 2 + (v / self.size[1]) ** 2 <= 1.0
        return (np.abs(u) <= self.size[0]) & (np.abs(v) <= self.size[1])


def _in_polygon(x: np.ndarray, y: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Even-odd rule: a ray towards +x crosses the outline an odd number of times."""
    inside = np.zeros(x.shape, bool)
    x0, y0 = vertices[:, 0], vertices[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    for ax, ay, bx, by in zip(x0, y0, x1, y1, strict=True):  # a few edges, every point at once
        crosses = (ay > y) != (by > y)
        at = ax + (y - ay) * (bx - ax) / np.where(by == ay, 1.0, by - ay)
        inside ^= crosses & (x < at)
    return inside


@dataclass(frozen=True)
class ReferencePlate:
    """A simulated flash recording and its truth.

    Attributes:
        frames: temperatures in C, ``(T, H, W)`` float32.
        dt: frame period in s (the flash is one period before the first frame).
        dx: pixel size in mm.
        plate_time: ``L^2 / a_z`` in s.
        defect_mask: pixels whose centre lies over a defect, ``(H, W)`` bool.
        depth_fraction: the shallowest defect's depth over the thickness at each pixel, NaN where sound,
            ``(H, W)``.
        info: the mesh and solver's sizes (cells per axis, cut faces, seconds).
    """

    frames: Tensor
    dt: float
    dx: float
    plate_time: float
    defect_mask: np.ndarray
    depth_fraction: np.ndarray
    info: dict = field(default_factory=dict)


def default_flash(width: float, height: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A flash brighter off-centre and towards one side, as a lamp at an angle lights a plate: relative
    intensity ``0.75 + 0.4 exp(-r^2 / 2 s^2) + 0.15 x / width`` (``r`` from ``(0.3, 0.6)`` of the frame,
    ``s`` 0.45 of its width), between about 0.75 and 1.3 over a ``width`` x ``height`` mm frame."""
    cx, cy, s = 0.3 * width, 0.6 * height, 0.45 * width

    def flash(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        bump = np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s**2))
        return 0.75 + 0.4 * bump + 0.15 * np.clip(x / width, -0.5, 1.5)

    return flash


@dataclass(frozen=True)
class PlateSetup:
    """What :func:`reference_plate_video` simulates.

    Attributes:
        thickness: plate thickness ``L`` in mm.
        duration: time of the last frame after the flash in s (frames at ``k duration / n_frames``,
            ``k = 1 .. n_frames``).
        shape: frame ``(H, W)`` in px.
        dx: pixel size in mm.
        n_frames: frames.
        diffusivity: ``(a_x, a_y, a_z)`` in mm^2/s.
        defects: the defects (none: an intact plate).
        energy: mean absorbed energy per area over ``rho c``, K mm.
        flash: relative intensity ``(x, y) -> (...)`` in mm (default :func:`default_flash`).
        noise_sd: camera noise sd in K.
        mesh_noise: relative error of the flash's energy per cell.
        cell: lateral cell size inside the frame in mm (default 1 px).
        growth: ratio of neighbouring cells' sizes outside the frame and through the thickness.
        seed: seed of the mesh's jitter, the per-cell error and the camera noise.

    Raises:
        ValueError: a non-positive size or time, a defect not inside the plate's thickness.
    """

    thickness: float
    duration: float
    shape: tuple[int, int] = (96, 96)
    dx: float = 0.3
    n_frames: int = 1000
    diffusivity: tuple[float, float, float] = (7.3, 1.1, 0.45)
    defects: Sequence[Defect] = ()
    energy: float = 3.0
    flash: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    noise_sd: float = 0.02
    mesh_noise: float = 0.03
    cell: float | None = None
    growth: float = 1.25
    seed: int = 0

    def __post_init__(self) -> None:
        height, width = self.shape
        if min(height, width) < 2 or self.n_frames < 2:
            raise ValueError(
                f"shape must be at least 2 x 2 px and n_frames >= 2, got {self.shape!r}, {self.n_frames}"
            )
        sizes = (self.thickness, self.duration, self.dx, *self.diffusivity)
        if not (all(size > 0 for size in sizes) and self.growth > 1):
            raise ValueError(
                "thickness, duration, dx and the diffusivities must be positive and growth > 1, got "
                f"{self.thickness!r}, {self.duration!r}, {self.dx!r}, {self.diffusivity!r}, {self.growth!r}"
            )
        for defect in self.defects:
            if not defect.depth < self.thickness:
                raise ValueError(
                    f"a defect's depth must be below {self.thickness} mm (the plate), got {defect.depth}"
                )


def reference_plate_video(setup: PlateSetup) -> ReferencePlate:
    """Simulate a flash recording of a plate (see the module text).

    Args:
        setup: the plate, its defects, the flash, the camera and the mesh.

    Returns:
        :class:`ReferencePlate`.

    Shape:
        ``frames`` ``(n_frames, H, W)``.
    """
    rng = np.random.default_rng(setup.seed)
    step = setup.duration / setup.n_frames
    solver, top = _mesh(setup, rng)
    state = np.zeros(solver.shape)
    state[0] = _deposit(setup, solver, rng) / solver.sizes[0][0]
    surface = np.empty((setup.n_frames, *solver.lateral))
    for index in range(setup.n_frames):
        for _ in range(2 if index < 2 else 1):  # Rannacher: 4 implicit-Euler half steps, then CN
            state = solver.euler(state) if index < 2 else solver.crank_nicolson(state)
        surface[index] = solver.surface(state)
    (height, width), dx = setup.shape, setup.dx
    _, y_edges, x_edges = solver.edges
    wy, wx = _camera(centres(y_edges), height, dx), _camera(centres(x_edges), width, dx)
    frames = np.einsum("hj,tji,wi->thw", wy, surface, wx, optimize=True)
    frames += _T_REF + setup.noise_sd * rng.standard_normal(frames.shape)
    mask, fraction = _truth(setup.defects, setup.shape, dx, setup.thickness)
    info = {"cells": solver.shape, "cut_faces": solver.cut_faces, "top_cell_mm": top}
    plate_time = setup.thickness**2 / setup.diffusivity[2]
    return ReferencePlate(
        torch.from_numpy(frames.astype(np.float32)), step, dx, plate_time, mask, fraction, info
    )


def _mesh(setup: PlateSetup, rng: np.random.Generator) -> tuple[PlateSolver, float]:
    """The solver on the plate's mesh with the defects cut, and the top cells' thickness in mm."""
    (height, width), dx, growth = setup.shape, setup.dx, setup.growth
    a_x, a_y, a_z = setup.diffusivity
    step = setup.duration / setup.n_frames
    cell = dx if setup.cell is None else setup.cell
    x_edges = _lateral_edges(width * dx, cell, 3.0 * math.sqrt(a_x * setup.duration), growth, rng)
    y_edges = _lateral_edges(height * dx, cell, 3.0 * math.sqrt(a_y * setup.duration), growth, rng)
    top = min(0.5 * math.sqrt(a_z * step), setup.thickness / 20)
    z_edges = _depth_edges(setup.thickness, top, growth, sorted({d.depth for d in setup.defects}))
    solver = PlateSolver(x_edges, y_edges, z_edges, (a_x, a_y, a_z), 2.0 / step)
    solver.cut(setup.defects)
    return solver, top


def _deposit(setup: PlateSetup, solver: PlateSolver, rng: np.random.Generator) -> np.ndarray:
    """The flash's energy per top cell column, K mm, with the mesh's per-cell error."""
    (height, width), dx = setup.shape, setup.dx
    flash = default_flash(width * dx, height * dx) if setup.flash is None else setup.flash
    _, y_edges, x_edges = solver.edges
    intensity = flash(centres(x_edges)[None, :], centres(y_edges)[:, None])
    return setup.energy * intensity * (1 + setup.mesh_noise * rng.standard_normal(solver.lateral))


# ------------------------------------------------------------------------------------------- mesh
def _lateral_edges(
    frame: float, cell: float, margin: float, growth: float, rng: np.random.Generator
) -> np.ndarray:
    """Edges over ``[0, frame]`` mm, jittered by up to a third of a cell, then growing by ``growth`` per
    cell over ``margin`` mm beyond each side."""
    count = max(int(math.ceil(frame / cell)), 2)
    inner = np.linspace(0.0, frame, count + 1)
    inner[1:-1] += rng.uniform(-1.0, 1.0, count - 1) * (frame / count) / 3.0
    outer, size = [], frame / count
    reach = 0.0
    while reach < margin:
        size *= growth
        reach += size
        outer.append(reach)
    outer_arr = np.asarray(outer)
    return np.concatenate([-outer_arr[::-1], inner, frame + outer_arr])


def _depth_edges(thickness: float, top: float, growth: float, depths: list[float]) -> np.ndarray:
    """Edges from the surface (0) to the back wall (``thickness``): cells ``top`` mm thick under the
    surface growing by ``growth`` up to a tenth of the plate, with a face at each of ``depths`` (faces
    closer than a third of a cell to one are dropped)."""
    edges, size = [0.0], top
    while edges[-1] + size < thickness:
        edges.append(edges[-1] + size)
        size = min(size * growth, thickness / 10)
    edges.append(thickness)
    grid = np.asarray(edges)
    for depth in depths:
        local = np.diff(grid)[min(np.searchsorted(grid, depth), len(grid) - 1) - 1]
        grid = np.sort(np.append(grid[np.abs(grid - depth) > local / 3], depth))
    return grid


def _camera(centres: np.ndarray, pixels: int, dx: float) -> np.ndarray:
    """Weights ``(pixels, centres)`` of a pixel's mean over its width of the linear interpolant (4 points
    per pixel)."""
    sub = (np.arange(4) + 0.5) / 4
    points = ((np.arange(pixels)[:, None] + sub[None, :]) * dx).ravel()
    return _bilinear(centres, points).reshape(pixels, 4, -1).mean(1)


def _bilinear(centres: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Linear interpolation weights from cell centres to ``points``, ``(points, centres)``."""
    upper = np.clip(np.searchsorted(centres, points), 1, len(centres) - 1)
    lower = upper - 1
    w = np.clip((points - centres[lower]) / (centres[upper] - centres[lower]), 0.0, 1.0)
    weights = np.zeros((len(points), len(centres)))
    rows = np.arange(len(points))
    weights[rows, lower] += 1.0 - w
    weights[rows, upper] += w
    return weights


def _truth(
    defects: Sequence[Defect], shape: tuple[int, int], dx: float, thickness: float
) -> tuple[np.ndarray, np.ndarray]:
    """The defect mask at the pixel centres and the shallowest defect's depth over the thickness."""
    y, x = ((np.arange(n) + 0.5) * dx for n in shape)
    fraction = np.full(shape, np.nan)
    for defect in sorted(defects, key=lambda d: -d.depth):  # the shallowest last: it is what the surface sees
        fraction[defect.inside(x[None, :], y[:, None])] = defect.depth / thickness
    return np.isfinite(fraction), fraction
