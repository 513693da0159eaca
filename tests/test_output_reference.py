"""The output reference (docs/reference/outputs.md) names every key the commands emit, and nothing else.

``anra simulate`` writes a small video; ``anra estimate --json``, ``anra features --json`` and ``anra batch``
run on it; their top-level keys and columns are compared with the first column of the page's tables, both
ways; ``anra features --depth --out --report --json`` on a tiny 3-D scene adds the depth keys and the
``--out`` file's entries (with those of a plain ``--out``), compared both ways too. ``anra diagnose --json``
runs once on a small advection video (with ``--source-map``, ``--roi`` and ``--maps``, so that the keys those
add appear too): its top-level keys and those of an effect, a phase, ``noise``, ``artefacts`` and
``defect_map`` (and the ``--maps`` file's entries) are compared the same way (a documented key whose
meaning begins with "only" may be absent), the keys of ``base``, ``extended``, ``raw``, ``source_map`` and
``input`` must be named in their row's meaning, and the effects' parameter table is compared with the
effects' registry.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from depth_scenes import beam_recording

from anra_torch.cli import main
from anra_torch.effects import EFFECTS
from anra_torch.video import save_npz

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "reference" / "outputs.md"


def table(heading: str) -> list[list[str]]:
    """The cells of the rows under ``## heading`` whose first cell is backquoted."""
    section = PAGE.read_text().split(f"\n## {heading}\n", 1)[1].split("\n## ", 1)[0]
    return [line.split("|")[1:-1] for line in section.splitlines() if line.startswith("| `")]


def names(cell: str) -> set[str]:
    return set(re.findall(r"`([^`]+)`", cell))


def documented(heading: str) -> set[str]:
    """The backquoted names in the first column of the table under ``## heading``."""
    return {name for row in table(heading) for name in names(row[0])}


def optional(heading: str) -> set[str]:
    """The documented names whose meaning (last column) begins with "only": they may be absent."""
    return {name for row in table(heading) if row[-1].strip().startswith("only") for name in names(row[0])}


def meaning(heading: str, key: str) -> str:
    """The meaning (last column) of ``key``'s row under ``## heading``."""
    (row,) = [row for row in table(heading) if key in names(row[0])]
    return row[-1]


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
    """Without options every key is emitted but those documented "only with" an option (``--depth``,
    ``--report``: :func:`test_depth_keys_and_maps_are_documented` emits them)."""
    keys = set(json.loads(run([command, str(video), "--json"], capsys)))
    page = documented(f"`anra {command} --json`")
    assert keys - page == set(), f"emitted, not documented: {sorted(keys - page)}"
    missing = page - keys - optional(f"`anra {command} --json`")
    assert missing == set(), f"documented, not emitted: {sorted(missing)}"


FEATURES, OUT = "`anra features --json`", "`anra features --out`"


def npz_entries(path: str) -> set[str]:
    """An ``--out`` file's entries, every ``units_<name>`` checked to name an entry and counted as one."""
    with np.load(path) as maps:
        entries = set(maps.files)
    units = {e for e in entries if e.startswith("units_")}
    assert {u.removeprefix("units_") for u in units} <= entries, sorted(units)
    return entries - units | ({"units_<name>"} if units else set())


@pytest.fixture(scope="module")
def tiny_depth(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """12 x 12 px (0.4 mm) of the beam on the independent 3-D simulator: depth maps and profiles made."""
    found = beam_recording(tmp_path_factory.mktemp("depth"))
    frames = found["frames"].numpy()[:, 2:26:2, 2:26:2]
    return save_npz(found["video"].parent / "tiny.npz", frames, dt=found["result"].dt, dx=0.4)


def test_depth_keys_and_maps_are_documented(
    tiny_depth: Path, video: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``features --depth --out --report --json`` on the tiny 3-D scene and a plain ``--json --out`` run (the
    rate and ANRA maps need 20 x 20 px): every documented key emitted by one of them, none undocumented,
    ``depth``'s keys named in its row; the two ``--out`` files' entries against the ``--out`` table, both
    ways."""
    maps = tmp_path / "depth.npz"
    argv = [str(tiny_depth), "--json", "--depth", "--out", str(maps), "--report", str(tmp_path / "r")]
    record = json.loads(run(["features", *argv], capsys))
    assert record["depth"]["maps"], record["depth"]["message"]
    plain = tmp_path / "plain.npz"
    keys = set(record) | set(json.loads(run(["features", str(video), "--json", "--out", str(plain)], capsys)))
    page = documented(FEATURES)
    assert set(record) - page == set(), f"emitted, not documented: {sorted(set(record) - page)}"
    assert page - keys == set(), f"documented, not emitted: {sorted(page - keys)}"
    unnamed = set(record["depth"]) - names(meaning(FEATURES, "depth"))
    assert unnamed == set(), f"depth holds {sorted(unnamed)}, which its row does not name"
    entries = npz_entries(str(maps)) | npz_entries(str(plain))
    assert npz_entries(str(plain)) & optional(OUT) == set(), "a plain --out wrote what only --depth writes"
    assert entries - documented(OUT) == set(), f"written, not documented: {sorted(entries - documented(OUT))}"
    assert documented(OUT) - entries == set(), f"documented, not written: {sorted(documented(OUT) - entries)}"


def test_batch_columns_are_documented(video: Path, capsys: pytest.CaptureFixture[str]) -> None:
    table = video.parent.parent / "rows.csv"
    run(["batch", str(video.parent), "--out", str(table)], capsys)
    with table.open() as f:
        columns = set(next(csv.reader(f)))
    page = documented("`anra batch` columns")
    assert columns - page == set(), f"emitted, not documented: {sorted(columns - page)}"
    assert page - columns == set(), f"documented, not emitted: {sorted(page - columns)}"


DIAGNOSE = "`anra diagnose --json`"
PARTS: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
    DIAGNOSE: lambda d: d,
    f"{DIAGNOSE}: an effect": lambda d: d["effects"][0],
    f"{DIAGNOSE}: a phase": lambda d: d["phases"][0],
    f"{DIAGNOSE}: `noise`": lambda d: d["noise"],
    f"{DIAGNOSE}: `artefacts`": lambda d: d["artefacts"],
    f"{DIAGNOSE}: `defect_map`": lambda d: d["defect_map"],
}


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """``anra diagnose --json`` of a 32 px advection video of 1 s (about 10 s)."""
    path = tmp_path_factory.mktemp("diagnose") / "h.npz"
    simulate = ["simulate", "--effect", "advection", "--size", "32", "--duration", "1.0", "-o", str(path)]
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(simulate) == 0
    out = io.StringIO()
    maps = path.with_name("maps.npz")
    argv = ["diagnose", str(path), "--json", "--source-map", "--roi", "1,1,30,30", "--maps", str(maps)]
    with contextlib.redirect_stdout(out):
        assert main(argv) == 0
    return {**json.loads(out.getvalue()), "maps file": npz_entries(str(maps))}


@pytest.mark.parametrize("heading", PARTS)
def test_diagnose_keys_are_documented(heading: str, diagnosed: dict[str, Any]) -> None:
    keys = set(PARTS[heading](diagnosed)) - {"maps file"}
    page = documented(heading)
    assert keys - page == set(), f"emitted, not documented: {sorted(keys - page)}"
    missing = page - keys - optional(heading)
    assert missing == set(), f"documented, not emitted (nor marked 'only ...'): {sorted(missing)}"


@pytest.mark.parametrize(
    ("heading", "key"),
    [(DIAGNOSE, k) for k in ("base", "extended", "raw", "source_map", "input")]
    + [(f"{DIAGNOSE}: a phase", "base")],
)
def test_diagnose_nested_keys_are_named(heading: str, key: str, diagnosed: dict[str, Any]) -> None:
    nested = set(PARTS[heading](diagnosed)[key])
    unnamed = nested - names(meaning(heading, key))
    assert unnamed == set(), f"{key} holds {sorted(unnamed)}, which its row does not name"


def test_effect_parameters_match_the_registry() -> None:
    rows = {
        next(iter(names(effect))): names(params)
        for effect, params in table(f"{DIAGNOSE}: an effect's `params`")
    }
    assert set(rows) == set(EFFECTS)
    for name, spec in EFFECTS.items():
        assert rows[name] == set(spec.params) | set(spec.derived_units), name


def test_diagnose_maps_entries_are_documented(diagnosed: dict[str, Any]) -> None:
    entries, page = diagnosed["maps file"], documented("`anra diagnose --maps`")
    assert entries - page == set(), f"written, not documented: {sorted(entries - page)}"
    assert page - entries == set(), f"documented, not written: {sorted(page - entries)}"
