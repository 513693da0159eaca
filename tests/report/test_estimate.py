"""Tests for anra_torch.report: the Markdown report, its figures, the attention map and the error paths."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import pytest
import torch

from anra_torch.estimation.estimator import ANRAEstimator, ANRAResult
from anra_torch.layers import GaussianSmoothing
from anra_torch.report import FIGURES, attention_map, format_pm, write_estimate_report
from anra_torch.simulation.synthetic import paper_video
from anra_torch.video import Video, load_video, save_npz

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def case(tmp_path_factory: pytest.TempPathFactory) -> tuple[Video, ANRAEstimator, ANRAResult]:
    """A 64 px crop of the paper's video, read back from disk, and its windowed estimate."""
    synthetic = paper_video(crop=64)
    path = save_npz(
        tmp_path_factory.mktemp("video") / "paper.npz",
        synthetic.frames[0],
        dt=synthetic.dt,
        dx=synthetic.dx,
        t=synthetic.times,
        a_true=synthetic.a,
    )
    video = load_video(path)
    estimator = ANRAEstimator(window=15)
    return video, estimator, estimator(video.frames, video.dt, video.dx)


@pytest.mark.slow
def test_report_writes_markdown_and_all_figures(tmp_path: Path, case: tuple) -> None:
    video, estimator, result = case
    report = write_estimate_report(tmp_path / "out", video, result, truth=0.2, estimator=estimator)
    assert report == tmp_path / "out" / "report.md"
    for name in FIGURES:
        figure = tmp_path / "out" / name
        assert figure.read_bytes()[:8] == PNG_MAGIC, name
        assert figure.stat().st_size > 5_000, name
        assert f"]({name})" in report.read_text()
    text = report.read_text()
    a, se = float(result.diffusivity), float(result.std_error)
    assert format_pm(a, se, "mm^2/s") in text
    assert "| truth | 0.2 mm^2/s (error " in text
    assert f"{video.frames.shape[0]} frames of 64 x 64 px" in text
    assert "| mode | lsq |" in text and "(15 px windows)" in text
    assert "Shown for reference (the paper's form): this estimator weighted pixels with" in text
    for unit in ("mm^2/s", " s ", " mm ", " px "):
        assert unit in text


def test_report_without_field_or_truth(tmp_path: Path, case: tuple) -> None:
    video, _, result = case
    plain = dataclasses.replace(result, field=None, confidence=None)
    report = write_estimate_report(tmp_path, video, plain)
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["attention.png", "frames.png", "per_frame.png"]
    text = report.read_text()
    assert "Not computed: estimate with a window" in text and "truth" not in text


def test_report_of_ratio_mode_with_wild_frames(tmp_path: Path, case: tuple) -> None:
    video, _, _ = case
    estimator = ANRAEstimator(mode="ratio", smoothing=0.0, strict=False)
    result = estimator(video.frames, video.dt, video.dx)
    report = write_estimate_report(tmp_path, video, result, truth=0.2, estimator=estimator)
    text = report.read_text()
    assert "| mode | ratio |" in text and "The estimator weighted its pixels with these." in text
    assert (tmp_path / "per_frame.png").read_bytes()[:8] == PNG_MAGIC


def test_attention_map_is_rtc_on_the_smoothed_rate(case: tuple) -> None:
    video, estimator, result = case
    weights = attention_map(video, result, estimator)
    assert weights.shape == video.frames.shape[1:]
    inside = torch.isfinite(weights)
    margin = GaussianSmoothing(float(result.smoothing)).radius
    assert not inside[:margin].any() and not inside[:, -margin:].any()
    assert inside[margin:-margin, margin:-margin].all()
    assert float(weights[inside].sum()) == pytest.approx(1.0, rel=1e-9)
    # The paper's blob sits in the centre, where the temperature falls fastest.
    peak = divmod(int(torch.nan_to_num(weights, nan=-1.0).argmax()), weights.shape[1])
    assert all(abs(p - 31.5) <= 3 for p in peak)
    # Without the estimator the defaults give the same weights.
    torch.testing.assert_close(attention_map(video, result), weights, equal_nan=True)


def test_attention_map_hides_pixels_next_to_masked_ones(case: tuple) -> None:
    video, estimator, _ = case
    frames = video.frames.clone()
    frames[:, 20, 20] = math.nan
    holey = dataclasses.replace(video, frames=frames)
    result = ANRAEstimator(smoothing=1.0)(frames, video.dt, video.dx)
    weights = attention_map(holey, result, estimator)
    assert torch.isnan(weights[20, 20]) and torch.isnan(weights[18, 22])
    assert float(weights[torch.isfinite(weights)].sum()) == pytest.approx(1.0, rel=1e-9)


def test_report_rejects_batched_results_and_missing_dx(tmp_path: Path, case: tuple) -> None:
    video, _, _ = case
    batch = paper_video(n_videos=2, size=48)
    batched = ANRAEstimator(smoothing=1.0)(batch.frames, batch.dt, batch.dx)
    with pytest.raises(ValueError, match=r"result must be for a single video, got a batch of 2"):
        write_estimate_report(tmp_path, video, batched)
    no_dx = dataclasses.replace(video, dx=None)
    with pytest.raises(ValueError, match=r"video\.dx is None; the report needs the pixel size in mm"):
        write_estimate_report(tmp_path, no_dx, ANRAEstimator(smoothing=1.0)(video.frames, video.dt, 0.1))
    assert not list(tmp_path.iterdir())


def test_report_without_matplotlib_names_the_extra(
    tmp_path: Path, case: tuple, monkeypatch: pytest.MonkeyPatch
) -> None:
    video, _, result = case
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(ImportError, match=r"pip install anra_torch\[plot\]"):
        write_estimate_report(tmp_path, video, result)


@pytest.mark.slow
def test_report_leaves_the_pyplot_backend_alone(tmp_path: Path, case: tuple) -> None:
    import matplotlib

    video, _, result = case
    before = matplotlib.rcParams["backend"]
    write_estimate_report(tmp_path, video, result)
    assert matplotlib.rcParams["backend"] == before
