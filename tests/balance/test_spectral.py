"""The fast paths of issue 35 against the computations they replace, in float32 and float64.

- the balance's ``U`` and ``L`` through the spectra (:mod:`anra_torch.balance.spectral`) against the
  shifted-slice filters (:meth:`MatchedFilters.terms`), and the pushed-back lever and its norm by Parseval
  against the explicit adjoint (:meth:`MatchedFilters.adjoint`);
- the estimator's standard error against the sandwich formula written out with the slice route;
- NumPy's median selection against ``torch.median`` / ``nanmedian``; the sampled fourth differences against
  the full ones; weights constant over the summed points factored out of the moments; the clean batch's
  preparation against the masked computation it skips.

Float32 results are held to a float64 computation of the old route (the slice route's own float32 error,
up to 1e-4 of the largest ``L`` for an 8 px Gaussian, is larger than the spectra's).
"""

from __future__ import annotations

import pytest
import torch

from anra_torch.balance import (
    MatchedFilters,
    NoiseModel,
    TermNoise,
    accumulate,
    batch_noise,
    prepare_batch,
    pushed_back,
    pushed_norm,
    spectral_stage,
    spectral_terms,
    stuck_pixels,
)
from anra_torch.estimation import ANRAEstimator
from anra_torch.simulation import gaussian_blob


def close(
    actual: torch.Tensor,
    reference: torch.Tensor,
    dtype: torch.dtype,
    *,
    scale: float | None = None,
    ops: int = 64,
) -> None:
    """Equal to rounding in ``dtype`` (``reference`` float64): within ``ops`` epsilons of ``scale``, by
    default the largest reference value; for a filter's output the bound on it, the input's largest value
    times the kernel's absolute sum (a transform's rounding is relative to the whole input)."""
    scale = float(reference.abs().max()) if scale is None else scale
    eps = torch.finfo(dtype).eps
    torch.testing.assert_close(actual.double(), reference.double(), rtol=0, atol=ops * eps * scale)


@pytest.fixture
def frames(dtype: torch.dtype) -> torch.Tensor:
    """Two smooth-plus-noise videos of a non-square size (odd width), float64 first."""
    t = torch.arange(11, dtype=torch.float64) / 27.0
    clean = gaussian_blob(t, shape=(66, 71), dx=0.1, a=0.2, peak=3.0, sigma=0.8)
    noisy = clean + 0.01 * torch.randn(2, *clean.shape, dtype=torch.float64)
    return noisy.to(dtype)


SPACING = (
    torch.tensor([1 / 27, 1 / 30], dtype=torch.float64),
    torch.tensor([0.1, 0.07], dtype=torch.float64),
)


@pytest.mark.parametrize("sigma", [0.0, 1.0, 4.0, 8.0])
@pytest.mark.parametrize("family", ["central", "holoborodko"])
def test_spectral_terms_equal_the_slice_route(frames: torch.Tensor, sigma: float, family: str) -> None:
    filters = MatchedFilters(sigma, laplacian_family=family)
    dt, dx = SPACING
    reference = filters.terms(frames.double(), dt, dx, ("U", "L"))
    new = spectral_terms(filters, spectral_stage(filters, frames, dt.to(frames)), dx.to(frames))
    # The slice route rounds after each stage: its bound is the input's largest value times the product
    # of the stages' absolute sums (time filter, Gaussian, Laplacian or its partner).
    stage = filters.time.taps.abs().sum() / dt.min(), filters.time.pair.abs().sum()
    space = (
        filters.laplacian.partner.kernels.abs().sum(),
        filters.laplacian.kernels.abs().sum() / dx.min() ** 2,
    )
    bounds = {"U": stage[0] * space[0], "L": stage[1] * space[1]}
    for name in ("U", "L"):
        assert new[name].shape == reference[name].shape and new[name].dtype == frames.dtype
        bound = float(frames.abs().max() * bounds[name])
        close(new[name], reference[name], frames.dtype, scale=bound)


@pytest.mark.parametrize("sigma", [1.0, 4.0])
def test_pushed_back_and_norm_equal_the_adjoint(frames: torch.Tensor, sigma: float) -> None:
    filters = MatchedFilters(sigma)
    dt, dx = SPACING
    a = torch.tensor([0.2, 0.35], dtype=torch.float64)
    lever = torch.randn_like(filters.terms(frames.double(), dt, dx, ("L",))["L"])
    reference = filters.adjoint({"U": lever, "L": -a.view(-1, 1, 1, 1) * lever}, dt, dx)
    kind = frames.dtype
    back = pushed_back(
        filters, lever.to(kind), a.to(kind), dt.to(kind), dx.to(kind), tuple(frames.shape[-2:])
    )
    close(back, reference, kind)
    norm = pushed_norm(
        filters, lever.to(kind), a.to(kind), dt.to(kind), dx.to(kind), tuple(frames.shape[-2:])
    )
    assert norm.dtype == torch.float64
    torch.testing.assert_close(norm, reference.pow(2).sum((1, 2, 3)), rtol=64 * torch.finfo(kind).eps, atol=0)


def test_pushed_spread_equals_the_spread_of_the_adjoint(frames: torch.Tensor) -> None:
    """White noise by Parseval, correlated noise through the field: both as ``BatchNoise.spread``."""
    filters = MatchedFilters(2.0)
    dt, dx = (v.to(frames) for v in SPACING)
    noise = batch_noise(frames - frames.mean(), None)
    correlated = NoiseModel(0.01, time_corr=(0.5, 0.2), space_length=1.0)
    noise = type(noise)(noise.cleaned, noise.sd, (noise.models[0], correlated), noise.pixel, noise.frame,
                        noise.artefacts)  # fmt: skip
    lever = torch.randn_like(filters.terms(frames, dt, dx, ("L",))["L"])
    a = torch.tensor([0.2, 0.3], dtype=frames.dtype)
    back = filters.adjoint({"U": lever, "L": -a.view(-1, 1, 1, 1) * lever}, dt, dx)
    expected = noise.spread(back.double()).double()
    got = noise.pushed_spread(filters, lever, a, dt, dx, tuple(frames.shape[-2:]))
    torch.testing.assert_close(got.double(), expected, rtol=256 * torch.finfo(frames.dtype).eps, atol=0)


def test_standard_error_is_the_sandwich_of_the_slice_route(frames: torch.Tensor) -> None:
    """The estimator's numbers for one smoothing and a known white noise, written out with the old route:
    ``a = sum (U L - K n c) / sum (L^2 - K n v)``, ``se = sd |A^T (w L)| / |sum w (L^2 - v)|``."""
    dt, dx = SPACING
    sd = 0.01
    result = ANRAEstimator(smoothing=2.0, noise_sd=sd, strict=False)(frames, dt.to(frames), dx.to(frames))
    filters = MatchedFilters(2.0)
    video = frames.double() - frames.double().mean((1, 2, 3), keepdim=True)
    terms = filters.terms(video, dt, dx, ("U", "L"))
    u, lap = terms["U"], terms["L"]
    n = lap.shape[-1] * lap.shape[-2]
    cov = filters.noise_covariance(("U", "L"), sd**2, dt, dx)  # (B, 2, 2)
    num = ((u * lap).sum((-2, -1)) / n - cov[:, None, 0, 1]).sum(1)
    den = ((lap * lap).sum((-2, -1)) / n - cov[:, None, 1, 1]).sum(1)
    a = num / den
    back = filters.adjoint({"U": lap / n, "L": -a.view(-1, 1, 1, 1) * lap / n}, dt, dx)
    se = sd * back.pow(2).sum((1, 2, 3)).sqrt() / den.abs()
    tol = 256 * torch.finfo(frames.dtype).eps
    torch.testing.assert_close(result.diffusivity.double(), a, rtol=tol, atol=0)
    torch.testing.assert_close(result.std_error.double(), se, rtol=max(tol, 1e-9), atol=0)


def test_constant_weights_factor_out_of_the_moments(dtype: torch.dtype) -> None:
    terms = {"U": torch.randn(2, 5, 30, 31, dtype=dtype), "L": torch.randn(2, 5, 30, 31, dtype=dtype)}
    per_frame = torch.rand(2, 5, 1, 1, dtype=dtype)
    noise = TermNoise(torch.tensor([[2.0, 0.5], [0.5, 1.0]], dtype=dtype))
    broadcast = accumulate(
        terms, ("U", "L"), dims=(-2, -1), weights=per_frame.expand(2, 5, 30, 31), noise=noise
    )
    dense = accumulate(terms, ("U", "L"), dims=(-2, -1), weights=per_frame.expand(2, 5, 30, 31).clone(),
                       noise=noise)  # fmt: skip
    tol = 64 * torch.finfo(dtype).eps
    torch.testing.assert_close(broadcast.raw, dense.raw, rtol=tol, atol=tol * float(dense.raw.abs().max()))
    torch.testing.assert_close(broadcast.noise, dense.noise, rtol=tol, atol=0)


def test_clean_batch_preparation_equals_the_masked_one(frames: torch.Tensor) -> None:
    """A batch without non-finite samples or dead elements skips the masks: the same video and noise."""
    fast = prepare_batch(frames)
    finite = torch.isfinite(frames) & ~stuck_pixels(frames, torch.isfinite(frames))
    counts = finite.sum((1, 2, 3))
    mean = torch.where(finite, frames, 0.0).sum((1, 2, 3)) / counts
    centred = torch.where(finite, frames - mean.view(-1, 1, 1, 1), 0.0)
    slow = batch_noise(centred, finite)
    assert fast.good is None and bool(fast.changing.all()) and int(fast.masked.sum()) == 0
    assert torch.equal(fast.video, slow.cleaned) and torch.equal(fast.noise.sd, slow.sd)
    assert [m.describe() for m in fast.noise.models] == [m.describe() for m in slow.models]
