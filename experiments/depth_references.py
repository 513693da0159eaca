"""3-D conduction that shares no code with the package, and what the depth-aware diffusivity makes of it.

- :func:`conduct`: explicit 3-D conduction in a block (cells of ``dx`` mm, zero-flux sides and bottom) with a
  heat flux into its top surface; the simulator of this module's slab and of ``sparse_recordings.py``.
- :func:`half_space_gaussian`: the exact surface of a Gaussian spreading in a half-space (a separable depth
  problem: the surface obeys ``dT/dt = a Lap T - (a / s^2) (T - 20)`` exactly).
- :func:`beam_heated_slab`: an 8 mm slab heated by a Gaussian beam for 120 s, losing by convection.

``tests/test_depth_aware.py`` asserts on them; this script prints the README's table: the plain ANRA
estimate and the depth-aware fit against the true ``a``.

    python -m experiments.depth_references      # about 10 s
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


def main() -> None:
    from anra_torch.estimation.estimator import ANRAEstimator
    from anra_torch.selection.depth_aware import depth_aware_diffusivity

    gaussian, s2 = half_space_gaussian()
    slab = beam_heated_slab()
    cases = [
        ("surface of a Gaussian spreading in a half-space (separable, exact)", gaussian, 1.0, 0.25),
        ("explicit slab, beam on 120 s, cooling from the switch-off", slab, 10.0, 0.5),
        ("the same slab from 60 s after the switch-off", slab[6:], 10.0, 0.5),
    ]
    print("| 3-D reference | plain `a` (ANRA) | depth-aware `a` |")
    print("|---|---|---|")
    for name, frames, dt, dx in cases:
        plain = float(ANRAEstimator()(frames, dt, dx).diffusivity)
        fit = depth_aware_diffusivity(frames, dt, dx)
        consistent = "consistent" if fit.consistent else "not consistent"
        depth = 100 * (fit.diffusivity / A - 1)
        print(f"| {name} | {100 * (plain / A - 1):+.0f} % | {depth:+.1f} %, {consistent} |")
    rates = depth_aware_diffusivity(gaussian, 1.0, 0.25).rates
    error = np.abs(np.asarray(rates) / (A / s2[2:-2]) - 1)
    median, most = 100 * np.median(error), 100 * error.max()
    print(f"\nhalf-space rates against a / s^2(t): median {median:.1f} %, max {most:.1f} %")


if __name__ == "__main__":
    main()
