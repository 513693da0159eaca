"""The frames continued beyond their edges: a slope continued, the frame kept."""

from __future__ import annotations

import torch
from depth_scenes import F64

from anra_torch.tissue.depth_window import widen


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
