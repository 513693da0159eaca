"""The reference plate's solver: fast diagonalisation plus the Woodbury capacitance of the cut faces against
an explicit dense solve of the same mesh, assembled face by face."""

from __future__ import annotations

import numpy as np

from anra_torch.simulation.plate_reference import Defect
from anra_torch.simulation.plate_solver import PlateSolver


def _dense_operator(solver: PlateSolver, removed: np.ndarray, k_cut: int) -> np.ndarray:
    """``M / tau + K`` of the solver's mesh assembled face by face (loops), with ``removed`` (ny, nx) of
    the conductance of the faces between layers ``k_cut - 1`` and ``k_cut``."""
    (z, y, x), (a_x, a_y, a_z) = solver.edges, solver.diffusivity
    centres = [0.5 * (e[1:] + e[:-1]) for e in (z, y, x)]
    sizes = [np.diff(e) for e in (z, y, x)]
    nz, ny, nx = solver.shape
    index = np.arange(nz * ny * nx).reshape(nz, ny, nx)
    a = np.zeros((nz * ny * nx, nz * ny * nx))
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                a[index[k, j, i], index[k, j, i]] += solver.shift * sizes[0][k] * sizes[1][j] * sizes[2][i]
                faces = []
                if i + 1 < nx:
                    faces.append(
                        (
                            index[k, j, i + 1],
                            a_x * sizes[0][k] * sizes[1][j] / (centres[2][i + 1] - centres[2][i]),
                        )
                    )
                if j + 1 < ny:
                    faces.append(
                        (
                            index[k, j + 1, i],
                            a_y * sizes[0][k] * sizes[2][i] / (centres[1][j + 1] - centres[1][j]),
                        )
                    )
                if k + 1 < nz:
                    g = a_z * sizes[1][j] * sizes[2][i] / (centres[0][k + 1] - centres[0][k])
                    faces.append((index[k + 1, j, i], g * (1 - removed[j, i]) if k + 1 == k_cut else g))
                for other, g in faces:
                    p = index[k, j, i]
                    a[p, p] += g
                    a[other, other] += g
                    a[p, other] -= g
                    a[other, p] -= g
    return a


def test_the_solver_is_the_dense_finite_volume_system_with_its_cut_faces() -> None:
    """Fast diagonalisation plus the Woodbury capacitance against a dense solve of the same mesh."""
    rng = np.random.default_rng(3)
    edges = (np.array([0.0, 0.05, 0.15, 0.4, 0.7, 1.0]), np.cumsum([0, 0.3, 0.5, 0.4, 0.6, 0.35]),
             np.cumsum([0, 0.4, 0.25, 0.5, 0.3, 0.45, 0.6]))  # fmt: skip
    solver = PlateSolver(edges[2], edges[1], edges[0], (7.3, 1.1, 0.45), 2.0 / 0.05)
    defect = Defect("ellipse", centre=(1.2, 1.0), size=(0.8, 0.6), depth=0.4)
    solver.cut([defect])
    assert solver.cut_faces > 0
    removed = np.zeros(solver.shape[1:])
    above, _ = solver.faces
    _, rows, cols = np.unravel_index(above, solver.shape)
    xs = (edges[2][:-1, None] + np.diff(edges[2])[:, None] * ((np.arange(8) + 0.5) / 8)[None]).ravel()
    ys = (edges[1][:-1, None] + np.diff(edges[1])[:, None] * ((np.arange(8) + 0.5) / 8)[None]).ravel()
    cover = (
        defect.inside(xs[None, :], ys[:, None]).reshape(solver.shape[1], 8, solver.shape[2], 8).mean((1, 3))
    )
    removed[rows, cols] = cover[rows, cols]
    b = rng.standard_normal(solver.shape)
    dense = np.linalg.solve(_dense_operator(solver, removed, 3), b.ravel()).reshape(solver.shape)
    np.testing.assert_allclose(solver.solve(b), dense, rtol=1e-9, atol=1e-12 * np.abs(dense).max())
