"""The plate's cooling model against its cosine series, the profiled fit against weighted least squares, the
grid's refined minimum against a known time constant, and the time bins' averages."""

from __future__ import annotations

import math

import numpy as np
import torch

from anra_torch.flash.cooling import log_surface, profile_rss, refine_minimum, tau_grid, time_bins

F64 = torch.float64


def _cosine_series(t: np.ndarray, tau: float) -> np.ndarray:
    """``ln(1 + 2 sum exp(-n^2 pi^2 t / tau)) - ln(tau) / 2`` with 2000 terms: the direct form."""
    n = np.arange(1, 2001)
    return np.log1p(2 * np.exp(-np.outer(t / tau, n**2) * math.pi**2).sum(1)) - 0.5 * math.log(tau)


def test_log_surface_is_the_cosine_series_on_both_sides_and_the_half_space_at_infinity() -> None:
    t = np.logspace(-3, 1.5, 200)
    taus = torch.tensor([0.05, 1.0, 7.0, math.inf], dtype=F64)
    got = log_surface(torch.from_numpy(t), taus).numpy()
    for k, tau in enumerate(taus.tolist()[:3]):
        np.testing.assert_allclose(got[k], _cosine_series(t, tau), rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[3], -0.5 * np.log(math.pi * t), rtol=0, atol=1e-15)


def test_profile_rss_is_the_weighted_least_squares_of_a_free_constant() -> None:
    gen = torch.Generator().manual_seed(1)
    y, w = torch.randn(5, 12, generator=gen, dtype=F64), torch.rand(5, 12, generator=gen, dtype=F64)
    curves = torch.randn(3, 12, generator=gen, dtype=F64)
    got = profile_rss(y, w, curves)
    for p in range(5):
        for k in range(3):
            r = (y[p] - curves[k]).numpy()
            c = (w[p].numpy() * r).sum() / w[p].sum().item()
            assert math.isclose(float(got[p, k]), float((w[p].numpy() * (r - c) ** 2).sum()), rel_tol=1e-9)


def test_refine_minimum_finds_a_time_constant_between_grid_points_and_inf_for_a_half_space() -> None:
    elapsed = torch.logspace(-2, 1, 120, dtype=F64)
    grid = tau_grid(elapsed)
    truth = torch.tensor([0.7, 3.3, math.inf], dtype=F64)
    y = log_surface(elapsed, truth) + torch.tensor([[1.0], [-2.0], [0.5]], dtype=F64)  # any flash energy
    tau, index = refine_minimum(profile_rss(y, torch.ones_like(y), grid.curves), grid.taus)
    torch.testing.assert_close(tau[:2], truth[:2], rtol=2e-3, atol=0)
    assert math.isinf(float(tau[2])) and int(index[2]) == len(grid.taus) - 1


def test_time_bins_grow_geometrically_and_average_their_frames() -> None:
    bins = time_bins(500, 0.01, 0.007, start=3, ratio=1.03)
    assert int(bins.counts.sum()) == 497 and bins.index[:3].eq(-1).all()
    assert bins.counts[:5].eq(1).all() and (bins.elapsed.diff() > 0).all()
    first = 0.007 + 0.01 * torch.arange(500, dtype=F64)
    ends = first[torch.cumsum(bins.counts.long(), 0) + 2]
    starts = first[torch.cumsum(bins.counts.long(), 0) + 3 - bins.counts.long()]
    assert bool(
        ((ends <= starts * 1.03 + 0.01) | bins.counts.eq(1)).all()
    )  # a bin spans its ratio, or one frame
    values = torch.randn(500, 2, dtype=F64)
    k = 40
    assert torch.allclose(bins.average(values)[k], values[bins.index == k].mean(0))
    torch.testing.assert_close(bins.elapsed[k], first[bins.index == k].mean())
