"""The batch table (:mod:`anra_torch.batch.table`): atomic writes, CSV and Parquet alike, the file mode."""

from __future__ import annotations

import math
import os
import stat
from pathlib import Path

import pytest
from commands import run

from anra_torch.batch import BATCH_COLUMNS, read_table, write_table


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


# ----------------------------------------------------------------------------------- batch: resume key


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
