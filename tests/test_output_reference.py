"""The output reference (docs/reference/outputs.md) names every key the commands emit, and nothing else.

``anra simulate`` writes a small video; ``anra estimate --json``, ``anra features --json`` and ``anra batch``
run on it; their top-level keys and columns are compared with the first column of the page's tables, both
ways. (``anra diagnose --json`` is not tabulated yet: the page says so.)
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from anra_torch.cli import main

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "reference" / "outputs.md"


def documented(heading: str) -> set[str]:
    """The backquoted names in the first column of the table under ``## heading``."""
    section = PAGE.read_text().split(f"\n## {heading}\n", 1)[1].split("\n## ", 1)[0]
    rows = [line.split("|")[1] for line in section.splitlines() if line.startswith("| `")]
    return {name for cell in rows for name in re.findall(r"`([^`]+)`", cell)}


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    capsys.readouterr()
    assert main(argv) == 0, capsys.readouterr().err[-2000:]
    return capsys.readouterr().out


@pytest.fixture
def video(tmp_path: Path) -> Path:
    path = tmp_path / "videos" / "v.npz"
    assert main(["simulate", "--preset", "blobs", "--size", "64", "--frames", "30", "-o", str(path)]) == 0
    return path


@pytest.mark.parametrize("command", ["estimate", "features"])
def test_json_keys_are_documented(command: str, video: Path, capsys: pytest.CaptureFixture[str]) -> None:
    keys = set(json.loads(run([command, str(video), "--json"], capsys)))
    page = documented(f"`anra {command} --json`")
    assert keys - page == set(), f"emitted, not documented: {sorted(keys - page)}"
    assert page - keys == set(), f"documented, not emitted: {sorted(page - keys)}"


def test_batch_columns_are_documented(video: Path, capsys: pytest.CaptureFixture[str]) -> None:
    table = video.parent.parent / "rows.csv"
    run(["batch", str(video.parent), "--out", str(table)], capsys)
    with table.open() as f:
        columns = set(next(csv.reader(f)))
    page = documented("`anra batch` columns")
    assert columns - page == set(), f"emitted, not documented: {sorted(columns - page)}"
    assert page - columns == set(), f"documented, not emitted: {sorted(page - columns)}"
