"""Separable Gaussian smoothing: the scipy answer for every border, affine fields kept, functional and
layer equal, gradients, transpose."""

from __future__ import annotations

import math

import numpy as np
import pytest
import reference as ref
import torch

from anra_torch.layers import GaussianSmoothing, gaussian_smooth
from anra_torch.layers.correlate import BORDERS
from anra_torch.layers.stencils import gaussian_taps

F64 = torch.float64
ALL_BORDERS = list(BORDERS)


def grid(h: int, w: int, dx: float, dtype: torch.dtype = F64) -> tuple[torch.Tensor, torch.Tensor]:
    """``(x, y)`` coordinates (mm) of an ``(h, w)`` image: x along W (columns), y along H (rows)."""
    y = (0.4 + dx * torch.arange(h, dtype=F64))[:, None].expand(h, w)
    x = (-0.7 + dx * torch.arange(w, dtype=F64))[None, :].expand(h, w)
    return x.to(dtype), y.to(dtype)


def crop(u: torch.Tensor, r: int) -> torch.Tensor:
    return u[..., r : u.shape[-2] - r, r : u.shape[-1] - r]


# ============================================================================== GaussianSmoothing
@pytest.mark.parametrize("border", ALL_BORDERS)
@pytest.mark.parametrize("sigma", [0.8, 1.3, 2.0, 3.0])  # narrow kernels use shifted slices, wide ones BLAS
def test_gaussian_smoothing_matches_scipy(border: str, sigma: float, dtype: torch.dtype, tol: float) -> None:
    layer = GaussianSmoothing(sigma, border=border)
    u = torch.randn(2, 3, 25, 27, dtype=F64)
    expected = ref.gaussian_smooth(u.numpy(), gaussian_taps(sigma).numpy(), border)
    out = layer(u.to(dtype))
    r = math.ceil(3.5 * sigma)
    assert layer.radius == r
    shrink = 2 * r if border == "crop" else 0
    assert out.shape == (2, 3, 25 - shrink, 27 - shrink) and out.dtype == dtype
    np.testing.assert_allclose(out.double().numpy(), expected, rtol=tol, atol=10 * tol)


def test_gaussian_smoothing_preserves_constants_and_linear_ramps(dtype: torch.dtype, tol: float) -> None:
    # Symmetric taps summing to 1 reproduce affine fields, so smoothing cannot shift a linear profile.
    x, y = grid(20, 21, 0.1, dtype)
    u = 2.0 + 3 * x - y
    out = GaussianSmoothing(1.5)(u)
    r = math.ceil(3.5 * 1.5)
    torch.testing.assert_close(out, crop(u, r), rtol=tol, atol=tol)


def test_gaussian_smoothing_identity_and_caching_across_dtypes() -> None:
    u = torch.randn(4, 5, dtype=F64)
    assert GaussianSmoothing(0.0)(u) is u
    layer = GaussianSmoothing(2.5, border="replicate")  # wide: banded matrices, cached per size and dtype
    first = layer(u.float())
    second = layer(u)
    assert first.dtype == torch.float32 and second.dtype == F64
    torch.testing.assert_close(first.double(), second, rtol=0, atol=1e-6)
    # a different frame size after caching still gives the scipy answer
    v = torch.randn(7, 9, dtype=F64)
    expected = ref.gaussian_smooth(v.numpy(), gaussian_taps(2.5).numpy(), "replicate")
    np.testing.assert_allclose(layer(v).numpy(), expected, rtol=1e-12, atol=1e-12)


def test_gaussian_smooth_functional_matches_layer(dtype: torch.dtype) -> None:
    u = torch.randn(2, 16, 16, dtype=dtype)
    torch.testing.assert_close(
        gaussian_smooth(u, 1.2, border="circular"), GaussianSmoothing(1.2, border="circular")(u)
    )


@pytest.mark.parametrize(("sigma", "border"), [(0.8, "crop"), (0.8, "reflect"), (2.0, "reflect")])
def test_gaussian_smoothing_gradcheck(sigma: float, border: str) -> None:
    u = torch.randn(2, 9, 10, dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(GaussianSmoothing(sigma, border=border), (u,), fast_mode=True)


def test_gaussian_smoothing_state_dict_round_trip() -> None:
    layer = GaussianSmoothing(1.1)
    assert "taps" in dict(layer.named_buffers())
    state = layer.state_dict()
    assert len(state) == 0
    other = GaussianSmoothing(1.1)
    result = other.load_state_dict(state, strict=True)
    assert not result.missing_keys and not result.unexpected_keys
    u = torch.randn(12, 12, dtype=F64)
    torch.testing.assert_close(other(u), layer(u), rtol=0, atol=0)


def test_gaussian_smoothing_errors() -> None:
    with pytest.raises(ValueError, match="unknown border 'mirror'"):
        GaussianSmoothing(1.0, border="mirror")
    with pytest.raises(ValueError, match="smoothing sigma must be a finite number >= 0"):
        GaussianSmoothing(-1.0)
    with pytest.raises(ValueError, match=r"need frames of at least 9 x 9 px for a 9-px kernel"):
        GaussianSmoothing(1.0)(torch.zeros(8, 20))


@pytest.mark.parametrize("sigma", [0.0, 1.0, 2.5, 4.0])
def test_gaussian_adjoint_is_the_exact_transpose(sigma: float) -> None:
    smooth = GaussianSmoothing(sigma)
    u = torch.randn(2, 40, 41, dtype=F64)
    out = smooth(u)
    y = torch.randn_like(out)
    torch.testing.assert_close((smooth.adjoint(y) * u).sum(), (y * out).sum(), rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="border='crop'"):
        GaussianSmoothing(sigma or 1.0, border="reflect").adjoint(y)
