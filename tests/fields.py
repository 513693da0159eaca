"""Small fields for the simulator and effect tests, and the moments that check how they spread.

Shape:
    Fields ``(..., H, W)``, x along W (columns), y along H (rows), coordinates in mm at pixel centres.
"""

from __future__ import annotations

import math

import torch

from anra_torch.simulation import gaussian_blob

F64 = torch.float64


def centres(n: int, dx: float, dtype: torch.dtype = F64) -> torch.Tensor:
    """Pixel-centre coordinates (mm) of n pixels."""
    return (torch.arange(n, dtype=dtype) + 0.5) * dx


def moments(u: torch.Tensor, dx: float) -> dict[str, torch.Tensor]:
    """Mass, centroid (mm) and covariance (mm^2) of a field ``(..., H, W)`` (x along W, y along H)."""
    x, y = centres(u.shape[-1], dx), centres(u.shape[-2], dx)[:, None]
    mass = u.sum((-2, -1))
    mx = (u * x).sum((-2, -1)) / mass
    my = (u * y).sum((-2, -1)) / mass
    dx_, dy_ = x - mx[..., None, None], y - my[..., None, None]
    return {
        "mass": mass,
        "x": mx,
        "y": my,
        "xx": (u * dx_**2).sum((-2, -1)) / mass,
        "yy": (u * dy_**2).sum((-2, -1)) / mass,
        "xy": (u * dx_ * dy_).sum((-2, -1)) / mass,
    }


def blob(
    n: int = 64, dx: float = 0.25, sigma: float = 1.5, centre: tuple[float, float] | None = None
) -> torch.Tensor:
    """A unit-peak Gaussian of sd ``sigma`` mm on an ``n x n`` frame (centred by default)."""
    return gaussian_blob([0.0], shape=(n, n), dx=dx, a=0.0, peak=1.0, sigma=sigma, centre=centre)[0]


def rough(n: int = 20) -> torch.Tensor:
    """Random pixels with a hot pixel on an edge: boundaries matter."""
    u = 30.0 + torch.rand(n, n, dtype=F64)
    u[0, n // 2] = 40.0
    return u


def plane_wave(
    height: int, width: int, dx: float, m: int, n: int, dtype: torch.dtype = F64
) -> tuple[torch.Tensor, float, float]:
    """``cos(kx x + ky y)`` periodic on the frame: m periods along W (x), n along H (y)."""
    kx = 2.0 * math.pi * m / (width * dx)
    ky = 2.0 * math.pi * n / (height * dx)
    x, y = centres(width, dx, dtype), centres(height, dx, dtype)
    return torch.cos(kx * x[None, :] + ky * y[:, None]), kx, ky


EXAMPLES = {
    "linear_loss": {"b": 0.3, "T_ref": 29.0},
    "source": {"x0": 6.0, "y0": 7.0, "x1": 9.0, "y1": 5.0, "rate": 4.0, "width": 1.2},
    "advection": {"vx": 0.8, "vy": -0.5},
    "anisotropy": {"a_x": 0.2, "a_y": 0.08, "a_xy": 0.06},
    "heterogeneity": {"x": 8.0, "y": 8.0, "radius": 4.0, "a_inside": 0.3, "a_outside": 0.1},
    "nonlinear_diffusion": {"a0": 0.1, "beta": 0.05, "T_ref": 30.0},
    "periodic_source": {"x": 8.0, "y": 7.0, "width": 1.2, "rate": 4.0, "frequency": 0.5, "phase": 1.0},
    "depth_conduction": {"strength": 1.0, "t_heat": -0.2, "depth_time": 3.0, "T_ref": 29.0},
    "delamination": {
        "x": 8.0,
        "y": 7.0,
        "radius": 3.0,
        "strength": 1.0,
        "depth_time": 0.4,
        "t_heat": -0.2,
        "plate_time": 3.0,
        "T_ref": 29.0,
        "reflected": 1.0,
    },
}
"""Parameters of every effect for the 16 px fields of the effect tests (mm, s, units of T)."""
EXAMPLES["delamination_2"] = {**EXAMPLES["delamination"], "x": 9.0}  # beside the first, 1 mm over
