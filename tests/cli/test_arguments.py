"""What the ``anra`` commands share (:mod:`anra_torch.cli.arguments`): flag types, strict JSON lines."""

from __future__ import annotations

import math

from commands import strict_json

from anra_torch.cli.arguments import json_line


def test_json_line_never_writes_nan() -> None:
    record = {"a": 1.0, "b": math.nan, "c": {"d": [1.0, math.inf]}, "warnings": ["x"]}
    line = json_line(record)
    parsed = strict_json(line + "\n")
    assert parsed == {
        "a": 1.0,
        "b": None,
        "c": {"d": [1.0, None]},
        "warnings": ["x", "not finite, reported as null: b, c.d[1]"],
    }
