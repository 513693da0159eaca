"""Temperature-dependent diffusivity (:mod:`anra_torch.effects.nonlinear_diffusion`): the conservative flux
form against a NumPy reference, heat conserved, hot regions spreading faster.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from fields import blob, moments, rough

from anra_torch.effects import (
    Effect,
    Grid,
    simulate_effects,
)

F64 = torch.float64


# ---------------------------------------------------------------------------- nonlinear_diffusion
def _flux_form_reference(u: np.ndarray, p: dict[str, float], dx: float) -> np.ndarray:
    """div(a(T) grad T) with a(T) at pixels, face diffusivity their mean, zero flux on the frame edge."""
    a = p["a0"] * (1 + p["beta"] * (u - p["T_ref"]))
    out = np.zeros_like(u)
    rows, cols = u.shape
    for i in range(rows):
        for j in range(cols):
            for di, dj in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                k, m = i + di, j + dj
                if 0 <= k < rows and 0 <= m < cols:
                    out[i, j] += 0.5 * (a[i, j] + a[k, m]) * (u[k, m] - u[i, j])
    return out / dx**2


def test_nonlinear_rhs_is_the_conservative_flux_form() -> None:
    u = rough(12)
    p = {"a0": 0.1, "beta": 0.08, "T_ref": 29.0}
    out = Effect("nonlinear_diffusion", p).term(u, 0.0, Grid((12, 12), 0.5))
    np.testing.assert_allclose(out.numpy(), _flux_form_reference(u.numpy(), p, 0.5), rtol=0, atol=1e-11)


def test_nonlinear_conserves_heat_and_hot_regions_spread_faster() -> None:
    n, dx, dt = 64, 0.25, 0.1
    u0 = 30.0 + 10.0 * blob(n, dx, 1.0, (8.0, 8.0))
    runs = {}
    for beta in (0.0, 0.05, 0.1):
        law = Effect("nonlinear_diffusion", {"a0": 0.1, "beta": beta, "T_ref": 30.0})
        video = simulate_effects(u0, a=0.1, dx=dx, dt=dt, n_frames=21, effects=[law])
        total = video.sum((-2, -1))
        torch.testing.assert_close(total, total[:1].expand(21), rtol=1e-14, atol=0)
        runs[beta] = moments(video - 30.0, dx)
    spread = {beta: float(m["xx"][-1] - m["xx"][0]) for beta, m in runs.items()}
    assert spread[0.0] == pytest.approx(2 * 0.1 * 2.0, rel=1e-6)
    # a ranges over 0.1 .. 0.1 (1 + 10 beta): 1.5x and 2x at the peak.
    assert spread[0.0] * 1.1 < spread[0.05] < spread[0.1] < spread[0.0] * 2.0
    assert float(runs[0.1]["x"][-1]) == pytest.approx(8.0, abs=1e-9)  # symmetric: no drift
