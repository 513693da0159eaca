"""The frames continued beyond their edges: a slope continued, the frame kept."""

from __future__ import annotations

import torch
from depth_scenes import F64

from anra_torch.tissue.depth_cooling import MARGIN, MAX_MARGIN, margin_mm
from anra_torch.tissue.depth_solver import dct_matrix
from anra_torch.tissue.depth_window import widen, widened_modes


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
