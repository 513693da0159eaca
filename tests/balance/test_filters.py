"""The matched filters and their term bank (:mod:`anra_torch.balance.filters`): exact on polynomials, the
noise they pass (against the tabulated time taps), their adjoint, and the one-line error.

The polynomial fields are exact for every term: the Gaussian is symmetric and normalised (it keeps linear
functions, moves a quadratic by a constant), the time filters are exact on linear time courses at their
common centre, and the spatial operators on quadratics; each term's expected value is the derivative of
the polynomial written out here, in physical units.
"""

from __future__ import annotations

import pytest
import torch
from reference import FIRST_DERIVATIVE, as_array

from anra_torch.balance import MatchedFilters
from anra_torch.balance.filters import TERMS

F64 = torch.float64
DT, DX = 0.2, 0.5  # s, mm


def grid(frames: int, height: int, width: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``t`` (s), ``y`` and ``x`` (mm) broadcastable to ``(frames, height, width)``."""
    t = (torch.arange(frames, dtype=F64) * DT)[:, None, None]
    y = (torch.arange(height, dtype=F64) * DX)[None, :, None]
    x = (torch.arange(width, dtype=F64) * DX)[None, None, :]
    return t, y, x


@pytest.mark.parametrize(("sigma", "family"), [(0.0, "central"), (1.0, "holoborodko"), (1.5, "central")])
def test_every_term_is_exact_on_a_quadratic_field_linear_in_time(sigma: float, family: str) -> None:
    filters = MatchedFilters(sigma, time_length=5, laplacian_size=5, laplacian_family=family)
    t, y, x = grid(9, 24, 26)
    field = 3.0 * t + 0.5 * x**2 + 0.25 * y**2 + 0.7 * x * y + 0.2 * x - 0.1 * y
    out = filters.terms(field, DT, DX, ["U", "L", "1", "T_x", "T_y", "D", "T_xy"])
    m = filters.margin
    assert out["U"].shape == (5, 24 - 2 * m, 26 - 2 * m)  # K = T - 5 + 1 frames, crop borders
    xs, ys = x[..., m : 26 - m], y[:, m : 24 - m]  # the output pixels' positions
    expected = {
        "U": torch.tensor(3.0, dtype=F64),  # dT/dt
        "L": torch.tensor(1.5, dtype=F64),  # 2 (0.5 + 0.25)
        "1": torch.tensor(1.0, dtype=F64),
        "T_x": (1.0 * xs + 0.7 * ys + 0.2).expand_as(out["U"]),
        "T_y": (0.5 * ys + 0.7 * xs - 0.1).expand_as(out["U"]),
        "D": torch.tensor(0.5, dtype=F64),  # d_xx - d_yy = 1 - 0.5
        "T_xy": torch.tensor(0.7, dtype=F64),
    }
    for name, value in expected.items():
        torch.testing.assert_close(out[name], value.expand_as(out[name]), rtol=1e-11, atol=1e-11, msg=name)


def test_the_square_term_is_the_squared_gradient_of_a_linear_field() -> None:
    """``N = Lap G S_t (T^2 / 2)``: for ``T`` linear in space, ``Lap (T^2 / 2) = |grad T|^2`` exactly."""
    filters = MatchedFilters(1.0, time_length=5, laplacian_size=5)
    _, y, x = grid(7, 20, 20)
    field = (5.0 + 0.2 * x - 0.1 * y).expand(7, 20, 20)
    n = filters.terms(field, DT, DX, ["N"])["N"]
    torch.testing.assert_close(n, torch.full_like(n, 0.05), rtol=1e-10, atol=1e-12)


def test_shapes_batches_and_the_margin_the_filters_take() -> None:
    filters = MatchedFilters(1.0, time_length=7, laplacian_size=5)
    video = torch.randn(2, 10, 30, 32, dtype=F64, generator=torch.Generator().manual_seed(0))
    out = filters.terms(video, torch.tensor([0.1, 0.2], dtype=F64), DX, ["U", "L"])
    m = filters.margin
    assert (
        m == filters.smoother.radius + 2 and filters.reach == m
    )  # Gaussian radius + half the 5-point support
    assert out["U"].shape == out["L"].shape == (2, 4, 30 - 2 * m, 32 - 2 * m)
    one = filters.terms(video[1], 0.2, DX, ["U", "L"])  # per-video spacing: the batch is each video alone
    torch.testing.assert_close(out["U"][1], one["U"], rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(out["L"][1], one["L"], rtol=1e-12, atol=1e-12)
    assert "margin=" in repr(filters)


def test_smoothing_the_frames_first_gives_the_same_terms() -> None:
    """The Gaussian commutes with the time filters: one spatial pass over the frames is the same bank."""
    filters = MatchedFilters(1.5, time_length=5, laplacian_size=5)
    video = torch.randn(12, 28, 28, dtype=F64, generator=torch.Generator().manual_seed(1))
    names = ["U", "L", "T", "T_x", "T_y", "D", "T_xy"]
    direct = filters.terms(video, DT, DX, names)
    staged = filters.terms(video, DT, DX, names, time_stage=filters.smoothed_stage(video, DT), smoothed=True)
    for name in names:
        torch.testing.assert_close(staged[name], direct[name], rtol=1e-10, atol=1e-12, msg=name)


def test_white_noise_through_u_is_the_tabulated_time_derivative() -> None:
    """Without smoothing, ``U`` is the 5-tap derivative alone: its noise per point is ``sum taps^2 / dt^2``
    (taps of REFERENCE.md), and ``U`` and ``L`` share their centre (antisymmetric against symmetric time
    filters: uncorrelated)."""
    filters = MatchedFilters(0.0, time_length=5, laplacian_size=5)
    taps = as_array(FIRST_DERIVATIVE[5])
    inner = filters.noise_inner(["U", "L"])
    assert float(inner[0, 0]) == pytest.approx(float((taps**2).sum()), rel=1e-13)  # 10 / 64
    assert abs(float(inner[0, 1])) < 1e-15
    cov = filters.noise_covariance(["U", "L"], 0.04, DT, DX)
    assert float(cov[0, 0]) == pytest.approx(0.04 * 10 / 64 / DT**2, rel=1e-13)
    assert float(cov[1, 1]) == pytest.approx(0.04 * float(inner[1, 1]) / DX**4, rel=1e-13)
    batched = filters.noise_covariance(
        ["U", "L"],
        torch.tensor([0.04, 0.09], dtype=F64),
        torch.tensor([DT, 0.1], dtype=F64),
        torch.tensor([DX, 1.0], dtype=F64),
    )
    assert batched.shape == (2, 2, 2)
    torch.testing.assert_close(batched[0], cov, rtol=1e-13, atol=0)
    torch.testing.assert_close(batched[1], filters.noise_covariance(["U", "L"], 0.09, 0.1, 1.0))


def test_impulse_responses_are_each_terms_weights_at_the_centre() -> None:
    """A linear term's value at the output centre is its impulse response dotted with the frames."""
    filters = MatchedFilters(1.0, time_length=5, laplacian_size=5, laplacian_family="holoborodko")
    names = ["U", "L", "T", "T_x", "D", "N", "1"]
    responses = filters.impulse_responses(names)
    side = 2 * filters.reach + 1
    assert responses.shape == (7, 5, side, side) and responses.dtype == F64
    probe = torch.randn(5, side, side, dtype=F64, generator=torch.Generator().manual_seed(2))
    out = filters.terms(probe, 1.0, 1.0, names[:5])
    for i, name in enumerate(names[:5]):
        assert float(out[name][0, 0, 0]) == pytest.approx(float((responses[i] * probe).sum()), rel=1e-10)
    torch.testing.assert_close(responses[5], responses[1])  # N's noise is carried by L's kernel
    assert TERMS["N"].noise_kernel == "L" and not bool(responses[6].any())  # "1" carries none


def test_the_adjoint_is_the_transpose_of_the_linear_terms() -> None:
    filters = MatchedFilters(1.0, time_length=5, laplacian_size=5, laplacian_family="holoborodko")
    g = torch.Generator().manual_seed(3)
    frames = torch.randn(1, 9, 24, 24, dtype=F64, generator=g)
    out = filters.terms(frames, DT, DX, ["U", "L", "T"])
    levers = {name: torch.randn(out[name].shape, dtype=F64, generator=g) for name in ("U", "L", "T")}
    back = filters.adjoint(levers, DT, DX)
    assert back.shape == frames.shape
    expected = sum(float((levers[n] * out[n]).sum()) for n in levers)
    assert float((back * frames).sum()) == pytest.approx(expected, rel=1e-10)
    with pytest.raises(ValueError, match="no explicit adjoint for term 'T_x'; push it back through autograd"):
        filters.adjoint({"T_x": levers["U"]}, DT, DX)


def test_an_unknown_term_is_a_one_line_error() -> None:
    filters = MatchedFilters(0.0)
    with pytest.raises(ValueError, match=r"unknown balance term 'Q'; expected one of: U, L, T, 1, T_x"):
        filters.terms(torch.zeros(6, 8, 8, dtype=F64), DT, DX, ["U", "Q"])
    with pytest.raises(ValueError, match=r"extent=\(frames, pixels\) is needed"):
        filters.noise_covariance(["U"], 1.0, DT, DX, within=("pixel",))
