"""Tests for anra_torch.simulation.fixed_grid: torchdiffeq's fixed-grid methods, bit for bit, without it.

The reference is ``torchdiffeq.odeint`` itself at ``step_size`` 1, on a right-hand side that depends on the
time (so every stage time counts), is nonlinear and switches at step boundaries (so ``perturb`` counts).
"""

from __future__ import annotations

import pytest
import torch
from torchdiffeq import odeint

from anra_torch.simulation import FIXED_STEP_METHODS
from anra_torch.simulation.fixed_grid import fixed_grid


def _rhs(rate: torch.Tensor):  # noqa: ANN202
    def rhs(t: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        switch = (t.floor() % 2).to(u.dtype)  # a forcing that flips on every step boundary
        return (-rate * u**3 * torch.sin(0.37 * t) + 0.2 * switch + 0.05 * t) * 0.1  # stable at unit steps

    return rhs


@pytest.mark.parametrize("perturb", [False, True])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("method", list(FIXED_STEP_METHODS))
def test_frames_and_gradients_are_torchdiffeqs_bit_for_bit(
    method: str, dtype: torch.dtype, perturb: bool
) -> None:
    rate = torch.tensor(0.8, dtype=dtype, requires_grad=True)
    u0 = torch.linspace(-1.0, 1.5, 6, dtype=dtype).reshape(2, 3).requires_grad_(True)
    t = torch.arange(5, dtype=dtype) * 3  # 3 steps per output time
    options = {"step_size": 1.0, "perturb": True} if perturb else {"step_size": 1.0}
    expected = odeint(_rhs(rate), u0, t, method=method, options=options)
    got = fixed_grid(_rhs(rate), u0, t, method, perturb=perturb)
    assert got.shape == expected.shape == (5, 2, 3)
    assert torch.equal(got, expected)
    weights = torch.rand(got.shape, dtype=dtype, generator=torch.Generator().manual_seed(0))
    want = torch.autograd.grad((expected * weights).sum(), (rate, u0))
    have = torch.autograd.grad((got * weights).sum(), (rate, u0))
    assert all(torch.equal(h, w) for h, w in zip(have, want, strict=True))


@pytest.mark.parametrize("perturb", [False, True])
@pytest.mark.parametrize("method", list(FIXED_STEP_METHODS))
def test_times_between_grid_points_and_a_short_last_step_are_torchdiffeqs(method: str, perturb: bool) -> None:
    rate, u0 = torch.tensor(0.8, dtype=torch.float64), torch.tensor([1.0, -0.5], dtype=torch.float64)
    t = torch.tensor([0.0, 0.5, 2.25, 4.5], dtype=torch.float64)  # the grid's last step is 0.5 long
    options = {"step_size": 1.0, "perturb": True} if perturb else {"step_size": 1.0}
    expected = odeint(_rhs(rate), u0, t, method=method, options=options)
    assert torch.equal(fixed_grid(_rhs(rate), u0, t, method, perturb=perturb), expected)
