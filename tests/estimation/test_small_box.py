"""The small-box models (:mod:`anra_torch.estimation.small_box`) against exact solutions: fitted rates,
forecasts, the harmonic interior, standard errors.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from scenes import DT, DX, still_box

from anra_torch.estimation.small_box import (
    SmallBoxModel,
    edge_explained,
    fit_small_box,
    forecast_small_box,
    harmonic_interior,
)


def mode_video(a: float, b: float, c: float, dt: float, dx: float, n: int = 120) -> np.ndarray:
    """Exact solution of dT/dt = a Lap T - b (T - 20) + c: a cosine mode plus a relaxing mean."""
    y, x = np.mgrid[:12, :14] * dx
    k = 2 * np.pi / (14 * dx)
    t = np.arange(n)[:, None, None] * dt
    mean = 20 + c / b + (5 - c / b) * np.exp(-b * t)
    return mean + 3 * np.cos(k * x + 0.3) * np.exp(-(a * k**2 + b) * t) + 0 * y


def test_box_fit_recovers_known_coefficients() -> None:
    a, b, c, dt, dx = 0.15, 0.05, 0.4, 0.1, 0.25
    video = mode_video(a, b, c, dt, dx)
    fit = fit_small_box(torch.as_tensor(video), dt, dx, "loss")
    # The 5-point Laplacian reads a cos mode of 14 px low by (sin(k dx/2)/(k dx/2))^2 = 0.983.
    assert fit.a == pytest.approx(a / 0.983, rel=0.02)
    assert fit.b == pytest.approx(b, rel=0.02)
    assert fit.c - fit.b * (20 - fit.t_ref) == pytest.approx(c, rel=0.05)


def test_box_forecast_follows_the_exact_solution() -> None:
    a, b, c, dt, dx = 0.15, 0.05, 0.4, 0.1, 0.25
    video = mode_video(a, b, c, dt, dx)
    frames = torch.as_tensor(video)
    fit = SmallBoxModel("loss", a=a, b=b, c=c, t_ref=20.0)  # dT/dt = a Lap T - b (T - 20) + c
    predicted = forecast_small_box(fit, frames, dt, dx, start=10, n=50).numpy()
    error = np.abs(predicted - video[11:61])[:, 1:-1, 1:-1].max()
    assert error < 0.05  # degC over 5 s (5-point Laplacian and Euler errors)
    plain = forecast_small_box(SmallBoxModel("plain", a=a), frames, dt, dx, start=10, n=50).numpy()
    assert np.abs(plain - video[11:61])[:, 1:-1, 1:-1].max() > 10 * error


def test_harmonic_interior_is_exact_on_harmonic_polynomials() -> None:
    y, x = np.mgrid[:9, :13].astype(float)
    frames = np.stack([x**2 - y**2 + 3 * x * y + 2 * x, 5 - y + 0.5 * (x * x - y * y)])  # Lap = 0
    np.testing.assert_allclose(harmonic_interior(torch.as_tensor(frames)), frames[:, 1:-1, 1:-1], atol=1e-10)
    bump = frames.copy()
    bump[:, 4, 6] += 1.0  # not harmonic inside: the steady state for the same edges does not see it
    np.testing.assert_allclose(harmonic_interior(torch.as_tensor(bump)), frames[:, 1:-1, 1:-1], atol=1e-10)


def test_quasi_steady_forecast_is_exact_for_a_stationary_source_under_moving_edges() -> None:
    """T = harmonic(edges(t)) + S: the limit a -> infinity of dT/dt = a Lap T + q with Lap S = -q / a."""
    y, x = np.mgrid[:9, :13].astype(float)
    source = np.sin(np.pi * x / 12) * np.sin(np.pi * y / 8)  # zero on the edges
    t = np.arange(80)[:, None, None] * 0.1
    frames = 100 + 0.3 * np.sin(2 * t) + 0.1 * t * (x - 6) + 0.05 * (x * y - 3 * y) * np.cos(t) + 4 * source
    video = torch.as_tensor(frames)
    model = fit_small_box(video[:41], 0.1, 0.25, "quasi_steady")
    np.testing.assert_allclose(
        forecast_small_box(model, video, 0.1, 0.25, 40, 39).numpy(), frames[41:80], atol=1e-9
    )
    assert edge_explained(video) == pytest.approx(1.0, abs=1e-9)


def test_a_negative_fitted_loss_rate_is_taken_as_zero_in_the_forecast() -> None:
    """A fitted b < 0 (a box that warms) would grow like exp(|b| t) over the horizon: it is clamped."""
    frames = torch.full((40, 6, 6), 30.0, dtype=torch.float64)
    fitted = fit_small_box(frames, DT, DX, "loss")
    growing = dataclasses.replace(fitted, b=-0.5, t_ref=20.0, c=0.0)
    forecast = forecast_small_box(growing, frames, DT, DX, 0, 30)
    torch.testing.assert_close(forecast, frames[1:31], rtol=0, atol=1e-12)


def test_harmonic_interior_is_exact_on_a_discrete_harmonic_field() -> None:
    y, x = np.mgrid[:9, :13].astype(float)
    field = x**2 - y**2 + 3 * x * y + 2 * x - y  # harmonic for the 5-point stencil exactly
    frames = torch.as_tensor(np.stack([field, 2 * field]))
    torch.testing.assert_close(harmonic_interior(frames), frames[:, 1:-1, 1:-1], rtol=0, atol=1e-10)
    assert edge_explained(frames) == pytest.approx(1.0)


def test_small_box_loss_model_recovers_its_rates() -> None:
    # dT/dt = -b (T - T_ref) + c on a uniform box (Lap T = 0): exponential relaxation, exact in the fit.
    b, c, t_ref = 0.2, 0.5, 25.0
    t = np.arange(200) * DT
    level = t_ref + c / b + (40 - t_ref - c / b) * np.exp(-b * t)
    frames = torch.as_tensor(np.broadcast_to(level[:, None, None], (200, 6, 6)).copy())
    model = fit_small_box(frames, DT, DX, "loss")
    assert model.b == pytest.approx(b, rel=1e-3) and model.c - model.b * (25 - model.t_ref) == pytest.approx(
        c, rel=1e-2
    )
    forecast = forecast_small_box(model, frames, DT, DX, 100, 50)
    # First-order explicit Euler at b dt = 0.02 drifts by about b dt / 2 of the relaxation: measured 0.0063 K.
    torch.testing.assert_close(forecast, frames[101:151], rtol=0, atol=0.01)


def _decaying_box(
    seed: int, a: float = 0.05, n: int = 160, size: int = 12, noise: float = 0.01
) -> torch.Tensor:
    """The slowest sine mode of a box with edges at 0, decaying at the 5-point Laplacian's exact rate for
    diffusivity ``a`` (a dt / dx^2 = 0.08: conduction resolved), plus white noise."""
    j = np.arange(size)
    mode = np.sin(np.pi * j / (size - 1))
    rate = 2 * a * 4 * np.sin(np.pi / (2 * (size - 1))) ** 2 / DX**2  # 1/s
    t = np.arange(n)[:, None, None] * DT
    field = 5.0 * np.exp(-rate * t) * mode[None, :, None] * mode[None, None, :]
    return torch.as_tensor(field + np.random.default_rng(seed).normal(0, noise, field.shape))


def test_small_box_standard_error_flags_a_still_box_and_covers_the_spread() -> None:
    """Over a box that does not change, the plain fit's ``a`` near 0 (the CSV exports' baselines: 8.5e-05
    mm^2/s) is within 3 block standard errors of 0; on a resolved decaying mode the standard error covers
    the spread over seeds. The block sandwich is conservative: on still boxes ``a / se`` spreads by 0.53
    (measured over 200 seeds), not 1."""
    still = [fit_small_box(still_box(s), DT, DX, "plain") for s in range(40)]
    assert all(m.significant is False for m in still)
    z = np.array([m.a / m.a_std_error for m in still])
    assert 0.3 < z.std() < 1.0
    decaying = [fit_small_box(_decaying_box(s), DT, DX, "plain") for s in range(20)]
    a = np.array([m.a for m in decaying])
    assert all(m.significant for m in decaying)
    assert a.mean() == pytest.approx(0.05, rel=0.02)
    assert np.mean([m.a_std_error for m in decaying]) >= a.std()
