"""The tissue simulator (:mod:`anra_torch.simulation.tissue`) against closed forms, its gradients, errors."""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.simulation import MovingSource, simulate_tissue
from anra_torch.tissue.learned import LearnedTissueModel

F64 = torch.float64


def test_uniform_tissue_relaxes_exponentially_to_body_temperature() -> None:
    u0 = torch.full((6, 7), 45.0, dtype=F64)
    video = simulate_tissue(u0, 0.2, 0.5, dx=0.5, dt=0.1, n_frames=21, body_temperature=37.0)
    t = torch.arange(21, dtype=F64) * 0.1
    expected = 37.0 + 8.0 * torch.exp(-0.5 * t)
    torch.testing.assert_close(video[:, 3, 3], expected, rtol=1e-8, atol=0)


def test_cosine_mode_decays_at_the_discrete_rate() -> None:
    # Zero-flux edges: cos(pi m (j + 1/2) / W) is an eigenvector of the 5-point Laplacian with
    # eigenvalue -(2 - 2 cos(pi m / W)) / dx^2.
    w, dx, a, b = 16, 0.25, 0.3, 0.2
    j = torch.arange(w, dtype=F64)
    mode = torch.cos(math.pi * 2 * (j + 0.5) / w)
    u0 = 37.0 + mode.expand(4, w).clone()
    video = simulate_tissue(u0, a, b, dx=dx, dt=0.05, n_frames=11)
    rate = a * (2 - 2 * math.cos(math.pi * 2 / w)) / dx**2 + b
    t = torch.arange(11, dtype=F64) * 0.05
    expected = 37.0 + torch.exp(-rate * t)[:, None] * mode
    torch.testing.assert_close(video[:, 2], expected, rtol=0, atol=1e-6)


def test_static_source_deposits_power_times_duration() -> None:
    u0 = torch.full((9, 9), 37.0, dtype=F64)
    source = MovingSource(start=(2.25, 2.25), end=(2.25, 2.25), width=0.5, power=4.0, t_on=0.0, t_off=1.0)
    video = simulate_tissue(u0, 0.0, 0.0, dx=0.5, dt=0.25, n_frames=9, source=source)
    # No diffusion, no loss: the centre pixel (4, 4) at (2.25, 2.25) mm gains 4 K/s while the source is on.
    assert video[4, 4, 4].item() == pytest.approx(37.0 + 4.0, rel=1e-9)
    assert video[-1, 4, 4].item() == pytest.approx(37.0 + 4.0, rel=1e-9)  # off after 1 s
    assert video[-1, 4, 5].item() == pytest.approx(37.0 + 4.0 * math.exp(-0.5), rel=1e-9)


@pytest.mark.slow
def test_gradients_flow_to_the_fields() -> None:
    u0 = 37.0 + torch.rand(5, 5, dtype=F64)
    a = torch.full((5, 5), 0.1, dtype=F64, requires_grad=True)
    b = torch.full((5, 5), 0.05, dtype=F64, requires_grad=True)

    def final(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return simulate_tissue(u0, a, b, dx=0.5, dt=0.1, n_frames=4, substeps=2)[-1]

    assert torch.autograd.gradcheck(final, (a, b))


def test_bad_arguments() -> None:
    u0 = torch.zeros(4, 4, dtype=F64)
    with pytest.raises(ValueError, match="initial must have shape"):
        simulate_tissue(u0[0], 0.1, dx=0.1, dt=0.1, n_frames=3)
    with pytest.raises(ValueError, match="n_frames must be an integer >= 2"):
        simulate_tissue(u0, 0.1, dx=0.1, dt=0.1, n_frames=1)
    with pytest.raises(ValueError, match="perfusion must be finite and non-negative"):
        simulate_tissue(u0, 0.1, -1.0, dx=0.1, dt=0.1, n_frames=3)
    with pytest.raises(ValueError, match="substeps=1 is unstable"):
        simulate_tissue(u0, 1.0, dx=0.1, dt=0.1, n_frames=3, substeps=1)
    with pytest.raises(ValueError, match="t_off must be after t_on"):
        MovingSource(start=(0, 0), end=(1, 1), width=1.0, power=1.0, t_on=2.0, t_off=1.0)
    with pytest.raises(ValueError, match=r"diffusivity must be a number or have shape \(6, 6\)"):
        LearnedTissueModel((8, 8), 0.1, diffusivity=torch.ones(3, 3))
