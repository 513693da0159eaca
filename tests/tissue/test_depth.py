"""Damage in depth: Omega in depth against direct integration, the threshold depth, shapes, units,
scaling, standard errors, gradients, devices and errors."""

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
    damage_in_depth,
    fit_depth_parameters,
    subsurface_temperature,
    surface_heat_input,
    threshold_depth,
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


def test_threshold_depth_interpolates_log_dose() -> None:
    dose = torch.tensor([100.0, 10.0, 1.0, 0.1]).view(4, 1, 1).expand(4, 2, 3).clone()
    dose[:, 1] = 0.5  # never reaches the threshold
    depth = threshold_depth(dose, torch.tensor([0.0, 0.1, 0.2, 0.3]), 3.0)
    assert depth.shape == (2, 3)
    assert float(depth[0, 0]) == pytest.approx(0.1 + 0.1 * math.log(10 / 3) / math.log(10))
    assert torch.all(depth[1] == 0.0)


def test_shapes_units_and_batches(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    batch = torch.stack([frames, frames])
    maps = damage_in_depth(
        batch, dt, dx, diffusivity=torch.tensor([A, 2 * A], dtype=F64), body_temperature=BODY
    )
    z = maps.depths.numel()
    assert maps.omega.shape == maps.cem43.shape == maps.peak.shape == (2, z, 20, 20)
    assert maps.damage_depth.shape == maps.damage_depth_std.shape == maps.cem43_depth.shape == (2, 20, 20)
    assert float(maps.depths[0]) == 0.0 and bool((maps.depths.diff() > 0).all())
    assert float(maps.damage_depth[1, 10, 10]) > float(maps.damage_depth[0, 10, 10])  # heat goes deeper
    # No parameter errors given: only the frames' sampling in time, half the two dose rules' difference.
    hold = damage_in_depth(batch, dt, dx, diffusivity=maps.diffusivity, body_temperature=BODY, rule="hold")
    torch.testing.assert_close(maps.damage_depth_std, 0.5 * (hold.damage_depth - maps.damage_depth).abs())
    assert float(maps.damage_depth_std.max()) < 0.01
    single = damage_in_depth(frames, dt, dx, diffusivity=A, body_temperature=BODY)
    assert single.damage_depth.shape == (20, 20)
    # The batch shares one depth grid (deep enough for its hottest video): 1e-6 mm apart.
    torch.testing.assert_close(single.damage_depth, maps.damage_depth[0], rtol=0, atol=1e-5)


def test_depth_scales_with_length(burn: tuple[torch.Tensor, float, float]) -> None:
    """Lengths x2 with a x4 (same times): the same solution at twice the depth (mm in, mm out)."""
    frames, dt, dx = burn
    base = damage_in_depth(frames, dt, dx, diffusivity=A, body_temperature=BODY).damage_depth
    scaled = damage_in_depth(frames, dt, 2 * dx, diffusivity=4 * A, body_temperature=BODY).damage_depth
    deep = base > 0.2
    np.testing.assert_allclose(scaled[deep].numpy(), 2 * base[deep].numpy(), rtol=0.01)


def test_standard_errors_follow_the_parameters(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    args = {"diffusivity": A, "loss_rate": 0.003, "body_temperature": BODY}
    maps = damage_in_depth(frames, dt, dx, diffusivity_std=0.014, loss_rate_std=0.002, noise_sd=0.3, **args)
    up = damage_in_depth(frames, dt, dx, **(args | {"diffusivity": 1.1 * A})).damage_depth
    down = damage_in_depth(frames, dt, dx, **(args | {"loss_rate": 0.005})).damage_depth
    base = maps.damage_depth
    floor = torch.sqrt((up - base) ** 2 + (down - base) ** 2)
    deep = base > 0.2
    assert bool((maps.damage_depth_std[deep] >= floor[deep] - 1e-12).all())
    assert bool((maps.damage_depth_std[deep] <= floor[deep] + 0.02).all())  # the noise adds little at depth
    # Deeper with a larger a, by less than the 1-D sqrt(a) scaling (5 %): the spot also loses more sideways.
    assert 0.0 < float((up - base)[10, 10]) < 0.05 * float(base[10, 10])


def test_coarse_copies_keep_the_map_and_its_parameter_spread(burn: tuple[torch.Tensor, float, float]) -> None:
    """``coarse=2``: the base map unchanged, the parameters' part of its standard error from copies on
    2 x 2 px means within 10 % of the full copies' where the damage is deep (the spread is smooth)."""
    frames, dt, dx = burn
    args = {"diffusivity": A, "loss_rate": 0.003, "body_temperature": BODY}
    args |= {"diffusivity_std": 0.014, "loss_rate_std": 0.002}
    full = damage_in_depth(frames, dt, dx, **args)
    coarse = damage_in_depth(frames, dt, dx, coarse=2, **args)
    torch.testing.assert_close(coarse.damage_depth, full.damage_depth, rtol=1e-9, atol=1e-12)
    deep = full.damage_depth > 0.2
    ratio = coarse.damage_depth_std[deep] / full.damage_depth_std[deep]
    assert 0.9 < float(ratio.min()) and float(ratio.max()) < 1.1
    with pytest.raises(ValueError, match="coarse"):
        damage_in_depth(frames, dt, dx, coarse=0, **args)


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
        maps = damage_in_depth(frames, dt, dx, diffusivity=A, body_temperature=BODY, noise_sd=0.1)
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
        damage_in_depth(frames, dt, dx, diffusivity=A, rule="mean")
    holed = frames.clone()
    holed[3, 2, 2] = math.nan
    with pytest.raises(ValueError, match="frames must be finite for the depth solve, got 1 non-finite"):
        damage_in_depth(holed, dt, dx, diffusivity=A)
    with pytest.raises(ValueError, match="diffusivity must be a number or have shape \\(1,\\)"):
        damage_in_depth(frames, dt, dx, diffusivity=torch.tensor([A, A]))
    with pytest.raises(TypeError, match="diffusivity must be a number in mm\\^2/s"):
        damage_in_depth(frames, dt, dx, diffusivity="fast")


def test_a_layer_deeper_than_the_heat_reaches_is_the_half_space(
    burn: tuple[torch.Tensor, float, float],
) -> None:
    """The grid stops where the heat does: ``thickness=1e300`` (and 10 mm) give the half-space's maps on the
    same nodes (no grid growing with the thickness); a shallow layer is its own problem."""
    frames, dt, dx = burn
    args = {"diffusivity": A, "body_temperature": BODY}
    free = damage_in_depth(frames, dt, dx, **args)
    for thickness in (10.0, 1e300):
        layer = damage_in_depth(frames, dt, dx, thickness=thickness, **args)
        torch.testing.assert_close(layer.depths, free.depths)
        torch.testing.assert_close(layer.damage_depth, free.damage_depth)
    shallow = damage_in_depth(frames, dt, dx, thickness=1.5, **args)
    n = shallow.depths.numel()
    assert float(shallow.depths[-1]) < 1.5 and torch.equal(shallow.depths, free.depths[:n])
    assert float(shallow.peak[-1, 10, 10]) < float(free.peak[n - 1, 10, 10]) - 0.1  # held at 37 C at 1.5 mm
