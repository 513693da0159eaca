"""The windowed loss-rate fit (:mod:`anra_torch.balance.loss`): exact on terms that obey ``U = a L - b R``
on their cooling frames, equal to a NumPy least squares per window, and its standard error.

The reference solves each window's 2 x 2 normal equations of ``U = a L - b R`` (``R`` the rise of ``T``
since its first frame, summed over each pixel's frames after its peak and over the window's pixels) with
explicit loops and :func:`numpy.linalg.lstsq`.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from anra_torch.balance import MatchedFilters, fit_loss_windows

F64 = torch.float64
A, B = 0.3, 0.2  # mm^2/s, 1/s
ONE = torch.ones(1, dtype=F64)


def features_filters(sigma: float = 0.0) -> MatchedFilters:
    """The filters of :class:`~anra_torch.tissue.TissueFeatures`: padding borders, 5-point Laplacian."""
    return MatchedFilters(
        sigma,
        laplacian_size=3,
        laplacian_family="holoborodko",
        border="replicate",
        smoothing_border="reflect",
    )


def loss_fit(terms: dict[str, torch.Tensor], window: int, noise_sd: float = 0.0, sigma: float = 0.0):
    """:func:`fit_loss_windows` at 0.1 s and 0.5 mm, fallback diffusivity 0."""
    size = terms["U"].shape[-2:]
    zero = torch.zeros(1, *size, dtype=F64)
    return fit_loss_windows(
        features_filters(sigma), terms, zero, noise_sd * ONE, 0.1 * ONE, 0.5 * ONE, window=window
    )


def balance_terms(
    frames: int = 12, size: int = 9, seed: int = 0, noise: float = 0.0
) -> dict[str, torch.Tensor]:
    """Terms ``(1, K, H, W)`` with ``U = A L - B (T - T_0)`` on every frame: ``T`` rises to a peak at
    frame 3 (a spot heated, then cooling) and ``L`` varies independently of it."""
    g = torch.Generator().manual_seed(seed)
    k = torch.arange(frames, dtype=F64)[:, None, None]
    shape = 1.0 + torch.rand(size, size, generator=g, dtype=F64)
    temperature = 20.0 + shape * torch.where(k <= 3, k, 3.0 * torch.exp(-(k - 3) / 4))
    lap = torch.randn(frames, size, size, generator=g, dtype=F64)
    error = noise * torch.randn(frames, size, size, generator=g, dtype=F64)
    rate = A * lap - B * (temperature - temperature[:1]) + error
    return {"U": rate[None], "L": lap[None], "T": temperature[None]}


def reference_fit(terms: dict[str, torch.Tensor], window: int) -> np.ndarray:
    """``b`` of every window by least squares over its pixels' cooling frames, ``(H, W)``."""
    u, lap, temp = (terms[n][0].numpy() for n in ("U", "L", "T"))
    rise = temp - temp[:1]
    cooling = np.arange(u.shape[0])[:, None, None] > temp.argmax(0)[None]
    h, w = u.shape[1:]
    out = np.empty((h, w))
    r = window // 2
    for i in range(h):
        for j in range(w):
            rows = (slice(None), slice(max(i - r, 0), i + r + 1), slice(max(j - r, 0), j + r + 1))
            keep = cooling[rows]
            design = np.stack([lap[rows][keep], -rise[rows][keep]], 1)
            out[i, j] = np.linalg.lstsq(design, u[rows][keep], rcond=None)[0][1]
    return out


def test_terms_that_obey_the_balance_give_its_loss_rate_everywhere() -> None:
    terms = balance_terms()
    fit = loss_fit(terms, 3)
    assert fit.loss_rate.shape == fit.source.shape == fit.std_error.shape == (1, 9, 9)
    torch.testing.assert_close(fit.loss_rate, torch.full((1, 9, 9), B, dtype=F64), rtol=1e-10, atol=1e-12)
    # What the balance leaves is the source: nothing here.
    assert float(fit.source.abs().max()) < 1e-10
    assert bool((fit.std_error == 0).all())  # no noise, no error
    # The diffusivity fitted with it is the balance's too.
    torch.testing.assert_close(fit.diffusivity, torch.full((1, 9, 9), A, dtype=F64), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("window", [3, 5])
def test_each_window_is_the_least_squares_of_its_pixels_cooling_frames(window: int) -> None:
    terms = balance_terms(seed=1, noise=0.05)
    fit = loss_fit(terms, window)
    np.testing.assert_allclose(fit.loss_rate[0].numpy(), reference_fit(terms, window), rtol=1e-9, atol=1e-12)


def test_a_window_that_never_cools_gets_the_videos_rate_and_an_infinite_error() -> None:
    terms = balance_terms(seed=2)
    rising = torch.arange(12, dtype=F64)[:, None] * torch.ones(3, dtype=F64)  # still heating at the end
    for name in ("T", "U"):  # the right third keeps rising: no cooling frame there
        terms[name] = terms[name].clone()
    terms["T"][0, :, :, 6:] = 20.0 + rising[:, None, :]
    terms["U"][0, :, :, 6:] = A * terms["L"][0, :, :, 6:] - B * (terms["T"][0, :, :, 6:] - 20.0)
    fit = loss_fit(terms, 3)
    assert bool(torch.isinf(fit.std_error[0, :, 7:]).all())  # windows wholly inside the rising third
    assert bool(torch.isfinite(fit.std_error[0, :, :5]).all())
    torch.testing.assert_close(fit.loss_rate[0, :, 7:], torch.full((9, 2), B, dtype=F64), rtol=1e-10, atol=0)


def test_the_standard_error_is_the_measured_noise_through_the_same_filters() -> None:
    """Propagated from white noise of the given sd: positive where the windows cool, and proportional to the
    sd but for the errors-in-variables correction of the window sums, which moves ``a`` and ``b`` a little
    (measured 3e-5 relative at these sds)."""
    terms = balance_terms(frames=16, size=12, seed=3)
    one = loss_fit(terms, 5, 0.01, sigma=1.0)
    two = loss_fit(terms, 5, 0.02, sigma=1.0)
    assert bool((one.std_error > 0).all()) and bool(torch.isfinite(one.std_error).all())
    torch.testing.assert_close(two.std_error, 2 * one.std_error, rtol=1e-3, atol=0)
