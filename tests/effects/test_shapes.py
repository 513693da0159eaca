"""The fitted shapes' helpers (:mod:`anra_torch.effects.shapes`): the tanh-edged disc, the peak's centroid,
the multi-start L-BFGS, the pixel grid and the filtering of outer-product frames."""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.balance import BalanceSystem
from anra_torch.effects.shapes import edge_disc, finish_outer, optimise, peak, pixel_grid

F64 = torch.float64


def test_the_disc_is_one_inside_zero_outside_and_half_on_its_edge() -> None:
    x = (torch.arange(40, dtype=F64) + 0.5) * 0.25
    y = (torch.arange(30, dtype=F64) + 0.5) * 0.25
    disc = edge_disc(x, y, 5.0, 3.75, 2.0, 0.05)
    assert disc.shape == (30, 40)
    r = torch.sqrt((x[None, :] - 5.0) ** 2 + (y[:, None] - 3.75) ** 2)
    assert bool((disc[r < 1.7] > 1 - 1e-4).all()) and bool((disc[r > 2.3] < 1e-4).all())
    assert float(edge_disc(x, y, 5.0, 3.75, float(r[15, 28]), 0.05)[15, 28]) == pytest.approx(0.5, abs=1e-5)
    # The disc's area is pi r^2 (the tanh edge is antisymmetric about r).
    area = float(edge_disc(x, y, 5.0, 3.75, 2.0, 0.2).sum()) * 0.25**2
    assert area == pytest.approx(math.pi * 4.0, rel=0.01)


def test_the_disc_is_differentiable_in_its_centre_and_radius_even_on_a_pixel_centre() -> None:
    x = (torch.arange(8, dtype=F64) + 0.5) * 0.5
    centre = torch.tensor([1.25, 1.25], dtype=F64, requires_grad=True)  # exactly on a pixel centre
    radius = torch.tensor(1.0, dtype=F64, requires_grad=True)
    edge_disc(x, x, centre[0], centre[1], radius, 0.3).sum().backward()
    assert bool(torch.isfinite(centre.grad).all()) and float(radius.grad) > 0


def test_the_peak_is_the_centroid_of_the_positive_part_around_the_maximum() -> None:
    image = torch.zeros(20, 20, dtype=F64)
    image[6, 10], image[6, 11], image[7, 10] = 4.0, 2.0, 2.0
    image[0, 0] = -5.0  # negative values outside and inside are ignored
    col, row = peak(image, radius=2)
    assert (col, row) == pytest.approx((10.25, 6.25))
    assert peak(torch.zeros(5, 5, dtype=F64), radius=1) == (0.0, 0.0)  # nothing positive: the maximum


def test_optimise_starts_from_the_best_starts_and_returns_the_best_seen() -> None:
    target = torch.tensor([1.5, -0.5], dtype=F64)

    def loss(theta: torch.Tensor) -> torch.Tensor:  # Rosenbrock-like valley with its minimum at target
        return (theta[0] - target[0]) ** 2 + 10 * (
            theta[1] - target[1] - 0.1 * (theta[0] - target[0]) ** 2
        ) ** 2

    starts = [torch.tensor(s, dtype=F64) for s in ([50.0, 50.0], [1.0, 0.0], [-3.0, 2.0])]
    best = optimise(loss, starts, iterations=50, runs=1)
    torch.testing.assert_close(best, target, rtol=0, atol=1e-6)
    untouched = optimise(loss, starts, iterations=50, runs=0)  # no run: the best start as it was
    torch.testing.assert_close(untouched, starts[1])


def test_the_pixel_grid_of_a_balance() -> None:
    system = BalanceSystem(torch.rand(8, 12, 16, dtype=F64), 0.1, 0.5, sigma=0.0, noise_sd=0.0)
    x, y = pixel_grid(system)
    torch.testing.assert_close(x, (torch.arange(16, dtype=F64) + 0.5) * 0.5)
    torch.testing.assert_close(y, (torch.arange(12, dtype=F64) + 0.5) * 0.5)


@pytest.mark.parametrize("sigma", [0.0, 1.0, 4.0])  # no Gaussian, slices, banded matrices (29 taps)
def test_outer_product_frames_are_filtered_like_the_full_frames(sigma: float) -> None:
    torch.manual_seed(0)
    system = BalanceSystem(torch.rand(12, 34, 37, dtype=F64), 0.1, 0.5, sigma=sigma, noise_sd=0.01)
    scale = torch.tensor(1.0, dtype=F64, requires_grad=True)
    rows, cols = torch.rand(12, 34, dtype=F64) * scale, torch.rand(12, 37, dtype=F64).pow(2) * scale
    fast = finish_outer(system, rows, cols)
    full = system.finish(system.filters.time.average(rows[:, :, None] * cols[:, None, :]))
    assert fast.shape == full.shape == system.u.shape
    torch.testing.assert_close(fast, full, rtol=1e-13, atol=1e-15)
    (fast_grad,) = torch.autograd.grad((fast * full.detach()).sum(), scale, retain_graph=True)
    (full_grad,) = torch.autograd.grad((full * full.detach()).sum(), scale)
    torch.testing.assert_close(fast_grad, full_grad, rtol=1e-13, atol=0)
