"""The report of a recording's phases (:mod:`anra_torch.report.phases`): the table states each phase's
numbers as the analysis found them, with the timeline and each phase's forecast figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scenes import DT, DX, heated_then_cooled, short_heating_phases

from anra_torch.report import write_phase_report
from anra_torch.report.phases import forecast_figure
from anra_torch.video import Video

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_the_table_holds_each_phases_analysis_and_the_figures_exist(tmp_path: Path) -> None:
    phases = short_heating_phases(9)  # 10 heating frames, then cooling (shared with the analysis's tests)
    video = Video(torch.as_tensor(heated_then_cooled(off=9, n=30)), DT, DX, source=tmp_path / "spot.npz")
    path = write_phase_report(tmp_path / "report", video, phases)
    assert path == tmp_path / "report" / "phases.md"
    text = path.read_text()
    assert text.startswith("# Phases of spot.npz")
    rows = [
        line for line in text.splitlines() if line.startswith("| heating |") or line.startswith("| cooling |")
    ]
    assert len(rows) == 2
    for row, phase in zip(rows, phases, strict=True):
        assert f"| {phase.phase.start}-{phase.phase.stop - 1} |" in row
        assert f"{phase.family}; {phase.model}" in row and f"{phase.gain:+.2f}" in row
    assert (tmp_path / "report" / "phases.png").read_bytes()[:8] == PNG_MAGIC
    forecasts = sorted((tmp_path / "report").glob("phase_*.png"))
    assert [p.name for p in forecasts] == ["phase_0_heating.png", "phase_1_cooling.png"]
    assert all(f"]({p.name})" in text for p in forecasts)


def test_a_forecast_figure_is_written(tmp_path: Path) -> None:
    measured = np.random.default_rng(0).normal(size=(3, 8, 9))
    forecast_figure(tmp_path / "f.png", "title", (measured, measured + 0.1, measured * 0.0), "K")
    assert (tmp_path / "f.png").read_bytes()[:8] == PNG_MAGIC
