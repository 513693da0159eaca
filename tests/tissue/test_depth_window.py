"""The frames continued beyond their edges: a slope continued, the frame kept."""

from __future__ import annotations

import pytest
import torch
from depth_scenes import F64

from anra_torch.tissue import depth_window
from anra_torch.tissue.depth_cooling import MARGIN, MAX_MARGIN, margin_mm
from anra_torch.tissue.depth_solver import (
    dct_matrix,
    depth_nodes,
    frame_problem,
    march,
    node_temperatures,
    solver_nodes,
)
from anra_torch.tissue.depth_window import (
    Beyond,
    widen,
    widened_modes,
    window_problem,
    window_temperatures,
)


def test_widen_continues_a_slope_and_keeps_the_frame() -> None:
    x = torch.arange(10, dtype=F64).expand(12, 10)
    ramp = 20.0 + 0.5 * x  # rises to the right edge
    wide = widen(ramp.expand(2, 3, 12, 10), 4)
    assert wide.shape == (2, 3, 20, 18) and torch.equal(wide[1, 2, 4:-4, 4:-4], ramp)
    left = wide[0, 0, 8, :4]  # falls on to the left, by the edge's slope flattened by the 5 x 5 means
    steps = left.diff()
    assert bool((steps > 0.25).all()) and bool((steps < 0.5).all())
    assert torch.equal(
        wide[0, 0, 8, -4:], torch.full((4,), float(ramp.max()), dtype=F64)
    )  # kept below the max
    y, x = torch.meshgrid(torch.arange(12, dtype=F64), torch.arange(10, dtype=F64), indexing="ij")
    spot = torch.exp(-((x - 4.5) ** 2 + (y - 5.5) ** 2) / 8)  # a bump: its continuation falls to 0, not below
    wide = widen(spot, 6)
    assert (
        torch.equal(wide[6:-6, 6:-6], spot)
        and float(wide.min()) == 0.0
        and float(wide.max()) == float(spot.max())
    )


def test_widen_curved_continues_a_gaussian_tail() -> None:
    y, x = torch.meshgrid(torch.arange(40, dtype=F64), torch.arange(40, dtype=F64), indexing="ij")
    world = 30.0 * torch.exp(-((x - 19.5) ** 2 + (y - 19.5) ** 2) / (2 * 14.0**2))  # wider than the frame
    frame = world[10:30, 10:30]
    curved, straight = widen(frame, 10, curved=True), widen(frame, 10)
    assert torch.equal(curved[10:30, 10:30], frame)
    row = slice(18, 22)  # across the spot's centre: beyond the edge the tail falls as the Gaussian's
    truth = world[row, :10]
    assert float(((curved[row, :10] - truth).abs() / truth).max()) < 0.1
    assert float(((straight[row, :10] - truth).abs() / truth).max()) > 0.3  # the line falls too fast
    off = world[10:30, 26:40]  # a spot centred 6.5 px beyond the left edge: the continuation rises
    left = widen(off, 10, curved=True)[10, :10].flip(0)  # the px beyond the edge, nearest first
    assert float(left[0]) > float(off[0, 0]) and float(left[:6].diff().min()) > 0.0
    assert 5 <= int(left.argmax()) <= 7 and float(left.max()) <= float(off.max())


def test_margin_follows_the_heats_reach() -> None:
    assert margin_mm(1.0) == MARGIN < margin_mm(60.0) < margin_mm(600.0) == MAX_MARGIN


def test_widened_modes_are_those_of_the_widened_frames() -> None:
    y, x = torch.meshgrid(torch.arange(12, dtype=F64), torch.arange(10, dtype=F64), indexing="ij")
    spot = 20.0 * torch.exp(-((x - 8.0) ** 2 + (y - 3.0) ** 2) / 10) + 0.1 * torch.sin(3.0 * x + y)
    frames = spot.expand(2, 3, 12, 10)
    for margin, options in ((4, {}), (15, {"curved": True}), (6, {"mirrored": True})):
        rows, cols = dct_matrix(12 + 2 * margin)[:7].to(F64), dct_matrix(10 + 2 * margin)[:5].to(F64)
        expected = rows @ widen(frames, margin, **options) @ cols.T
        assert torch.allclose(widened_modes(frames, margin, rows, cols, **options), expected, atol=1e-10)


def _temperatures(rise: torch.Tensor, dx: float, margin: int, *, window: bool) -> torch.Tensor:
    """The rise at the reported nodes under the frame's pixels: by :func:`window_problem` or by the cosine
    modes of the whole widened frame (cropped to the frame)."""
    one = lambda x: torch.tensor([x], dtype=F64)  # noqa: E731
    dt, rates = one(0.1), (one(0.15), one(0.0))
    reported = depth_nodes(0.6, growth=1.1)
    grid = (solver_nodes(reported, 8.0), len(reported))
    if window:
        problem, shape = window_problem(rise, dt, one(dx), rates, grid, Beyond(margin, curved=True))
        blocks = [window_temperatures(rise, problem, shape, s, w) for s, w in march(problem, 64)]
        return torch.cat(blocks, 1)
    wide = widen(rise, margin, curved=True)
    problem = frame_problem(wide, dt, one(dx), *rates, *grid)
    inner = (..., slice(margin, wide.shape[-2] - margin), slice(margin, wide.shape[-1] - margin))
    return torch.cat([node_temperatures(wide, problem, s, w)[inner] for s, w in march(problem, 64)], 1)


def test_window_problem_splits_the_widened_frame_exactly(monkeypatch: pytest.MonkeyPatch) -> None:
    torch.manual_seed(0)
    rise = 5.0 + torch.rand(1, 6, 12, 10, dtype=F64)  # rough, not smooth: every mode carries something
    monkeypatch.setattr(depth_window, "LOW_WAVENUMBER", 1e3)  # every widened mode low: the detail is 0
    split = _temperatures(rise, 0.1, 5, window=True)
    assert torch.allclose(split, _temperatures(rise, 0.1, 5, window=False), atol=1e-9)
    monkeypatch.setattr(depth_window, "LOW_WAVENUMBER", 4.0)  # the detail through the frame's modes
    assert torch.allclose(_temperatures(rise, 0.1, 5, window=True), split, atol=0.05 * 6)


def test_window_lets_a_wide_spots_heat_out_as_the_tissue_does() -> None:
    # a spot wider than the frame (sd 1.6 mm, frame 1.6 mm) heating for 2 s: the world's 64 px frame is the
    # truth at the frame's 16 px; the frame alone (its cosine walls) holds the heat in
    y, x = torch.meshgrid(torch.arange(64, dtype=F64), torch.arange(64, dtype=F64), indexing="ij")
    shape = torch.exp(-((x - 31.5) ** 2 + (y - 31.5) ** 2) / (2 * 16.0**2))
    rise = (20.0 * torch.linspace(0.0, 1.0, 21, dtype=F64).view(-1, 1, 1) * shape).unsqueeze(0)
    world = _temperatures(rise, 0.1, 0, window=False)  # margin 0: the world's own frame, far walls
    frame = rise[..., 24:40, 24:40]
    truth = world[..., 24:40, 24:40]
    windowed = _temperatures(frame, 0.1, 24, window=True)
    walled = _temperatures(frame, 0.1, 1, window=True)  # a 0.1 mm margin: the walls at the frame
    widened = _temperatures(frame, 0.1, 24, window=False)  # every mode of the widened frame
    error = lambda x: float((x - truth).abs().max())  # noqa: E731
    # 0.11 K of 20 K (the tail guessed beyond the frame errs by ~1 K), the walls 0.82 K; the split costs
    # nothing against the whole widened frame (0.24 K)
    assert error(windowed) < 0.15 * error(walled) and error(windowed) <= error(widened)


def test_a_cold_frames_noise_continues_finite_without_a_noise_floor() -> None:
    torch.manual_seed(0)
    noise = 0.3 * torch.randn(1, 8, 64, 64)  # before the heating: the frames' noise only (float32)
    wide = widen(noise, 48, curved=True)
    assert bool(torch.isfinite(wide).all()) and float(wide.max()) <= float(noise.max())
