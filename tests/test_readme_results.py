"""The README's headline results name commands that run as written: every ``python -m experiments.NAME ...``
of the "Headline results" table parses its arguments with the script's own parser (the experiments take
minutes to hours: each is run up to its parsed arguments, in this process), and every ``anra ...`` there runs
to exit 0.
"""

from __future__ import annotations

import argparse
import re
import runpy
import shlex
import sys
from pathlib import Path

import pytest

from anra_torch.cli import main

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


class Parsed(Exception):
    """Raised by the patched parser once the script's arguments parsed: what the test waits for."""


def headline_commands() -> list[str]:
    """The commands in backticks of the README's "Headline results" table (``... --flag`` shorthands, which
    repeat the command before them, and a bare ``anra NAME``, a program's name in the text, are left out)."""
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Headline results\n", 1)[1].split("\n## ", 1)[0]
    found = re.findall(r"`((?:python -m experiments\.|anra )[^`]*)`", section)
    return [c for c in found if not c.startswith("...") and len(shlex.split(c)) > 2]


def test_the_headline_table_names_commands() -> None:
    found = headline_commands()
    assert len(found) >= 8 and sum(c.startswith("python -m experiments.") for c in found) >= 6


@pytest.mark.parametrize(
    "command", [c for c in headline_commands() if c.startswith("python -m experiments.")], ids=str
)
def test_each_experiment_parses_its_arguments(command: str, monkeypatch: pytest.MonkeyPatch) -> None:
    _, _, module, *args = shlex.split(command)
    original = argparse.ArgumentParser.parse_args

    def parse_then_stop(self: argparse.ArgumentParser, *a: object, **k: object) -> argparse.Namespace:
        original(self, *a, **k)  # an unknown flag or a bad value exits 2 here
        raise Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    monkeypatch.setattr(sys, "argv", [module, *args])
    with pytest.raises(Parsed):
        runpy.run_module(module, run_name="__main__", alter_sys=True)


@pytest.mark.parametrize("command", [c for c in headline_commands() if c.startswith("anra ")], ids=str)
def test_each_anra_command_runs(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    argv = shlex.split(command)[1:]
    if any(a.startswith("../shared/data") for a in argv):
        if not DATA.is_dir():
            pytest.skip("needs ../shared/data beside the repository")
        argv = [
            str(DATA / a.removeprefix("../shared/data/")) if a.startswith("../shared/data") else a
            for a in argv
        ]
    assert main(argv) == 0
    out, err = capsys.readouterr()
    assert out and "Traceback" not in err
