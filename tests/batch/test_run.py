"""Batch runs (:mod:`anra_torch.batch.run`): one row per input matching the estimator, same-shaped batching,
interrupted runs, regions and calibration, recordings read in chunks, diagnosis columns.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from shared_data import DATA

from anra_torch import batch as batch_module
from anra_torch.batch import BATCH_COLUMNS, BatchOptions, expand_inputs, read_table, run_batch
from anra_torch.cli import main
from anra_torch.effects import hidden_effect_video
from anra_torch.estimation.estimator import ANRAEstimator, ANRAResult
from anra_torch.recording import plan as recording_plan
from anra_torch.recording import read as read_module
from anra_torch.simulation.synthetic import PaperSpot, paper_video
from anra_torch.video import prepare_video, save_npz


def _offline(path: Path, dtype: torch.dtype = torch.float64) -> float:
    data = np.load(path)
    frames = torch.from_numpy(data["frames"]).to(dtype)
    return float(ANRAEstimator(strict=False)(frames, float(data["dt"]), float(data["dx"])).diffusivity)


def test_rows_match_the_estimator_and_bad_files_get_error_rows(video_folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.csv"
    summary = run_batch(
        [video_folder, "missing.npz"], out, options=BatchOptions(dtype="float64"), progress=False
    )
    assert (summary.total, summary.ok, summary.failed, summary.skipped) == (7, 4, 3, 0)
    rows = {Path(r["path"]).name: r for r in read_table(out)}
    assert list(rows) == ["broken.npz", "nodt.npy", "p0.npz", "p1.npz", "p2.npz", "q.npz", "missing.npz"]
    for name in ("p0.npz", "p1.npz", "p2.npz", "sub/q.npz"):
        row = rows[Path(name).name]
        assert row["status"] == "ok" and row["error"] is None
        assert row["diffusivity"] == pytest.approx(_offline(video_folder / name), rel=1e-9)
        assert abs(row["diffusivity"] - 0.2) < 5 * row["std_error"] + 1e-3
    assert rows["p0.npz"]["a_true"] == 0.2 and rows["p0.npz"]["height"] == 64
    assert "no frame period" in rows["nodt.npy"]["error"]
    assert rows["missing.npz"]["error"] == "missing.npz: no such file"
    assert rows["broken.npz"]["status"] == "error" and rows["broken.npz"]["diffusivity"] is None


def test_same_shaped_videos_share_one_estimator_call(video_folder: Path, tmp_path: Path, monkeypatch) -> None:
    calls: list[tuple[int, ...]] = []
    forward = ANRAEstimator.forward

    def spy(self, frames, dt, dx, **kwargs):
        calls.append(tuple(frames.shape))
        return forward(self, frames, dt, dx, **kwargs)

    monkeypatch.setattr(ANRAEstimator, "forward", spy)
    run_batch([video_folder / "p*.npz", video_folder / "sub"], tmp_path / "r.csv", progress=False)
    assert sorted(calls) == [(1, 28, 72, 72), (3, 28, 64, 64)]


def test_each_file_is_measured_once(video_folder: Path, tmp_path: Path, monkeypatch) -> None:
    """The artefact search, the white noise level and the noise model run once per file: the phases are
    searched in the measured recording's repairs, and the estimator takes the measurement as it is."""
    counts = {"find_artefacts": 0, "estimate_noise_sd": 0, "measure_noise": 0}

    def counted(module, name: str) -> None:  # noqa: ANN001 - a module
        original = getattr(module, name)

        def spy(frames, *args, **kwargs):  # noqa: ANN001, ANN202
            counts[name] += 1 if frames.ndim == 3 else frames.shape[0]
            return original(frames, *args, **kwargs)

        monkeypatch.setattr(module, name, spy)

    modules = [sys.modules[f"anra_torch.{m}"] for m in ("balance.batch_noise", "recording.phases")]
    for module in modules:
        for name in counts:
            if hasattr(module, name):
                counted(module, name)
    run_batch([video_folder / "p*.npz", video_folder / "sub"], tmp_path / "r.csv", progress=False)
    assert counts == {"find_artefacts": 4, "estimate_noise_sd": 4, "measure_noise": 4}
    assert [r["status"] for r in read_table(tmp_path / "r.csv")] == ["ok"] * 4


def test_float32_default_agrees_with_float64(video_folder: Path, tmp_path: Path) -> None:
    run_batch([video_folder / "p0.npz"], tmp_path / "r.csv", progress=False)
    (row,) = read_table(tmp_path / "r.csv")
    assert row["diffusivity"] == pytest.approx(_offline(video_folder / "p0.npz"), rel=1e-4)


def test_interrupted_run_keeps_finished_batches(video_folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.parquet"

    def interrupted(chunks, options):
        yield batch_module.process_paths(chunks[0], options)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch([video_folder / "p*.npz"], out, batch_size=2, progress=False, runner=interrupted)
    rows = read_table(out)
    assert [Path(r["path"]).name for r in rows] == ["p0.npz", "p1.npz"]
    assert [p.name for p in tmp_path.iterdir()] == ["r.parquet"]  # no temporary file left
    resumed = run_batch([video_folder / "p*.npz"], out, batch_size=2, progress=False)
    assert (resumed.skipped, resumed.ok) == (2, 1)


@pytest.mark.slow
def test_diagnose_columns(tmp_path: Path) -> None:
    # 32 px: advection named with gain 0.986-0.994 over seeds 1-3 (64 px: 0.988); with advection left out
    # of the diagnosis' search the row names source and this fails
    path = hidden_effect_video(["advection"], seed=1, size=32, duration=3.0).to_npz(tmp_path / "adv.npz")
    out = tmp_path / "r.csv"
    run_batch([path], out, options=BatchOptions(diagnose=True), progress=False)
    (row,) = read_table(out)
    assert row["status"] == "ok" and row["top_effect"] == "advection"
    assert row["gain"] > 0.3 and row["extended_rmse"] < row["base_rmse"]
    assert row["noise_floor"] > 0


def test_roi_and_calibration_are_applied_and_recorded(
    video_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = tmp_path / "double.csv"
    table.write_text("T,IR\n-100,-50\n100,50\n")  # true = 2 x apparent: a unchanged, noise doubled
    out = tmp_path / "r.csv"
    summary = run_batch(
        [video_folder / "p0.npz", video_folder / "p1.npz", video_folder / "sub" / "q.npz"],
        out,
        options=BatchOptions(roi="8,4,48,40", calibration=table, dtype="float64"),
        progress=False,
    )
    assert (summary.ok, summary.failed) == (3, 0)
    rows = {Path(r["path"]).name: r for r in read_table(out)}
    for name in ("p0.npz", "p1.npz"):
        row = rows[name]
        assert (row["roi"], row["calibration"], row["height"], row["width"]) == (
            "8,4,48,40",
            str(table),
            40,
            48,
        )
        video = prepare_video(video_folder / name, roi="8,4,48,40", calibration=table)
        offline = ANRAEstimator(strict=False)(video.frames, video.dt, video.dx)
        assert row["diffusivity"] == pytest.approx(float(offline.diffusivity), rel=1e-9)
        assert row["noise_sd"] == pytest.approx(float(offline.noise_sd), rel=1e-9)
    assert rows["q.npz"]["height"] == 40  # the 72 px video, cropped alike
    # The CLI flags give the same rows; a region that does not fit is one video's error row.
    cli_out = tmp_path / "cli.csv"
    argv = ["batch", str(video_folder / "p0.npz"), "--roi", "8,4,48,40", "--calibration", str(table)]
    assert main([*argv, "--float64", "--out", str(cli_out), "--no-progress"]) == 0
    (row,) = read_table(cli_out)
    assert row["diffusivity"] == rows["p0.npz"]["diffusivity"] and row["roi"] == "8,4,48,40"
    wide = run_batch(
        [video_folder / "p0.npz"],
        tmp_path / "wide.csv",
        options=BatchOptions(roi=(40, 0, 30, 10)),
        progress=False,
    )
    assert wide.failed == 1
    (row,) = read_table(tmp_path / "wide.csv")
    assert "roi 40,0,30,10 (x0,y0,W,H px) does not fit in the 64 x 64 px frame" in row["error"]
    assert row["roi"] is None  # the cells record what was done
    with pytest.raises(ValueError, match=r"roi must be X0,Y0,W,H in px \(four integers\), got '1,2'"):
        run_batch(
            [video_folder / "p0.npz"], tmp_path / "x.csv", options=BatchOptions(roi="1,2"), progress=False
        )
    assert (
        main(
            [
                "batch",
                str(video_folder / "p0.npz"),
                "--out",
                str(tmp_path / "y.csv"),
                "--calibration",
                "none.csv",
            ]
        )
        == 2
    )
    assert capsys.readouterr().err.strip() == "anra: error: none.csv: no such calibration file"


@pytest.mark.skipif(
    not (DATA / "laser_silicone").is_dir(),
    reason="../shared/data/laser_silicone is absent",
)
@pytest.mark.slow
def test_flir_jpeg_folders_run_as_videos_with_resample(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = DATA / "laser_silicone"
    assert expand_inputs([data]) == [str(data / "Nov19"), str(data / "Nov19_2")]
    out = tmp_path / "flir.csv"
    # Non-uniform EXIF times are resampled by default, as in every command (resample=True changes nothing).
    summary = run_batch([data], out, options=BatchOptions(dx=0.55), progress=False)
    rows = read_table(out)
    # 24 resampled frames each; the row measures the cooling phase (12 frames), as anra estimate does.
    assert summary.ok == 2 and [(int(float(r["frames"])), r["phase"]) for r in rows] == [(12, "cooling")] * 2
    for row in rows:
        capsys.readouterr()
        assert main(["estimate", row["path"], "--dx", "0.55", "--json"]) == 0
        estimate = json.loads(capsys.readouterr().out)
        assert float(row["diffusivity"]) == pytest.approx(estimate["diffusivity"], rel=1e-5)  # float32 batch


def test_a_large_recording_is_read_in_chunks_and_a_bad_one_gets_its_row(
    video_folder: Path, tmp_path: Path, monkeypatch
) -> None:
    """Over CHUNKED_VALUES a .npz stays on disk and gets estimate_chunked's row (both videos here); a file
    truncated on disk gets an error row and the others still run."""
    from anra_torch.estimation.chunked import estimate_chunked
    from anra_torch.video.lazy import LazyFrames

    monkeypatch.setattr(recording_plan, "CHUNKED_VALUES", 100_000)  # p*.npz: 28 x 64 x 64 = 114688 values
    truncated = tmp_path / "cut.npy"
    np.save(truncated, np.zeros((40, 64, 64), dtype=np.float32))
    truncated.write_bytes(truncated.read_bytes()[:-5000])
    out = tmp_path / "r.csv"
    run_batch(
        [video_folder / "p0.npz", video_folder / "sub", truncated],
        out,
        options=BatchOptions(dt=1 / 27, dx=10 / 224),
        progress=False,
    )
    rows = {Path(r["path"]).name: r for r in read_table(out)}
    # computed in float32, batch's default, whatever the file holds
    chunked = estimate_chunked(
        LazyFrames(video_folder / "p0.npz"), 1 / 27, 10 / 224, dtype=torch.float32
    ).result
    assert rows["p0.npz"]["status"] == "ok"
    assert rows["p0.npz"]["diffusivity"] == pytest.approx(float(chunked.diffusivity), rel=1e-12)
    q = rows["q.npz"]
    assert abs(q["diffusivity"] - _offline(video_folder / "sub" / "q.npz")) < q["std_error"]
    assert rows["cut.npy"]["status"] == "error" and "truncated" in rows["cut.npy"]["error"]


def test_a_recording_read_in_chunks_gets_the_row_of_its_cooling(tmp_path: Path, monkeypatch, capsys) -> None:
    """A heating then cooling too large to hold (a .npy left on disk): its phases are found on a copy
    strided in space, and the row is the cooling's, read chunk by chunk, as anra estimate reports it
    (before, the whole recording was estimated: heating and cooling mixed)."""
    from anra_torch.effects import simulate_effects
    from anra_torch.estimation.chunked import estimate_chunked
    from anra_torch.video.lazy import LazyFrames

    y, x = torch.meshgrid(torch.arange(48.0), torch.arange(48.0), indexing="ij")
    q = 4.0 * torch.exp(-((x - 24) ** 2 + (y - 24) ** 2) * 0.25**2 / 2).double()  # K/s, sigma 1 mm
    heat = simulate_effects(
        torch.full((48, 48), 20.0).double(), a=0.3, dx=0.25, dt=0.1, n_frames=40, forcing=q
    )
    cool = simulate_effects(heat[-1], a=0.3, dx=0.25, dt=0.1, n_frames=81)[1:]
    noise = 0.01 * torch.randn(120, 48, 48, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    path = tmp_path / "laser.npy"
    np.save(path, (torch.cat([heat, cool]) + noise).float().numpy())
    monkeypatch.setattr(recording_plan, "CHUNKED_VALUES", 100_000)  # 120 x 48 x 48 = 276480 values
    out = tmp_path / "r.csv"
    run_batch([path], out, options=BatchOptions(dt=0.1, dx=0.25), progress=False)
    (row,) = read_table(out)
    assert row["status"] == "ok" and row["phase"] == "cooling" and 75 <= row["frames"] <= 80
    cooling = LazyFrames(path).window(120 - row["frames"], 120)
    chunked = estimate_chunked(cooling, 0.1, 0.25, dtype=torch.float32).result
    assert row["diffusivity"] == pytest.approx(float(chunked.diffusivity), rel=1e-12)
    assert row["diffusivity"] == pytest.approx(0.3, rel=0.05)  # pure diffusion after the switch-off
    assert main(["estimate", str(path), "--dt", "0.1", "--dx", "0.25", "--json"]) == 0
    estimate = json.loads(capsys.readouterr().out)
    assert estimate["chunked"] is not None and estimate["phase"] == "cooling"
    assert estimate["diffusivity"] == pytest.approx(row["diffusivity"], rel=1e-4)  # float64 and float32


def test_recordings_read_in_chunks_run_side_by_side_with_the_rows_of_one_at_a_time(
    video_folder: Path, tmp_path: Path, monkeypatch
) -> None:
    """With two torch threads, two chunked recordings run at once, one thread each: the same rows in the
    same order as one at a time, the truncated file's error row among them, and the thread count restored."""
    monkeypatch.setattr(recording_plan, "CHUNKED_VALUES", 100_000)
    truncated = tmp_path / "cut.npy"
    np.save(truncated, np.zeros((40, 64, 64), dtype=np.float32))
    truncated.write_bytes(truncated.read_bytes()[:-5000])
    inputs = [video_folder / "p0.npz", truncated, video_folder / "sub"]
    threads = torch.get_num_threads()
    tables = []
    try:
        for count in (1, 2):
            torch.set_num_threads(count)
            out = tmp_path / f"r{count}.csv"
            run_batch(inputs, out, options=BatchOptions(dt=1 / 27, dx=10 / 224), progress=False)
            assert torch.get_num_threads() == count
            tables.append(read_table(out))
    finally:
        torch.set_num_threads(threads)
    one, two = tables
    assert [Path(r["path"]).name for r in two] == ["p0.npz", "cut.npy", "q.npz"]
    assert [r["status"] for r in two] == ["ok", "error", "ok"]
    for a, b in zip(one, two, strict=True):
        assert a["path"] == b["path"] and a["status"] == b["status"] and a["error"] == b["error"]
        if a["status"] == "ok":
            assert b["diffusivity"] == pytest.approx(a["diffusivity"], rel=1e-9)
            assert b["std_error"] == pytest.approx(a["std_error"], rel=1e-9)


def test_precision_reads_each_video_until_its_standard_error_is_reached(tmp_path: Path) -> None:
    """``anra batch --precision``: chunked rows with frames_used; the option is part of the resume key."""
    from anra_torch.simulation import gaussian_blob

    t = torch.arange(120, dtype=torch.float64) / 27
    clean = gaussian_blob(t, shape=(48, 48), dx=0.1, a=0.2, peak=3.0, sigma=1.0)
    generator = torch.Generator().manual_seed(8)
    for i in range(2):
        noisy = clean + 0.01 * torch.randn(clean.shape, generator=generator, dtype=torch.float64)
        save_npz(tmp_path / f"v{i}.npz", noisy.float(), dt=1 / 27, dx=0.1)
    out = tmp_path / "r.csv"
    assert (
        main(["batch", str(tmp_path / "v*.npz"), "--out", str(out), "--precision", "0.2%", "--no-progress"])
        == 0
    )
    for row in read_table(out):
        assert row["status"] == "ok" and row["frames_used"] < 120
        assert row["std_error"] <= 0.002 * row["diffusivity"]
        assert abs(row["diffusivity"] - 0.2) < 5 * row["std_error"]
        assert json.loads(row["parameters"])["precision"] == 0.002
    whole = tmp_path / "whole.csv"
    run_batch([tmp_path / "v0.npz"], whole, progress=False)
    (row,) = read_table(whole)
    assert row["frames_used"] is None and json.loads(row["parameters"])["precision"] is None
    with pytest.raises(ValueError, match=r"precision must be a relative standard error in \(0, 1\), got 2"):
        run_batch([tmp_path / "v0.npz"], whole, options=BatchOptions(precision=2), progress=False)


@pytest.mark.slow
def test_diagnose_of_a_large_recording_reads_it_in_chunks_and_diagnoses_its_copy(
    tmp_path: Path, monkeypatch
) -> None:
    """Over CHUNKED_VALUES the recording stays on disk (chunked estimate), over DIAGNOSE_VALUES it is
    diagnosed on its block-averaged copy (here 2 frames per block, the frame kept whole), and the row
    says so."""
    from anra_torch.recording import decimate

    path = hidden_effect_video(["advection"], seed=1, size=64, duration=6.0).to_npz(tmp_path / "adv.npz")
    monkeypatch.setattr(recording_plan, "CHUNKED_VALUES", 100_000)  # 181 x 64 x 64 = 741376 values
    monkeypatch.setattr(decimate, "DIAGNOSE_VALUES", 400_000)
    loaded = []
    never = lambda *a, **k: loaded.append(a)  # noqa: E731 - the recording is never loaded whole
    monkeypatch.setattr(read_module, "prepare_video", never)
    out = tmp_path / "r.csv"
    run_batch([path], out, options=BatchOptions(diagnose=True), progress=False)
    (row,) = read_table(out)
    assert loaded == [] and row["status"] == "ok" and row["top_effect"] == "advection"
    assert "diagnosed on a copy averaged over 1 x 1 px and 2 frames" in row["message"]
    assert row["gain"] > 0.3 and int(float(row["frames_used"])) == 181


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


def test_the_table_is_never_an_input(video_folder: Path, tmp_path: Path) -> None:
    """A table named as an input is refused; one inside a folder of inputs is left out of them."""
    with pytest.raises(ValueError, match=r"--out .*x\.csv is the input .*x\.csv"):
        run_batch([video_folder, video_folder / "x.csv"], video_folder / "x.csv")
    inside = tmp_path / "videos"
    inside.mkdir()
    video = paper_video(size=32, spot=PaperSpot(extent=32 * 10 / 224), seed=1)
    save_npz(inside / "v.npz", video.frames[0], dt=video.dt, dx=video.dx)
    table = inside / "rows.csv"
    for _ in range(2):  # the second run finds rows.csv in the folder
        summary = run_batch([inside], table, progress=False)
        assert summary.total == 1
    assert [row["path"] for row in read_table(table)] == [str(inside / "v.npz")]
