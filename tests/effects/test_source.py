"""A moving Gaussian source (:mod:`anra_torch.effects.source`): heat accumulated at its rate, its path,
saturation against loss.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from fields import centres, moments

from anra_torch.effects import (
    Effect,
    simulate_effects,
)

F64 = torch.float64


# ---------------------------------------------------------------------------------------- source
def test_static_source_on_zero_field_accumulates_rate_t() -> None:
    p = {"x0": 5.25, "y0": 4.75, "x1": 5.25, "y1": 4.75, "rate": 2.0, "width": 1.0}
    n, dx, dt = 24, 0.5, 0.25
    video = simulate_effects(
        torch.zeros(n, n, dtype=F64), a=0.0, dx=dx, dt=dt, n_frames=9, effects=[Effect("source", p)]
    )
    t = torch.arange(9, dtype=F64) * dt
    torch.testing.assert_close(video[:, 9, 10], 2.0 * t, rtol=1e-14, atol=1e-14)  # the centre pixel
    shape = torch.exp(-((centres(n, dx)[None, :] - 5.25) ** 2 + (centres(n, dx)[:, None] - 4.75) ** 2) / 2.0)
    torch.testing.assert_close(video, 2.0 * t[:, None, None] * shape, rtol=1e-13, atol=1e-15)


def _swept_gaussian(p: dict[str, float], t: float, duration: float, n: int, dx: float) -> np.ndarray:
    """Independent quadrature of the integral over [0, t] of rate exp(-|r - c(s)|^2 / (2 width^2)) ds."""
    nodes, weights = np.polynomial.legendre.leggauss(40)
    s = 0.5 * t * (nodes + 1)
    x = (np.arange(n) + 0.5) * dx
    cx = p["x0"] + (p["x1"] - p["x0"]) * s / duration
    cy = p["y0"] + (p["y1"] - p["y0"]) * s / duration
    gx = np.exp(-((x[None, :] - cx[:, None]) ** 2) / (2 * p["width"] ** 2))
    gy = np.exp(-((x[None, :] - cy[:, None]) ** 2) / (2 * p["width"] ** 2))
    return 0.5 * t * p["rate"] * np.einsum("k,ki,kj->ij", weights, gy, gx)


def test_moving_source_follows_its_path() -> None:
    p = {"x0": 6.0, "y0": 12.0, "x1": 13.0, "y1": 8.0, "rate": 3.0, "width": 1.0}  # >= 6 widths inside
    n, dx, dt, frames = 40, 0.5, 0.2, 11
    duration = (frames - 1) * dt
    moving = Effect("source", p)
    zero = torch.zeros(n, n, dtype=F64)
    # The centre moves 4 mm/s past a 1 mm wide source: RK4's time error needs small steps here.
    errors = []
    for substeps in (4, 8):
        video = simulate_effects(
            zero, a=0.0, dx=dx, dt=dt, n_frames=frames, effects=[moving], substeps=substeps
        )
        errors.append(
            max(
                float(np.abs(video[k].numpy() - _swept_gaussian(p, k * dt, duration, n, dx)).max())
                for k in (3, 10)
            )
        )
    assert errors[1] < 1e-6 and 12.0 < errors[0] / errors[1] < 20.0
    # The accumulated heat's centroid is the path's mean position so far: c0 + (c1 - c0) t / (2 duration),
    # with or without diffusion (diffusion moves no centroid).
    t = torch.arange(1, frames, dtype=F64) * dt
    for a in (0.0, 0.2):
        run = simulate_effects(zero, a=a, dx=dx, dt=dt, n_frames=frames, effects=[moving], substeps=8)
        m = moments(run[1:], dx)
        torch.testing.assert_close(
            m["x"], p["x0"] + (p["x1"] - p["x0"]) * t / (2 * duration), rtol=0, atol=1e-6
        )
        torch.testing.assert_close(
            m["y"], p["y0"] + (p["y1"] - p["y0"]) * t / (2 * duration), rtol=0, atol=1e-6
        )
        torch.testing.assert_close(m["mass"], 3.0 * t * 2 * math.pi / dx**2, rtol=1e-6, atol=0)


def test_source_with_loss_saturates_analytically() -> None:
    p = {"x0": 6.25, "y0": 6.25, "x1": 6.25, "y1": 6.25, "rate": 2.0, "width": 1.5}
    b = 0.8
    effects = [Effect("source", p), Effect("linear_loss", {"b": b, "T_ref": 0.0})]
    zero = torch.zeros(25, 25, dtype=F64)
    video = simulate_effects(zero, a=0.0, dx=0.5, dt=0.25, n_frames=17, effects=effects, substeps=10)
    t = torch.arange(17, dtype=F64) * 0.25
    torch.testing.assert_close(video[:, 12, 12], 2.0 * (1 - torch.exp(-b * t)) / b, rtol=1e-8, atol=1e-12)
