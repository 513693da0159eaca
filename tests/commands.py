"""Running ``anra`` in-process as the tests do: the exit status and the captured output, one-line errors."""

from __future__ import annotations

import contextlib
import io
import json
import re
import warnings

import pytest

from anra_torch.cli import main


def run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    """``anra ARGV...`` in this process: ``(exit status, stdout, stderr)``."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(result: tuple[int, str, str], match: str) -> str:
    """Assert a :func:`run` result is exit 2 with nothing on stdout and one ``anra: error:`` line matching
    ``match`` on stderr; return that line."""
    code, out, err = result
    assert code == 2
    assert out == ""
    assert err.startswith("anra: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert re.search(match, err), err
    return err


def strict_json(text: str) -> dict:
    """Parse one JSON line, refusing NaN and infinities (what ``allow_nan=False`` forbids)."""

    def refuse(name: str) -> None:
        raise AssertionError(f"non-finite number {name} in JSON")

    assert text.count("\n") == 1, text
    return json.loads(text, parse_constant=refuse)


NON_FINITE_WORD = re.compile(r"\b(nan|inf|infinity)\b", re.IGNORECASE)
"""A non-finite number written out as a word."""
ECHOED_NON_FINITE = re.compile(r"got '?[-+]?(nan|inf)'?", re.IGNORECASE)
"""An error quoting the non-finite value it received (``got nan``): not a number the command made."""


def run_isolated(argv: list[str]) -> tuple[int, str, str, list[warnings.WarningMessage]]:
    """``anra ARGV...`` in this process with stdout, stderr and every Python warning captured:
    ``(exit status, stdout, stderr, warnings)``."""
    out, err = io.StringIO(), io.StringIO()
    with (
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
        warnings.catch_warnings(record=True) as caught,
    ):
        warnings.simplefilter("always")
        code = main(argv)
    return code, out.getvalue(), err.getvalue(), list(caught)


def assert_clean(label: str, code: int, out: str, err: str, caught: list[warnings.WarningMessage]) -> None:
    """A fuzzed run ended cleanly: exit 0 or 2, no traceback and no Python warning, on exit 2 one
    ``anra: error:`` line, every JSON line strict (no NaN, no infinity), no non-finite word in the output."""
    assert code in (0, 2), f"{label}: exit {code}: {err}"
    assert "Traceback" not in err and not caught, f"{label}: {err} {[str(w.message) for w in caught]}"
    if code == 2:
        assert err.startswith("anra: error: ") and err.count("\n") == 1, f"{label}: {err!r}"
    for line in out.splitlines():
        if line.startswith("{"):

            def refuse(name: str, line: str = line) -> None:
                raise AssertionError(f"{label}: non-finite {name} in JSON: {line}")

            json.loads(line, parse_constant=refuse)
    text = ECHOED_NON_FINITE.sub("", out + err)  # an error may quote the non-finite value it received
    assert not NON_FINITE_WORD.search(text), f"{label}: non-finite word in output: {out} {err}"
