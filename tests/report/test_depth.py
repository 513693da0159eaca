"""``anra features --depth --report``: the depth report draws the damage-depth map and the depth profiles."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from commands import run

from anra_torch.simulation import BioheatScene, SurfaceFlux, Tissue, camera_frames, simulate_bioheat
from anra_torch.simulation.bioheat_scenes import flux_peak
from anra_torch.video import save_npz


@pytest.fixture(scope="module")
def depth_burn(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A 0.4 mm beam for 3 s on skin-like tissue (independent 3-D simulator), 3 s of cooling, 0.2 K noise."""
    tissue = Tissue(diffusivity=0.13, perfusion=0.003)
    centre = (2.8, 2.8)
    unit = SurfaceFlux(centre, centre, 0.4, 1.0, 0.5, 3.5)
    power = 45.0 / flux_peak(unit, tissue, np.array([centre]), np.array([3.5]))
    scene = BioheatScene(
        tissue, (SurfaceFlux(centre, centre, 0.4, power, 0.5, 3.5),), 7.0, (28, 28), 0.2, 10.0, 1.5
    )
    result = simulate_bioheat(scene)
    frames = camera_frames(result, 0.2, 5)
    folder = tmp_path_factory.mktemp("depth")
    return {
        "video": save_npz(folder / "burn.npz", frames, dt=result.dt, dx=result.dx),
        "no_dx": save_npz(folder / "no_dx.npz", frames, dt=result.dt, dx=None),
        "frames": torch.from_numpy(frames),
        "result": result,
    }


def test_depth_report_draws_the_map_and_profiles(
    depth_burn: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "report"
    code, out, err = run(capsys, "features", depth_burn["video"], "--depth", "--report", folder)
    assert (code, err) == (0, "")
    assert "damage_depth_mm_max:" in out and f"report: {folder / 'depth.md'}" in out
    text = (folder / "depth.md").read_text()
    assert "![damage depth map](depth_map.png)" in text and "| diffusivity a |" in text
    assert (folder / "depth_map.png").stat().st_size > 0 and (
        folder / "depth_profiles.png"
    ).stat().st_size > 0
