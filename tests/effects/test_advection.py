"""Advection (:mod:`anra_torch.effects.advection`) against the moments of a moving, spreading Gaussian."""

from __future__ import annotations

import torch
from fields import blob, moments

from anra_torch.effects import (
    Effect,
    simulate_effects,
)
from anra_torch.simulation import gaussian_blob

F64 = torch.float64


# -------------------------------------------------------------------------------------- advection
def test_advection_moves_the_centroid_by_vt_and_spreads_by_2at() -> None:
    n, dx, a, dt, sigma, c = 96, 0.25, 0.1, 0.1, 1.5, (11.0, 13.0)
    v = (0.6, -0.4)
    u0 = blob(n, dx, sigma, c)
    flow = Effect("advection", {"vx": v[0], "vy": v[1]})
    video = simulate_effects(u0, a=a, dx=dx, dt=dt, n_frames=21, effects=[flow])
    t = torch.arange(21, dtype=F64) * dt
    m = moments(video, dx)
    # Central differences and the 5-point Laplacian are exact on quadratics: the moments evolve exactly.
    torch.testing.assert_close(m["x"], c[0] + v[0] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["y"], c[1] + v[1] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["xx"], sigma**2 + 2 * a * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["yy"], sigma**2 + 2 * a * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["xy"], torch.zeros_like(t), rtol=0, atol=1e-8)
    # The field is the analytic Gaussian carried along by v (translation commutes with diffusion).
    exact = torch.stack(
        [
            gaussian_blob(
                [s],
                shape=(n, n),
                dx=dx,
                a=a,
                peak=1.0,
                sigma=sigma,
                centre=(c[0] + v[0] * s, c[1] + v[1] * s),
            )[0]
            for s in t.tolist()
        ]
    )
    assert float((video - exact).abs().max()) < 1e-2  # central differences' dispersion, O(dx^2)
