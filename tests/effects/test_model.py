"""The extended heat model (:mod:`anra_torch.effects.model`): terms, the right-hand side, errors, JSON."""

from __future__ import annotations

import json
import math
import re

import pytest
import torch
from fields import EXAMPLES

from anra_torch.effects import (
    EFFECTS,
    Effect,
    ExtendedHeatRHS,
    Grid,
    effects_from_json,
    effects_to_json,
)
from anra_torch.simulation import HeatRHS

F64 = torch.float64


@pytest.mark.parametrize("name", list(EFFECTS))
def test_term_shapes_and_dtype(name: str, dtype: torch.dtype) -> None:
    grid = Grid((12, 16), 1.0, duration=2.0)
    effect = Effect(name, EXAMPLES[name])
    u = 30.0 + torch.rand(3, 12, 16, dtype=dtype)
    out = effect.term(u, 0.5, grid)
    assert out.shape == (3, 12, 16) and out.dtype == dtype and bool(out.isfinite().all())
    assert effect.term(u[0], torch.tensor(0.5), grid).shape == (12, 16)


def test_extended_rhs_sums_the_terms() -> None:
    grid = Grid((10, 12), 0.5, duration=2.0)
    effects = [
        Effect(name, EXAMPLES[name]) for name in ("linear_loss", "source", "advection", "heterogeneity")
    ]
    rhs = ExtendedHeatRHS(0.2, grid=grid, effects=effects, time_scale=0.5)
    u = 30.0 + torch.rand(10, 12, dtype=F64)
    t = torch.tensor(2.0, dtype=F64)  # solver time: 1 s
    expected = sum(e.term(u, 1.0, grid) for e in effects) * 0.5
    torch.testing.assert_close(rhs(t, u), expected, rtol=1e-14, atol=1e-14)
    plain = ExtendedHeatRHS(0.2, grid=grid, effects=effects[:3])
    expected = HeatRHS(0.2, dx=0.5)(t, u)[0] + sum(e.term(u, 2.0, grid) for e in effects[:3])
    torch.testing.assert_close(plain(t, u), expected, rtol=1e-14, atol=1e-14)
    assert "effects=(linear_loss, source, advection)" in repr(plain) and "boundary='neumann'" in repr(plain)


# ------------------------------------------------------------------------------------------ errors
def one_line(err: pytest.ExceptionInfo[BaseException]) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: Effect("perfusion", {}),
            "unknown effect 'perfusion'; expected one of: linear_loss, source, advection, anisotropy, "
            "heterogeneity, nonlinear_diffusion",
        ),
        (
            lambda: Effect("advection", {"vx": 1.0}),
            "effect 'advection' is missing vy; expected: vx (mm/s), vy (mm/s)",
        ),
        (
            lambda: Effect("advection", {"vx": 1.0, "vy": 0.0, "vz": 1.0}),
            "effect 'advection' has no parameter 'vz'",
        ),
        (
            lambda: Effect("anisotropy", {"a_x": 0.1, "a_y": 0.1, "a_xy": 0.1, "ratio": 2.0}),
            "has no parameter 'ratio' (derived, set from the others)",
        ),
        (
            lambda: Effect("advection", {"vx": math.nan, "vy": 0.0}),
            "advection.vx must be a finite number in mm/s",
        ),
        (
            lambda: Effect("source", {**EXAMPLES["source"], "width": 0.0}),
            "source.width must be positive in mm, got 0.0",
        ),
        (lambda: Effect("linear_loss", {"b": -1.0, "T_ref": 0.0}), "linear_loss.b must be non-negative"),
        (
            lambda: Effect("heterogeneity", {**EXAMPLES["heterogeneity"], "radius": -1.0}),
            "heterogeneity.radius must be positive",
        ),
        (
            lambda: Effect("nonlinear_diffusion", {"a0": 0.0, "beta": 0.1, "T_ref": 0.0}),
            "nonlinear_diffusion.a0 must be positive",
        ),
        (
            lambda: Effect("anisotropy", {"a_x": 0.1, "a_y": 0.1, "a_xy": 0.2}),
            "anisotropy tensor [[a_x, a_xy], [a_xy, a_y]] must be positive definite",
        ),
        (lambda: Effect("anisotropy", {"a_x": -0.1, "a_y": -0.1, "a_xy": 0.0}), "must be positive definite"),
    ],
)
def test_invalid_effects_give_one_line_value_errors(build, message: str) -> None:  # noqa: ANN001
    with pytest.raises(ValueError, match=re.escape(message)) as err:
        build()
    one_line(err)


# ------------------------------------------------------------------------------------------ truth
def test_effects_json_round_trip_with_derived_values() -> None:
    effects = tuple(
        Effect(name, EXAMPLES[name]) for name in ("linear_loss", "source", "advection", "anisotropy")
    )
    text = effects_to_json(effects)
    records = json.loads(text)
    assert [r["name"] for r in records] == ["linear_loss", "source", "advection", "anisotropy"]
    assert set(records[3]["params"]) == {"a_x", "a_y", "a_xy", "angle_deg", "ratio"}
    assert records[3]["units"]["angle_deg"] == "deg" and records[1]["units"]["rate"] == "K/s"
    assert effects_from_json(text) == effects
    records[3]["params"]["ratio"] = 9.0
    with pytest.raises(ValueError, match=r"anisotropy.ratio=9.0 disagrees with the parameters"):
        effects_from_json(json.dumps(records))
    with pytest.raises(ValueError, match="effects must be a JSON list"):
        effects_from_json("{not json")
    assert hash(effects[0]) == hash(Effect("linear_loss", dict(EXAMPLES["linear_loss"])))
