"""Tests for anra_torch.layers.derivatives: units, delays, borders, fast paths, adjoint, gradients, errors."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
import reference as ref
import torch
import torch.nn.functional as F
from tolerances import assert_rounding_close

from anra_torch.layers import stencils
from anra_torch.layers.derivatives import (
    BORDERS,
    Gradient,
    Laplacian,
    SecondDerivatives,
    TimeDerivative,
    gradient,
    laplacian,
    second_derivatives,
    time_derivative,
)
from anra_torch.layers.stencils import time_stencil

F64 = torch.float64


ALL_BORDERS = list(BORDERS)


TIME_CASES = [("smooth", 4), ("smooth", 5), ("smooth", 8), ("centred", 7), ("hybrid", 4), ("hybrid", 8)]


def grid(h: int, w: int, dx: float, dtype: torch.dtype = F64) -> tuple[torch.Tensor, torch.Tensor]:
    """``(x, y)`` coordinates (mm) of an ``(h, w)`` image: x along W (columns), y along H (rows)."""
    y = (0.4 + dx * torch.arange(h, dtype=F64))[:, None].expand(h, w)
    x = (-0.7 + dx * torch.arange(w, dtype=F64))[None, :].expand(h, w)
    return x.to(dtype), y.to(dtype)


def crop(u: torch.Tensor, r: int) -> torch.Tensor:
    return u[..., r : u.shape[-2] - r, r : u.shape[-1] - r]


def make_spatial(kind: str, size: int, border: str = "crop") -> Laplacian | Gradient | SecondDerivatives:
    if kind == "laplacian":
        return Laplacian(size, border=border)
    if kind == "central":
        return Laplacian(size, family="central", border=border)
    if kind == "gradient":
        return Gradient(size, border=border)
    return SecondDerivatives(size, border=border)


def stacked(layer: torch.nn.Module, out: torch.Tensor) -> torch.Tensor:
    """Layer output with a channel dimension at -3 (the Laplacian squeezes its single channel)."""
    return out.unsqueeze(-3) if isinstance(layer, Laplacian) else out


SPATIAL_CASES = [
    ("laplacian", 3),
    ("laplacian", 5),
    ("laplacian", 7),
    ("central", 5),
    ("gradient", 3),
    ("gradient", 7),
    ("second", 3),
    ("second", 5),
]


# ================================================================================== TimeDerivative
def test_time_derivative_shapes_and_dtype(dtype: torch.dtype) -> None:
    layer = TimeDerivative("smooth", 5)
    frames = torch.randn(2, 9, 4, 6, dtype=dtype)
    rate = layer(frames, 0.1)
    assert rate.shape == (2, 5, 4, 6) and rate.dtype == dtype
    assert layer.average(frames).shape == (2, 5, 4, 6)
    assert layer.length == 5 and layer.centre == 2.0 and layer.delay == 2.0
    assert TimeDerivative("hybrid", 6).delay == 0.0


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_time_derivative_exact_on_quadratics_at_k_plus_centre(
    family: str, length: int, dtype: torch.dtype, tol: float
) -> None:
    layer, dt, t0, n = TimeDerivative(family, length), 0.05, 0.3, length + 4
    c0, c1, c2 = torch.randn(3, 1, 1, 3, 4, dtype=F64)
    t = (t0 + dt * torch.arange(n, dtype=F64))[None, :, None, None]
    frames = c0 + c1 * t + c2 * t**2
    rate = layer(frames.to(dtype), dt)
    k = torch.arange(n - length + 1, dtype=F64)
    t_est = (t0 + dt * (k + layer.centre))[None, :, None, None]
    expected = c1 + 2 * c2 * t_est
    scale = float(frames.abs().max()) / dt
    torch.testing.assert_close(rate, expected.to(dtype), rtol=tol, atol=tol * scale)


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_time_derivative_on_cubic_in_time_has_the_predicted_error_at_k_plus_centre(
    family: str, length: int, dtype: torch.dtype, tol: float
) -> None:
    # p(t) = c3 t^3 + ...: the estimate is p'(t_c) + c3 dt^2 m3 with m3 = sum_i w_i (i - centre)^3.
    layer, dt, t0, n = TimeDerivative(family, length), 0.1, -0.2, length + 3
    c = torch.randn(4, 1, 1, 2, 3, dtype=F64)
    t = (t0 + dt * torch.arange(n, dtype=F64))[None, :, None, None]
    frames = c[0] + c[1] * t + c[2] * t**2 + c[3] * t**3
    taps = time_stencil(family, length).taps.numpy()
    m3 = float(np.sum(taps * (np.arange(length) - layer.centre) ** 3))
    assert abs(m3) > 0.1  # the cubic term really shows, so a wrong frame or scale cannot pass
    t_c = (t0 + dt * (torch.arange(n - length + 1, dtype=F64) + layer.centre))[None, :, None, None]
    expected = c[1] + 2 * c[2] * t_c + 3 * c[3] * t_c**2 + c[3] * dt**2 * m3
    scale = float(frames.abs().max()) / dt
    torch.testing.assert_close(layer(frames.to(dtype), dt), expected.to(dtype), rtol=tol, atol=tol * scale)


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_time_average_is_exact_on_linear_at_k_plus_centre(family: str, length: int, tol: float) -> None:
    layer, dt, n = TimeDerivative(family, length), 0.1, length + 2
    c0, c1 = torch.randn(2, 1, 1, 2, 2, dtype=F64)
    t = (dt * torch.arange(n, dtype=F64))[None, :, None, None]
    t_c = (dt * (torch.arange(n - length + 1, dtype=F64) + layer.centre))[None, :, None, None]
    torch.testing.assert_close(layer.average(c0 + c1 * t), c0 + c1 * t_c, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_time_derivative_matches_reference_correlation(family: str, length: int, dtype: torch.dtype) -> None:
    frames = torch.randn(2, length + 3, 3, 4, dtype=F64)
    stencil = time_stencil(family, length)
    expected = ref.time_filter(frames.numpy(), stencil.taps.numpy()) / 0.04
    rate = TimeDerivative(family, length)(frames.to(dtype), 0.04)
    np.testing.assert_allclose(rate.double().numpy(), expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())


def test_time_derivative_per_video_dt(dtype: torch.dtype, tol: float) -> None:
    layer = TimeDerivative("smooth", 5)
    frames = torch.randn(2, 8, 3, 3, dtype=dtype)
    dt = torch.tensor([0.05, 0.2], dtype=dtype)
    rate = layer(frames, dt)
    for b in range(2):
        torch.testing.assert_close(
            rate[b : b + 1], layer(frames[b : b + 1], float(dt[b])), rtol=tol, atol=tol
        )
    torch.testing.assert_close(rate[0], 4 * layer(frames[:1], 0.2)[0], rtol=tol, atol=tol)


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_with_average_equals_forward_and_average(family: str, length: int, dtype: torch.dtype) -> None:
    layer = TimeDerivative(family, length)
    frames = torch.randn(2, length + 3, 4, 5, dtype=dtype)
    for dt in (0.1, torch.tensor([0.1, 0.3], dtype=dtype)):
        rate, mean = layer.with_average(frames, dt)
        # Sums of `length` products of values up to max|frames| (/ dt for the rate).
        scale = float(frames.abs().max()) * length
        assert_rounding_close(rate, layer(frames, dt), scale=scale / float(torch.as_tensor(dt).min()))
        assert_rounding_close(mean, layer.average(frames), scale=scale)


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_adjoint_is_the_exact_transpose(family: str, length: int) -> None:
    layer = TimeDerivative(family, length)
    x = torch.randn(2, length + 5, 3, 4, dtype=F64)
    rw = torch.randn(2, 6, 3, 4, dtype=F64)
    aw = torch.randn(2, 6, 3, 4, dtype=F64)
    for dt in (0.07, torch.tensor([0.07, 0.5], dtype=F64)):
        rate, mean = layer.with_average(x, dt)
        lhs = (rw * rate).sum() + (aw * mean).sum()
        back = layer.adjoint(rw, aw, dt)
        assert back.shape == x.shape
        assert float((back * x).sum()) == pytest.approx(float(lhs), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("family", ["smooth", "hybrid"])
def test_time_derivative_converges_at_second_order(family: str) -> None:
    # d/dt of sin(3 t) g(x, y); halving dt should quarter the error (exact on quadratics -> O(dt^2)).
    layer, omega = TimeDerivative(family, 6), 3.0
    g = torch.rand(1, 1, 2, 2, dtype=F64) + 0.5
    errors = []
    for dt in (0.02, 0.01):
        t = (0.2 + dt * torch.arange(10, dtype=F64))[None, :, None, None]
        rate = layer(torch.sin(omega * t) * g, dt)
        t_c = (0.2 + dt * (torch.arange(5, dtype=F64) + layer.centre))[None, :, None, None]
        errors.append(float((rate - omega * torch.cos(omega * t_c) * g).abs().max()))
    assert 1.8 < math.log2(errors[0] / errors[1]) < 2.2


def test_time_derivative_functional_matches_layer(dtype: torch.dtype) -> None:
    frames = torch.randn(1, 9, 3, 3, dtype=dtype)
    torch.testing.assert_close(
        time_derivative(frames, 0.2, family="hybrid", length=7), TimeDerivative("hybrid", 7)(frames, 0.2)
    )


def test_time_derivative_gradcheck() -> None:
    layer = TimeDerivative("hybrid", 4)
    frames = torch.randn(1, 6, 2, 3, dtype=F64, requires_grad=True)
    dt = torch.tensor([0.3], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda u, s: layer(u, s), (frames, dt))
    assert torch.autograd.gradcheck(layer.average, (frames,))
    rw = torch.randn(1, 3, 2, 3, dtype=F64, requires_grad=True)
    aw = torch.randn(1, 3, 2, 3, dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: layer.adjoint(a, b, 0.3), (rw, aw))


def test_time_derivative_state_dict_round_trip() -> None:
    layer = TimeDerivative("smooth", 7)
    assert {name for name, _ in layer.named_buffers()} == {"taps", "pair"}
    state = layer.state_dict()
    assert len(state) == 0
    other = TimeDerivative("smooth", 7)
    result = other.load_state_dict(state, strict=True)
    assert not result.missing_keys and not result.unexpected_keys
    frames = torch.randn(1, 8, 2, 2, dtype=F64)
    torch.testing.assert_close(other(frames, 0.1), layer(frames, 0.1), rtol=0, atol=0)


def test_time_derivative_too_few_frames() -> None:
    layer = TimeDerivative("smooth", 7)
    frames = torch.zeros(1, 4, 3, 3)
    with pytest.raises(ValueError, match="need at least 7 frames for a time filter of length 7, got 4"):
        layer(frames, 0.1)
    with pytest.raises(ValueError, match="need at least 7 frames"):
        layer.average(frames)
    with pytest.raises(ValueError, match="need at least 7 frames"):
        layer.with_average(frames, 0.1)


def test_time_derivative_accepts_one_unbatched_video() -> None:
    video = torch.randn(8, 3, 3, dtype=F64)
    layer = TimeDerivative()
    torch.testing.assert_close(layer(video, 0.1), layer(video[None], 0.1)[0])
    rate, average = layer.with_average(video, 0.1)
    torch.testing.assert_close(average, layer.average(video[None])[0])
    with pytest.raises(
        ValueError, match=r"frames must have shape \(T, H, W\) or \(B, T, H, W\), got \(8, 3\)"
    ):
        layer(torch.zeros(8, 3), 0.1)


@pytest.mark.parametrize("dt", [0.0, -0.1, math.nan, math.inf, torch.tensor([0.1, 0.0])])
def test_time_derivative_rejects_bad_dt(dt: float | torch.Tensor) -> None:
    layer, frames = TimeDerivative(), torch.zeros(2, 6, 3, 3)
    with pytest.raises(ValueError, match="dt must be a positive finite number in s"):
        layer(frames, dt)
    with pytest.raises(ValueError, match="dt must be a positive finite number in s"):
        layer.with_average(frames, dt)


def test_time_derivative_rejects_unknown_family_and_length() -> None:
    with pytest.raises(ValueError, match="unknown time family 'backward'"):
        TimeDerivative("backward", 5)
    with pytest.raises(ValueError, match="hybrid time family has lengths"):
        TimeDerivative("hybrid", 12)


# ============================================================================ spatial derivatives
@pytest.mark.parametrize(("kind", "size"), SPATIAL_CASES)
@pytest.mark.parametrize("border", ALL_BORDERS)
def test_spatial_shapes(kind: str, size: int, border: str, dtype: torch.dtype) -> None:
    layer = make_spatial(kind, size, border)
    channels = {"laplacian": (), "central": (), "gradient": (2,), "second": (3,)}[kind]
    shrink = size - 1 if border == "crop" else 0
    for lead in ((), (3,), (2, 3)):
        out = layer(torch.randn(*lead, 11, 12, dtype=dtype), 0.5)
        assert out.shape == (*lead, *channels, 11 - shrink, 12 - shrink)
        assert out.dtype == dtype
    assert layer.support == size


@pytest.mark.parametrize("size", [3, 5, 7, 9, 11])
@pytest.mark.parametrize("family", ["holoborodko", "central"])
def test_laplacian_of_cubic_in_physical_units(size: int, family: str, dtype: torch.dtype, tol: float) -> None:
    dx = 0.1
    x, y = grid(15, 17, dx)
    u = x**3 + x * y**2  # Laplacian 8 x, varying along W only
    layer = Laplacian(size, family=family)
    out = layer(u.to(dtype), dx)
    r = size // 2
    scale = float(u.abs().max()) / dx**2
    torch.testing.assert_close(out, crop(8 * x, r).to(dtype), rtol=tol, atol=tol * scale)


@pytest.mark.parametrize("size", [3, 5, 7])
def test_gradient_of_quadratic_in_physical_units(size: int, dtype: torch.dtype, tol: float) -> None:
    dx = 0.2
    x, y = grid(12, 13, dx)
    u = x**2 + 3 * y  # (d/dx, d/dy) = (2 x, 3)
    out = Gradient(size)(u.to(dtype), dx)
    r = size // 2
    expected = torch.stack([crop(2 * x, r), torch.full_like(crop(x, r), 3.0)])
    torch.testing.assert_close(out, expected.to(dtype), rtol=tol, atol=tol * float(u.abs().max()) / dx)


@pytest.mark.parametrize("size", [3, 5, 7])
def test_second_derivatives_of_cubic_in_physical_units(size: int, dtype: torch.dtype, tol: float) -> None:
    dx = 0.15
    x, y = grid(12, 13, dx)
    u = x**3 + x**2 * y + 2 * y**2  # d11 = 6x + 2y, d22 = 4, d12 = 2x
    out = SecondDerivatives(size)(u.to(dtype), dx)
    r = size // 2
    expected = torch.stack([crop(6 * x + 2 * y, r), torch.full_like(crop(x, r), 4.0), crop(2 * x, r)])
    scale = float(u.abs().max()) / dx**2
    torch.testing.assert_close(out, expected.to(dtype), rtol=tol, atol=tol * scale)


@pytest.mark.parametrize(("kind", "size"), SPATIAL_CASES)
def test_spatial_dx_scaling(kind: str, size: int, dtype: torch.dtype, tol: float) -> None:
    layer = make_spatial(kind, size)
    u = torch.randn(2, 3, 10, 10, dtype=dtype)
    factor = 2.0**layer.order  # doubling dx quarters second derivatives and halves first
    torch.testing.assert_close(layer(u, 0.6), factor * layer(u, 1.2), rtol=tol, atol=tol)


@pytest.mark.parametrize(("kind", "size"), SPATIAL_CASES)
def test_spatial_per_video_dx(kind: str, size: int, dtype: torch.dtype, tol: float) -> None:
    layer = make_spatial(kind, size, "reflect")
    u = torch.randn(3, 2, 9, 10, dtype=dtype)
    dx = torch.tensor([0.5, 1.0, 2.0], dtype=dtype)
    out = layer(u, dx)
    for b in range(3):
        torch.testing.assert_close(out[b], layer(u[b], float(dx[b])), rtol=tol, atol=tol)


@pytest.mark.parametrize(("kind", "size"), SPATIAL_CASES)
@pytest.mark.parametrize("border", ALL_BORDERS)
def test_spatial_matches_reference_for_every_border(
    kind: str, size: int, border: str, dtype: torch.dtype, tol: float
) -> None:
    layer = make_spatial(kind, size, border)
    u = torch.randn(2, 3, 11, 13, dtype=F64)
    dx = 0.7
    out = stacked(layer, layer(u.to(dtype), dx)).double().numpy()
    for c, kernel in enumerate(layer.kernels):
        expected = ref.filter2d(u.numpy(), kernel.numpy(), border) / dx**layer.order
        np.testing.assert_allclose(
            out[..., c, :, :], expected, rtol=tol, atol=10 * tol * np.abs(expected).max()
        )


@pytest.mark.parametrize(
    ("kind", "size", "separable"),
    [
        ("laplacian", 3, False),
        ("laplacian", 5, True),
        ("laplacian", 11, True),
        ("central", 5, True),
        ("gradient", 3, True),
        ("gradient", 5, True),
        ("second", 5, True),
        ("second", 9, True),
    ],
)
@pytest.mark.parametrize("border", ALL_BORDERS)
def test_separable_path_equals_conv2d(
    kind: str, size: int, separable: bool, border: str, dtype: torch.dtype
) -> None:
    # The separable kernels run as 1-D passes, the others as shifted-slice sums (_filter2d's fast route).
    layer = make_spatial(kind, size, border)
    assert layer.separable is separable
    u = torch.randn(2, 2, 14, 15, dtype=dtype)
    flat = u.reshape(-1, 1, 14, 15)
    r = size // 2
    if BORDERS[border] is not None:
        flat = F.pad(flat, (r, r, r, r), mode=BORDERS[border])
    direct = F.conv2d(flat, layer.kernels.to(dtype).unsqueeze(1)) / 0.5**layer.order
    direct = direct.reshape(2, 2, *direct.shape[1:])
    # Sums of size^2 products of values up to max|u| / 0.5^order.
    scale = float(u.abs().max()) * float(layer.kernels.abs().sum(dim=(-2, -1)).max()) / 0.5**layer.order
    assert_rounding_close(stacked(layer, layer(u, 0.5)), direct, scale=scale, ops=4 * size)


@pytest.mark.parametrize(
    ("kind", "size", "order"),
    [
        ("laplacian", 3, 2),
        ("laplacian", 5, 2),
        ("laplacian", 7, 2),
        ("central", 5, 4),
        ("central", 7, 6),
        ("gradient", 5, 2),
        ("second", 5, 2),
    ],
)
def test_spatial_convergence_order(kind: str, size: int, order: int) -> None:
    # u = sin(2 pi x) cos(2 pi y) on a fixed 1 mm domain; the error falls as dx**order when dx halves.
    layer = make_spatial(kind, size)
    k = 2 * math.pi
    errors = []
    for n in (32, 64):
        dx = 1.0 / n
        x, y = grid(n, n, dx)
        u = torch.sin(k * x) * torch.cos(k * y)
        exact = {
            "laplacian": (-2 * k**2 * u)[None],
            "central": (-2 * k**2 * u)[None],
            "gradient": torch.stack(
                [k * torch.cos(k * x) * torch.cos(k * y), -k * torch.sin(k * x) * torch.sin(k * y)]
            ),
            "second": torch.stack([-(k**2) * u, -(k**2) * u, -(k**2) * torch.cos(k * x) * torch.sin(k * y)]),
        }[kind]
        errors.append(float((stacked(layer, layer(u, dx)) - crop(exact, size // 2)).abs().max()))
    assert order - 0.25 < math.log2(errors[0] / errors[1]) < order + 0.25


@pytest.mark.parametrize("size", [3, 5, 7, 11])
@pytest.mark.parametrize("border", ALL_BORDERS)
def test_laplacian_partner_layer(size: int, border: str, dtype: torch.dtype, tol: float) -> None:
    layer = Laplacian(size, border=border)
    u = torch.randn(2, 3, 13, 14, dtype=F64)
    smoothed = layer.partner(u.to(dtype))
    assert smoothed.shape == layer(u.to(dtype), 0.5).shape and smoothed.dtype == dtype
    expected = ref.filter2d(u.numpy(), stencils.laplacian_partner(size).numpy(), border)
    np.testing.assert_allclose(smoothed.double().numpy(), expected, rtol=tol, atol=10 * tol)


@pytest.mark.parametrize("size", [5, 7, 11])
def test_laplacian_equals_five_point_laplacian_of_its_partner(
    size: int, dtype: torch.dtype, tol: float
) -> None:
    # exact on a periodic image: both sides are circular correlations with the same composite kernel
    layer, five_point = Laplacian(size, border="circular"), Laplacian(3, border="circular")
    u = torch.randn(2, 16, 15, dtype=dtype)
    torch.testing.assert_close(layer(u, 0.4), five_point(layer.partner(u), 0.4), rtol=tol, atol=tol * 100)


@pytest.mark.parametrize(("size", "gain"), sorted(ref.LAPLACIAN_GAIN.items()))
def test_laplacian_white_noise_gain_through_layer(size: int, gain: float) -> None:
    noise = torch.randn(1, 256, 256, dtype=F64)
    out = Laplacian(size)(noise, 1.0)
    assert float(out.std()) == pytest.approx(gain, rel=0.02)


@pytest.mark.parametrize(
    ("kind", "size"), [("laplacian", 3), ("laplacian", 5), ("central", 5), ("gradient", 5), ("second", 3)]
)
@pytest.mark.parametrize("border", ["crop", "reflect"])
def test_spatial_gradcheck(kind: str, size: int, border: str) -> None:
    layer = make_spatial(kind, size, border)
    u = torch.randn(2, 6, 7, dtype=F64, requires_grad=True)
    dx = torch.tensor([0.5, 1.5], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: layer(a, b), (u, dx), fast_mode=True)


@pytest.mark.parametrize(("kind", "size"), SPATIAL_CASES)
def test_spatial_state_dict_round_trip(kind: str, size: int) -> None:
    layer = make_spatial(kind, size)
    assert "kernels" in dict(layer.named_buffers())
    state = layer.state_dict()
    assert len(state) == 0
    other = make_spatial(kind, size)
    result = other.load_state_dict(state, strict=True)
    assert not result.missing_keys and not result.unexpected_keys
    u = torch.randn(1, 12, 12, dtype=F64)
    torch.testing.assert_close(other(u, 0.3), layer(u, 0.3), rtol=0, atol=0)


@pytest.mark.parametrize(
    ("functional", "layer", "kwargs"),
    [
        (
            laplacian,
            Laplacian(7, family="central", border="circular"),
            {"size": 7, "family": "central", "border": "circular"},
        ),
        (gradient, Gradient(3, border="zeros"), {"size": 3, "border": "zeros"}),
        (second_derivatives, SecondDerivatives(5), {"size": 5}),
    ],
    ids=["laplacian", "gradient", "second_derivatives"],
)
def test_spatial_functionals_match_layers(
    functional: Callable[..., torch.Tensor], layer: torch.nn.Module, kwargs: dict[str, object]
) -> None:
    u = torch.randn(2, 10, 11, dtype=F64)
    torch.testing.assert_close(functional(u, 0.3, **kwargs), layer(u, 0.3))


@pytest.mark.parametrize("kind", ["laplacian", "gradient", "second"])
def test_spatial_layers_can_be_moved_and_cast(kind: str) -> None:
    layer = make_spatial(kind, 5)
    moved = torch.nn.Sequential(layer).to("cpu", torch.float32)
    assert moved[0].kernels.dtype == torch.float32
    u = torch.randn(1, 9, 9)
    torch.testing.assert_close(moved[0](u, 1.0), make_spatial(kind, 5)(u, 1.0))


@pytest.mark.parametrize("dx", [0.0, -1.0, math.nan, math.inf, torch.tensor([1.0, -1.0])])
@pytest.mark.parametrize("kind", ["laplacian", "gradient", "second"])
def test_spatial_rejects_bad_dx(dx: float | torch.Tensor, kind: str) -> None:
    with pytest.raises(ValueError, match="dx must be a positive finite number in mm"):
        make_spatial(kind, 5)(torch.zeros(2, 8, 8), dx)


@pytest.mark.parametrize("kind", ["laplacian", "central", "gradient", "second"])
def test_spatial_rejects_unknown_border(kind: str) -> None:
    message = "unknown border 'mirror'; expected one of: crop, reflect, replicate, circular, zeros"
    with pytest.raises(ValueError, match=message):
        make_spatial(kind, 5, "mirror")


@pytest.mark.parametrize("kind", ["laplacian", "central", "gradient", "second"])
def test_spatial_rejects_bad_size(kind: str) -> None:
    with pytest.raises(ValueError, match=r"spatial kernel size must be one of \(3, 5, 7, 9, 11\), got 4"):
        make_spatial(kind, 4)


def test_laplacian_rejects_unknown_family() -> None:
    with pytest.raises(ValueError, match="unknown Laplacian family 'log'"):
        Laplacian(5, family="log")


def test_spatial_rejects_small_frames_with_crop_and_bad_rank() -> None:
    message = r"need frames of at least 5 x 5 px for a 5-px kernel with border='crop', got 4 x 9"
    with pytest.raises(ValueError, match=message):
        Laplacian(5)(torch.zeros(2, 4, 9), 1.0)
    with pytest.raises(ValueError, match=r"input must have shape \(\.\.\., H, W\), got \(9,\)"):
        Gradient(3)(torch.zeros(9), 1.0)


def test_spatial_reflect_on_frames_smaller_than_the_kernel_raises_value_error() -> None:
    with pytest.raises(ValueError, match="reflect"):
        Laplacian(7, border="reflect")(torch.zeros(1, 3, 3), 1.0)


def test_spatial_rejects_dx_of_wrong_length() -> None:
    with pytest.raises(ValueError, match="dx"):
        Laplacian(5)(torch.zeros(2, 9, 9), torch.tensor([1.0, 2.0, 3.0]))


@pytest.mark.parametrize(
    "make",
    [
        lambda: Laplacian(5, family="central"),
        lambda: Laplacian(5),
        lambda: Laplacian(3),
        lambda: Laplacian(9),
        lambda: Laplacian(7).partner,
    ],
    ids=["central5", "holoborodko5", "five-point", "holoborodko9", "partner7"],
)
def test_spatial_adjoint_is_the_exact_transpose(make) -> None:
    op = make()
    u = torch.randn(2, 3, 30, 31, dtype=F64)
    dx = torch.tensor([0.3, 0.7], dtype=F64)
    out = op(u, dx) if op.order else op(u)
    y = torch.randn_like(out)
    back = op.adjoint(y, dx if op.order else 1.0)
    assert back.shape == u.shape
    torch.testing.assert_close((back * u).sum(), (y * out).sum(), rtol=1e-12, atol=1e-12)
