"""Restarted GMRES (:mod:`anra_torch.simulation.krylov`) against :func:`numpy.linalg.solve`."""

from __future__ import annotations

import numpy as np
import pytest

from anra_torch.simulation.krylov import gmres


def implicit_stage(n: int, h: float, seed: int = 0) -> np.ndarray:
    """``I - h K`` with ``K`` a random advection-diffusion-like operator: what an implicit stage solves."""
    rng = np.random.default_rng(seed)
    lap = -2 * np.eye(n) + np.eye(n, k=1) + np.eye(n, k=-1)
    return np.eye(n) - h * (lap + 0.3 * rng.normal(size=(n, n)) / np.sqrt(n))


@pytest.mark.parametrize(("n", "h"), [(20, 0.1), (150, 0.4), (400, 2.0)])
def test_gmres_solves_to_its_tolerance(n: int, h: float) -> None:
    matrix = implicit_stage(n, h)
    b = np.random.default_rng(1).normal(size=n)
    x = gmres(lambda v: matrix @ v, b, 1e-9)
    assert np.linalg.norm(matrix @ x - b) <= 1e-10  # tolerance / 10
    np.testing.assert_allclose(x, np.linalg.solve(matrix, b), rtol=0, atol=1e-10 * np.linalg.cond(matrix))


def test_a_zero_right_side_is_solved_at_once() -> None:
    calls = []
    x = gmres(lambda v: calls.append(1) or v, np.zeros(5), 1e-8)
    assert not x.any() and calls == []


def test_a_system_it_cannot_solve_is_a_clear_error() -> None:
    """A singular system with a right side outside its range: no x meets the tolerance."""
    singular = np.diag([1.0, 1.0, 0.0])
    with pytest.raises(RuntimeError, match="GMRES did not converge; use more substeps"):
        gmres(lambda v: singular @ v, np.array([1.0, 1.0, 1.0]), 1e-9)
