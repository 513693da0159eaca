"""Local quadratic derivatives exact on quadratics up to the frame's corners, their noise gain, the lateral
integrals in closed form, and the lateral diffusivities recovered from an exact anisotropic flash."""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.flash.cooling import log_surface
from anra_torch.flash.lateral import (
    fit_lateral,
    gaussian_derivatives,
    gaussian_noise_covariance,
    lateral_integrals,
    local_quadratic,
    value_noise_gain,
)

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


def test_the_cubic_local_fit_is_exact_on_a_cubic_at_every_pixel_and_the_quadratic_one_inside() -> None:
    dx = 0.4
    y, x = torch.meshgrid(torch.arange(24, dtype=F64) * dx, torch.arange(30, dtype=F64) * dx, indexing="ij")
    field = 1 + x - y + 0.5 * x**2 + 0.3 * x * y - 0.2 * y**2 + 0.05 * x**3 - 0.04 * x**2 * y + 0.03 * y**3
    value, second = local_quadratic(field[None], 3.0, dx, cubic=True)
    torch.testing.assert_close(value[0], field, rtol=1e-8, atol=1e-8)
    expected = torch.stack([1 + 0.3 * x - 0.08 * y, -0.4 + 0.18 * y, 0.3 - 0.08 * x])
    torch.testing.assert_close(second[:, 0], expected, rtol=1e-7, atol=1e-7)  # edges and corners too
    _, plain = local_quadratic(field[None], 3.0, dx)
    assert (plain[:, 0] - expected).abs().max() > 1e-3  # the quadratic fit's one-sided bias at the edge
    noise = torch.randn(2, 24, 30, dtype=F64)
    inside = (slice(None), slice(None), slice(9, -9), slice(9, -9))
    torch.testing.assert_close(
        local_quadratic(noise, 3.0, dx, cubic=True)[1][inside], local_quadratic(noise, 3.0, dx)[1][inside]
    )


def test_value_noise_gain_is_the_fits_noise_in_the_interior() -> None:
    noise = torch.randn(200, 32, 32, dtype=F64)
    value, _ = local_quadratic(noise, 1.0, 1.0)
    measured = float(value[:, 8:-8, 8:-8].std())
    assert measured == pytest.approx(value_noise_gain(1.0), rel=0.03)


def test_gaussian_derivatives_are_exact_on_a_quadratic_away_from_the_edges(dtype: torch.dtype) -> None:
    """The second derivatives are exact on a quadratic, the value on a plane (a Gaussian smooths)."""
    dx = 0.25
    y, x = torch.meshgrid(torch.arange(24, dtype=F64) * dx, torch.arange(27, dtype=F64) * dx, indexing="ij")
    plane = 3 + 0.5 * x - 2 * y
    field = plane + 1.5 * x**2 - 0.7 * x * y + 0.2 * y**2
    value, second = gaussian_derivatives(torch.stack([plane, field]).to(dtype), 1.5, dx)
    tol = 1e-9 if dtype == F64 else 2e-3
    inner = (slice(5, -5), slice(5, -5))
    torch.testing.assert_close(value[0][inner], plane[inner].to(dtype), rtol=tol, atol=tol)
    expected = torch.tensor([3.0, 0.4, -0.7], dtype=dtype).view(3, 1, 1).expand(3, 14, 17)
    torch.testing.assert_close(second[:, 1][(slice(None), *inner)], expected, rtol=tol, atol=tol)
    torch.testing.assert_close(second[:, 0][(slice(None), *inner)], 0 * expected, rtol=tol, atol=tol)


def test_gaussian_noise_covariance_is_the_filters_noise_in_the_interior() -> None:
    generator = torch.Generator().manual_seed(3)
    noise = torch.randn(300, 36, 36, dtype=F64, generator=generator)
    value, second = gaussian_derivatives(noise, 2.0, 0.5)
    outputs = torch.cat([value[None], second * torch.tensor([1.0, 1.0, 2.0], dtype=F64).view(3, 1, 1, 1)])
    outputs = outputs[:, :, 6:-6, 6:-6].flatten(1)
    measured = outputs @ outputs.T / outputs.shape[1]
    expected = gaussian_noise_covariance(2.0, 0.5)
    scale = expected.diagonal().sqrt()
    torch.testing.assert_close(
        measured / scale.outer(scale), expected / scale.outer(scale), rtol=0, atol=0.03
    )


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


def test_fit_lateral_is_not_biased_to_zero_where_late_regressors_are_noise() -> None:
    """At 20 mK the late blocks' lateral integrals are mostly noise: plain least squares gave a_x 1.8 for 7.3
    (errors in variables); with their noise parts taken off and the same smoothing on both sides of the
    heat equation the fit stays within 5 %."""
    truth = (7.3, 1.1, 0.6)
    elapsed = torch.logspace(-1.5, 0.5, 60, dtype=F64)
    generator = torch.Generator().manual_seed(1)
    noise = 0.02 * torch.randn(60, 40, 48, dtype=F64, generator=generator)
    frames = 20.0 + _anisotropic_flash(truth, elapsed, 0.3) + noise
    a, used = fit_lateral(
        frames, elapsed, torch.ones(60, dtype=F64), dx=0.3, t_ref=20.0, noise_sd=0.02, sigma=2.5, labels=None
    )
    assert used >= 4
    torch.testing.assert_close(a, torch.tensor(truth, dtype=F64), rtol=0.05, atol=0.05)


def test_fit_lateral_keeps_the_blocks_before_the_model_breaks() -> None:
    """Half the frame changes depth (a defect showing) after the first two blocks: the stop rule ends the
    fit there, and the two blocks still give the diffusivities (they were thrown away below four)."""
    truth = (7.3, 1.1, 0.6)
    elapsed = torch.logspace(-1.5, 0.5, 60, dtype=F64)
    generator = torch.Generator().manual_seed(2)
    excess = _anisotropic_flash(truth, elapsed, 0.3)
    late = (1 + 4 * (elapsed - 0.05).clamp_min(0)).view(-1, 1, 1)  # warmer: the heat stops above a defect
    excess[:, :, 24:] *= late
    frames = 20.0 + excess + 0.005 * torch.randn(60, 40, 48, dtype=F64, generator=generator)
    a, used = fit_lateral(
        frames, elapsed, torch.ones(60, dtype=F64), dx=0.3, t_ref=20.0, noise_sd=0.005, sigma=2.5, labels=None
    )
    assert 2 <= used < 4
    torch.testing.assert_close(a, torch.tensor(truth, dtype=F64), rtol=0.1, atol=0.15)


def test_fit_lateral_starts_later_where_the_first_blocks_are_broken() -> None:
    """Half the frame is hotter at first and evens out within 0.1 s (a shallow layer over a defect): no run
    from the first block is physical (zeros before), the longest physical run from a later block is."""
    truth = (7.3, 1.1, 0.6)
    elapsed = torch.logspace(-1.5, 0.5, 60, dtype=F64)
    generator = torch.Generator().manual_seed(2)
    excess = _anisotropic_flash(truth, elapsed, 0.3)
    excess[:, :, 24:] *= (1 + torch.exp(-elapsed / 0.1)).view(-1, 1, 1)
    frames = 20.0 + excess + 0.005 * torch.randn(60, 40, 48, dtype=F64, generator=generator)
    a, used = fit_lateral(
        frames, elapsed, torch.ones(60, dtype=F64), dx=0.3, t_ref=20.0, noise_sd=0.005, sigma=2.5, labels=None
    )
    assert used >= 2
    torch.testing.assert_close(a, torch.tensor(truth, dtype=F64), rtol=0.15, atol=0.2)
