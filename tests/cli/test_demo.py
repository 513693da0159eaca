"""``anra demo`` (:mod:`anra_torch.cli.demo`): the report, its figures, the full-size run's accuracy."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from commands import run

import anra_torch.cli.demo as demo_command
from anra_torch.simulation.synthetic import paper_video


# ------------------------------------------------------------------------------------------------ demo
@pytest.mark.slow
def test_demo_writes_report_and_figures(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # The same pipeline on the central 96 px of the paper's video, to keep the fast suite fast.
    monkeypatch.setattr(demo_command, "paper_video", lambda **kw: paper_video(crop=96, **kw))
    code, out, err = run(capsys, "demo", "--out", tmp_path / "demo")
    assert (code, err) == (0, "")
    for name in (
        "report.md",
        "paper_simulation.npz",
        "frames.png",
        "attention.png",
        "field.png",
        "per_frame.png",
    ):
        assert (tmp_path / "demo" / name).stat().st_size > 0, name
    assert re.search(r"estimate a = 0\.\d+ ± 0\.\d+ mm\^2/s, error [-+][\d.e-]+ % against 0\.2", out)
    assert f"report: {tmp_path / 'demo' / 'report.md'}" in out and re.search(r"estimated in [\d.]+ s", out)


@pytest.mark.slow
def test_demo_full_size_is_accurate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The demo's default, the paper's full frame (its speed is measured by the benchmarks, not here)."""
    code, out, err = run(capsys, "demo", "--out", tmp_path)
    assert (code, err) == (0, "")
    assert "224 x 224 px" in out
    error = float(re.search(r"error ([-+][\d.e-]+) %", out).group(1))
    assert abs(error) < 1.0
    assert (tmp_path / "report.md").is_file() and len(list(tmp_path.glob("*.png"))) == 4
