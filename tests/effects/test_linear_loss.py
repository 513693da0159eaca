"""Linear loss (:mod:`anra_torch.effects.linear_loss`): a uniform field decays exactly; diffusion x decay."""

from __future__ import annotations

import torch
from fields import blob

from anra_torch.effects import (
    Effect,
    simulate_effects,
)
from anra_torch.simulation import gaussian_blob, simulate_heat

F64 = torch.float64


# ------------------------------------------------------------------------------------ linear_loss
def test_linear_loss_uniform_field_decays_exactly(dtype: torch.dtype) -> None:
    u0 = torch.full((2, 8, 8), 40.0, dtype=dtype)
    u0[1] = 20.0  # below T_ref: warms up towards it
    loss = Effect("linear_loss", {"b": 0.4, "T_ref": 30.0})
    video = simulate_effects(u0, a=0.2, dx=0.5, dt=0.1, n_frames=31, effects=[loss])
    t = torch.arange(31, dtype=F64) * 0.1
    z = -0.4 * 0.1  # one RK4 step (one substep per frame here) multiplies the excess by R(z)
    step = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
    tol = 1e-12 if dtype == F64 else 1e-5
    for k, t0 in enumerate((40.0, 20.0)):
        discrete = 30.0 + (t0 - 30.0) * step ** torch.arange(31, dtype=F64)
        torch.testing.assert_close(video[k, :, 3, 5].double(), discrete, rtol=tol, atol=0)
        continuous = 30.0 + (t0 - 30.0) * torch.exp(-0.4 * t)
        torch.testing.assert_close(video[k, :, 3, 5].double(), continuous, rtol=0, atol=1e3 * tol + 1e-7)
        assert float((video[k] - video[k, :, :1, :1]).abs().max()) <= tol * 40  # stays uniform


def test_linear_loss_gaussian_is_diffusion_times_decay() -> None:
    u0 = blob()
    b, a, dt = 0.5, 0.1, 0.1
    loss = Effect("linear_loss", {"b": b, "T_ref": 0.0})
    video = simulate_effects(u0, a=a, dx=0.25, dt=dt, n_frames=21, effects=[loss])
    t = torch.arange(21, dtype=F64) * dt
    decay = torch.exp(-b * t)[:, None, None]
    # The loss commutes with the Laplacian: the semi-discrete solution is the heat solution times
    # exp(-b t) (up to RK4's O(ds^4) time error).
    heat = simulate_heat(u0, a=a, dx=0.25, dt=dt, n_frames=21)
    torch.testing.assert_close(video, heat * decay, rtol=0, atol=1e-7)
    exact = gaussian_blob(t, shape=(64, 64), dx=0.25, a=a, peak=1.0, sigma=1.5) * decay
    assert float((video - exact).abs().max()) < 2e-3  # the 5-point Laplacian's O(dx^2)
