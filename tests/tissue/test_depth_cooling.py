"""What the depth fit sees of the cooling: the first frame of the fit."""

from __future__ import annotations

import pytest
import torch
from depth_scenes import BODY, burn_video

from anra_torch.tissue.depth_cooling import cooling_start


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    return burn_video()


def test_cooling_starts_two_frames_after_the_switch_off(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, _, _ = burn
    assert int(cooling_start((frames - BODY).unsqueeze(0))[0]) == 16 + 2  # last heated frame: 16
