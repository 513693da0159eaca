"""The subsurface temperature and the damage in depth from it: Omega in depth against direct integration,
gradients, devices and errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depth_scenes import (
    BODY,
    F64,
    A,
    arrhenius_direct,
    burn_video,
)

from anra_torch.tissue import (
    DepthSettings,
    StandardErrors,
    damage_in_depth,
    fit_depth_parameters,
    subsurface_temperature,
    surface_heat_input,
)


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    return burn_video()


def test_omega_in_depth_matches_direct_integration(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    maps = damage_in_depth(frames, dt, dx, diffusivity=A, loss_rate=0.003, body_temperature=BODY)
    hot = maps.peak[:, 10, 10] > 45.0
    # At every node of damage_in_depth's grid (and so on the same solver grid), then its hot nodes.
    history = subsurface_temperature(
        frames, dt, dx, maps.depths, diffusivity=A, loss_rate=0.003, body_temperature=BODY
    )[:, hot]
    direct = arrhenius_direct(history[:, :, 10, 10].numpy(), dt)
    np.testing.assert_allclose(maps.omega[hot, 10, 10].numpy(), direct, rtol=1e-6)
    np.testing.assert_allclose(
        maps.peak[hot, 10, 10].numpy(), history[:, :, 10, 10].amax(0).numpy(), rtol=1e-12
    )
    # The damage depth: where ln Omega, linear between the nodes, crosses 0.
    log = np.log(np.maximum(maps.omega[:, 10, 10].numpy(), 1e-300))
    j = int(np.flatnonzero(log >= 0).max())
    z = maps.depths.numpy()
    expected = z[j] + (z[j + 1] - z[j]) * log[j] / (log[j] - log[j + 1])
    assert float(maps.damage_depth[10, 10]) == pytest.approx(expected, rel=1e-12)
    assert 0.3 < expected < 1.5


def test_gradients_flow_to_frames_and_parameters() -> None:
    frames = (BODY + 20 * torch.rand(3, 2, 2, dtype=F64)).requires_grad_()
    a = torch.tensor(A, dtype=F64, requires_grad=True)

    def solve(f: torch.Tensor, diffusivity: torch.Tensor) -> torch.Tensor:
        return subsurface_temperature(
            f, 0.5, 0.2, [0.05, 0.1], diffusivity=diffusivity, body_temperature=BODY
        )

    assert torch.autograd.gradcheck(solve, (frames, a))
    burn = BODY + 50 * torch.exp(-torch.arange(9, dtype=F64).view(9, 1, 1) / 6).expand(9, 3, 3)
    burn = torch.cat([torch.full((1, 3, 3), BODY, dtype=F64), burn])
    depth = damage_in_depth(burn, 0.5, 0.2, diffusivity=a, body_temperature=BODY).damage_depth[1, 1]
    (grad,) = torch.autograd.grad(depth, a)
    eps = 1e-6
    plus = damage_in_depth(burn, 0.5, 0.2, diffusivity=A + eps, body_temperature=BODY).damage_depth[1, 1]
    minus = damage_in_depth(burn, 0.5, 0.2, diffusivity=A - eps, body_temperature=BODY).damage_depth[1, 1]
    assert float(grad) == pytest.approx(float(plus - minus) / (2 * eps), rel=1e-4)
    assert float(grad) > 0


def test_runs_on_the_inputs_device_whatever_the_default(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    expected = damage_in_depth(frames, dt, dx, diffusivity=A, body_temperature=BODY).damage_depth
    with torch.device("meta"):
        t = subsurface_temperature(frames, dt, dx, [0.0, 0.5], diffusivity=A)
        maps = damage_in_depth(
            frames, dt, dx, diffusivity=A, body_temperature=BODY, errors=StandardErrors(noise_sd=0.1)
        )
        heat = surface_heat_input(frames, dt, dx, diffusivity=A)
        fit = fit_depth_parameters(frames, dt, dx)
    assert t.device.type == maps.damage_depth.device.type == heat.device.type == "cpu"
    assert fit.diffusivity.device.type == "cpu"
    torch.testing.assert_close(maps.damage_depth, expected)


def test_errors_name_the_argument(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    with pytest.raises(ValueError, match="diffusivity must be positive and finite in mm\\^2/s"):
        damage_in_depth(frames, dt, dx, diffusivity=0.0)
    with pytest.raises(ValueError, match="loss_rate must be non-negative"):
        damage_in_depth(frames, dt, dx, diffusivity=A, loss_rate=-0.1)
    with pytest.raises(ValueError, match="depths must be finite depths >= 0 mm"):
        subsurface_temperature(frames, dt, dx, [-1.0], diffusivity=A)
    with pytest.raises(ValueError, match="thickness must be deeper than the deepest depth"):
        subsurface_temperature(frames, dt, dx, [1.0], diffusivity=A, thickness=0.5)
    with pytest.raises(ValueError, match="rule must be one of"):
        damage_in_depth(frames, dt, dx, diffusivity=A, settings=DepthSettings(rule="mean"))
    holed = frames.clone()
    holed[3, 2, 2] = math.nan
    with pytest.raises(ValueError, match="frames must be finite for the depth solve, got 1 non-finite"):
        damage_in_depth(holed, dt, dx, diffusivity=A)
    with pytest.raises(ValueError, match="diffusivity must be a number or have shape \\(1,\\)"):
        damage_in_depth(frames, dt, dx, diffusivity=torch.tensor([A, A]))
    with pytest.raises(TypeError, match="diffusivity must be a number in mm\\^2/s"):
        damage_in_depth(frames, dt, dx, diffusivity="fast")
