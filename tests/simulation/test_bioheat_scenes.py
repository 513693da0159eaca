"""Random bioheat scenes (spot, sweep, contact, near-infrared) stay in the ranges they state."""

from __future__ import annotations

import pytest

from anra_torch.simulation.bioheat_scenes import KINDS, random_scene

A, BODY = 0.15, 37.0


@pytest.mark.parametrize("seed", range(6))
def test_random_scenes_stay_in_the_issue_ranges(seed: int) -> None:
    scene = random_scene(seed)
    source = scene.sources[0]
    assert scene.label == KINDS[seed % 3]
    assert 0.10 <= scene.tissue.diffusivity <= 0.20 and 0.0 <= scene.tissue.perfusion <= 0.01
    assert 0.5 - 1e-9 <= source.t_off - source.t_on <= 60.0 + 1e-9
    assert scene.rate in (5.0, 10.0, 15.0, 30.0) and 0.1 <= scene.dx <= 0.25
