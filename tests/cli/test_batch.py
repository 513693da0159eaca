"""``anra batch`` (:mod:`anra_torch.cli.batch`): the summary, the exit status and one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

from anra_torch.cli import main


def test_cli_batch(video_folder: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "r.csv"
    assert main(["batch", str(video_folder / "p*.npz"), "--out", str(out), "--json", "--no-progress"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert (record["total"], record["ok"], record["failed"], record["out"]) == (3, 3, 0, str(out))
    assert main(["batch", str(video_folder), "--out", str(out), "--no-progress"]) == 2
    captured = capsys.readouterr()
    assert captured.err.strip() == f"anra: error: 2 of 6 inputs failed; see the 'error' column of {out}"
    assert "1 ok, 2 failed, 3 already done (6 inputs)" in captured.out
    assert main(["batch", str(video_folder), "--out", str(tmp_path / "r.txt")]) == 2
    assert "--out must end in .csv or .parquet, got 'r.txt'" in capsys.readouterr().err
