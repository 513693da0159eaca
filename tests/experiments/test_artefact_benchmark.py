"""The artefact benchmark's harness (experiments/, not the package): how it reads a diagnosis, classifies
errors and scores records, on made-up diagnoses and records (no video is diagnosed here)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import torch

from experiments.artefact_benchmark import KINDS, acceptance, summarise
from experiments.benchmark_cases import classify_error, diagnosis_record


@dataclass
class _Today:
    effects: list
    base: float = 0.15
    residual_map: torch.Tensor = field(default_factory=lambda: torch.zeros(40, 40))


@dataclass
class _Tomorrow(_Today):
    negligible: list = field(default_factory=list)
    artefacts: dict = field(default_factory=dict)


def test_reads_todays_diagnosis_and_new_keys_without_assuming_them() -> None:
    effects = [{"name": "advection", "params": {"vx": 0.1, "vy": -0.2}, "score": 12.0}]
    today = diagnosis_record(_Today(effects))
    assert today["found"] == ["advection"] and today["params"]["advection"] == {"vx": 0.1, "vy": -0.2}
    assert today["extras"] == {} and today["effect_extras"] == {}
    masked = torch.zeros(81, 40, 40, dtype=torch.bool)
    masked[3, 4, 5] = True
    tomorrow = _Tomorrow(
        [{**effects[0], "negligible": False}],
        negligible=["linear_loss"],
        artefacts={"spikes": 1, "mask": masked, "steps": [12, 40]},
    )
    record = diagnosis_record(tomorrow)
    assert record["extras"]["negligible"] == ["linear_loss"]
    assert record["extras"]["artefacts"]["spikes"] == 1
    assert record["extras"]["artefacts"]["mask"] == {
        "shape": [81, 40, 40],
        "mean": 1 / (81 * 1600),
        "nonzero": 1,
    }
    assert record["effect_extras"] == {"advection": {"negligible": False}}
    json.dumps(record, allow_nan=False)


def test_classifies_errors() -> None:
    assert classify_error(ValueError("frames must have shape (T, H, W), got (64, 64)")) == "input"
    assert (
        classify_error(ValueError("heterogeneity.a_inside must be non-negative in mm^2/s, got -0.1"))
        == "internal"
    )
    assert classify_error(
        ValueError("anisotropy tensor [[a_x, a_xy], [a_xy, a_y]] must be positive definite")
    ) == ("internal")
    assert classify_error(RuntimeError("singular matrix")) == "internal"
    assert classify_error(IndexError("out of range")) == "internal"


def _record(group: str, kind: str, found: list | None, index: int = 0, a: float | None = None) -> dict:
    truth = set() if group == "pure" else {group}
    rec = {"group": group, "index": index, "kind": kind, "found": found, "seconds": 1.0}
    if found is None:
        rec["outcome"] = "internal_error"
    else:
        rec["exact"] = set(found) == truth
        rec["top"] = found[0] if found else None
        rec["outcome"] = "exact" if rec["exact"] else ("false_positive" if group == "pure" else "inexact")
    if group == "pure":
        rec["a_estimate"] = a
    rec["sindy"] = {"exact": group == "pure", "found": []}
    return rec


def test_summary_and_acceptance() -> None:
    records = [
        _record("pure", "none", [], a=0.150),
        _record("advection", "none", ["advection"]),
        _record("pure", "bad_elements", ["source"], a=0.120),
        _record("advection", "bad_elements", None),
        _record("pure", "offset_steps", [], a=0.151),
        _record("advection", "offset_steps", ["advection", "linear_loss"]),
    ]
    summary = summarise(records)
    assert list(summary) == [k for k in KINDS if k in ("none", "bad_elements", "offset_steps")]
    assert summary["none"]["exact_set"] == 1.0 and summary["none"]["pure_false_positive"] == 0.0
    bad = summary["bad_elements"]
    assert bad["exact_set"] == 0.0 and bad["pure_no_effect"] == 0.0 and bad["internal_errors"] == 1
    assert math.isclose(bad["a_error_max"], 0.2)
    steps = summary["offset_steps"]
    assert steps["exact_set"] == 0.5 and steps["top_effect"] == 1.0 and steps["pure_no_effect"] == 1.0
    assert math.isclose(steps["a_error_max"], 0.151 / 0.150 - 1)
    text, ok = acceptance(summary)
    assert not ok
    assert "- PASS: none: named set == true set >= 95 %: 100 %" in text
    assert "- PASS: none: pure videos name no effect >= 98 %: 100 %" in text
    assert "- FAIL: bad_elements: no internal error: 1" in text
    assert "- PASS: offset_steps: pure diffusivity within 2 % of the clean estimate" in text
    assert "- FAIL: offset_steps: named set == true set >= 90 %: 50 %" in text
