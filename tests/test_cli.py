"""Tests for anra_torch.cli: estimate, simulate and demo in-process, one-line errors, the entry points.

Contract for a video without thermal activity: ``anra estimate`` exits with status 2 and one
``anra: error: ...`` line on stderr; with ``--json`` it also prints the flagged record on stdout
(``"valid": false``, ``"diffusivity": null``, the reason in ``"message"``) so batch scripts keep a row.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import anra_torch.cli.demo as demo_command
from anra_torch import ANRAEstimator
from anra_torch.cli import main
from anra_torch.simulation.synthetic import paper_video
from anra_torch.video import load_video

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


def run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def estimate_json(capsys: pytest.CaptureFixture[str], *argv: object) -> dict:
    code, out, err = run(capsys, "estimate", *argv, "--json")
    assert (code, err) == (0, "")
    assert out.count("\n") == 1  # one JSON object on one line
    return json.loads(out)


def assert_one_line_error(result: tuple[int, str, str], match: str) -> str:
    code, out, err = result
    assert code == 2
    assert out == ""
    assert err.startswith("anra: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert re.search(match, err), err
    return err


@pytest.fixture(scope="module")
def paper96(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The paper's case cropped to its central 96 x 96 px, written by ``anra simulate``."""
    path = tmp_path_factory.mktemp("cli") / "paper96.npz"
    assert main(["simulate", "--crop", "96", "-o", str(path)]) == 0
    return path


# ------------------------------------------------------------------------------------------- simulate
def test_simulate_writes_a_readable_npz(paper96: Path) -> None:
    with np.load(paper96) as data:
        assert set(data.files) == {"frames", "dt", "dx", "t", "a_true", "noise_sd", "seed", "preset"}
        assert data["frames"].shape == (28, 96, 96)
        assert float(data["dt"]) == pytest.approx(1 / 27) and float(data["dx"]) == pytest.approx(10 / 224)
        np.testing.assert_allclose(data["t"], np.arange(28) / 27)
        assert float(data["a_true"]) == 0.2 and str(data["preset"]) == "paper"
        # The crop is the centre of the paper's full video, noise included.
        full = paper_video(noise_sd=0.01, seed=0).frames[0, :, 64:160, 64:160].numpy()
        np.testing.assert_array_equal(data["frames"], full)


def test_simulate_flags(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(
        capsys,
        *("simulate", "--a", "0.1", "--noise", "0", "--fps", "10", "--frames", "9", "--size", "40"),
        *("--dx", "0.25", "-o", tmp_path / "p"),
    )
    assert code == 0 and f"wrote {tmp_path / 'p.npz'}: 9 frames of 40 x 40 px" in out
    with np.load(tmp_path / "p.npz") as data:
        assert (float(data["a_true"]), float(data["dx"]), float(data["dt"])) == (0.1, 0.25, 0.1)
        clean = paper_video(noise_sd=0.0, fps=10, duration=0.8, size=40, extent=10.0, a=0.1).clean.numpy()
        np.testing.assert_allclose(data["frames"], clean, rtol=0, atol=1e-12)


def test_simulate_blobs_preset_with_duration_and_crop(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = (
        "simulate",
        "--preset",
        "blobs",
        "--duration",
        "0.5",
        "--fps",
        "20",
        "--crop",
        "32",
        "--seed",
        "3",
    )
    code, _, _ = run(capsys, *argv, "-o", tmp_path / "b.npz")
    assert code == 0
    with np.load(tmp_path / "b.npz") as data:
        assert data["frames"].shape == (11, 32, 32)
        assert (float(data["a_true"]), float(data["dx"]), int(data["seed"])) == (0.15, 0.5, 3)


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


# --------------------------------------------------------------------------------------------- errors
def _bad_files(tmp: Path, paper96: Path) -> dict[str, tuple[list[object], str]]:
    frames = np.zeros((8, 16, 16))
    np.save(tmp / "raw.npy", frames)
    np.savez(tmp / "noframes.npz", video=frames, dt=0.1)
    np.savez(tmp / "flat2d.npz", frames=frames[0], dt=0.1, dx=0.1)
    np.savez(tmp / "nodx.npz", frames=frames, dt=0.1)
    np.savez(tmp / "short.npz", frames=frames[:3], dt=0.1, dx=0.1)
    (tmp / "trunc.npz").write_bytes(paper96.read_bytes()[:5000])
    (tmp / "clip.avi").write_bytes(b"RIFF")
    return {
        "missing file": (["estimate", tmp / "none.npz"], r"none\.npz: no such file"),
        "unknown suffix": (
            ["estimate", tmp / "clip.avi"],
            r"unknown video format '\.avi'; expected one of: .*\.npz",
        ),
        "npy without dt": (["estimate", tmp / "raw.npy"], r"raw\.npy: no frame period: .*--dt"),
        "npy without dx": (
            ["estimate", tmp / "raw.npy", "--dt", "0.1"],
            r"raw\.npy: no pixel size: .*--dx in mm",
        ),
        "npz without dx": (["estimate", tmp / "nodx.npz"], r"nodx\.npz: no pixel size"),
        "no frames": (["estimate", tmp / "noframes.npz"], r"noframes\.npz: no 'frames' array"),
        "wrong ndim": (
            ["estimate", tmp / "flat2d.npz"],
            r"frames must have shape \(T, H, W\), got \(16, 16\)",
        ),
        "too few frames": (["estimate", tmp / "short.npz"], r"short\.npz: .*at least 5 frames"),
        "truncated": (
            ["estimate", tmp / "trunc.npz"],
            r"trunc\.npz: cannot read as \.npz .*truncated or corrupt",
        ),
        "negative dt": (
            ["estimate", paper96, "--dt", "-1"],
            r"argument --dt: must be a positive number in s",
        ),
        "text dx": (["estimate", paper96, "--dx", "wide"], r"argument --dx: must be a positive number in mm"),
        "even window": (
            ["estimate", paper96, "--window", "14"],
            r"argument --window: must be an odd integer",
        ),
        "unknown mode": (["estimate", paper96, "--mode", "fast"], r"argument --mode: invalid choice: 'fast'"),
        "no command": ([], r"required: COMMAND \(see 'anra --help'\)"),
        "unknown command": (["fit"], r"invalid choice: 'fit'"),
        "frames and duration": (
            ["simulate", "--frames", "5", "--duration", "1", "-o", tmp / "x.npz"],
            r"argument --duration: not allowed with argument --frames",
        ),
        "no output": (["simulate"], r"required: -o/--out"),
        "crop too large": (
            ["simulate", "--size", "32", "--crop", "64", "-o", tmp / "x.npz"],
            r"--crop must be at",
        ),
        "negative noise": (["simulate", "--noise", "-1", "-o", tmp / "x.npz"], r"non-negative number"),
    }


BAD_CASES = [
    "missing file",
    "unknown suffix",
    "npy without dt",
    "npy without dx",
    "npz without dx",
    "no frames",
    "wrong ndim",
    "too few frames",
    "truncated",
    "negative dt",
    "text dx",
    "even window",
    "unknown mode",
    "no command",
    "unknown command",
    "frames and duration",
    "no output",
    "crop too large",
    "negative noise",
]


@pytest.mark.parametrize("case", BAD_CASES)
def test_bad_input_gives_one_line_error_and_exit_2(
    case: str, paper96: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cases = _bad_files(tmp_path, paper96)
    assert set(cases) == set(BAD_CASES)
    argv, match = cases[case]
    assert_one_line_error(run(capsys, *argv), match)
    assert not (tmp_path / "x.npz").exists()


def test_help_texts_state_units(capsys: pytest.CaptureFixture[str]) -> None:
    for command, units in {
        (): ("mm^2/s", "mm,", " s,"),
        ("estimate",): ("in s", "in mm", "mm^2/s", "(T, H, W)"),
        ("simulate",): ("mm^2/s", "Hz", "in mm", "in px", "in s"),
        ("demo",): ("mm^2/s", "mm", "Hz"),
    }.items():
        code, out, err = run(capsys, *command, "--help")
        assert (code, err) == (0, "")
        text = " ".join(out.split())
        for unit in units:
            assert unit in text, (command, unit)


@pytest.mark.slow
def test_entry_points_run_outside_the_process(tmp_path: Path) -> None:
    helped = subprocess.run(
        [sys.executable, "-m", "anra_torch", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert helped.returncode == 0 and helped.stdout.startswith("usage: anra ")
    script = Path(sys.executable).with_name("anra")
    failed = subprocess.run(
        [str(script), "estimate", str(tmp_path / "none.npz")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert failed.returncode == 2 and failed.stdout == ""
    assert failed.stderr == f"anra: error: {tmp_path / 'none.npz'}: no such file\n"


# ------------------------------------------------------------------------------------------------ demo
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


def test_threads_option_sets_torch_threads(paper96: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = torch.get_num_threads()
    try:
        assert main(["--threads", "1", "estimate", str(paper96), "--json"]) == 0
        assert torch.get_num_threads() == 1
        assert json.loads(capsys.readouterr().out)["diffusivity"] == pytest.approx(0.2, rel=0.01)
        assert main(["--threads", "0", "estimate", str(paper96)]) == 2
        assert "argument --threads: must be an integer >= 1" in capsys.readouterr().err
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize(("running", "expected"), [(1, 4), (2, 3), (4, 1), (9, 1)])
def test_default_threads_leave_the_cores_other_processes_run_on(
    tmp_path: Path, running: int, expected: int
) -> None:
    from anra_torch.cli import free_cores

    loadavg = tmp_path / "loadavg"
    loadavg.write_text(f"3.93 4.27 4.78 {running}/88 20791\n")  # the runnable count includes this process
    assert free_cores(4, loadavg) == expected
    assert free_cores(4, tmp_path / "absent") == 4


def test_the_default_thread_count_does_not_shrink_call_after_call(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The free-core default starts from the process's own count each time, not from the last command's."""
    import anra_torch.cli as cli

    bases: list[int] = []
    monkeypatch.setattr(cli, "free_cores", lambda cores: bases.append(cores) or max(1, cores - 1))
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(4)  # each call's default then sets fewer
        for seed in range(3):
            argv = ["simulate", "--size", "16", "--frames", "8", "--seed", str(seed)]
            assert main([*argv, "-o", str(tmp_path / f"v{seed}.npz")]) == 0
    finally:
        torch.set_num_threads(before)
    assert len(bases) == 3 and len(set(bases)) == 1


def test_a_large_recording_is_read_in_chunks_with_the_same_estimate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Above CHUNKED_VALUES an uncompressed .npz is read chunk by chunk: same diffusivity within its error."""
    from anra_torch.recording import estimate as estimate_policy
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
    monkeypatch.setattr(estimate_policy, "CHUNKED_VALUES", 10_000)  # the name the recording policy reads
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
