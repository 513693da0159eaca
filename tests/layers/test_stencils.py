"""Tests for anra_torch.layers.stencils: every family and size against polynomials, Nyquist and the tables."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from reference import (
    BINOMIAL,
    CENTRAL_SECOND_5,
    FIRST_DERIVATIVE,
    FIRST_DERIVATIVE_GAIN,
    FIVE_POINT,
    GRADIENT_X,
    HYBRID_8_GAIN,
    HYBRID_NEWEST_FIRST,
    LAPLACIAN,
    LAPLACIAN_GAIN,
    SECOND_DERIVATIVE,
    SECOND_DERIVATIVE_GAIN,
    SMOOTH_ONE_SIDED,
    as_array,
    response,
    response2d,
)
from scipy import signal

from anra_torch.layers import stencils
from anra_torch.layers.stencils import (
    SPATIAL_SIZES,
    binomial,
    central_second_derivative_taps,
    first_derivative_taps,
    gaussian_taps,
    gradient_kernels,
    laplacian_kernel,
    laplacian_partner,
    second_derivative_kernels,
    second_derivative_taps,
    time_stencil,
)

X0, Y0, H = 0.3, -0.4, 0.5
"""An off-centre evaluation point and a non-unit spacing, so sign, offset and scale errors all show."""


EXACT = 1e-12
"""Rounding tolerance, relative to the sum of the magnitudes of the terms of each filter sum."""


NOT_EXACT = 1e-6
"""A filter 'is not exact' when it misses by more than this, relative to the same scale."""


TIME_LENGTHS = {"smooth": range(3, 12), "centred": (3, 5, 7, 9, 11), "hybrid": (4, 5, 6, 7, 8)}


TIME_CASES = [(family, length) for family, lengths in TIME_LENGTHS.items() for length in lengths]


NYQUIST_SWEEP = np.linspace(0.0, math.pi, 13)


def falling(a: int, k: int) -> int:
    """``a (a-1) ... (a-k+1)``: the coefficient of ``d^k/dx^k x^a``."""
    return math.prod(range(a - k + 1, a + 1)) if k <= a else 0


def np_taps(taps: torch.Tensor) -> np.ndarray:
    assert taps.dtype == torch.float64
    return taps.numpy()


def filter_1d(taps: np.ndarray, centre: float, power: int, order: int) -> tuple[float, float, float]:
    """Apply taps to ``x**power`` sampled at ``X0 + (i - centre) H``: (estimate, truth, scale)."""
    x = X0 + (np.arange(len(taps)) - centre) * H
    terms = taps * x**power / H**order
    truth = falling(power, order) * X0 ** (power - order) if power >= order else 0.0
    return float(terms.sum()), truth, float(np.abs(terms).sum())


def filter_2d(kernel: np.ndarray, a: int, b: int, order: int) -> tuple[float, float]:
    """Apply a centred kernel to ``x**a y**b`` around ``(X0, Y0)`` (rows y, columns x): (estimate, scale)."""
    r = kernel.shape[0] // 2
    y = Y0 + (np.arange(kernel.shape[0])[:, None] - r) * H
    x = X0 + (np.arange(kernel.shape[1])[None, :] - r) * H
    terms = kernel * x**a * y**b / H**order
    return float(terms.sum()), float(np.abs(terms).sum())


def d_monomial(a: int, b: int, kx: int, ky: int) -> float:
    """``d^kx/dx^kx d^ky/dy^ky (x**a y**b)`` at ``(X0, Y0)``."""
    c = falling(a, kx) * falling(b, ky)
    return c * X0 ** (a - kx) * Y0 ** (b - ky) if c else 0.0


def monomials(degree: int) -> list[tuple[int, int]]:
    return [(a, d - a) for d in range(degree + 1) for a in range(d + 1)]


def assert_exact_2d(kernel: np.ndarray, order: int, derivs: list[tuple[int, int]], degree: int) -> None:
    """The kernel reproduces the sum of the given derivatives on every monomial of total degree <= degree."""
    for a, b in monomials(degree):
        estimate, scale = filter_2d(kernel, a, b, order)
        truth = sum(d_monomial(a, b, kx, ky) for kx, ky in derivs)
        assert abs(estimate - truth) <= EXACT * max(scale, 1.0), (a, b, estimate, truth)


def misses_some_2d(kernel: np.ndarray, order: int, derivs: list[tuple[int, int]], degree: int) -> bool:
    """Whether some monomial of total degree ``degree`` is not reproduced."""
    misses = []
    for a, b in monomials(degree)[-(degree + 1) :]:
        estimate, scale = filter_2d(kernel, a, b, order)
        truth = sum(d_monomial(a, b, kx, ky) for kx, ky in derivs)
        misses.append(abs(estimate - truth) > NOT_EXACT * scale)
    return any(misses)


def assert_nyquist_border_zero(kernel: np.ndarray) -> None:
    for omega in NYQUIST_SWEEP:
        assert abs(response2d(kernel, math.pi, omega)) < 1e-14
        assert abs(response2d(kernel, omega, math.pi)) < 1e-14


# ------------------------------------------------------------------------------------------ binomial
@pytest.mark.parametrize("n", [2, 4])
def test_binomial_matches_table(n: int) -> None:
    np.testing.assert_allclose(np_taps(binomial(n)), as_array(BINOMIAL[n]), rtol=0, atol=1e-16)


@pytest.mark.parametrize("n", range(0, 11))
def test_binomial_is_a_symmetric_average(n: int) -> None:
    taps = np_taps(binomial(n))
    assert taps.shape == (n + 1,)
    assert taps.sum() == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_array_equal(taps, taps[::-1])
    assert (taps > 0).all()


def test_binomial_rejects_negative_order() -> None:
    with pytest.raises(ValueError, match="binomial order must be >= 0, got -1"):
        binomial(-1)


# --------------------------------------------------------------------------------- first derivative
@pytest.mark.parametrize("n", sorted(FIRST_DERIVATIVE))
def test_first_derivative_matches_table(n: int) -> None:
    np.testing.assert_allclose(np_taps(first_derivative_taps(n)), as_array(FIRST_DERIVATIVE[n]), atol=1e-16)


@pytest.mark.parametrize("n", range(3, 12))
def test_first_derivative_exact_to_quadratics_only(n: int) -> None:
    taps, centre = np_taps(first_derivative_taps(n)), (n - 1) / 2
    for power in range(3):
        estimate, truth, scale = filter_1d(taps, centre, power, 1)
        assert estimate == pytest.approx(truth, abs=EXACT * scale)
    # d/dx x^2 = 2 x: sign and scale at the off-centre point
    assert filter_1d(taps, centre, 2, 1)[0] == pytest.approx(2 * X0, rel=1e-12)
    estimate, truth, scale = filter_1d(taps, centre, 3, 1)
    assert abs(estimate - truth) > NOT_EXACT * scale


@pytest.mark.parametrize("n", range(3, 12))
def test_first_derivative_zero_at_nyquist(n: int) -> None:
    taps = np_taps(first_derivative_taps(n))
    assert abs(response(taps, math.pi, (n - 1) / 2)) < 1e-15


@pytest.mark.parametrize("n", sorted(FIRST_DERIVATIVE_GAIN))
def test_first_derivative_white_noise_gain(n: int) -> None:
    gain = float(np.sqrt(np.sum(np_taps(first_derivative_taps(n)) ** 2)))
    assert round(gain, 2) == FIRST_DERIVATIVE_GAIN[n]


def test_first_derivative_rejects_short_length() -> None:
    with pytest.raises(ValueError, match="first-derivative length must be >= 3, got 2"):
        first_derivative_taps(2)


# -------------------------------------------------------------------------------- second derivative
@pytest.mark.parametrize("n", sorted(SECOND_DERIVATIVE))
def test_second_derivative_matches_table(n: int) -> None:
    np.testing.assert_allclose(np_taps(second_derivative_taps(n)), as_array(SECOND_DERIVATIVE[n]), atol=1e-16)


def test_second_derivative_3_is_plain_difference() -> None:
    np.testing.assert_array_equal(np_taps(second_derivative_taps(3)), [1.0, -2.0, 1.0])


@pytest.mark.parametrize("n", [3, 5, 7, 9, 11])
def test_second_derivative_exact_to_cubics_only(n: int) -> None:
    taps, centre = np_taps(second_derivative_taps(n)), (n - 1) / 2
    for power in range(4):
        estimate, truth, scale = filter_1d(taps, centre, power, 2)
        assert estimate == pytest.approx(truth, abs=EXACT * scale)
    # d2/dx2 x^3 = 6 x
    assert filter_1d(taps, centre, 3, 2)[0] == pytest.approx(6 * X0, rel=1e-12)
    estimate, truth, scale = filter_1d(taps, centre, 4, 2)
    assert abs(estimate - truth) > NOT_EXACT * scale


@pytest.mark.parametrize("n", [5, 7, 9, 11])
def test_second_derivative_zero_at_nyquist(n: int) -> None:
    assert abs(response(np_taps(second_derivative_taps(n)), math.pi, (n - 1) / 2)) < 1e-15


def test_second_derivative_3_not_zero_at_nyquist() -> None:
    assert response(np_taps(second_derivative_taps(3)), math.pi, 1.0) == pytest.approx(-4.0)


@pytest.mark.parametrize("n", sorted(SECOND_DERIVATIVE_GAIN))
def test_second_derivative_white_noise_gain(n: int) -> None:
    gain = float(np.sqrt(np.sum(np_taps(second_derivative_taps(n)) ** 2)))
    assert round(gain, 2) == SECOND_DERIVATIVE_GAIN[n]


@pytest.mark.parametrize("n", [1, 4, 6])
def test_second_derivative_rejects_bad_size(n: int) -> None:
    with pytest.raises(ValueError, match=f"second-derivative size must be odd and >= 3, got {n}"):
        second_derivative_taps(n)


# ---------------------------------------------------------------------- central second difference
def test_central_second_difference_5_matches_table() -> None:
    np.testing.assert_allclose(
        np_taps(central_second_derivative_taps(5)), as_array(CENTRAL_SECOND_5), atol=1e-14
    )
    np.testing.assert_allclose(np_taps(central_second_derivative_taps(3)), [1.0, -2.0, 1.0], atol=1e-15)


@pytest.mark.parametrize("n", [3, 5, 7, 9, 11])
def test_central_second_difference_exact_to_degree_n_only(n: int) -> None:
    taps, centre = np_taps(central_second_derivative_taps(n)), (n - 1) / 2
    for power in range(n + 1):
        estimate, truth, scale = filter_1d(taps, centre, power, 2)
        assert estimate == pytest.approx(truth, abs=EXACT * scale), power
    estimate, truth, scale = filter_1d(taps, centre, n + 1, 2)
    assert abs(estimate - truth) > NOT_EXACT * scale


@pytest.mark.parametrize("n", [3, 5, 7, 9, 11])
def test_central_second_difference_not_zero_at_nyquist(n: int) -> None:
    # No noise suppression: the response at pi is at least as large as the 3-point stencil's (-4).
    assert response(np_taps(central_second_derivative_taps(n)), math.pi, (n - 1) / 2).real < -4.0 + 1e-12


@pytest.mark.parametrize("n", [1, 4, 8])
def test_central_second_difference_rejects_bad_size(n: int) -> None:
    with pytest.raises(ValueError, match=f"central second difference needs an odd size >= 3, got {n}"):
        central_second_derivative_taps(n)


# ------------------------------------------------------------------------------------ time stencils
@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_time_stencil_exact_to_quadratics_at_centre_only(family: str, length: int) -> None:
    stencil = time_stencil(family, length)
    taps = np_taps(stencil.taps)
    assert stencil.length == length and taps.shape == (length,)
    assert stencil.exact_degree == 2
    for power in range(3):
        estimate, truth, scale = filter_1d(taps, stencil.centre, power, 1)
        assert estimate == pytest.approx(truth, abs=EXACT * scale), power
    estimate, truth, scale = filter_1d(taps, stencil.centre, 3, 1)
    assert abs(estimate - truth) > NOT_EXACT * scale


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_time_stencil_centre_and_delay(family: str, length: int) -> None:
    stencil = time_stencil(family, length)
    expected_centre = float(length - 1) if family == "hybrid" else (length - 1) / 2
    assert stencil.centre == expected_centre
    assert stencil.delay == (length - 1) - expected_centre
    assert stencil.family == family


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_time_stencil_pair_is_an_average_with_the_same_centre(family: str, length: int) -> None:
    stencil = time_stencil(family, length)
    pair = np_taps(stencil.pair)
    assert pair.shape == (length,)
    assert (pair >= 0).all()
    assert pair.sum() == pytest.approx(1.0, abs=1e-15)
    assert float(np.sum(pair * np.arange(length))) == pytest.approx(stencil.centre, abs=1e-13)
    # applied to a linear signal, the pair returns its value at the derivative's centre
    estimate, truth, scale = filter_1d(pair, stencil.centre, 1, 0)
    assert estimate == pytest.approx(X0, abs=EXACT * scale)


@pytest.mark.parametrize(("family", "length"), TIME_CASES)
def test_time_stencil_zero_at_nyquist(family: str, length: int) -> None:
    stencil = time_stencil(family, length)
    assert abs(response(np_taps(stencil.taps), math.pi, stencil.centre)) < 1e-14


@pytest.mark.parametrize("length", sorted(SMOOTH_ONE_SIDED))
def test_smooth_time_family_matches_table(length: int) -> None:
    np.testing.assert_allclose(
        np_taps(time_stencil("smooth", length).taps), as_array(SMOOTH_ONE_SIDED[length]), atol=1e-16
    )


@pytest.mark.parametrize("length", [3, 5, 7, 9, 11])
def test_centred_time_family_uses_the_smooth_taps(length: int) -> None:
    centred, smooth = time_stencil("centred", length), time_stencil("smooth", length)
    torch.testing.assert_close(centred.taps, smooth.taps, rtol=0, atol=0)
    torch.testing.assert_close(centred.pair, smooth.pair, rtol=0, atol=0)
    assert centred.centre == smooth.centre


@pytest.mark.parametrize("length", sorted(HYBRID_NEWEST_FIRST))
def test_hybrid_time_family_matches_table_oldest_first(length: int) -> None:
    expected = as_array(HYBRID_NEWEST_FIRST[length])[::-1]
    np.testing.assert_allclose(np_taps(time_stencil("hybrid", length).taps), expected, atol=1e-15)


@pytest.mark.parametrize("omega", sorted(HYBRID_8_GAIN))
def test_hybrid_8_overshoots_at_mid_frequencies(omega: float) -> None:
    stencil = time_stencil("hybrid", 8)
    gain = abs(response(np_taps(stencil.taps), omega, stencil.centre)) / omega
    assert round(gain, 2) == HYBRID_8_GAIN[omega]


def test_smooth_8_does_not_overshoot() -> None:
    stencil = time_stencil("smooth", 8)
    for omega in np.linspace(0.01, math.pi, 50):
        assert abs(response(np_taps(stencil.taps), omega, stencil.centre)) / omega <= 1.0 + 1e-12


@pytest.mark.parametrize(
    ("family", "length", "message"),
    [
        ("spline", 5, "unknown time family 'spline'; expected one of: smooth, centred, hybrid"),
        ("smooth", 2, "time filter length must be an integer >= 3, got 2"),
        ("smooth", 5.0, "time filter length must be an integer >= 3, got 5.0"),
        ("centred", 6, "the centred time family needs an odd length, got 6"),
        ("hybrid", 3, r"hybrid time family has lengths \[4, 5, 6, 7, 8\], got 3"),
        ("hybrid", 9, r"hybrid time family has lengths \[4, 5, 6, 7, 8\], got 9"),
    ],
)
def test_time_stencil_errors(family: str, length: int, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        time_stencil(family, length)


def test_time_families_registry() -> None:
    assert set(stencils.TIME_FAMILIES) == {"smooth", "centred", "hybrid"}


# ------------------------------------------------------------------------------------ 2D: gradient
@pytest.mark.parametrize("size", SPATIAL_SIZES)
def test_gradient_kernels_shape_and_transpose(size: int) -> None:
    kernels = gradient_kernels(size)
    assert kernels.shape == (2, size, size) and kernels.dtype == torch.float64
    torch.testing.assert_close(kernels[1], kernels[0].T, rtol=0, atol=0)


@pytest.mark.parametrize("size", sorted(GRADIENT_X))
def test_gradient_kernels_match_table(size: int) -> None:
    np.testing.assert_allclose(gradient_kernels(size)[0].numpy(), as_array(GRADIENT_X[size]), atol=1e-16)


@pytest.mark.parametrize("size", SPATIAL_SIZES)
def test_gradient_exact_to_quadratics_only(size: int) -> None:
    ddx, ddy = (k.numpy() for k in gradient_kernels(size))
    assert_exact_2d(ddx, 1, [(1, 0)], 2)
    assert_exact_2d(ddy, 1, [(0, 1)], 2)
    # d/dx (x^2 + 3 y) = 2 x and d/dy = 3: x along columns, y along rows
    assert filter_2d(ddx, 2, 0, 1)[0] == pytest.approx(2 * X0, rel=1e-12)
    assert filter_2d(ddy, 0, 1, 1)[0] == pytest.approx(1.0, rel=1e-12)
    assert filter_2d(ddx, 0, 1, 1)[0] == pytest.approx(0.0, abs=1e-12)
    assert misses_some_2d(ddx, 1, [(1, 0)], 3)
    assert misses_some_2d(ddy, 1, [(0, 1)], 3)


@pytest.mark.parametrize("size", [s for s in SPATIAL_SIZES if s >= 5])
def test_gradient_zero_on_nyquist_border(size: int) -> None:
    for kernel in gradient_kernels(size):
        assert_nyquist_border_zero(kernel.numpy())


# ------------------------------------------------------------------------- 2D: second derivatives
@pytest.mark.parametrize("size", SPATIAL_SIZES)
def test_second_derivative_kernels_exact_to_cubics_only(size: int) -> None:
    kernels = second_derivative_kernels(size)
    assert kernels.shape == (3, size, size) and kernels.dtype == torch.float64
    d11, d22, d12 = (k.numpy() for k in kernels)
    np.testing.assert_array_equal(d22, d11.T)
    for kernel, derivs in ((d11, [(2, 0)]), (d22, [(0, 2)]), (d12, [(1, 1)])):
        assert_exact_2d(kernel, 2, derivs, 3)
        assert misses_some_2d(kernel, 2, derivs, 4)
    # d11 (x^3) = 6 x, d22 (x y^2) = 2 x, d12 (x^2 y) = 2 x
    assert filter_2d(d11, 3, 0, 2)[0] == pytest.approx(6 * X0, rel=1e-12)
    assert filter_2d(d22, 1, 2, 2)[0] == pytest.approx(2 * X0, rel=1e-12)
    assert filter_2d(d12, 2, 1, 2)[0] == pytest.approx(2 * X0, rel=1e-12)


@pytest.mark.parametrize("size", [s for s in SPATIAL_SIZES if s >= 5])
def test_second_derivative_kernels_zero_on_nyquist_border(size: int) -> None:
    for kernel in second_derivative_kernels(size):
        assert_nyquist_border_zero(kernel.numpy())


# -------------------------------------------------------------------------------- 2D: Laplacians
@pytest.mark.parametrize("size", sorted(LAPLACIAN))
def test_holoborodko_laplacian_matches_table(size: int) -> None:
    np.testing.assert_allclose(laplacian_kernel(size).numpy(), as_array(LAPLACIAN[size]), atol=1e-16)


@pytest.mark.parametrize("family", ["holoborodko", "central"])
def test_laplacian_3_is_five_point_stencil(family: str) -> None:
    np.testing.assert_allclose(laplacian_kernel(3, family).numpy(), as_array(FIVE_POINT), atol=1e-15)


@pytest.mark.parametrize("size", SPATIAL_SIZES)
def test_holoborodko_laplacian_exact_to_cubics_only(size: int) -> None:
    kernel = laplacian_kernel(size).numpy()
    assert kernel.shape == (size, size)
    np.testing.assert_array_equal(kernel, kernel.T)
    assert_exact_2d(kernel, 2, [(2, 0), (0, 2)], 3)
    # Laplacian of x^3 + x y^2 is 8 x
    value = filter_2d(kernel, 3, 0, 2)[0] + filter_2d(kernel, 1, 2, 2)[0]
    assert value == pytest.approx(8 * X0, rel=1e-12)
    assert misses_some_2d(kernel, 2, [(2, 0), (0, 2)], 4)


@pytest.mark.parametrize("size", SPATIAL_SIZES)
def test_central_laplacian_exact_to_degree_n_per_variable(size: int) -> None:
    kernel = laplacian_kernel(size, "central").numpy()
    np.testing.assert_array_equal(kernel, kernel.T)
    for a in range(size + 1):
        for b in range(size + 1):
            estimate, scale = filter_2d(kernel, a, b, 2)
            truth = d_monomial(a, b, 2, 0) + d_monomial(a, b, 0, 2)
            assert abs(estimate - truth) <= EXACT * max(scale, 1.0), (a, b)
    estimate, scale = filter_2d(kernel, size + 1, 0, 2)
    assert abs(estimate - d_monomial(size + 1, 0, 2, 0)) > NOT_EXACT * scale


@pytest.mark.parametrize("size", [s for s in SPATIAL_SIZES if s >= 5])
def test_holoborodko_laplacian_zero_on_nyquist_border(size: int) -> None:
    assert_nyquist_border_zero(laplacian_kernel(size).numpy())


@pytest.mark.parametrize(("size", "family"), [(3, "holoborodko")] + [(s, "central") for s in SPATIAL_SIZES])
def test_five_point_and_central_laplacians_not_zero_at_nyquist(size: int, family: str) -> None:
    kernel = laplacian_kernel(size, family).numpy()
    assert abs(response2d(kernel, math.pi, 0.0)) > 1.0
    assert abs(response2d(kernel, math.pi, math.pi)) > 1.0


@pytest.mark.parametrize("size", sorted(LAPLACIAN_GAIN))
def test_laplacian_white_noise_gain(size: int) -> None:
    gain = float(np.sqrt(np.sum(laplacian_kernel(size).numpy() ** 2)))
    assert round(gain, 2) == LAPLACIAN_GAIN[size]


@pytest.mark.parametrize("size", [5, 7])
def test_holoborodko_laplacian_reads_a_few_percent_low_at_0_3_rad_per_px(size: int) -> None:
    kernel = laplacian_kernel(size).numpy()
    for omega_x, omega_y in ((0.3, 0.0), (0.0, 0.3)):
        ratio = response2d(kernel, omega_x, omega_y).real / -(0.3**2)
        assert 0.94 < ratio < 0.98


@pytest.mark.parametrize("size", SPATIAL_SIZES)
def test_holoborodko_laplacian_is_five_point_after_its_partner(size: int) -> None:
    # D2_N = [1, -2, 1] * B_{N-3}, so L_N = (5-point) o (B_{N-3} (x) B_{N-3}): the partner is that smoothing.
    partner = laplacian_partner(size).numpy()
    assert partner.shape == (size, size)
    assert partner.sum() == pytest.approx(1.0, abs=1e-15)
    assert (partner >= 0).all()
    np.testing.assert_array_equal(partner, partner.T)
    np.testing.assert_array_equal(partner, partner[::-1, ::-1])  # same centre as the Laplacian
    composite = signal.convolve2d(as_array(FIVE_POINT), partner, mode="full")
    np.testing.assert_allclose(composite[1:-1, 1:-1], laplacian_kernel(size).numpy(), rtol=0, atol=1e-15)
    assert np.abs(composite).sum() == pytest.approx(np.abs(composite[1:-1, 1:-1]).sum(), abs=1e-15)


@pytest.mark.parametrize("size", SPATIAL_SIZES)
def test_central_laplacian_partner_is_the_identity(size: int) -> None:
    expected = np.zeros((size, size))
    expected[size // 2, size // 2] = 1.0
    np.testing.assert_array_equal(laplacian_partner(size, "central").numpy(), expected)
    if size == 3:
        np.testing.assert_array_equal(laplacian_partner(3).numpy(), expected)


def test_laplacian_partner_errors() -> None:
    with pytest.raises(ValueError, match="unknown Laplacian family 'sobel'"):
        laplacian_partner(5, "sobel")
    with pytest.raises(ValueError, match=r"spatial kernel size must be one of \(3, 5, 7, 9, 11\), got 6"):
        laplacian_partner(6)


@pytest.mark.parametrize("size", [1, 4, 13])
def test_spatial_kernels_reject_bad_size(size: int) -> None:
    message = r"spatial kernel size must be one of \(3, 5, 7, 9, 11\), got " + str(size)
    for build in (gradient_kernels, second_derivative_kernels, laplacian_kernel):
        with pytest.raises(ValueError, match=message):
            build(size)
    with pytest.raises(ValueError, match=message):
        laplacian_kernel(size, "central")


def test_laplacian_rejects_unknown_family() -> None:
    with pytest.raises(
        ValueError, match="unknown Laplacian family 'sobel'; expected one of: holoborodko, central"
    ):
        laplacian_kernel(5, "sobel")


# ------------------------------------------------------------------------------------------ Gaussian
@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.3])
def test_gaussian_taps(sigma: float) -> None:
    taps = np_taps(gaussian_taps(sigma))
    radius = math.ceil(3.5 * sigma)
    assert taps.shape == (2 * radius + 1,)
    offsets = np.arange(-radius, radius + 1)
    expected = np.exp(-(offsets**2) / (2 * sigma**2))
    np.testing.assert_allclose(taps, expected / expected.sum(), rtol=1e-14)
    np.testing.assert_array_equal(taps, taps[::-1])
    assert taps.sum() == pytest.approx(1.0, abs=1e-15)


def test_gaussian_taps_truncate_and_identity() -> None:
    assert gaussian_taps(2.0, truncate=1.0).shape == (5,)
    np.testing.assert_array_equal(np_taps(gaussian_taps(0.0)), [1.0])


@pytest.mark.parametrize("sigma", [-1.0, math.nan, math.inf])
def test_gaussian_taps_reject_bad_sigma(sigma: float) -> None:
    with pytest.raises(ValueError, match="smoothing sigma must be a finite number >= 0"):
        gaussian_taps(sigma)
