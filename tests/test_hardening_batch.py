"""The batch / dose half of the hardening issue, one test (or two) per row of its table.

Expected doses come from the closed forms of a constant temperature (/work/shared/REFERENCE.md), written here
from the formulas: ``CEM43 = R^(43 - T) t / 60`` (R = 0.5 at or above 43 C, 0.25 below) and
``Omega = A exp(-Ea / (R_gas T_K)) t``, never from the code under test.
"""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch.batch import BATCH_COLUMNS, read_table, run_batch, write_table
from anra_torch.cli import main
from anra_torch.estimation.estimator import ANRAResult
from anra_torch.simulation.synthetic import paper_video
from anra_torch.tissue.features import MAX_LOSS_ERROR, MIN_CONFIDENCE, TissueFeatures, feature_summary
from anra_torch.video import save_npz

A_SKIN, EA_SKIN = 3.1e98, 6.28e5  # 1/s, J/mol (Henriques & Moritz)
R_GAS = 8.314462618  # J/(mol K), the SI value


def cem43_constant(celsius: float, seconds: float) -> float:
    """CEM43 (min) of ``seconds`` at a constant ``celsius``."""
    return (0.5 if celsius >= 43.0 else 0.25) ** (43.0 - celsius) * seconds / 60.0


def omega_constant(celsius: float, seconds: float) -> float:
    """Arrhenius Omega of ``seconds`` at a constant ``celsius``, skin constants."""
    return A_SKIN * math.exp(-EA_SKIN / (R_GAS * (celsius + 273.15))) * seconds


def run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# ------------------------------------------------------------------ dose features on any frame size
@pytest.mark.parametrize(
    ("shape", "celsius", "minutes", "dx"),
    [((16, 16), 43.0, 10.0, 0.5), ((3, 5), 44.0, 5.0, 0.5), ((1, 1), 42.0, 20.0, None)],
    ids=["16x16", "3x5", "1x1-no-dx"],
)
def test_features_dose_works_on_any_frame_size(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    shape: tuple[int, int],
    celsius: float,
    minutes: float,
    dx,
) -> None:
    seconds = minutes * 60.0
    frames = np.full((round(seconds) + 1, *shape), celsius)  # 1 s apart: the record spans `seconds`
    path = save_npz(tmp_path / "v.npz", frames, dt=1.0, dx=dx)
    code, out, err = run(capsys, "features", path, "--json")
    assert (code, err) == (0, "")
    record = json.loads(out)
    assert record["cem43_minutes_max"] == pytest.approx(cem43_constant(celsius, seconds), rel=1e-12)
    assert record["omega_max"] == pytest.approx(omega_constant(celsius, seconds), rel=1e-12)
    assert record["peak_temperature_max"] == pytest.approx(celsius, rel=1e-14)
    above = seconds if celsius >= 43.0 else 0.0
    assert record["time_above_43_max"] == pytest.approx(above) and record["time_above_50_max"] == 0.0
    # The ANRA maps do not fit: absent, with the reason, and so said in the message.
    assert "diffusivity_max" not in record and "loss_rate_max" not in record and record["valid"] is False
    reason = "no pixel size" if dx is None else "frames must be at least 20 x 20 px"
    assert set(record["absent"]) == {
        "heating_rate",
        "cooling_rate",
        "rtc_attention",
        "diffusivity",
        "confidence",
        "loss_rate",
        "source",
    }
    assert all(reason in why for why in record["absent"].values()) and reason in record["message"]
    code, out, err = run(capsys, "features", path, "--out", tmp_path / "maps.npz")
    assert code == 0 and "cem43_minutes_max: " in out and "diffusivity_global: n/a" in out
    saved = np.load(tmp_path / "maps.npz")
    assert saved["cem43_minutes"].shape == shape and "diffusivity" not in saved.files


def test_a_one_dimensional_trace_is_a_one_pixel_video() -> None:
    trace = torch.full((301,), 44.0, dtype=torch.float64)  # a thermocouple: 5 min at 44 C, 1 s apart
    out = TissueFeatures()(trace, dt=1.0)
    assert out.maps["cem43_minutes"].shape == (1, 1)
    assert float(out.summary["cem43_minutes_max"]) == pytest.approx(cem43_constant(44.0, 300.0), rel=1e-12)
    assert float(out.summary["omega_max"]) == pytest.approx(omega_constant(44.0, 300.0), rel=1e-12)
    assert out.absent["diffusivity"].startswith("no pixel size") and "diffusivity" not in out.maps
    with pytest.raises(ValueError, match=r"unknown feature map 'source' \(no pixel size"):
        out.stack(["source"])
    record, _ = feature_summary(trace, 1.0)
    assert (record["frames"], record["height"], record["width"], record["dx"]) == (301, 1, 1, None)


# --------------------------------------------------------------- the recorded span, the constants named
def test_features_integrate_the_recorded_span_and_name_the_constants(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = save_npz(tmp_path / "hot.npz", np.full((11, 64, 64), 60.0), dt=1.0, dx=0.5)  # 11 frames: 10 s
    code, out, err = run(capsys, "features", path, "--json")
    assert (code, err) == (0, "")
    record = json.loads(out)
    assert record["omega_max"] == pytest.approx(omega_constant(60.0, 10.0), rel=1e-12)  # 10.69
    assert record["cem43_minutes_max"] == pytest.approx(cem43_constant(60.0, 10.0), rel=1e-12)
    assert record["time_above_60_max"] == pytest.approx(10.0)
    dose = record["dose"]
    assert (dose["rule"], dose["span_s"]) == ("linear", 10.0)
    assert (dose["arrhenius"]["A_per_s"], dose["arrhenius"]["Ea_J_per_mol"]) == (A_SKIN, EA_SKIN)
    assert dose["arrhenius"]["R_gas_J_per_mol_K"] == R_GAS
    assert (dose["cem43"]["R_at_or_above_43C"], dose["cem43"]["R_below_43C"]) == (0.5, 0.25)
    assert dose["thresholds_C"] == [43.0, 50.0, 60.0] and dose["smoothing_px"] == 1.0
    # Each frame held for dt, as an option: 11 s.
    code, out, err = run(capsys, "features", path, "--json", "--rule", "hold")
    held = json.loads(out)
    assert held["omega_max"] == pytest.approx(omega_constant(60.0, 11.0), rel=1e-12)  # 11.76
    assert (held["dose"]["rule"], held["dose"]["span_s"]) == ("hold", 11.0)
    # One frame has no span: the message says what to do.
    one = save_npz(tmp_path / "one.npz", np.full((1, 64, 64), 60.0), dt=1.0, dx=0.5)
    code, out, err = run(capsys, "features", one, "--json")
    assert code == 2 and err.count("\n") == 1 and "needs at least 2, got 1" in err and "--rule hold" in err
    code, out, err = run(capsys, "features", one, "--json", "--rule", "hold")
    assert code == 0 and json.loads(out)["omega_max"] == pytest.approx(omega_constant(60.0, 1.0), rel=1e-12)


# -------------------------------------------------------------- map extremes over confident windows
def _extremes(video) -> dict:
    record, maps = feature_summary(video.frames[0], video.dt, video.dx)
    record["span"] = (video.frames.shape[1] - 1) * video.dt
    record["maps"] = maps
    return record


def test_pure_heat_video_extremes_come_from_confident_windows() -> None:
    # The paper's Gaussian on 64 px, 40 frames: before, loss_rate_max was 2.25 1/s (no loss here).
    video = paper_video(n_videos=1, seed=0, size=64, duration=39 / 27)
    record = _extremes(video)
    assert record["diffusivity_global"] == pytest.approx(0.2, rel=0.01)
    assert record["diffusivity_max"] == pytest.approx(0.2, rel=0.1)
    # b is measured to within MAX_LOSS_ERROR / span (1 sd) where it counts: no window beyond 3 sd of 0.
    assert abs(record["loss_rate_max"]) <= 3 * MAX_LOSS_ERROR / record["span"]
    assert abs(record["source_max"]) < 0.02 * 3.8  # K, against a 3.8 K peak
    assert 0.2 < record["confident_fraction"] <= 1 and 0 < record["loss_confident_fraction"] <= 1
    assert "confidence >= 0.9" in record["extremes"]["diffusivity_max"]
    maps = record["maps"]
    best = int(maps.maps["diffusivity"].masked_fill(maps.maps["confidence"] < MIN_CONFIDENCE, -1).argmax())
    assert maps.maps["diffusivity"].flatten()[best] == pytest.approx(record["diffusivity_max"], rel=1e-12)


@pytest.mark.slow
def test_paper_case_extremes_come_from_confident_windows() -> None:
    # The measurement (224 px, 28 frames): diffusivity_max 2.33 mm^2/s and loss_rate_max 227 1/s
    # for a = 0.2 and no loss, source_max 8.4 K.
    video = paper_video(n_videos=1, seed=0)
    record = _extremes(video)
    assert record["diffusivity_max"] == pytest.approx(0.2, rel=0.25)  # measured 0.238
    assert abs(record["loss_rate_max"]) <= 3 * MAX_LOSS_ERROR / record["span"]  # measured 0.23
    assert abs(record["source_max"]) < 0.05 * 3.8  # measured 0.13 K


# ----------------------------------------------------------------------------------- batch: resume key
@pytest.fixture
def one_video(tmp_path: Path) -> Path:
    video = paper_video(n_videos=1, seed=5, crop=40)
    return save_npz(tmp_path / "v.npz", video.frames[0], dt=video.dt, dx=video.dx)


def test_batch_resume_key_holds_every_parameter(
    one_video: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "r.csv"
    base = ["batch", one_video, "--out", out, "--no-progress"]
    assert run(capsys, *base)[0] == 0
    (first,) = read_table(out)
    assert json.loads(first["parameters"])["dx"] is None and "bytes" in first["input_stamp"]
    before = out.read_bytes()
    code, text, _ = run(capsys, *base)
    assert code == 0 and "0 ok, 0 failed, 1 already done" in text
    # Another dx would change the result: the run stops before any work and says what differs.
    code, text, err = run(capsys, *base, "--dx", "1.0")
    assert code == 2 and text == "" and err.count("\n") == 1
    assert f"dx {first['dx']:g} -> 1" in err and "--rerun" in err and str(one_video) in err
    assert out.read_bytes() == before
    # The file's own dx, given explicitly, is the same result: still done.
    assert "1 already done" in run(capsys, *base, "--dx", repr(first["dx"]))[1]
    # Every other parameter that changes a result is in the key too.
    table = tmp_path / "cal.csv"
    table.write_text("true,apparent\n0,0\n100,50\n")
    for flags, named in (
        (["--dt", "0.05"], "dt "),
        (["--roi", "0,0,32,32"], "roi null -> [0, 0, 32, 32]"),
        (["--float64"], 'dtype "float32" -> "float64"'),
        (["--resample"], "resample false -> true"),
        (["--calibration", table], 'calibration null -> "sha256:'),
    ):
        code, _, err = run(capsys, *base, *flags)
        assert code == 2 and named in err, flags
    assert out.read_bytes() == before
    # --rerun recomputes and replaces: a scales with dx^2 (the Laplacian's 1/dx^2).
    assert run(capsys, *base, "--dx", "1.0", "--rerun")[0] == 0
    (row,) = read_table(out)
    assert row["dx"] == 1.0 and json.loads(row["parameters"])["dx"] == 1.0
    assert row["diffusivity"] == pytest.approx(first["diffusivity"] / first["dx"] ** 2, rel=1e-4)


def test_batch_recomputes_an_input_that_changed(one_video: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.csv"
    run_batch([one_video], out, progress=False)
    (first,) = read_table(out)
    data = dict(np.load(one_video))
    data["frames"] = data["frames"][:, :32, :32]  # another video at the same path
    np.savez(one_video, **data)
    summary = run_batch([one_video], out, progress=False)
    assert (summary.skipped, summary.ok) == (0, 1)
    (row,) = read_table(out)
    assert (row["height"], row["width"]) == (32, 32) and row["input_stamp"] != first["input_stamp"]
    assert "the input has changed" in row["message"]
    # A table from before the key (no parameters column) is recomputed, not trusted.
    rows = read_table(out)
    rows[0]["parameters"] = None
    write_table(out, rows)
    assert run_batch([one_video], out, progress=False).ok == 1


# ------------------------------------------------------------------------------ batch: message column
def test_batch_message_column_keeps_warnings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    video = paper_video(n_videos=1, seed=5, crop=40)
    backwards = save_npz(tmp_path / "backwards.npz", video.frames[0].flip(0), dt=video.dt, dx=video.dx)
    still = save_npz(tmp_path / "still.npz", np.full((28, 40, 40), 37.0), dt=video.dt, dx=video.dx)
    out = tmp_path / "r.csv"
    run_batch([backwards, still], out, progress=False)
    rows = {Path(r["path"]).name: r for r in read_table(out)}
    # Heat that concentrates (time reversed): a valid, negative a with the estimator's warning.
    assert rows["backwards.npz"]["status"] == "ok" and rows["backwards.npz"]["diffusivity"] < 0
    assert "significantly negative" in rows["backwards.npz"]["message"]
    # Nothing measured (valid=false): the reason is the error and the message.
    assert rows["still.npz"]["status"] == "error" and "frames are constant" in rows["still.npz"]["message"]
    # The record's own "warnings" list is joined in (first), without repeating the message.
    to_record = ANRAResult.to_record

    def with_warnings(self, index=0, **kwargs):
        record = to_record(self, index, **kwargs)
        return record | {"warnings": ["first warning", "second warning", *record["warnings"]]}

    monkeypatch.setattr(ANRAResult, "to_record", with_warnings)
    run_batch([backwards], tmp_path / "w.csv", progress=False)
    (row,) = read_table(tmp_path / "w.csv")
    assert row["message"] == f"first warning; second warning; {rows['backwards.npz']['message']}"
    # The columns of before are all kept, in their order, the new ones after them.
    old = ["path", "status", "error", "diffusivity", "std_error", "smoothing_px", "noise_sd", "reliability"]
    old += ["n_masked", "frames", "height", "width", "dt", "dx", "a_true", "seconds", "top_effect", "effects"]
    old += ["gain", "noise_floor", "base_rmse", "extended_rmse", "roi", "calibration"]
    new = ["message", "input_stamp", "parameters", "explained", "frames_used", "phase"]
    assert list(BATCH_COLUMNS) == [*old, *new]


# ------------------------------------------------------------------------------ output files: the umask
@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_output_files_respect_the_umask(
    one_video: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], umask: int
) -> None:
    pytest.importorskip("pyarrow", reason="Parquet needs the 'parquet' extra")
    previous = os.umask(umask)
    try:
        made = [tmp_path / "r.csv", tmp_path / "r.parquet", tmp_path / "maps.npz"]
        assert run(capsys, "batch", one_video, "--out", made[0], "--no-progress")[0] == 0
        assert run(capsys, "batch", one_video, "--out", made[1], "--no-progress")[0] == 0
        assert run(capsys, "features", one_video, "--out", made[2])[0] == 0
    finally:
        os.umask(previous)
    for path in made:
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask, path.name
