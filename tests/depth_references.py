"""3-D conduction that shares no code with the package, for the tests of depth-aware fits and phases.

- :func:`conduct`: explicit 3-D conduction in a block (cells of ``dx`` mm, zero-flux sides and bottom) with a
  heat flux into its top surface; the simulator of this module's slab and of
  ``experiments/sparse_recordings.py``.
- :func:`half_space_gaussian`: the exact surface of a Gaussian spreading in a half-space (a separable depth
  problem: the surface obeys ``dT/dt = a Lap T - (a / s^2) (T - 20)`` exactly).
- :func:`beam_heated_slab`: an 8 mm slab heated by a Gaussian beam for 120 s, losing by convection.

``tests/selection/test_depth_aware.py`` asserts on them; ``python -m experiments.depth_references`` prints the
results page's table from them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

A = 0.12  # mm^2/s, the references' diffusivity
RHO_C = 1.5e-3  # J/(mm^3 K), a polymer's heat capacity per volume


def conduct(
    u: np.ndarray,
    start: float,
    stop: float,
    a: float,
    dx: float,
    surface: Callable[[np.ndarray, float], np.ndarray],
) -> np.ndarray:
    """Explicit 3-D conduction of ``u`` (``(D, H, W)`` K, layer 0 the surface) from ``start`` to ``stop`` s,
    with ``surface(top, t)`` (W/mm^2) flowing into the top cells; zero flux through every other face."""
    step, now = 0.9 * dx**2 / (6 * a), start
    while now < stop - 1e-9:
        k = min(step, stop - now)
        p = np.pad(u, 1, mode="edge")
        lap = p[1:-1, 1:-1, 2:] + p[1:-1, 1:-1, :-2] + p[1:-1, 2:, 1:-1] + p[1:-1, :-2, 1:-1]
        lap = (lap + p[2:, 1:-1, 1:-1] + p[:-2, 1:-1, 1:-1] - 6 * u) / dx**2
        lap[0] += surface(u[0], now) / (RHO_C * a * dx)
        u, now = u + k * a * lap, now + k
    return u


def half_space_gaussian(
    dx: float = 0.25, dt: float = 1.0, n: int = 30, size: int = 64, s0: float = 1.5
) -> tuple[torch.Tensor, np.ndarray]:
    """The surface ``z = 0`` of ``(s0^2 / s^2)^(3/2) exp(-r^2 / (2 s^2))``, ``s^2 = s0^2 + 2 a t``, with
    0.01 K noise: the frames and ``s^2(t)`` (mm^2)."""
    t = np.arange(n) * dt
    y, x = (np.mgrid[:size, :size] - (size - 1) / 2) * dx
    s2 = s0**2 + 2 * A * t
    shape = (s0**2 / s2[:, None, None]) ** 1.5 * np.exp(-(x**2 + y**2)[None] / (2 * s2[:, None, None]))
    noise = np.random.default_rng(0).normal(0, 0.01, shape.shape)
    return torch.as_tensor(20 + 50 * shape + noise), s2


def beam_heated_slab(
    n: int = 30,
    dt: float = 10.0,
    on: float = 120.0,
    dx: float = 0.5,
    size: int = 48,
    start: float | None = None,
) -> torch.Tensor:
    """The surface of an 8 mm slab whose top takes a Gaussian beam's flux (0.5 W, sigma 2 mm) for ``on`` s
    and loses by convection (10 W/m^2/K), sampled every ``dt`` from ``start`` s (default the switch-off) on,
    with 0.02 K noise."""
    y, x = (np.mgrid[:size, :size] - (size - 1) / 2) * dx
    flux = 0.5 / (2 * np.pi * 2.0**2) * np.exp(-(x**2 + y**2) / (2 * 2.0**2))  # W/mm^2

    def surface(top: np.ndarray, t: float) -> np.ndarray:
        return (flux if t < on else 0.0) - 10e-6 * (top - 20.0)

    u, now, frames = np.full((16, size, size), 20.0), 0.0, []
    for target in (on if start is None else start) + dt * np.arange(n):
        u, now = conduct(u, now, target, A, dx, surface), target
        frames.append(u[0].copy())
    return torch.as_tensor(np.asarray(frames) + np.random.default_rng(1).normal(0, 0.02, (n, size, size)))
