"""Restarted GMRES in plain NumPy for the independent simulator's implicit stages (no SciPy, no BLAS
threads: the systems are small and the machine may be shared)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = ["gmres"]

_GMRES_RESTART, _GMRES_CYCLES = 30, 10


def _dot(u: np.ndarray, v: np.ndarray) -> float:
    """``sum u v`` without BLAS (whose thread pool can stall a busy machine for no gain at this size)."""
    return float(np.multiply(u, v).sum())


def gmres(matvec: Callable[[np.ndarray], np.ndarray], b: np.ndarray, tolerance: float) -> np.ndarray:
    """``x`` with ``|matvec(x) - b| <= tolerance / 10`` (2-norm): restarted GMRES, modified Gram-Schmidt."""
    x, residual, goal = np.zeros_like(b), b, 0.1 * tolerance
    for _ in range(_GMRES_CYCLES):
        beta = math.sqrt(_dot(residual, residual))
        if beta <= goal:
            return x
        basis, hessenberg = [residual / beta], np.zeros((_GMRES_RESTART + 1, _GMRES_RESTART))
        target = np.zeros(_GMRES_RESTART + 1)
        target[0] = beta
        for j in range(_GMRES_RESTART):
            w = matvec(basis[j])
            for i, v in enumerate(basis):
                hessenberg[i, j] = _dot(v, w)
                w = w - hessenberg[i, j] * v
            hessenberg[j + 1, j] = math.sqrt(_dot(w, w))
            small, rhs = hessenberg[: j + 2, : j + 1], target[: j + 2]
            y = np.linalg.lstsq(small, rhs, rcond=None)[0]
            if np.linalg.norm(small @ y - rhs) <= goal or hessenberg[j + 1, j] == 0.0:
                break
            basis.append(w / hessenberg[j + 1, j])
        x = x + sum(c * v for c, v in zip(y, basis, strict=False))
        residual = b - matvec(x)
    if math.sqrt(_dot(residual, residual)) > goal:
        raise RuntimeError("independent simulator: GMRES did not converge; use more substeps")
    return x
