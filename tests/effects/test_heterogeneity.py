"""A disc of other diffusivity (:mod:`anra_torch.effects.heterogeneity`): its map, heat conserved, the
spreading changed inside, the sampled disc where the heat reaches it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from fields import blob, centres, moments

from anra_torch.effects import (
    EFFECTS,
    Effect,
    Grid,
    hidden_effect_video,
    simulate_effects,
)

F64 = torch.float64


# ---------------------------------------------------------------------------------- heterogeneity
def test_heterogeneity_map_has_a_one_pixel_tanh_edge() -> None:
    p = {"x": 10.0, "y": 8.0, "radius": 4.0, "a_inside": 0.3, "a_outside": 0.1}
    grid = Grid((40, 48), 0.5)
    a_map = EFFECTS["heterogeneity"].diffusivity_map(p, grid)
    assert a_map.shape == (40, 48)
    assert float(a_map[16, 20]) == pytest.approx(0.3, abs=1e-6)  # pixel centre (10.25, 8.25) mm
    assert float(a_map[0, 0]) == pytest.approx(0.1, abs=1e-12)
    r = torch.sqrt((centres(48, 0.5)[None, :] - 10.0) ** 2 + (centres(40, 0.5)[:, None] - 8.0) ** 2)
    middle = a_map[(r - 4.0).abs() < 0.05]
    assert middle.numel() and bool(((middle - 0.2).abs() < 0.02).all())  # halfway on the circle
    assert bool((a_map[(r - 4.0) > 1.5] < 0.1 + 0.2 * 0.01).all())  # 3 px out: < 1 % of the step


def test_heterogeneity_conserves_heat_and_changes_the_spreading_inside() -> None:
    n, dx, dt, sigma, c = 64, 0.25, 0.05, 0.75, (8.0, 8.0)
    u0 = blob(n, dx, sigma, c)
    t = torch.arange(11, dtype=F64) * dt
    rates = {}
    for a_in in (0.05, 0.1, 0.25):
        disc = Effect(
            "heterogeneity", {"x": 8.0, "y": 8.0, "radius": 5.0, "a_inside": a_in, "a_outside": 0.1}
        )
        video = simulate_effects(u0, a=0.1, dx=dx, dt=dt, n_frames=11, effects=[disc])
        m = moments(video, dx)
        torch.testing.assert_close(m["mass"], m["mass"][:1].expand(11), rtol=1e-13, atol=0)
        # d/dt (xx + yy) = 4 a for heat that stays inside the disc (the blob is 6.7 sd inside its edge).
        rates[a_in] = float(((m["xx"] + m["yy"])[-1] - (m["xx"] + m["yy"])[0]) / (4 * t[-1]))
    assert rates[0.05] == pytest.approx(0.05, rel=1e-3)
    assert rates[0.1] == pytest.approx(0.1, rel=1e-3)
    assert rates[0.25] == pytest.approx(0.25, rel=1e-3)


def test_heterogeneity_sample_puts_the_disc_edge_near_the_first_hot_spot() -> None:
    # The edge must lie within two hot-spot widths (sigma) of the spot, or no heat crosses it in the video.
    for seed in range(20):
        video = hidden_effect_video(["heterogeneity"], seed=seed, size=64, duration=0.1)
        p = video.effects[0].params
        rng = np.random.default_rng(seed)  # replay the hot-spot draws of hidden_effect_video
        rng.integers(1, 3)  # number of spots
        rng.uniform(5.0, 20.0)  # rise of the first
        sigma = rng.uniform(3.0, 8.0)
        margin = min(2.5 * sigma + 10.0, 32.0)
        sx, sy = rng.uniform(margin, 64 - margin), rng.uniform(margin, 64 - margin)
        centre = math.hypot(p["x"] / 0.5 - sx, p["y"] / 0.5 - sy)
        radius = p["radius"] / 0.5
        assert 8.0 <= radius <= 20.0 and centre <= 0.5 * radius + 1e-9
        assert abs(radius - centre) <= 2.0 * sigma + 1e-9, (seed, radius, centre, sigma)
