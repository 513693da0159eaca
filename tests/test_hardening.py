"""The hardening issue's table, row by row: hostile input values, spacings and files through the CLI.

The input policy (:mod:`anra_torch.video.prepare`): a sample that is non-finite or beyond +-1e6 data units
is masked and counted, the same way for estimate, diagnose, features and batch; a video with no sample left
is refused in one line; dt and dx must lie in 1e-6..1e6 s / mm. Results carry ``warnings`` (an implausible
or negative diffusivity, a model that does not explain the data) and JSON never holds NaN or inf. Each test
checks its row against an independent reference: the same video without the bad sample, the library called
directly, or arithmetic on the printed numbers.
"""

from __future__ import annotations

import contextlib
import csv
import io
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from commands import run, strict_json

from anra_torch import ANRAEstimator
from anra_torch.checks import VALUE_LIMIT
from anra_torch.cli import main
from anra_torch.video import CalibrationTable, input_warnings, prepare_video


def one_line_error(code: int, out: str, err: str, match: str) -> None:
    assert code == 2, (code, err)
    assert err.startswith("anra: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err and re.search(match, err), err
    assert not re.search(r"\bnan\b", err, re.IGNORECASE), err


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The paper's case at 32 x 32 px, 30 frames (dx = 0.3125 mm, a = 0.2 mm^2/s), from ``anra simulate``."""
    path = tmp_path_factory.mktemp("hardening") / "clean.npz"
    assert main(["simulate", "--size", "32", "--frames", "30", "-o", str(path)]) == 0
    return path


def variant(clean: Path, path: Path, frames: np.ndarray) -> Path:
    with np.load(clean) as data:
        arrays = {k: data[k] for k in data.files}
    np.savez(path, **{**arrays, "frames": frames})
    return path


def frames_of(clean: Path, dtype: type = np.float64) -> np.ndarray:
    with np.load(clean) as data:
        return data["frames"].astype(dtype)


def spiked(clean: Path, tmp_path: Path, value: float, dtype: type = np.float64) -> tuple[Path, np.ndarray]:
    """The clean video with one sample (frame 10, row 16, column 16) set to ``value``."""
    frames = frames_of(clean, dtype)
    frames[10, 16, 16] = value
    return variant(clean, tmp_path / f"spike_{value:g}.npz", frames), frames


def json_of(*argv: str) -> dict:
    """The JSON object a command prints (outside capsys, for module fixtures)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(list(argv)) == 0
    return strict_json(out.getvalue())


@pytest.fixture(scope="module")
def clean_estimate(clean: Path) -> dict:
    """``anra estimate --json`` of the clean video: the reference for the variants."""
    return json_of("estimate", str(clean), "--json")


@pytest.fixture(scope="module")
def clean_diagnosis(clean: Path) -> dict:
    """``anra diagnose --json`` of the clean video: the reference for the spiked ones."""
    return json_of("diagnose", str(clean), "--json")


# ----------------------------------------------------------------------------- values beyond any physics
def test_a_1e30_sample_is_masked_and_estimate_matches_the_library_without_it(
    clean: Path, clean_estimate: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, frames = spiked(clean, tmp_path, 1e30)
    code, out, err = run(capsys, "estimate", path, "--json")
    assert (code, err) == (0, "")
    s = strict_json(out)
    # Reference: the estimator called directly on the frames with that sample made NaN.
    frames[10, 16, 16] = np.nan
    with np.load(clean) as data:
        dt, dx = float(data["dt"]), float(data["dx"])
    ref = ANRAEstimator()(torch.from_numpy(frames), dt, dx)
    assert s["valid"] is True and s["n_masked"] == 1
    assert s["diffusivity"] == pytest.approx(float(ref.diffusivity), rel=1e-9)
    # The mask drops every output pixel whose filters reach the sample: within the standard error.
    assert abs(s["diffusivity"] - clean_estimate["diffusivity"]) < 3 * clean_estimate["std_error"]
    assert s["input"]["masked_values"]["beyond_limit"] == 1 and s["input"]["masked_values"]["largest"] == 1e30
    expected = (
        "input: 1 of 30720 samples masked (1 beyond +-1e+06 data units, the largest 1e+30: not a measurement)"
    )
    assert s["warnings"] == [expected]


def test_batch_takes_the_same_decision_as_estimate_on_a_float32_1e15_sample(
    clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = spiked(clean, tmp_path, 1e15, np.float32)
    code, out, err = run(capsys, "estimate", path, "--json")
    alone = strict_json(out)
    assert (code, err) == (0, "") and alone["valid"] is True
    table = tmp_path / "rows.csv"
    code, out, err = run(capsys, "batch", path, "--out", table, "--no-progress")  # float32, as the issue's
    assert (code, err) == (0, "")
    with table.open() as handle:
        (row,) = list(csv.DictReader(handle))
    assert row["status"] == "ok" and int(row["n_masked"]) == 1
    assert "1 beyond +-1e+06" in row["message"] and "not a measurement" in row["message"]  # as estimate says
    assert any("1 beyond +-1e+06" in w for w in alone["warnings"])
    rtol = 100 * torch.finfo(torch.float32).eps  # both in float32; summation order may differ
    assert float(row["diffusivity"]) == pytest.approx(alone["diffusivity"], rel=rtol)


def test_a_1e300_sample_gives_valid_json_in_estimate(
    clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = spiked(clean, tmp_path, 1e300)
    code, out, err = run(capsys, "estimate", path, "--json")
    assert (code, err) == (0, "")
    s = strict_json(out)
    assert s["valid"] is True and s["n_masked"] == 1 and "1e+300" in s["warnings"][0]


@pytest.mark.parametrize("value", [1e300, 1e20, 1e3])
def test_diagnose_of_one_bad_sample_matches_the_clean_video(
    value: float, clean: Path, clean_diagnosis: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """1e300 raised LinAlgError, 1e20 and 1e3 internal checks: now beyond 1e6 is masked, 1e3 is a spike the
    artefact stage repairs, and the diagnosis is the clean video's."""
    path, _ = spiked(clean, tmp_path, value)
    code, out, err = run(capsys, "diagnose", path, "--json")
    assert (code, err) == (0, "")
    s = strict_json(out)
    assert s["base"]["diffusivity"] == pytest.approx(clean_diagnosis["base"]["diffusivity"], rel=0.01)
    assert s["extended"]["prediction_rmse"] < 1.5 * clean_diagnosis["extended"]["prediction_rmse"]
    masked = [w for w in s["warnings"] if w.startswith("input: ")]
    assert len(masked) == (value > VALUE_LIMIT)
    assert not any("does not explain" in w for w in s["warnings"])


def test_diagnose_text_of_a_1e300_sample_is_not_a_traceback(
    clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = spiked(clean, tmp_path, 1e300)
    code, out, err = run(capsys, "diagnose", path)
    assert (code, err) == (0, "")
    assert "warning: input: 1 of 30720 samples masked" in out and "plain heat equation: a = 0.2" in out


# ------------------------------------------------------------------------------------------ all NaN
def test_a_bad_sample_is_masked_before_irregular_times_are_resampled(clean: Path, tmp_path: Path) -> None:
    """Resampling would blend a 1e7 error code into its neighbours (one came out at 4.8e5, under the limit);
    masked as read, it is counted once and no resampled value is beyond any temperature."""
    frames = frames_of(clean)
    frames[3, 16, 16] = 1e7
    t = np.arange(frames.shape[0], dtype=np.float64) * 0.1
    t[2::3] += 0.03  # irregular steps: resampled by default
    path = tmp_path / "irregular.npz"
    with np.load(clean) as data:
        np.savez(path, frames=frames, t=t, dx=data["dx"])
    video = prepare_video(path, timestamps="resample")
    assert "resampled" in video.meta and video.meta["masked_values"]["beyond_limit"] == 1
    finite = video.frames[torch.isfinite(video.frames)]
    assert float(finite.abs().max()) < 100.0


def test_a_calibration_that_pushes_values_beyond_the_limit_is_counted_with_the_largest(
    clean: Path, tmp_path: Path
) -> None:
    """The file has only a NaN (no largest value yet); the calibration's extrapolation adds values beyond
    the limit: the warning names them and the largest, instead of failing on a missing number."""
    frames = frames_of(clean)
    frames[0, 0, 0] = np.nan
    path = variant(clean, tmp_path / "nan.npz", frames)
    top = float(np.nanmax(frames))
    # the identity up to just below the hottest reading, then 1e12 true per apparent unit
    steep = CalibrationTable(np.array([0.0, top - 0.01, top - 0.01 + 1e10]), np.array([0.0, top - 0.01, top]))
    video = prepare_video(path, calibration=steep)
    found = video.meta["masked_values"]
    assert found["non_finite"] == 1 and found["beyond_limit"] > 0 and found["largest"] > VALUE_LIMIT
    (line,) = input_warnings(video)
    assert f"{found['beyond_limit']} beyond" in line


@pytest.mark.parametrize("command", ["estimate", "diagnose", "features"])
def test_an_all_nan_video_is_refused_with_the_true_count(
    command: str, clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = np.full_like(frames_of(clean), np.nan)
    path = variant(clean, tmp_path / "void.npz", frames)
    one_line_error(
        *run(capsys, command, path),
        rf"void\.npz: frames must hold finite values within \+-1e\+06 \(data units\), got none: "
        rf"{frames.size} non-finite and 0 beyond the limit of {frames.size} samples",
    )


def test_batch_gives_an_all_nan_video_an_error_row(
    clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = variant(clean, tmp_path / "void.npz", np.full_like(frames_of(clean), np.nan))
    table = tmp_path / "rows.csv"
    code, _, _ = run(capsys, "batch", path, "--out", table, "--no-progress")
    with table.open() as handle:
        (row,) = list(csv.DictReader(handle))
    assert code == 2 and row["status"] == "error" and "got none: 30720 non-finite" in row["error"]


def test_diagnose_counts_non_finite_samples_over_the_whole_video(
    clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The count used to cover only the diagnosed (fit) frames: here the NaN are all in the held-out part."""
    frames = frames_of(clean)
    frames[20:] = np.nan  # 10 of 30 frames: 10240 samples, all after the split
    path = variant(clean, tmp_path / "late.npz", frames)
    expected = (
        r"late\.npz: frames must be mostly finite, got 10240 non-finite values of 30720 \(more than 5 %\)"
    )
    one_line_error(*run(capsys, "diagnose", path), expected)


# ----------------------------------------------------------------------------------------- spacings
@pytest.mark.parametrize(("flag", "value", "unit"), [("--dt", "1e-300", "s"), ("--dx", "1e300", "mm")])
def test_a_spacing_outside_the_float_range_is_refused_clearly(
    flag: str, value: str, unit: str, clean: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    name, shown = flag[2:], re.escape(f"{float(value):g}")
    for command in ("estimate", "diagnose", "features"):
        one_line_error(
            *run(capsys, command, clean, flag, value),
            rf"clean\.npz: {name} must be between 1e-06 and 1e\+06 {unit}, got {shown}; "
            r"check its unit \(dt in s, dx in mm\)",
        )


def test_the_estimator_never_prints_nan_for_an_overflowing_spacing(clean: Path) -> None:
    """The library itself (no spacing range there): the message names the overflow, not nan."""
    frames = torch.from_numpy(frames_of(clean))
    result = ANRAEstimator(strict=False)(frames, 1e-300, 0.3125)
    assert not bool(result.valid)
    assert "not finite (an overflow" in result.messages[0] and "nan" not in result.messages[0]


def test_dx_in_metres_gets_a_plausibility_warning(
    clean: Path, clean_estimate: dict, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "estimate", clean, "--dx", "0.0003125", "--json")  # 0.3125 mm in metres
    assert (code, err) == (0, "")
    s = strict_json(out)
    # a scales as dx^2: (0.0003125 / 0.3125)^2 = 1e-6 of the file's own estimate.
    assert s["diffusivity"] == pytest.approx(1e-6 * clean_estimate["diffusivity"], rel=1e-9)
    (warning,) = s["warnings"]
    assert "is outside every known material (about 0.001 to 2000 mm^2/s" in warning
    fixed = float(re.search(r"dx = 0\.3125 mm would give ([\d.e-]+) mm\^2/s", warning).group(1))
    assert "likely cause: dx = 0.0003125 given in m instead of mm" in warning
    assert fixed == pytest.approx(s["diffusivity"] * 1e6, rel=1e-3)
    assert s["message"] == "" and s["valid"] is True  # kept, and flagged in warnings only
    code, out, _ = run(capsys, "estimate", clean, "--dx", "0.0003125")
    assert code == 0 and f"  warning: {warning}\n" in out


# ------------------------------------------------------------------------------------- model failure
@pytest.mark.slow
def test_a_time_reversed_video_is_reported_as_not_explained(
    clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = variant(clean, tmp_path / "reversed.npz", frames_of(clean)[::-1].copy())
    code, out, err = run(capsys, "diagnose", path, "--json")
    assert (code, err) == (0, "")
    s = strict_json(out)
    ratio = s["extended"]["prediction_rmse"] / s["noise_floor"]
    assert ratio > 3 and s["base"]["diffusivity"] < 0
    failure = [w for w in s["warnings"] if w.startswith("the model does not explain the data")]
    assert len(failure) == 1 and f"is {ratio:.3g} times the noise floor" in failure[0]
    assert any(w.startswith("the diffusivity is negative") for w in s["warnings"])


# -------------------------------------------------------------------------------------- broken files
@pytest.mark.parametrize("command", ["estimate", "diagnose", "features"])
def test_random_bytes_named_npz_are_not_a_valid_zip(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "junk.npz"
    path.write_bytes(np.random.default_rng(0).bytes(5000))
    one_line_error(
        *run(capsys, command, path, "--dx", "0.1", "--dt", "0.1"), r"junk\.npz: not a valid \.npz \(zip\)"
    )


def test_batch_row_for_random_bytes_says_not_a_valid_zip(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "junk.npz"
    path.write_bytes(np.random.default_rng(1).bytes(5000))
    table = tmp_path / "rows.csv"
    code, _, _ = run(capsys, "batch", path, "--out", table, "--no-progress")
    with table.open() as handle:
        (row,) = list(csv.DictReader(handle))
    assert code == 2 and "not a valid .npz (zip) file" in row["error"]


def test_an_internal_error_is_one_line_with_exit_1(
    clean: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import anra_torch.cli.estimate as estimate_command

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("linalg.eigh: failed to converge")

    monkeypatch.setattr(estimate_command, "ANRAEstimator", broken)
    monkeypatch.delenv("ANRA_TRACEBACK", raising=False)
    code, out, err = run(capsys, "estimate", clean)
    assert code == 1 and out == "" and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("anra: internal error: RuntimeError: linalg.eigh: failed to converge (a bug")
    monkeypatch.setenv("ANRA_TRACEBACK", "1")
    with pytest.raises(RuntimeError, match="failed to converge"):
        main(["estimate", str(clean)])
