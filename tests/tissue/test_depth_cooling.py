"""What the depth fit sees of the cooling: the first frame of the fit."""

from __future__ import annotations

import pytest
import torch
from depth_scenes import BODY, burn_video

from anra_torch.tissue.depth_cooling import cooling_modes, cooling_start


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    return burn_video()


def test_cooling_starts_two_frames_after_the_switch_off(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, _, _ = burn
    assert int(cooling_start((frames - BODY).unsqueeze(0))[0]) == 16 + 2  # last heated frame: 16


def test_one_frames_modes_are_the_records(burn: tuple[torch.Tensor, float, float]) -> None:
    """A frame's modes alone (``length``: the record's margin) equal its modes among all frames."""
    frames, dt, dx = burn
    rise = (frames - BODY).unsqueeze(0).double()
    spacing = (torch.tensor([dx], dtype=torch.float64), torch.tensor([dt], dtype=torch.float64))
    noise = torch.tensor([0.3], dtype=torch.float64)
    every = cooling_modes(rise, *spacing, noise)
    one = cooling_modes(rise[:, 17:18], *spacing, noise, length=rise.shape[1])
    assert one.shape == (1, 1, every.shape[2])
    torch.testing.assert_close(one[:, 0], every[:, 17], rtol=1e-12, atol=1e-12)
