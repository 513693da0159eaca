"""``anra features --depth --report``: the depth report draws the damage-depth map and the depth profiles."""

from __future__ import annotations

from pathlib import Path

import pytest
from commands import run
from depth_scenes import beam_recording


@pytest.fixture(scope="module")
def depth_burn(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A 0.4 mm beam for 3 s on skin-like tissue (independent 3-D simulator), 3 s of cooling, 0.2 K noise."""
    return beam_recording(tmp_path_factory.mktemp("depth"))


@pytest.mark.slow
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
