"""``anra estimate`` (:mod:`anra_torch.cli.estimate`): the JSON record and the human summary, flags, masked
and dead pixels, the phases, recordings read in chunks, real files.

Contract for a video without thermal activity: ``anra estimate`` exits with status 2 and one
``anra: error: ...`` line on stderr; with ``--json`` it also prints the flagged record on stdout
(``"valid": false``, ``"diffusivity": null``, the reason in ``"message"``) so batch scripts keep a row.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from commands import assert_one_line_error, run
from scenes import DT, DX, heated_then_cooled
from shared_data import DATA, needs_data

from anra_torch import ANRAEstimator
from anra_torch.cli import main
from anra_torch.video import load_video, save_npz

JSON_KEYS = {
    "path",
    "noise",
    "artefacts",
    "diffusivity",
    "std_error",
    "valid",
    "message",
    "warnings",
    "frames",
    "height",
    "width",
    "dt",
    "dx",
    "mode",
    "smoothing_px",
    "noise_sd",
    "reliability",
    "explained",
    "n_masked",
    "window_px",
    "field_median",
    "field_coverage",
    "a_true",
    "elapsed_s",
    "units",
    "phase",
    "phases",
    "chunked",
    "depth_aware",
}


def estimate_json(capsys: pytest.CaptureFixture[str], *argv: object) -> dict:
    code, out, err = run(capsys, "estimate", *argv, "--json")
    assert (code, err) == (0, "")
    assert out.count("\n") == 1  # one JSON object on one line
    return json.loads(out)


# ------------------------------------------------------------------------------------------- estimate
def test_estimate_json_recovers_the_paper_diffusivity(
    paper96: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = estimate_json(capsys, paper96)
    assert set(s) == JSON_KEYS
    assert s["diffusivity"] == pytest.approx(0.2, rel=0.01)
    assert 0 < s["std_error"] < 0.002
    assert s["valid"] is True and s["message"] == "" and s["warnings"] == []
    assert (s["frames"], s["height"], s["width"]) == (28, 96, 96)
    assert s["dt"] == pytest.approx(1 / 27) and s["dx"] == pytest.approx(10 / 224)
    assert s["mode"] == "lsq" and s["smoothing_px"] >= 0 and s["n_masked"] == 0
    assert s["noise_sd"] == pytest.approx(0.01, rel=0.05)
    assert 0.9 < s["reliability"] <= 1.0
    assert s["a_true"] == 0.2 and s["path"] == str(paper96)
    assert s["units"]["diffusivity"] == "mm^2/s" and s["units"]["dt"] == "s" and s["units"]["dx"] == "mm"
    assert (s["window_px"], s["field_median"], s["field_coverage"]) == (None, None, None)
    # the measured noise model and the artefacts: white noise of 0.01, nothing found
    assert s["noise"]["white"] is True and s["noise"]["sd"] == pytest.approx(s["noise_sd"])
    assert s["artefacts"] == {
        "bad_pixels": [],
        "spikes": 0,
        "non_finite": 0,
        "fixed_pattern": False,
        "pattern_sd": 0.0,
        "steps": [],
        "step_sizes": [],
        "fixed_effects": [],
    }


def test_to_record_is_what_estimate_json_prints(paper96: Path, capsys: pytest.CaptureFixture[str]) -> None:
    s = estimate_json(capsys, paper96)
    video = load_video(paper96)
    record = ANRAEstimator(strict=False)(video.frames, video.dt, video.dx).to_record(unit=video.unit)
    units = record.pop("units")
    assert {k: s[k] for k in record} == record
    assert {k: s["units"][k] for k in units} == units
    # A batched result: one record per video, the same as each video's own.
    frames = torch.stack([video.frames, video.frames.flip(-1)])
    batched = ANRAEstimator(strict=False)(frames, video.dt, video.dx)
    alone = ANRAEstimator(strict=False)(frames[1], video.dt, video.dx)
    assert batched.to_record(1)["diffusivity"] == pytest.approx(alone.to_record()["diffusivity"], rel=1e-9)
    with pytest.raises(ValueError, match=r"index must be an integer in \[0, 2\) for this result, got 2"):
        batched.to_record(2)


def test_estimate_human_summary(paper96: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "estimate", paper96)
    assert (code, err) == (0, "")
    assert re.search(r"diffusivity a = 0\.\d+ ± 0\.\d+ mm\^2/s \(lsq", out)
    assert "28 frames of 96 x 96 px, dt = 0.037037 s (27 Hz), dx = 0.0446429 mm" in out
    assert "px (chosen from the data)" in out and "noise sd" in out and "reliability" in out
    assert "file's a_true = 0.2 mm^2/s (error" in out


def test_estimate_flags_override_the_file(paper96: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = estimate_json(capsys, paper96)
    # a is in units of dx^2 / dt: the estimator is exactly linear in 1/dt and dx^2.
    slower = estimate_json(capsys, paper96, "--dt", 2 / 27)
    coarser = estimate_json(capsys, paper96, "--dx", 20 / 224)
    assert slower["dt"] == pytest.approx(2 / 27) and coarser["dx"] == pytest.approx(20 / 224)
    assert slower["diffusivity"] == pytest.approx(base["diffusivity"] / 2, rel=1e-9)
    assert coarser["diffusivity"] == pytest.approx(base["diffusivity"] * 4, rel=1e-9)


def test_estimate_window_and_ratio_mode(paper96: Path, capsys: pytest.CaptureFixture[str]) -> None:
    field = estimate_json(capsys, paper96, "--window", "15")
    assert field["window_px"] == 15 and 0 < field["field_coverage"] <= 1
    assert field["field_median"] == pytest.approx(0.2, rel=0.01)
    ratio = estimate_json(capsys, paper96, "--mode", "ratio")
    # The paper's ratio estimator as published is erratic on noisy data; the CLI must pass it through as is.
    with np.load(paper96) as data:
        direct = ANRAEstimator(mode="ratio")(
            torch.from_numpy(data["frames"]), float(data["dt"]), float(data["dx"])
        )
    assert ratio["mode"] == "ratio" and ratio["diffusivity"] == pytest.approx(
        float(direct.diffusivity), rel=1e-9
    )


def _variant(source: Path, path: Path, **changes: object) -> Path:
    with np.load(source) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update(changes)
    np.savez(path, **arrays)
    return path


def test_nan_pixels_are_masked_and_counted(
    paper96: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with np.load(paper96) as data:
        frames = data["frames"].copy()
    frames[:, 3, 4] = np.nan  # a dead pixel near the border
    frames[10, 20:22, 70:73] = np.inf  # a glitch in one frame
    s = estimate_json(capsys, _variant(paper96, tmp_path / "nan.npz", frames=frames))
    assert s["n_masked"] == 28 + 6
    assert s["valid"] is True and math.isfinite(s["diffusivity"])
    assert s["diffusivity"] == pytest.approx(0.2, rel=0.01)


def test_dead_pixel_near_the_centre_still_gives_an_estimate(
    paper96: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with np.load(paper96) as data:
        frames = data["frames"].copy()
    frames[:, 40, 40] = np.nan
    s = estimate_json(capsys, _variant(paper96, tmp_path / "dead.npz", frames=frames))
    assert s["n_masked"] == 28 and s["diffusivity"] == pytest.approx(0.2, rel=0.01)


def test_integer_frames_work(paper96: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with np.load(paper96) as data:
        counts = np.round(20000 + 1000 * data["frames"]).astype(np.uint16)  # 1 count = 1 mK
    s = estimate_json(capsys, _variant(paper96, tmp_path / "counts.npz", frames=counts))
    assert s["diffusivity"] == pytest.approx(0.2, rel=0.01)
    assert s["noise_sd"] == pytest.approx(10.0, rel=0.05)  # in counts


def test_video_without_thermal_activity_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(0)
    still = 30.0 + 0.01 * rng.standard_normal((20, 48, 48))  # a constant scene seen through sensor noise
    path = tmp_path / "still.npz"
    np.savez(path, frames=still, dt=0.04, dx=0.1)
    assert_one_line_error(run(capsys, "estimate", path), r"still\.npz: frames show no thermal activity")
    code, out, err = run(capsys, "estimate", path, "--json")
    assert code == 2 and err.count("\n") == 1 and "no thermal activity" in err
    s = json.loads(out)
    assert s["valid"] is False and s["diffusivity"] is None and s["std_error"] is None
    assert "no thermal activity" in s["message"]


def test_exactly_constant_video_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "flat.npz"
    np.savez(path, frames=np.full((20, 48, 48), 3.0), dt=0.04, dx=0.1)
    assert_one_line_error(run(capsys, "estimate", path), r"no thermal activity")


def test_a_large_recording_is_read_in_chunks_with_the_same_estimate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Above CHUNKED_VALUES an uncompressed .npz is read chunk by chunk: same diffusivity within its error."""
    from anra_torch.recording import plan as recording_plan
    from anra_torch.simulation import gaussian_blob
    from anra_torch.video import save_npz

    t = torch.arange(90, dtype=torch.float64) / 27
    clean = gaussian_blob(t, shape=(48, 56), dx=0.1, a=0.2, peak=3.0, sigma=1.0)
    noisy = clean + 0.01 * torch.randn(
        clean.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64
    )
    path = save_npz(tmp_path / "v.npz", noisy.float(), dt=1 / 27, dx=0.1)
    whole = estimate_json(capsys, path)
    assert whole["chunked"] is None
    monkeypatch.setattr(recording_plan, "CHUNKED_VALUES", 10_000)  # the name the recording policy reads
    chunked = estimate_json(capsys, path)
    assert set(chunked) == JSON_KEYS and chunked["frames"] == 90
    # The pilot reads at most a third of a recording: one block of 16 frames here, in its middle.
    assert chunked["chunked"]["frames_used"] == 90 and chunked["chunked"]["pilot"] == [[37, 53]]
    assert abs(chunked["diffusivity"] - whole["diffusivity"]) < 2 * whole["std_error"]
    assert chunked["std_error"] == pytest.approx(whole["std_error"], rel=0.25)
    precise = estimate_json(capsys, path, "--precision", "1%")
    assert precise["chunked"]["frames_used"] < 90 and precise["std_error"] <= 0.01 * precise["diffusivity"]
    code, out, _ = run(capsys, "estimate", path, "--precision", "1%")
    assert code == 0 and "of 90 frames used" in out


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (
            ["--precision", "0"],
            r"argument --precision: must be a relative standard error in \(0, 100%\), got '0'",
        ),
        (
            ["--precision", "abc"],
            r"argument --precision: must be a relative standard error like 0.1% or 0.001",
        ),
        (
            ["--precision", "1%", "--window", "5"],
            r"--precision reads the recording in chunks: it needs --mode lsq",
        ),
    ],
)
def test_bad_precision_gets_a_one_line_error(
    paper96: Path, capsys: pytest.CaptureFixture[str], argv: list[str], match: str
) -> None:
    assert_one_line_error(run(capsys, "estimate", paper96, *argv), match)


def test_estimate_gives_phase_times_in_seconds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A uniform video has no timestamps: the phases' times are frame numbers times dt, as in diagnose."""
    path = save_npz(tmp_path / "laser.npz", heated_then_cooled(off=60), dt=DT, dx=DX)
    main(["estimate", str(path), "--json"])
    heating, cooling = json.loads(capsys.readouterr().out)["phases"]
    assert heating["t_start"] == 0.0 and cooling["t_start"] == pytest.approx(cooling["start_frame"] * DT)
    assert cooling["t_stop"] == pytest.approx((cooling["stop_frame"] - 1) * DT)


@needs_data
def test_cli_estimates_a_flir_folder_and_says_it_resampled(capsys: pytest.CaptureFixture[str]) -> None:
    folder = DATA / "laser_silicone" / "Nov19_2"
    assert (
        main(["estimate", str(folder), "--dx", "0.55", "--resample", "--roi", "30,20,70,60", "--json"]) == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert out["input"]["resampled"]["from_frames"] == 25
    assert [p["kind"] for p in out["phases"]] == ["heating", "cooling"] and out["phase"] == "cooling"
    assert out["frames"] == out["phases"][1]["stop_frame"] - out["phases"][1]["start_frame"]
    assert (out["height"], out["width"]) == (60, 70) and out["input"]["roi"] == [30, 20, 70, 60]
    assert out["dt"] == pytest.approx(4.994, abs=1e-3)


def test_a_single_frame_has_no_time_axis_with_or_without_dt(tmp_path: Path, capsys) -> None:
    """One message, whether or not --dt is given: a frame period would not give it a time axis."""
    frame = save_npz(tmp_path / "frame.npz", np.random.default_rng(0).random((1, 24, 24)), dt=0.1, dx=0.1)
    np.savez(tmp_path / "stamp.npz", frames=np.ones((1, 24, 24)), t=np.zeros(1), dx=0.1)
    for argv in (
        [frame],
        [frame, "--dt", "0.1"],
        [tmp_path / "stamp.npz"],
        [tmp_path / "stamp.npz", "--dt", "1"],
    ):
        for command in ("estimate", "diagnose"):
            assert_one_line_error(
                run(capsys, command, *argv),
                r"(frame|stamp)\.npz: a single frame has no time axis; this needs",
            )
