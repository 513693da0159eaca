"""Resuming a batch run (:mod:`anra_torch.batch.resume`): done inputs skipped, errors retried, the resume
key holding every result-changing option, a changed input recomputed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from commands import run

from anra_torch.batch import read_table, run_batch, write_table
from anra_torch.batch import run as run_module

# ----------------------------------------------------------------------------------- batch: resume key


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


def test_resume_skips_done_inputs_and_retries_errors(video_folder: Path, tmp_path: Path, monkeypatch) -> None:
    folder = tmp_path / "in"
    folder.mkdir()
    for name in ("p0.npz", "p1.npz", "broken.npz"):
        (folder / name).write_bytes((video_folder / name).read_bytes())
    out = tmp_path / "r.csv"
    first = run_batch([folder], out, progress=False)
    assert (first.ok, first.failed) == (2, 1)
    loaded: list[str] = []
    load = run_module._open
    monkeypatch.setattr(run_module, "_open", lambda path, options: loaded.append(path) or load(path, options))
    (folder / "broken.npz").write_bytes((video_folder / "p2.npz").read_bytes())  # a fixed one is retried
    second = run_batch([folder], out, progress=False)
    assert (second.skipped, second.ok, second.failed) == (2, 1, 0)
    assert [Path(p).name for p in loaded] == ["broken.npz"]  # done inputs are not read again
    assert [r["status"] for r in read_table(out)] == ["ok", "ok", "ok"]
