"""Camera artefacts (:mod:`anra_torch.balance.artefacts`): each kind planted by
:mod:`anra_torch.simulation.camera` on a pure-diffusion video is found and repaired or recorded as it says;
a clean video has none.
"""

from __future__ import annotations

import pytest
import torch
from scenes import camera_scene, with_artefacts

from anra_torch.balance.artefacts import find_artefacts
from anra_torch.balance.noise import measure_noise


@pytest.fixture(scope="module")
def pure():
    return camera_scene()


def test_a_clean_video_has_no_artefacts(pure) -> None:
    repaired, found = find_artefacts(pure.frames)
    assert not found.any and found.within == ()
    assert torch.equal(repaired, pure.frames)
    assert measure_noise(repaired).white


def test_spikes_and_dead_and_hot_elements_are_found_and_repaired(pure) -> None:
    frames, record = with_artefacts(pure, "bad_elements")
    repaired, found = find_artefacts(frames)
    planted = {(p["row"], p["col"]) for p in record["dead"] + record["hot"]}
    assert set(found.bad_pixels) == planted
    assert found.spikes == len(record["spikes"])
    assert not found.fixed_pattern and not found.steps
    # Repaired samples are back within a few noise sds of the clean video everywhere but at the elements.
    good = torch.ones(frames.shape[1:], dtype=torch.bool)
    for i, j in planted:
        good[i, j] = False
    assert float((repaired - pure.frames)[:, good].abs().max()) < 8 * pure.noise_sd


def test_offset_steps_are_found_and_give_per_frame_fixed_effects(pure) -> None:
    frames, record = with_artefacts(pure, "offset_steps")
    repaired, found = find_artefacts(frames)
    assert set(found.steps) == {s["frame"] for s in record["steps"]}
    for step in record["steps"]:
        size = found.step_sizes[found.steps.index(step["frame"])]
        # measured: within 0.01 K of the planted step (the drift adds 0.001 K per frame)
        assert size == pytest.approx(step["size"] + record["drift_rate"] * pure.dt, abs=0.02)
    assert found.within == ("frame",) and not found.fixed_pattern
