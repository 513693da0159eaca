"""Running ``anra`` in-process as the tests do: the exit status and the captured output, one-line errors."""

from __future__ import annotations

import json
import re

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
