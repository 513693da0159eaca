"""A smoothing candidate's sums and the choice among candidates (:mod:`anra_torch.estimation.candidates`):
shares in [0, 1], the smallest measurable error wins, unmeasurable windows are NaN, the ratio skips L = 0."""

from __future__ import annotations

import torch

from anra_torch.estimation.candidates import (
    Candidate,
    choose,
    explained_of,
    ratio_sums,
    reliability_of,
    windowed_field,
)

F64 = torch.float64


def candidate(num: list[float], den: list[float], energy: list[float], std_error: list[float]) -> Candidate:
    """One frame per video: ``(B, 1)`` sums and ``(B,)`` errors; no field."""
    column = lambda v: torch.tensor(v, dtype=F64)[:, None]  # noqa: E731
    error = torch.tensor(std_error, dtype=F64)
    return Candidate(
        column(num), column(num), column(den), column(energy), column([0.0] * len(num)),
        error, error, None, None, None, None,
    )  # fmt: skip


def test_reliability_and_explained_are_shares_and_zero_without_energy() -> None:
    share = reliability_of(torch.tensor([0.5, 0.0, 2.0], dtype=F64), torch.tensor([1.0, 0.0, 2.0], dtype=F64))
    torch.testing.assert_close(share, torch.tensor([0.5, 0.0, 1.0], dtype=F64))
    exact = candidate([2.0, 0.0], [4.0, 0.0], [4.0, 0.0], [0.1, 0.1])  # U = L / 2: sum U^2 = 1 on video 0
    exact.rate_energy = torch.tensor([[1.0], [0.0]], dtype=F64)
    assert explained_of(exact).tolist() == [1.0, 0.0]  # all of dT/dt explained; no energy


def test_each_video_takes_the_measurable_candidate_with_the_smallest_error() -> None:
    # video 0: candidate 1 has the smaller error; video 1: candidate 1 is not measurable (no signal energy)
    first = candidate([2.0, 2.0], [10.0, 10.0], [10.0, 10.0], [0.02, 0.01])
    second = candidate([2.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.01, 0.001])
    chosen, measured, index = choose([first, second], "lsq")
    assert index.tolist() == [1, 0] and measured.tolist() == [True, True]
    torch.testing.assert_close(chosen.std_error, torch.tensor([0.01, 0.01], dtype=F64))
    _, _, index = choose([first, second], "lsq", torch.tensor([[True, False], [True, False]]))
    assert index.tolist() == [0, 0]


def test_the_windowed_field_is_nan_where_it_measures_nothing() -> None:
    maps = torch.tensor([[[1.0, 1.0]]], dtype=F64), torch.tensor([[[2.0, 0.0]]], dtype=F64)
    chosen = Candidate(*[torch.zeros(1, 1, dtype=F64)] * 7, None, maps[0], maps[1], maps[1])
    field, confidence = windowed_field(chosen)
    assert field[0, 0, 0] == 0.5 and torch.isnan(field[0, 0, 1])
    assert confidence.tolist() == [[[1.0, 0.0]]]


def test_the_ratio_sums_skip_pixels_where_the_laplacian_is_zero() -> None:
    rate = torch.tensor([[[[2.0, 3.0]]]], dtype=F64)
    lap = torch.tensor([[[[4.0, 0.0]]]], dtype=F64)
    assert ratio_sums(rate, lap, torch.ones_like(rate)).tolist() == [[0.5]]
