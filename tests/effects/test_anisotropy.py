"""Anisotropic diffusion (:mod:`anra_torch.effects.anisotropy`): the covariance of a Gaussian grows as
``Sigma0 + 2 A t``, its derived angle and ratio, heat conserved with a mixed term.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from fields import blob, centres, moments, rough

from anra_torch.effects import (
    Boundary,
    Effect,
    simulate_effects,
)

F64 = torch.float64


# ------------------------------------------------------------------------------------- anisotropy
def test_anisotropy_covariance_grows_as_sigma0_plus_2At() -> None:
    n, dx, dt, sigma, c = 96, 0.25, 0.1, 1.5, (12.0, 12.0)
    p = {"a_x": 0.2, "a_y": 0.08, "a_xy": 0.06}
    video = simulate_effects(
        blob(n, dx, sigma, c), a=0.0, dx=dx, dt=dt, n_frames=21, effects=[Effect("anisotropy", p)]
    )
    t = torch.arange(21, dtype=F64) * dt
    m = moments(video, dx)
    torch.testing.assert_close(m["xx"], sigma**2 + 2 * p["a_x"] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["yy"], sigma**2 + 2 * p["a_y"] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["xy"], 2 * p["a_xy"] * t, rtol=0, atol=1e-8)
    torch.testing.assert_close(m["x"], torch.full_like(t, c[0]), rtol=0, atol=1e-8)
    # The field: sigma0^2 / sqrt(det S) exp(-r' S^-1 r / 2) with S = sigma0^2 I + 2 A t.
    A = np.array([[p["a_x"], p["a_xy"]], [p["a_xy"], p["a_y"]]])
    x, y = centres(n, dx)[None, :] - c[0], centres(n, dx)[:, None] - c[1]
    for k in (5, 20):
        S = sigma**2 * np.eye(2) + 2 * A * float(t[k])
        Si = np.linalg.inv(S)
        q = Si[0, 0] * x**2 + 2 * Si[0, 1] * x * y + Si[1, 1] * y**2
        exact = sigma**2 / math.sqrt(np.linalg.det(S)) * torch.exp(-0.5 * q)
        assert float((video[k] - exact).abs().max()) < 2e-3


def test_anisotropy_derived_angle_and_ratio_match_the_eigenvectors() -> None:
    for p in (
        {"a_x": 0.2, "a_y": 0.08, "a_xy": 0.06},
        {"a_x": 0.1, "a_y": 0.3, "a_xy": -0.05},
        {"a_x": 0.1, "a_y": 0.1, "a_xy": 0.0},
    ):
        derived = Effect("anisotropy", p).derived()
        values, vectors = np.linalg.eigh(np.array([[p["a_x"], p["a_xy"]], [p["a_xy"], p["a_y"]]]))
        assert derived["ratio"] == pytest.approx(values[1] / values[0], rel=1e-12)
        assert -90.0 < derived["angle_deg"] <= 90.0
        if values[1] > values[0]:  # the larger eigenvalue's axis (undefined when isotropic)
            angle = math.radians(derived["angle_deg"])
            axis = [math.cos(angle), math.sin(angle)]
            assert abs(np.dot(vectors[:, 1], axis)) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("boundary", ["neumann", "periodic"])
def test_anisotropy_conserves_heat_with_a_mixed_term(boundary: str) -> None:
    p = {"a_x": 0.1, "a_y": 0.3, "a_xy": -0.12}
    video = simulate_effects(
        rough(),
        a=0.0,
        dx=0.5,
        dt=0.2,
        n_frames=20,
        effects=[Effect("anisotropy", p)],
        boundary=Boundary(boundary),
    )
    total = video.sum((-2, -1))
    torch.testing.assert_close(total, total[:1].expand_as(total), rtol=1e-13, atol=0)
