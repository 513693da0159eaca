"""Batch runs: input expansion, one row per input, same-shaped batching, resumable atomic tables, CLI,
Dask."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch import batch as batch_module
from anra_torch.batch import BATCH_COLUMNS, expand_inputs, read_table, run_batch, write_table
from anra_torch.batch import run as run_module
from anra_torch.cli import main
from anra_torch.effects import hidden_effect_video
from anra_torch.estimation.estimator import ANRAEstimator
from anra_torch.recording import estimate as estimate_policy
from anra_torch.recording import read as read_module
from anra_torch.simulation.synthetic import paper_video
from anra_torch.video import prepare_video, save_npz


@pytest.fixture(scope="module")
def videos(tmp_path_factory) -> Path:
    """Folder: 3 paper videos 64 px, one 72 px, a corrupt file, a .npy without dt, a text file."""
    root = tmp_path_factory.mktemp("videos")
    small = paper_video(n_videos=3, seed=5, crop=64)
    for i in range(3):
        save_npz(root / f"p{i}.npz", small.frames[i], dt=small.dt, dx=small.dx, a_true=0.2)
    other = paper_video(n_videos=1, seed=6, crop=72)
    (root / "sub").mkdir()
    save_npz(root / "sub" / "q.npz", other.frames[0], dt=other.dt, dx=other.dx)
    (root / "broken.npz").write_bytes(b"not a zip archive")
    np.save(root / "nodt.npy", np.zeros((6, 40, 40)))
    (root / "notes.txt").write_text("not a video")
    return root


def _offline(path: Path, dtype: torch.dtype = torch.float64) -> float:
    data = np.load(path)
    frames = torch.from_numpy(data["frames"]).to(dtype)
    return float(ANRAEstimator(strict=False)(frames, float(data["dt"]), float(data["dx"])).diffusivity)


def test_expand_inputs_files_folders_globs(videos: Path) -> None:
    found = expand_inputs([videos])
    names = [Path(p).name for p in found]
    assert names == ["broken.npz", "nodt.npy", "p0.npz", "p1.npz", "p2.npz", "q.npz"]  # no notes.txt
    globbed = expand_inputs([str(videos / "p*.npz"), videos / "p1.npz", str(videos / "zz*.npz")])
    assert [Path(p).name for p in globbed] == ["p0.npz", "p1.npz", "p2.npz", "zz*.npz"]
    assert expand_inputs(["missing.npz"]) == ["missing.npz"]  # kept: it gets an error row


def test_rows_match_the_estimator_and_bad_files_get_error_rows(videos: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.csv"
    summary = run_batch([videos, "missing.npz"], out, dtype="float64", progress=False)
    assert (summary.total, summary.ok, summary.failed, summary.skipped) == (7, 4, 3, 0)
    rows = {Path(r["path"]).name: r for r in read_table(out)}
    assert list(rows) == ["broken.npz", "nodt.npy", "p0.npz", "p1.npz", "p2.npz", "q.npz", "missing.npz"]
    for name in ("p0.npz", "p1.npz", "p2.npz", "sub/q.npz"):
        row = rows[Path(name).name]
        assert row["status"] == "ok" and row["error"] is None
        assert row["diffusivity"] == pytest.approx(_offline(videos / name), rel=1e-9)
        assert abs(row["diffusivity"] - 0.2) < 5 * row["std_error"] + 1e-3
    assert rows["p0.npz"]["a_true"] == 0.2 and rows["p0.npz"]["height"] == 64
    assert "no frame period" in rows["nodt.npy"]["error"]
    assert rows["missing.npz"]["error"] == "missing.npz: no such file"
    assert rows["broken.npz"]["status"] == "error" and rows["broken.npz"]["diffusivity"] is None


def test_same_shaped_videos_share_one_estimator_call(videos: Path, tmp_path: Path, monkeypatch) -> None:
    calls: list[tuple[int, ...]] = []
    forward = ANRAEstimator.forward

    def spy(self, frames, dt, dx):
        calls.append(tuple(frames.shape))
        return forward(self, frames, dt, dx)

    monkeypatch.setattr(ANRAEstimator, "forward", spy)
    run_batch([videos / "p*.npz", videos / "sub"], tmp_path / "r.csv", progress=False)
    assert sorted(calls) == [(1, 28, 72, 72), (3, 28, 64, 64)]


def test_float32_default_agrees_with_float64(videos: Path, tmp_path: Path) -> None:
    run_batch([videos / "p0.npz"], tmp_path / "r.csv", progress=False)
    (row,) = read_table(tmp_path / "r.csv")
    assert row["diffusivity"] == pytest.approx(_offline(videos / "p0.npz"), rel=1e-4)


def test_resume_skips_done_inputs_and_retries_errors(videos: Path, tmp_path: Path, monkeypatch) -> None:
    folder = tmp_path / "in"
    folder.mkdir()
    for name in ("p0.npz", "p1.npz", "broken.npz"):
        (folder / name).write_bytes((videos / name).read_bytes())
    out = tmp_path / "r.csv"
    first = run_batch([folder], out, progress=False)
    assert (first.ok, first.failed) == (2, 1)
    loaded: list[str] = []
    load = run_module._open
    monkeypatch.setattr(run_module, "_open", lambda path, options: loaded.append(path) or load(path, options))
    (folder / "broken.npz").write_bytes((videos / "p2.npz").read_bytes())  # a fixed one is retried
    second = run_batch([folder], out, progress=False)
    assert (second.skipped, second.ok, second.failed) == (2, 1, 0)
    assert [Path(p).name for p in loaded] == ["broken.npz"]  # done inputs are not read again
    assert [r["status"] for r in read_table(out)] == ["ok", "ok", "ok"]


def test_interrupted_run_keeps_finished_batches(videos: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.parquet"

    def interrupted(chunks, options):
        yield batch_module.process_paths(chunks[0], options)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch([videos / "p*.npz"], out, batch_size=2, progress=False, runner=interrupted)
    rows = read_table(out)
    assert [Path(r["path"]).name for r in rows] == ["p0.npz", "p1.npz"]
    assert [p.name for p in tmp_path.iterdir()] == ["r.parquet"]  # no temporary file left
    resumed = run_batch([videos / "p*.npz"], out, batch_size=2, progress=False)
    assert (resumed.skipped, resumed.ok) == (2, 1)


def test_write_is_atomic(tmp_path: Path, monkeypatch) -> None:
    out = tmp_path / "r.csv"
    write_table(out, [{"path": "a.npz", "status": "ok", "diffusivity": 0.2}])
    before = out.read_bytes()

    def crash(*args):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="disk full"):
        write_table(out, [{"path": "b.npz", "status": "ok", "diffusivity": 0.3}])
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["r.csv"]


def test_csv_and_parquet_hold_the_same_rows(tmp_path: Path) -> None:
    rows = [
        {"path": "a.npz", "status": "ok", "diffusivity": 0.2, "n_masked": 3, "top_effect": "advection"},
        {"path": "b.npz", "status": "error", "error": "b.npz: no such file", "diffusivity": math.nan},
    ]
    for suffix in (".csv", ".parquet"):
        write_table(tmp_path / f"r{suffix}", rows)
    csv_rows, parquet_rows = read_table(tmp_path / "r.csv"), read_table(tmp_path / "r.parquet")
    assert csv_rows == parquet_rows
    assert list(csv_rows[0]) == list(BATCH_COLUMNS)
    assert csv_rows[1]["diffusivity"] is None and csv_rows[0]["n_masked"] == 3
    with pytest.raises(ValueError, match=r"--out must end in \.csv or \.parquet, got 'r.txt'"):
        write_table(tmp_path / "r.txt", rows)


@pytest.mark.slow
def test_diagnose_columns(tmp_path: Path) -> None:
    path = hidden_effect_video(["advection"], seed=1, size=64, duration=3.0).to_npz(tmp_path / "adv.npz")
    out = tmp_path / "r.csv"
    run_batch([path], out, diagnose=True, progress=False)
    (row,) = read_table(out)
    assert row["status"] == "ok" and row["top_effect"] == "advection"
    assert row["gain"] > 0.3 and row["extended_rmse"] < row["base_rmse"]
    assert row["noise_floor"] > 0


def test_cli_batch(videos: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "r.csv"
    assert main(["batch", str(videos / "p*.npz"), "--out", str(out), "--json", "--no-progress"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert (record["total"], record["ok"], record["failed"], record["out"]) == (3, 3, 0, str(out))
    assert main(["batch", str(videos), "--out", str(out), "--no-progress"]) == 2
    captured = capsys.readouterr()
    assert captured.err.strip() == f"anra: error: 2 of 6 inputs failed; see the 'error' column of {out}"
    assert "1 ok, 2 failed, 3 already done (6 inputs)" in captured.out
    assert main(["batch", str(videos), "--out", str(tmp_path / "r.txt")]) == 2
    assert "--out must end in .csv or .parquet, got 'r.txt'" in capsys.readouterr().err


def test_roi_and_calibration_are_applied_and_recorded(
    videos: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = tmp_path / "double.csv"
    table.write_text("T,IR\n-100,-50\n100,50\n")  # true = 2 x apparent: a unchanged, noise doubled
    out = tmp_path / "r.csv"
    summary = run_batch(
        [videos / "p0.npz", videos / "p1.npz", videos / "sub" / "q.npz"],
        out,
        roi="8,4,48,40",
        calibration=table,
        dtype="float64",
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
        video = prepare_video(videos / name, roi="8,4,48,40", calibration=table)
        offline = ANRAEstimator(strict=False)(video.frames, video.dt, video.dx)
        assert row["diffusivity"] == pytest.approx(float(offline.diffusivity), rel=1e-9)
        assert row["noise_sd"] == pytest.approx(float(offline.noise_sd), rel=1e-9)
    assert rows["q.npz"]["height"] == 40  # the 72 px video, cropped alike
    # The CLI flags give the same rows; a region that does not fit is one video's error row.
    cli_out = tmp_path / "cli.csv"
    argv = ["batch", str(videos / "p0.npz"), "--roi", "8,4,48,40", "--calibration", str(table)]
    assert main([*argv, "--float64", "--out", str(cli_out), "--no-progress"]) == 0
    (row,) = read_table(cli_out)
    assert row["diffusivity"] == rows["p0.npz"]["diffusivity"] and row["roi"] == "8,4,48,40"
    wide = run_batch([videos / "p0.npz"], tmp_path / "wide.csv", roi=(40, 0, 30, 10), progress=False)
    assert wide.failed == 1
    (row,) = read_table(tmp_path / "wide.csv")
    assert "roi 40,0,30,10 (x0,y0,W,H px) does not fit in the 64 x 64 px frame" in row["error"]
    assert row["roi"] is None  # the cells record what was done
    with pytest.raises(ValueError, match=r"roi must be X0,Y0,W,H in px \(four integers\), got '1,2'"):
        run_batch([videos / "p0.npz"], tmp_path / "x.csv", roi="1,2", progress=False)
    assert (
        main(["batch", str(videos / "p0.npz"), "--out", str(tmp_path / "y.csv"), "--calibration", "none.csv"])
        == 2
    )
    assert capsys.readouterr().err.strip() == "anra: error: none.csv: no such calibration file"


@pytest.mark.slow
def test_dask_two_worker_cluster_gives_the_local_rows(videos: Path, tmp_path: Path) -> None:
    pytest.importorskip("distributed", reason="the Dask engine needs the 'dask' extra")
    from anra_torch.batch.dask import run_batch_dask

    local, remote = tmp_path / "local.csv", tmp_path / "dask.csv"
    run_batch([videos], local, batch_size=2, progress=False)
    summary = run_batch_dask([videos], remote, workers=2, batch_size=2, progress=False)
    assert (summary.ok, summary.failed) == (4, 2)
    by_path = {r["path"]: r for r in read_table(local)}
    for row in read_table(remote):
        assert row["status"] == by_path[row["path"]]["status"]
        assert row["error"] == by_path[row["path"]]["error"]
        if row["status"] == "ok":
            assert row["diffusivity"] == pytest.approx(by_path[row["path"]]["diffusivity"], rel=1e-6)


def test_estimator_slices_of_a_big_batch_equal_the_whole(monkeypatch) -> None:
    from anra_torch.estimation import estimator as estimator_module

    video = paper_video(n_videos=5, seed=7, crop=48)
    frames = video.frames.clone()
    frames[3] = frames[3, :1].expand_as(frames[3])  # static video: flagged, not raised, with strict=False
    whole = ANRAEstimator(strict=False, window=9)(frames, video.dt, video.dx)
    monkeypatch.setattr(estimator_module, "_SLICE_ELEMENTS", 2 * frames[0].numel())  # slices of 2 videos
    sliced = ANRAEstimator(strict=False, window=9)(frames, video.dt, video.dx)
    for name in ("diffusivity", "std_error", "per_frame", "smoothing", "valid", "field", "confidence"):
        torch.testing.assert_close(getattr(sliced, name), getattr(whole, name), equal_nan=True)
    assert sliced.messages == whole.messages and not bool(sliced.valid[3])
    with pytest.raises(ValueError, match=r"^video 3: frames show no thermal activity"):
        ANRAEstimator()(frames, video.dt, video.dx)


def test_a_folder_of_frames_is_one_input(tmp_path: Path) -> None:
    """Per-frame matrices and FLIR JPEG folders are one video each; FLIR CSV exports stay one per file."""
    frames = tmp_path / "run" / "frames"
    frames.mkdir(parents=True)
    for k in range(3):
        np.savetxt(frames / f"f{k:03d}.csv", np.full((4, 5), float(k)), delimiter=",")
    (tmp_path / "run" / "a.npz").write_bytes(b"")
    exports = tmp_path / "exports"
    exports.mkdir()
    (exports / "one.csv").write_text("File Name,x\nFrame 1,\n1,2\n")
    (exports / "two.csv").write_text("File Name,y\nFrame 1,\n1,2\n")
    assert expand_inputs([tmp_path]) == [
        str(exports / "one.csv"),
        str(exports / "two.csv"),
        str(tmp_path / "run" / "a.npz"),
        str(frames),
    ]


@pytest.mark.skipif(
    not (Path(__file__).resolve().parents[2] / "shared" / "data" / "laser_silicone").is_dir(),
    reason="../shared/data/laser_silicone is absent",
)
def test_flir_jpeg_folders_run_as_videos_with_resample(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = Path(__file__).resolve().parents[2] / "shared" / "data" / "laser_silicone"
    assert expand_inputs([data]) == [str(data / "Nov19"), str(data / "Nov19_2")]
    out = tmp_path / "flir.csv"
    # Non-uniform EXIF times are resampled by default, as in every command (resample=True changes nothing).
    summary = run_batch([data], out, dx=0.55, progress=False)
    rows = read_table(out)
    # 24 resampled frames each; the row measures the cooling phase (12 frames), as anra estimate does.
    assert summary.ok == 2 and [(int(float(r["frames"])), r["phase"]) for r in rows] == [(12, "cooling")] * 2
    for row in rows:
        capsys.readouterr()
        assert main(["estimate", row["path"], "--dx", "0.55", "--json"]) == 0
        estimate = json.loads(capsys.readouterr().out)
        assert float(row["diffusivity"]) == pytest.approx(estimate["diffusivity"], rel=1e-5)  # float32 batch


def test_a_large_recording_is_read_in_chunks_and_a_bad_one_gets_its_row(
    videos: Path, tmp_path: Path, monkeypatch
) -> None:
    """Over CHUNKED_VALUES a .npz stays on disk and gets estimate_chunked's row (both videos here); a file
    truncated on disk gets an error row and the others still run."""
    from anra_torch.estimation.chunked import estimate_chunked
    from anra_torch.video.lazy import LazyFrames

    monkeypatch.setattr(estimate_policy, "CHUNKED_VALUES", 100_000)  # p*.npz: 28 x 64 x 64 = 114688 values
    truncated = tmp_path / "cut.npy"
    np.save(truncated, np.zeros((40, 64, 64), dtype=np.float32))
    truncated.write_bytes(truncated.read_bytes()[:-5000])
    out = tmp_path / "r.csv"
    run_batch([videos / "p0.npz", videos / "sub", truncated], out, dt=1 / 27, dx=10 / 224, progress=False)
    rows = {Path(r["path"]).name: r for r in read_table(out)}
    # computed in float32, batch's default, whatever the file holds
    chunked = estimate_chunked(LazyFrames(videos / "p0.npz"), 1 / 27, 10 / 224, dtype=torch.float32).result
    assert rows["p0.npz"]["status"] == "ok"
    assert rows["p0.npz"]["diffusivity"] == pytest.approx(float(chunked.diffusivity), rel=1e-12)
    q = rows["q.npz"]
    assert abs(q["diffusivity"] - _offline(videos / "sub" / "q.npz")) < q["std_error"]
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
    monkeypatch.setattr(estimate_policy, "CHUNKED_VALUES", 100_000)  # 120 x 48 x 48 = 276480 values
    out = tmp_path / "r.csv"
    run_batch([path], out, dt=0.1, dx=0.25, progress=False)
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
    videos: Path, tmp_path: Path, monkeypatch
) -> None:
    """With two torch threads, two chunked recordings run at once, one thread each: the same rows in the
    same order as one at a time, the truncated file's error row among them, and the thread count restored."""
    monkeypatch.setattr(estimate_policy, "CHUNKED_VALUES", 100_000)
    truncated = tmp_path / "cut.npy"
    np.save(truncated, np.zeros((40, 64, 64), dtype=np.float32))
    truncated.write_bytes(truncated.read_bytes()[:-5000])
    inputs = [videos / "p0.npz", truncated, videos / "sub"]
    threads = torch.get_num_threads()
    tables = []
    try:
        for count in (1, 2):
            torch.set_num_threads(count)
            out = tmp_path / f"r{count}.csv"
            run_batch(inputs, out, dt=1 / 27, dx=10 / 224, progress=False)
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
        run_batch([tmp_path / "v0.npz"], whole, precision=2, progress=False)


@pytest.mark.slow
def test_diagnose_of_a_large_recording_reads_it_in_chunks_and_diagnoses_its_copy(
    tmp_path: Path, monkeypatch
) -> None:
    """Over CHUNKED_VALUES the recording stays on disk (chunked estimate), over DIAGNOSE_VALUES it is
    diagnosed on its block-averaged copy (here 2 frames per block, the frame kept whole), and the row
    says so."""
    from anra_torch.recording import decimate

    path = hidden_effect_video(["advection"], seed=1, size=64, duration=6.0).to_npz(tmp_path / "adv.npz")
    monkeypatch.setattr(estimate_policy, "CHUNKED_VALUES", 100_000)  # 181 x 64 x 64 = 741376 values
    monkeypatch.setattr(decimate, "DIAGNOSE_VALUES", 400_000)
    loaded = []
    never = lambda *a, **k: loaded.append(a)  # noqa: E731 - the recording is never loaded whole
    monkeypatch.setattr(read_module, "prepare_video", never)
    out = tmp_path / "r.csv"
    run_batch([path], out, diagnose=True, progress=False)
    (row,) = read_table(out)
    assert loaded == [] and row["status"] == "ok" and row["top_effect"] == "advection"
    assert "diagnosed on a copy averaged over 1 x 1 px and 2 frames" in row["message"]
    assert row["gain"] > 0.3 and int(float(row["frames_used"])) == 181


@pytest.mark.slow
def test_batch_and_estimate_agree_on_every_shared_recording(tmp_path: Path, capsys) -> None:
    """One recording policy: ``anra batch`` and ``anra estimate`` give the same diffusivity, status and phase
    for every recording in ../shared/data (the FLIR JPEG folders at 0.55 mm/px, the CSV box exports at an
    assumed 10 frames/s and 0.25 mm/px)."""
    data = Path(__file__).resolve().parents[2] / "shared" / "data"
    cases = [(data / "laser_silicone" / name, {"dx": 0.55}) for name in ("Nov19", "Nov19_2")]
    cases += [(path, {"dt": 0.1, "dx": 0.25}) for path in sorted((data / "flir_csv").glob("* M1.csv"))]
    cases += [(data / "flir_csv" / "Q 100 Silver 1.csv", {"dt": 0.1, "dx": 0.25})]
    for path, spacing in cases:
        flags = [x for key, value in spacing.items() for x in (f"--{key}", str(value))]
        capsys.readouterr()
        code = main(["estimate", str(path), *flags, "--json"])
        estimate = json.loads(capsys.readouterr().out)
        out = tmp_path / f"{path.stem}.csv"
        run_batch([path], out, dtype="float64", progress=False, **spacing)
        (row,) = read_table(out)
        several = len(estimate["phases"]) > 1
        assert row["phase"] == (estimate["phase"] if several else None), path.name
        assert (row["status"] == "ok") == (code == 0) == estimate["valid"], path.name
        if estimate["diffusivity"] is None:
            assert row["diffusivity"] is None, path.name
        else:
            assert row["diffusivity"] == pytest.approx(estimate["diffusivity"], rel=1e-9), path.name
            assert int(row["frames"]) == estimate["frames"], path.name
