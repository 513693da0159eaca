"""Local quadratic derivatives exact on quadratics up to the frame's corners, their noise gain, the lateral
integrals in closed form, and the lateral diffusivities recovered from an exact anisotropic flash."""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.flash.cooling import log_surface
from anra_torch.flash.lateral import fit_lateral, lateral_integrals, local_quadratic, value_noise_gain

F64 = torch.float64


def test_local_quadratic_is_exact_on_a_quadratic_at_every_pixel_edges_included(dtype: torch.dtype) -> None:
    dx = 0.25
    y, x = torch.meshgrid(torch.arange(20, dtype=F64) * dx, torch.arange(27, dtype=F64) * dx, indexing="ij")
    field = 3 + 0.5 * x - 2 * y + 1.5 * x**2 - 0.7 * x * y + 0.2 * y**2
    frames = torch.stack([field, 2 * field]).to(dtype)
    value, second = local_quadratic(frames, 2.0, dx)
    tol = 1e-9 if dtype == F64 else 2e-3
    torch.testing.assert_close(value, frames, rtol=tol, atol=tol)
    expected = torch.tensor([3.0, 0.4, -0.7], dtype=dtype).view(3, 1, 1, 1) * torch.tensor(
        [1.0, 2.0], dtype=dtype
    ).view(1, 2, 1, 1)
    torch.testing.assert_close(second, expected.expand_as(second), rtol=tol, atol=tol * 10)


def test_value_noise_gain_is_the_fits_noise_in_the_interior() -> None:
    noise = torch.randn(200, 32, 32, dtype=F64)
    value, _ = local_quadratic(noise, 1.0, 1.0)
    measured = float(value[:, 8:-8, 8:-8].std())
    assert measured == pytest.approx(value_noise_gain(1.0), rel=0.03)


def test_lateral_integrals_of_constant_ratios_grow_linearly() -> None:
    elapsed = torch.tensor([0.1, 0.2, 0.5, 1.0], dtype=F64)
    second = torch.tensor([1.0, -2.0, 3.0], dtype=F64).view(3, 1, 1).expand(3, 4, 2)
    out = lateral_integrals(second, torch.full((4, 2), 4.0, dtype=F64), elapsed)
    expected = torch.tensor([0.25, -0.5, 1.5], dtype=F64).view(3, 1, 1) * (elapsed - 0.1).view(1, 4, 1)
    torch.testing.assert_close(out, expected.expand(3, 4, 2))


def _anisotropic_flash(a: tuple[float, float, float], elapsed: torch.Tensor, dx: float) -> torch.Tensor:
    """A uniform flash plus a Gaussian one spreading exactly under ``(a_x, a_y, a_xy)``, times an insulated
    plate's depth factor (tau 40 s): the surface excess of an intact anisotropic plate."""
    y, x = torch.meshgrid(torch.arange(40, dtype=F64) * dx, torch.arange(48, dtype=F64) * dx, indexing="ij")
    r = torch.stack([x - 5.0, y - 4.0])
    a_x, a_y, a_xy = a
    frames = []
    for t in elapsed.tolist():
        sxx, syy, sxy = 4.0 + 2 * a_x * t, 2.0 + 2 * a_y * t, 0.5 + 2 * a_xy * t
        det = sxx * syy - sxy**2
        quad = (syy * r[0] ** 2 - 2 * sxy * r[0] * r[1] + sxx * r[1] ** 2) / det
        frames.append(1.0 + 8.0 * torch.exp(-0.5 * quad) / math.sqrt(det))
    depth = log_surface(elapsed, torch.tensor([40.0], dtype=F64))[0].exp()
    return torch.stack(frames) * depth[:, None, None] / depth[0]


def test_fit_lateral_recovers_the_anisotropic_diffusivities_of_an_exact_flash() -> None:
    truth = (7.3, 1.1, 0.6)
    elapsed = torch.logspace(-1.5, 0.5, 60, dtype=F64)
    frames = 20.0 + _anisotropic_flash(truth, elapsed, 0.3) + 0.005 * torch.randn(60, 40, 48, dtype=F64)
    a, used = fit_lateral(
        frames, elapsed, torch.ones(60, dtype=F64), dx=0.3, t_ref=20.0, noise_sd=0.005, sigma=2.5, labels=None
    )
    assert used >= 4
    torch.testing.assert_close(a, torch.tensor(truth, dtype=F64), rtol=0.1, atol=0.15)
