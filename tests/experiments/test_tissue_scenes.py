"""The multi-tissue scenes of the learning pipeline (:mod:`experiments.tissue_scenes`): the tissues' damage
constants, the batched simulation against the library's single-scene simulator, the truth, the cached set."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch.simulation import MovingSource, simulate_tissue
from anra_torch.tissue import GAS_CONSTANT
from anra_torch.video import load_video
from experiments import tissue_scenes
from experiments.tissue_scenes import (
    DX,
    TISSUES,
    SceneSettings,
    omega_of_tissues,
    scene_setup,
    simulate,
    write_scenes,
)

F64 = torch.float64
SMALL = SceneSettings(size=24, duration=8.0, exposure=(2.0, 4.0), mixed=0.5)
SHORT = SceneSettings(size=24, duration=3.0, exposure=(1.0, 2.0))


def test_the_tissues_damage_in_one_minute_at_their_published_temperatures() -> None:
    t60 = {t.name: t.t60 for t in TISSUES}
    assert t60 == pytest.approx({"skin": 54.0, "liver": 50.1, "arterial wall": 69.6}, abs=0.05)
    # One minute at T60 is Omega = 1 with each tissue's own constants (the hold rule: 60 frames of 1 s).
    for k, t in enumerate(TISSUES):
        history = torch.full((1, 60, 1, 1), t.t60, dtype=F64)
        omega = omega_of_tissues(history, 1.0, torch.full((1, 1, 1), k))  # piecewise linear over 59 s
        assert float(omega) == pytest.approx(59 / 60, rel=1e-9)
    # 10 min at 48 C damages liver (small Ea) but neither skin nor arterial wall.
    rate = [
        t.constants.frequency * math.exp(-t.constants.activation_energy / (GAS_CONSTANT * 321.15))
        for t in TISSUES
    ]
    assert rate[1] * 600 > 1 > rate[0] * 600 > rate[2] * 600


def test_a_batch_of_scenes_is_the_library_simulator_scene_by_scene() -> None:
    """The batched spots (one per scene) against :func:`anra_torch.simulation.simulate_tissue` with each
    scene's :class:`~anra_torch.simulation.MovingSource`, at the batch's step."""
    seeds = [3, 4]
    made = simulate(seeds, SHORT)
    setups = [scene_setup(s, SHORT) for s in seeds]
    a_max = max(float(s["a"].max()) for s in setups)
    b_max = max(float(s["b"].max()) for s in setups)
    steps = math.ceil((8 * a_max / DX**2 + b_max) * SHORT.fine_dt / (0.9 * 2.785))
    for k, s in enumerate(setups):
        source = MovingSource(tuple(s["start"]), tuple(s["end"]), s["width"], power=1.0, t_off=s["t_off"])
        start = torch.full((24, 24), 37.0, dtype=F64)
        frames = round(SHORT.duration / SHORT.fine_dt) + 1
        rise = (
            simulate_tissue(
                start, s["a"], s["b"], dx=DX, dt=SHORT.fine_dt, n_frames=frames, source=source, substeps=steps
            )
            - 37.0
        )
        expected = 37.0 + (s["peak"] - 37.0) / float(rise.max()) * rise
        torch.testing.assert_close(made["clean"][k], expected[:: SHORT.stride], rtol=1e-9, atol=1e-9)
        peak = float(made["clean"][k].max())  # the camera's frames may miss the peak itself
        assert s["peak"] - 2.0 < peak <= s["peak"] + 1e-9
    assert made["damage"].dtype == torch.bool and made["tissue"].shape == (2, 24, 24)


def test_mixed_scenes_hold_two_tissues_along_a_boundary_and_others_one() -> None:
    counts = [len(scene_setup(seed, SMALL)["tissue"].unique()) for seed in range(24)]
    assert set(counts) == {1, 2}
    assert 6 <= counts.count(2) <= 18  # half of them on average
    kinds = {int(scene_setup(seed, SMALL)["tissue"][0, 0]) for seed in range(24)}
    assert kinds == {0, 1, 2}


def test_the_truth_is_each_pixels_own_tissue_omega() -> None:
    """A minute at 52 C damages liver (Omega 1.7) but not skin (0.24) nor arterial wall: with one history for
    all, the truth follows the tissue map."""
    history = torch.full((1, 121, 1, 3), 52.0, dtype=F64)
    omega = omega_of_tissues(history, 0.5, torch.tensor([[[0, 1, 2]]]))
    assert float(omega[0, 0, 1]) > 1.5 and 0.1 < float(omega[0, 0, 0]) < 0.5 and float(omega[0, 0, 2]) < 1e-3


def test_a_scene_set_is_written_once_and_reused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    facts = write_scenes(tmp_path, range(0, 3), SMALL)
    files = sorted(p.name for p in tmp_path.glob("*.npz"))
    assert files == ["scene_0000.npz", "scene_0001.npz", "scene_0002.npz"] and len(facts) == 3
    video = load_video(tmp_path / "scene_0001.npz")
    assert (
        video.frames.shape == (17, 24, 24)
        and video.dt == pytest.approx(0.5)
        and video.dx == pytest.approx(DX)
    )
    with np.load(tmp_path / "scene_0001.npz") as data:
        assert data["damage"].dtype == bool and data["tissue"].shape == (24, 24)
    assert set(facts[0]) == {"exposure_s", "peak_c", "tissues", "damaged_fraction"}

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the scenes were simulated again")

    monkeypatch.setattr(tissue_scenes, "simulate", refuse)
    assert write_scenes(tmp_path, range(0, 3), SMALL) == json.loads(json.dumps(facts))
    monkeypatch.undo()
    write_scenes(tmp_path, range(5, 7), SMALL)  # another set: the old files go
    assert sorted(p.name for p in tmp_path.glob("*.npz")) == ["scene_0005.npz", "scene_0006.npz"]


def test_frames_too_small_for_the_layer_are_refused() -> None:
    with pytest.raises(ValueError, match="size must be 20-48 px"):
        SceneSettings(size=16)
