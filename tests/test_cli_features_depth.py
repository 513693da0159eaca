"""``anra features --depth``: the depth maps in the .npz, the assumptions in the JSON, the report."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch.cli import main
from anra_torch.simulation.bioheat_reference import (
    BioheatScene,
    SurfaceFlux,
    Tissue,
    camera_frames,
    simulate_bioheat,
)
from anra_torch.simulation.bioheat_scenes import flux_peak
from anra_torch.tissue import depth_features
from anra_torch.video import save_npz


def run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def burn(tmp_path_factory: pytest.TempPathFactory) -> dict:
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


def test_depth_maps_json_and_npz(burn: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "maps.npz"
    code, out, err = run(capsys, "features", burn["video"], "--depth", "--out", target, "--json")
    assert (code, err) == (0, "")
    record = json.loads(out)
    depth = record["depth"]
    assert depth["absorption"].startswith("at the surface") and depth["geometry"] == "half-space"
    assert depth["diffusivity_mm2_s"] == pytest.approx(0.13, rel=0.1)
    assert depth["diffusivity_std_mm2_s"] > 0 and depth["loss_rate_per_s"] >= 0
    assert "zero surface flux" in depth["parameters_from"] and depth["maps"] and not depth["volumetric"]
    assert record["units"]["damage_depth_mm_max"] == "mm"
    maps = np.load(target)
    h, w = burn["frames"].shape[1:]
    for name in ("damage_depth_mm", "damage_depth_std_mm", "cem43_depth_mm", "cem43_depth_std_mm"):
        assert maps[name].shape == (h, w) and np.isfinite(maps[name]).all()
        assert str(maps[f"units_{name}"]) == "mm"
    z = maps["depth_mm"]
    assert z[0] == 0.0 and maps["peak_temperature_depth"].shape == maps["omega_depth"].shape == (z.size, h, w)
    # The same numbers as the library call, and close to the independent simulator's truth.
    expected = depth_features(burn["frames"], burn["result"].dt, burn["result"].dx)
    np.testing.assert_allclose(
        maps["damage_depth_mm"], expected.maps["damage_depth_mm"][0].numpy(), rtol=1e-12
    )
    truth = burn["result"].damage_depth
    assert record["damage_depth_mm_max"] == pytest.approx(truth.max(), abs=0.03)
    assert 0.1 < truth.max() < 0.4


def test_depth_report_draws_the_map_and_profiles(
    burn: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "report"
    code, out, err = run(capsys, "features", burn["video"], "--depth", "--report", folder)
    assert (code, err) == (0, "")
    assert "damage_depth_mm_max:" in out and f"report: {folder / 'depth.md'}" in out
    text = (folder / "depth.md").read_text()
    assert "![damage depth map](depth_map.png)" in text and "| diffusivity a |" in text
    assert (folder / "depth_map.png").stat().st_size > 0 and (
        folder / "depth_profiles.png"
    ).stat().st_size > 0


def test_depth_without_pixel_size_says_why(burn: dict, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "features", burn["no_dx"], "--depth", "--json")
    assert code == 0
    record = json.loads(out)
    assert record["depth"] is None
    assert record["absent"]["damage_depth_mm"] == "no pixel size (pass dx, --dx in mm)"


def test_report_needs_depth(burn: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "features", burn["video"], "--report", tmp_path)
    assert code == 2
    assert "--report draws the depth maps: pass --depth with it" in err


def test_thickness_is_stated(burn: dict, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "features", burn["video"], "--depth", "--thickness", "8", "--json")
    assert (code, err) == (0, "")
    assert json.loads(out)["depth"]["geometry"].startswith("layer of 8 mm")
