"""The solver of :mod:`anra_torch.simulation.plate_reference`: ``(M / tau + K) x = b`` on its finite volumes.

The intact plate's operator is separable and inverted exactly by the fast diagonalisation method (a
generalised eigenproblem per axis); the faces a defect cuts are added by the Woodbury identity through a
capacitance matrix of the cut faces. NumPy float64, no SciPy; shares no code with the rest of the package.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

__all__ = ["PlateSolver", "centres"]

_SUBSAMPLES = 8  # points per cell side for a defect's coverage


class _Cut(Protocol):
    """What the solver needs of a defect (:class:`~anra_torch.simulation.plate_reference.Defect`)."""

    @property
    def depth(self) -> float: ...

    @property
    def transmission(self) -> float: ...

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray: ...


def centres(edges: np.ndarray) -> np.ndarray:
    """The cells' centres from their edges."""
    return 0.5 * (edges[1:] + edges[:-1])


class PlateSolver:
    """``(M / tau + K) x = b`` for the plate's finite volumes, ``M`` the cell volumes, ``K`` the
    conductances; exact for the intact plate by fast diagonalisation, for cut faces by Woodbury."""

    def __init__(
        self,
        x_edges: np.ndarray,
        y_edges: np.ndarray,
        z_edges: np.ndarray,
        diffusivity: tuple[float, float, float],
        shift: float,
    ) -> None:
        self.edges = (z_edges, y_edges, x_edges)
        self.sizes = tuple(np.diff(e) for e in self.edges)  # (dz, dy, dx) per cell
        self.shape = tuple(len(s) for s in self.sizes)
        self.lateral = self.shape[1:]
        self.shift = shift  # 1 / tau: 2 / step for a half step of implicit Euler and for Crank-Nicolson
        a_x, a_y, a_z = diffusivity
        self.diffusivity, self.a_z = diffusivity, a_z
        self.axes = [self._axis(e, a) for e, a in zip(self.edges, (a_z, a_y, a_x), strict=True)]
        self.volume = (
            self.sizes[0][:, None, None] * self.sizes[1][None, :, None] * self.sizes[2][None, None, :]
        )
        lam = [ax[0] for ax in self.axes]
        self.denominator = shift + lam[0][:, None, None] + lam[1][None, :, None] + lam[2][None, None, :]
        self.cut_faces = 0
        self.faces: tuple[np.ndarray, np.ndarray] | None = None
        self.capacitance: np.ndarray | None = None

    @staticmethod
    def _axis(edges: np.ndarray, a: float) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues and mass-orthonormal eigenvectors of one axis' ``K v = lambda M v``."""
        size, middles = np.diff(edges), centres(edges)
        conductance = a / np.diff(middles)
        k = np.diag(np.concatenate([conductance, [0.0]]) + np.concatenate([[0.0], conductance]))
        k -= np.diag(conductance, 1) + np.diag(conductance, -1)
        scale = 1.0 / np.sqrt(size)
        values, vectors = np.linalg.eigh(scale[:, None] * k * scale[None, :])
        return np.clip(values, 0.0, None), scale[:, None] * vectors

    def _forward(self, b: np.ndarray) -> np.ndarray:
        (_, vz), (_, vy), (_, vx) = self.axes
        b = b @ vx
        b = np.matmul(vy.T, b)
        return (vz.T @ b.reshape(self.shape[0], -1)).reshape(self.shape)

    def _back(self, c: np.ndarray) -> np.ndarray:
        (_, vz), (_, vy), (_, vx) = self.axes
        c = (vz @ c.reshape(self.shape[0], -1)).reshape(self.shape)
        c = np.matmul(vy, c)
        return c @ vx.T

    def _intact(self, b: np.ndarray) -> np.ndarray:
        return self._back(self._forward(b) / self.denominator)

    def cut(self, defects: Sequence[_Cut]) -> None:
        """Remove the covered share of the conductance of the faces at each defect's depth."""
        if not defects:
            return
        z_edges, y_edges, x_edges = self.edges
        sub = (np.arange(_SUBSAMPLES) + 0.5) / _SUBSAMPLES
        xs = (x_edges[:-1, None] + np.diff(x_edges)[:, None] * sub[None, :]).ravel()
        ys = (y_edges[:-1, None] + np.diff(y_edges)[:, None] * sub[None, :]).ravel()
        removed: dict[int, np.ndarray] = {}  # face index below the cut -> removed share per lateral cell
        for defect in defects:
            cover = defect.inside(xs[None, :], ys[:, None]).reshape(
                self.shape[1], _SUBSAMPLES, self.shape[2], _SUBSAMPLES
            )
            share = cover.mean((1, 3)) * (1.0 - defect.transmission)
            k = int(np.argmin(np.abs(z_edges - defect.depth)))
            removed[k] = np.maximum(removed.get(k, 0.0), share)
        zc = centres(z_edges)
        above, below, weights, groups = [], [], [], []
        area = self.sizes[1][:, None] * self.sizes[2][None, :]
        for k, share in removed.items():
            rows, cols = np.nonzero(share > 0)
            g = share[rows, cols] * area[rows, cols] * self.a_z / (zc[k] - zc[k - 1])
            above.append(np.ravel_multi_index((np.full_like(rows, k - 1), rows, cols), self.shape))
            below.append(np.ravel_multi_index((np.full_like(rows, k), rows, cols), self.shape))
            weights.append(g)
            groups.append((k, rows, cols))
        self.faces = (np.concatenate(above), np.concatenate(below))
        self.cut_faces = len(self.faces[0])
        s = self._cut_products(groups)
        self.capacitance = np.linalg.inv(np.diag(1.0 / np.concatenate(weights)) - s)

    def _cut_products(self, groups: list[tuple[int, np.ndarray, np.ndarray]]) -> np.ndarray:
        """``U^T (M / tau + K_intact)^-1 U`` for the cut faces' vectors ``U`` (+1 above, -1 below)."""
        (lz, vz), (ly, vy), (lx, vx) = self.axes
        lateral = self.shift + ly[:, None] + lx[None, :]  # (ny, nx)
        blocks = []
        for ka, ra, ca in groups:
            wa = vz[ka - 1] - vz[ka]
            pa = (vy[ra][:, :, None] * vx[ca][:, None, :]).reshape(len(ra), -1)
            row = []
            for kb, rb, cb in groups:
                wb = vz[kb - 1] - vz[kb]
                kernel = ((wa * wb)[:, None, None] / (lz[:, None, None] + lateral[None])).sum(0).ravel()
                pb = (vy[rb][:, :, None] * vx[cb][:, None, :]).reshape(len(rb), -1)
                row.append((pa * kernel[None, :]) @ pb.T)
            blocks.append(row)
        return np.block(blocks)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``(M / tau + K)^-1 b`` with the cut faces."""
        x = self._intact(b)
        if self.faces is None:
            return x
        above, below = self.faces
        flat = x.ravel()
        y = self.capacitance @ (flat[above] - flat[below])
        r = np.zeros(x.size)
        np.add.at(r, above, y)
        np.add.at(r, below, -y)
        return x + self._intact(r.reshape(self.shape))

    def euler(self, state: np.ndarray) -> np.ndarray:
        """One implicit-Euler step of ``tau`` (half the frame step)."""
        return self.solve(self.shift * self.volume * state)

    def crank_nicolson(self, state: np.ndarray) -> np.ndarray:
        """One Crank-Nicolson step of ``2 tau``: ``x = 2 (M / tau + K)^-1 (M / tau) T - T``."""
        return 2.0 * self.euler(state) - state

    def surface(self, state: np.ndarray) -> np.ndarray:
        """The surface temperature, extrapolated linearly from the two top cells' centres."""
        dz = self.sizes[0]
        return state[0] + (state[0] - state[1]) * (0.5 * dz[0]) / (0.5 * (dz[0] + dz[1]))
