"""The README's "Use" block runs as written: its Python, then every command of its shell block, in order,
in an empty folder.

The data folder ``../shared/data`` (next to the repository) is resolved to its absolute path; a command that
needs it is left out when it is absent.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import torch

from anra_torch.cli import main

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


def use_blocks(language: str) -> list[str]:
    """The ``language`` code blocks of the README's "## Use" section."""
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Use\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(rf"```{language}\n(.*?)```", section, flags=re.S)


def commands() -> list[str]:
    """The shell commands of the "Use" block, one per line, comments and blank lines dropped."""
    (block,) = use_blocks("bash")
    return [line for line in block.splitlines() if shlex.split(line, comments=True)]


def test_the_use_block_is_found() -> None:
    found = commands()
    assert len(found) >= 8 and all(line.startswith("anra ") for line in found)
    # Every input file a command reads is made by an earlier command (or is the repository's data).
    made: set[str] = set()
    for line in found:
        argv = shlex.split(line, comments=True)
        if "-o" in argv:
            made.add(argv[argv.index("-o") + 1])
        for arg in argv:
            if arg.endswith(".npz") and argv[argv.index(arg) - 1] not in ("-o", "--out"):
                assert arg in made, f"{line}: reads {arg} before any command makes it"
            if arg == "videos/":
                assert any(m.startswith("videos/") for m in made), line


@pytest.mark.slow
def test_readme_use_commands_run_in_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """In this process, through ``anra_torch.cli.main`` (torch is imported once, not per command; the
    console script itself is run in ``tests/test_cli.py::test_entry_points_run_outside_the_process``)."""
    monkeypatch.chdir(tmp_path)
    (python,) = use_blocks("python")
    exec(compile(python, "README.md", "exec"), {})  # noqa: S102 - the README's own example
    outputs = {}
    threads = torch.get_num_threads()
    try:
        for line in commands():
            argv = shlex.split(line, comments=True)
            if any("../shared/data" in a for a in argv):
                if not DATA.is_dir():
                    continue
                argv = [a.replace("../shared/data", str(DATA)) for a in argv]
            capsys.readouterr()
            code = main(argv[1:])
            done = capsys.readouterr()
            assert code == 0, f"{line}\n{done.err[-3000:]}"
            outputs[line] = done.out
    finally:
        torch.set_num_threads(threads)
    # What the comments claim: the second batch run finds both videos done.
    (again,) = [out for line, out in outputs.items() if line.startswith("anra --threads 1 batch")]
    assert "0 ok, 0 failed, 2 already done (2 inputs)" in again
    assert (tmp_path / "results" / "demo" / "report.md").exists() and (tmp_path / "maps.npz").exists()
