"""Exact solutions (:mod:`anra_torch.simulation.analytic`): ``heat_spectral`` on Fourier and cosine modes and
Gaussians, its gradient in ``a``; Gaussian blobs; one-line errors.
"""

from __future__ import annotations

import math

import pytest
import torch
from fields import centres, plane_wave
from tolerances import assert_rounding_close

from anra_torch.simulation import (
    HeatRHS,
    gaussian_blob,
    gaussian_blobs,
    heat_spectral,
)

F64 = torch.float64


def test_heat_spectral_fourier_mode_is_exact(dtype: torch.dtype) -> None:
    dx, a = 0.25, 0.3
    u0, kx, ky = plane_wave(24, 32, dx, m=3, n=-2, dtype=dtype)
    times = torch.tensor([0.0, 0.5, 1.0, 4.0], dtype=dtype)
    out = heat_spectral(u0, a=a, dx=dx, times=times, boundary="periodic")
    expected = u0 * torch.exp(-a * (kx**2 + ky**2) * times)[:, None, None]
    assert out.shape == (4, 24, 32) and out.dtype == dtype
    # FFT round trip: a few epsilons of the mode's amplitude (measured 3-4).
    assert_rounding_close(out, expected, ops=32)


def test_heat_spectral_neumann_cosine_mode_is_exact(dtype: torch.dtype) -> None:
    # cos(pi m x / Lx) cos(pi n y / Ly) has no flux through the frame edges: Neumann eigenfunction.
    dx, a, height, width = 0.2, 0.15, 20, 30
    lx, ly = width * dx, height * dx
    x, y = centres(width, dx, dtype), centres(height, dx, dtype)
    u0 = 2.0 + torch.cos(math.pi * 3 * x / lx)[None, :] * torch.cos(math.pi * 2 * y / ly)[:, None]
    times = torch.tensor([0.0, 0.3, 2.0], dtype=dtype)
    out = heat_spectral(u0, a=a, dx=dx, times=times, boundary="neumann")
    k2 = (math.pi * 3 / lx) ** 2 + (math.pi * 2 / ly) ** 2
    expected = 2.0 + (u0 - 2.0) * torch.exp(-a * k2 * times)[:, None, None]
    assert_rounding_close(out, expected, ops=32)


@pytest.mark.parametrize("boundary", ["periodic", "neumann"])
def test_heat_spectral_matches_analytic_gaussian(boundary: str) -> None:
    # A Gaussian far from the edges is (to ~1e-14) band-limited and unaffected by the boundary.
    shape, dx, a = (96, 112), 0.25, 0.2
    times = torch.tensor([0.0, 0.5, 2.0], dtype=F64)
    centre = (13.3, 11.9)
    exact = gaussian_blob(times, shape=shape, dx=dx, a=a, peak=3.0, sigma=1.0, centre=centre)
    out = heat_spectral(exact[0], a=a, dx=dx, times=times, boundary=boundary)
    torch.testing.assert_close(out, exact, rtol=0, atol=1e-11)


@pytest.mark.parametrize("boundary", ["periodic", "neumann"])
def test_heat_spectral_conserves_heat_and_batches(boundary: str) -> None:
    u0 = torch.rand(3, 16, 20, dtype=F64)
    a = torch.tensor([0.05, 0.1, 0.4], dtype=F64)
    dx = torch.tensor([0.1, 0.2, 0.3], dtype=F64)
    out = heat_spectral(u0, a=a, dx=dx, times=[0.0, 0.7], boundary=boundary)
    assert out.shape == (3, 2, 16, 20)
    torch.testing.assert_close(out[:, 0], u0, rtol=0, atol=1e-13)
    torch.testing.assert_close(out.sum((-2, -1))[:, 1], u0.sum((-2, -1)), rtol=1e-13, atol=0)
    for i in range(3):
        single = heat_spectral(u0[i], a=a[i].item(), dx=dx[i].item(), times=[0.0, 0.7], boundary=boundary)
        torch.testing.assert_close(out[i], single, rtol=0, atol=1e-13)


def test_heat_spectral_gradient_in_a_is_analytic() -> None:
    dx, t = 0.25, 1.5
    u0, kx, ky = plane_wave(16, 16, dx, m=1, n=2)
    a = torch.tensor(0.2, dtype=F64, requires_grad=True)
    out = heat_spectral(u0, a=a, dx=dx, times=[t])
    weight = torch.rand_like(u0)
    (grad,) = torch.autograd.grad((out[0] * weight).sum(), a)
    k2 = kx**2 + ky**2
    expected = -k2 * t * math.exp(-0.2 * k2 * t) * (u0 * weight).sum()
    torch.testing.assert_close(grad, expected, rtol=1e-12, atol=0)


def test_gaussian_blob_peak_and_mass() -> None:
    dx, sigma, a, peak = 0.05, 0.5, 0.2, 3.8
    times = torch.tensor([0.0, 0.5, 1.0], dtype=F64)
    shape = (240, 200)
    blob = gaussian_blob(times, shape=shape, dx=dx, a=a, peak=peak, sigma=sigma, centre=(5.025, 6.025))
    # That centre is the centre of pixel (row 120, column 100): the peak is sampled exactly.
    expected_peak = peak * sigma**2 / (sigma**2 + 2 * a * times)
    torch.testing.assert_close(blob[:, 120, 100], expected_peak, rtol=1e-14, atol=0)
    mass = blob.sum((-2, -1)) * dx**2  # heat is conserved: 2 pi peak sigma^2
    torch.testing.assert_close(mass, torch.full_like(mass, 2 * math.pi * peak * sigma**2), rtol=1e-8, atol=0)
    default = gaussian_blob(times, shape=shape, dx=dx, a=a, peak=peak, sigma=sigma, background=2.0)
    # Default centre: the frame centre.
    torch.testing.assert_close(default[0], default[0].flip(-1).flip(-2), rtol=0, atol=1e-14)
    assert default.min() >= 2.0


def test_gaussian_blobs_is_linear_and_batches() -> None:
    times, shape, dx, a = [0.0, 0.8], (30, 40), 0.25, 0.3
    peaks, sigmas, spots = [1.0, -2.0, 3.0], [0.5, 1.0, 0.8], [(2.0, 3.0), (6.0, 4.0), (8.0, 5.5)]
    total = gaussian_blobs(
        times, shape=shape, dx=dx, a=a, peaks=peaks, sigmas=sigmas, centres=spots, background=1.0
    )
    parts = [
        gaussian_blob(times, shape=shape, dx=dx, a=a, peak=p, sigma=s, centre=c)
        for p, s, c in zip(peaks, sigmas, spots, strict=True)
    ]
    torch.testing.assert_close(total, 1.0 + sum(parts), rtol=0, atol=1e-14)
    batched = gaussian_blobs(
        times,
        shape=shape,
        dx=dx,
        a=torch.tensor([a, 0.1], dtype=F64),
        peaks=[peaks, peaks[::-1]],
        sigmas=[sigmas, sigmas[::-1]],
        centres=[spots, spots[::-1]],
        background=torch.tensor([1.0, 0.0], dtype=F64),
    )
    assert batched.shape == (2, 2, 30, 40)
    torch.testing.assert_close(batched[0], total, rtol=0, atol=1e-14)
    second = gaussian_blobs(
        times,
        shape=shape,
        dx=dx,
        a=0.1,
        peaks=peaks[::-1],
        sigmas=sigmas[::-1],
        centres=spots[::-1],
    )
    torch.testing.assert_close(batched[1], second, rtol=0, atol=1e-14)


# --------------------------------------------------------------------------- errors
U0 = torch.zeros(8, 8, dtype=F64)


def test_heat_spectral_and_gaussian_errors() -> None:
    with pytest.raises(ValueError, match=r"unknown boundary 'dirichlet'; expected one of: periodic, neumann"):
        heat_spectral(U0, a=0.1, dx=0.1, times=[0.0], boundary="dirichlet")
    with pytest.raises(
        ValueError, match=r"a must be a number, a tensor \(1,\) in mm\^2/s, got shape \(8, 8\)"
    ):
        heat_spectral(U0, a=torch.ones(8, 8), dx=0.1, times=[0.0])
    with pytest.raises(ValueError, match=r"times must be finite and non-negative in s"):
        heat_spectral(U0, a=0.1, dx=0.1, times=[0.0, -1.0])
    with pytest.raises(ValueError, match=r"sigma must be a positive finite number in mm, got -1.0"):
        gaussian_blob([0.0], shape=(8, 8), dx=0.1, a=0.1, peak=1.0, sigma=-1.0)
    with pytest.raises(ValueError, match=r"shape must be \(H, W\) with positive integers, got \(8, 0\)"):
        gaussian_blob([0.0], shape=(8, 0), dx=0.1, a=0.1, peak=1.0, sigma=1.0)
    with pytest.raises(ValueError, match=r"dx must be a positive finite number in mm, got 0"):
        gaussian_blob([0.0], shape=(8, 8), dx=0, a=0.1, peak=1.0, sigma=1.0)
    with pytest.raises(ValueError, match=r"centres must have shape \(2, 2\)"):
        gaussian_blobs(
            [0.0],
            shape=(8, 8),
            dx=0.1,
            a=0.1,
            peaks=[1.0, 2.0],
            sigmas=[1.0, 1.0],
            centres=[(1.0, 1.0)],
        )
    with pytest.raises(
        ValueError, match=r"unknown boundary 'open'; expected one of: neumann, dirichlet, periodic"
    ):
        HeatRHS(0.1, dx=0.1, boundary="open")
