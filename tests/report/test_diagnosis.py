"""The diagnosis report (:mod:`anra_torch.report.diagnosis`): the table states the diagnosis and the
forecasts' numbers as computed, the effects found with their parameters, and the three figures."""

from __future__ import annotations

from pathlib import Path

import pytest

from anra_torch.effects import hidden_effect_video
from anra_torch.forecast import assess_gain
from anra_torch.report import DIAGNOSIS_FIGURES, write_diagnosis_report
from anra_torch.video import Video

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_the_report_states_the_diagnosis_and_the_forecasts(tmp_path: Path) -> None:
    truth = hidden_effect_video(["source"], seed=1, size=40, duration=1.0)  # 31 frames: a moving source
    video = Video(truth.frames, truth.dt, truth.dx)
    gain = assess_gain(video.frames, video.dt, video.dx)
    diagnosis = gain.diagnosis
    path = write_diagnosis_report(tmp_path / "out", video, diagnosis, gain)
    assert path == tmp_path / "out" / "report.md"
    text = path.read_text(encoding="utf-8")
    assert text.startswith("# Hidden-effect diagnosis: <memory>")
    assert "| video | 31 frames of 40 x 40 px, dt = 0.0333333 s, dx = 0.5 mm |" in text
    assert f"| plain diffusivity a | {diagnosis.a_plain:.5g} mm^2/s |" in text
    assert f"| gain 1 - RMSE_ext / RMSE_plain | {gain.gain:.3f} |" in text
    assert f"| diagnosed frames | 0-{gain.split}; forecast {gain.held_out} held-out frames |" in text
    (source,) = diagnosis.effects
    assert source["name"] == "source" and f"- **source** (score {source['score']:.1f}): " in text
    assert f"x0 = {source['params']['x0']:.4g}" in text
    assert DIAGNOSIS_FIGURES == ("forecast.png", "maps.png", "rmse.png")
    for name in DIAGNOSIS_FIGURES:
        assert (tmp_path / "out" / name).read_bytes()[:8] == PNG_MAGIC, name
        assert f"]({name})" in text
    with pytest.raises(ValueError, match=r"video\.dx is None; the report needs the pixel size in mm"):
        write_diagnosis_report(tmp_path / "none", Video(truth.frames, truth.dt, None), diagnosis, gain)
