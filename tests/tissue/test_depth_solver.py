"""The subsurface solver against closed forms of the half-space: the erfc step, perfusion's decaying
and exponential profiles, a lateral cosine mode, a layer held at its bottom,
the heat input of a constant flux."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depth_scenes import (
    BODY,
    F64,
    RISE,
    A,
    decaying_response,
    ramp_response,
    step_video,
)

from anra_torch.tissue import (
    subsurface_temperature,
    surface_heat_input,
)
from anra_torch.tissue.depth_solver import (
    depth_nodes,
    frame_problem,
    free_surface_operator,
    march,
    solver_nodes,
    state_at,
)


def test_step_of_the_surface_gives_the_erfc_profile(dtype: torch.dtype) -> None:
    dt, n = 0.1, 101
    depths = np.array([0.0, 0.05, 0.2, 0.5, 1.0, 2.0])
    t = subsurface_temperature(
        step_video(n, dt, dtype=dtype), dt, 0.2, depths, diffusivity=A, body_temperature=BODY
    )
    assert t.dtype == dtype and t.shape == (n, 6, 6, 6)
    exact = BODY + RISE * ramp_response(depths[None], (np.arange(n) * dt)[:, None], A, dt)
    # 2nd-order depth grid (spacings 0.01 mm at the surface, 3 % more per node): 0.025 K of 43 K at 2 mm.
    np.testing.assert_allclose(t[:, :, 3, 3].double().numpy(), exact, rtol=0, atol=0.04)
    assert float(t.flatten(2).std(-1).max()) < 1e-4  # uniform surface: no lateral structure


@pytest.mark.parametrize("elapsed", [5.0, 30.0])
def test_perfusion_gives_the_decaying_step_response(elapsed: float) -> None:
    b, dt = 0.05, 0.5
    n = round(elapsed / dt) + 1
    depths = np.array([0.2, 0.5, 1.0, 2.0])
    t = subsurface_temperature(
        step_video(n, dt), dt, 0.2, depths, diffusivity=A, loss_rate=b, body_temperature=BODY
    )
    exact = BODY + RISE * decaying_response(depths, elapsed, A, b, dt)
    np.testing.assert_allclose(t[-1, :, 2, 2].numpy(), exact, rtol=0, atol=0.03)


def test_perfusion_profile_decays_exponentially_in_the_steady_state() -> None:
    b, dt = 0.05, 2.0
    depths = np.array([0.1, 0.5, 1.0, 2.0, 3.0])
    t = subsurface_temperature(
        step_video(151, dt), dt, 0.2, depths, diffusivity=A, loss_rate=b, body_temperature=BODY
    )
    exact = BODY + RISE * np.exp(-depths * math.sqrt(b / A))  # erfc(sqrt(b t)) ~ 1e-8 at 300 s
    np.testing.assert_allclose(t[-1, :, 0, 0].numpy(), exact, rtol=0, atol=0.03)  # 0.017 K at 3 mm


def test_a_lateral_cosine_mode_decays_faster_with_depth() -> None:
    """A surface ``20 cos(k x)`` switched on over the first frame: each depth follows the decaying step
    response with the lateral loss ``a k^2 + b``: the lateral terms of the 3-D problem."""
    w, dx, dt, b = 16, 0.1, 0.2, 0.01
    k = math.pi * 2 / (w * dx)  # the cosine mode p = 2 along x: 3.9 1/mm
    x = (torch.arange(w, dtype=F64) + 0.5) * dx
    mode = 20.0 * torch.cos(k * x).expand(8, w)
    frames = torch.full((26, 8, w), BODY, dtype=F64)
    frames[1:] += mode
    depths = np.array([0.05, 0.2, 0.5])
    t = subsurface_temperature(frames, dt, dx, depths, diffusivity=A, loss_rate=b, body_temperature=BODY)
    exact = decaying_response(depths, 25 * dt, A, A * k**2 + b, dt)
    profile = (t[-1, :, 4] - BODY) / mode[0]  # (Z, W)
    np.testing.assert_allclose(
        profile[:, [0, 3, 12]].numpy(), np.repeat(exact[:, None], 3, 1), rtol=0, atol=1e-3
    )
    steady = np.exp(-depths * math.sqrt(k**2 + b / A))
    # Far below the 1-D (lateral-free) profile; at 5 s already the steady one.
    assert np.all(exact < 0.9 * np.exp(-depths * math.sqrt(b / A)))
    np.testing.assert_allclose(exact, steady, rtol=1e-5)


def test_a_layer_held_at_its_bottom_reaches_the_linear_profile() -> None:
    depths = np.array([0.5, 1.0, 1.5])
    t = subsurface_temperature(
        step_video(121, 1.0), 1.0, 0.2, depths, diffusivity=A, thickness=2.0, body_temperature=BODY
    )
    np.testing.assert_allclose(t[-1, :, 0, 0].numpy(), BODY + RISE * (1 - depths / 2.0), rtol=0, atol=1e-6)


def test_equilibrium_start_and_the_surface_row() -> None:
    frames = step_video(3, 0.5)
    t = subsurface_temperature(frames, 0.5, 0.1, [0.0, 0.3], diffusivity=A)  # body: the first frame's median
    assert torch.equal(t[:, 0], frames)  # depth 0 is the surface itself
    assert torch.allclose(t[0], torch.full_like(t[0], BODY))  # in equilibrium with the first frame


def test_heat_input_of_a_constant_flux_grows_linearly() -> None:
    q, dt, n = 5.0, 0.1, 101  # K mm/s: the surface 37 + 2 q sqrt(t / (pi a))
    time = torch.arange(n, dtype=F64) * dt
    frames = (BODY + 2 * q * torch.sqrt(time / (math.pi * A))).view(n, 1, 1).expand(n, 4, 4)
    heat = surface_heat_input(frames, dt, 0.2, diffusivity=A, body_temperature=BODY)[:, 0, 0]
    # The first interval's sqrt(t) is sampled by a straight line: 0.1 K mm early, 0.5 % late.
    np.testing.assert_allclose(heat.numpy(), (q * time).numpy(), rtol=0.006, atol=0.12)


def test_the_free_surface_operator_conserves_heat_without_loss() -> None:
    """With no loss to the air the only exit is the far bottom: the slowest mode's decay tends to
    ``(pi / 2 L)^2`` (a layer held at 0 at depth L, insulated at the top), and a loss speeds every mode."""
    nodes = solver_nodes(depth_nodes(1.0, growth=1.1), 20.0)
    free = free_surface_operator(nodes, 0.0)
    assert float(-free["lam"].max()) == pytest.approx((math.pi / (2 * 20.0)) ** 2, rel=0.02)
    lossy = free_surface_operator(nodes, 0.5)
    assert bool((lossy["lam"].sort().values < free["lam"].sort().values + 1e-12).all())
    # modes to nodes and back: the surface row of the inverse is ``surface``
    torch.testing.assert_close(torch.linalg.inv(free["to_modes"])[0], free["surface"])


def test_the_closed_form_state_is_the_march() -> None:
    rise = torch.randn(2, 9, 4, 5, dtype=F64, generator=torch.Generator().manual_seed(1))
    a, b = torch.tensor([0.1, 0.2], dtype=F64), torch.tensor([0.0, 0.01], dtype=F64)
    dt, dx = torch.tensor([0.1, 0.2], dtype=F64), torch.tensor([0.1, 0.1], dtype=F64)
    nodes = solver_nodes(depth_nodes(0.5, growth=1.1), 5.0)
    problem = frame_problem(rise, dt, dx, a, b, nodes, 2)
    states = torch.cat([s for _, s in march(problem, 4)], 1)  # (B, T, K, M)
    last = torch.tensor([8, 5])
    torch.testing.assert_close(state_at(problem, last), states[torch.arange(2), last])
