"""Damage in depth: the threshold depth, shapes, units, batches, scaling, the standard errors and their
coarse copies, layers deeper than the heat reaches."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depth_scenes import (
    BODY,
    F64,
    A,
    burn_video,
)

from anra_torch.tissue import (
    DepthSettings,
    StandardErrors,
    damage_in_depth,
    threshold_depth,
)


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    return burn_video()


def test_threshold_depth_interpolates_log_dose() -> None:
    dose = torch.tensor([100.0, 10.0, 1.0, 0.1]).view(4, 1, 1).expand(4, 2, 3).clone()
    dose[:, 1] = 0.5  # never reaches the threshold
    depth = threshold_depth(dose, torch.tensor([0.0, 0.1, 0.2, 0.3]), 3.0)
    assert depth.shape == (2, 3)
    assert float(depth[0, 0]) == pytest.approx(0.1 + 0.1 * math.log(10 / 3) / math.log(10))
    assert torch.all(depth[1] == 0.0)


@pytest.mark.slow
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
    hold = damage_in_depth(
        batch,
        dt,
        dx,
        diffusivity=maps.diffusivity,
        body_temperature=BODY,
        settings=DepthSettings(rule="hold"),
    )
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
    maps = damage_in_depth(frames, dt, dx, errors=StandardErrors(0.014, 0.002, 0.3), **args)
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
    args |= {"errors": StandardErrors(0.014, 0.002)}
    full = damage_in_depth(frames, dt, dx, **args)
    coarse = damage_in_depth(frames, dt, dx, settings=DepthSettings(coarse=2), **args)
    torch.testing.assert_close(coarse.damage_depth, full.damage_depth, rtol=1e-9, atol=1e-12)
    deep = full.damage_depth > 0.2
    ratio = coarse.damage_depth_std[deep] / full.damage_depth_std[deep]
    assert 0.9 < float(ratio.min()) and float(ratio.max()) < 1.1
    with pytest.raises(ValueError, match="coarse"):
        damage_in_depth(frames, dt, dx, settings=DepthSettings(coarse=0), **args)


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
