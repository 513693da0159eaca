"""Tests for :mod:`anra_torch.forecast.refine`: Problem-1 refinement through torchdiffeq, from the direct
estimate.

The reference is the truth of the simulated video: a model whose parameters are pushed 30 % off the
direct estimate must come back to the truth, and the Problem-1 error must fall.
"""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.effects import hidden_effect_video
from anra_torch.forecast import refine_model
from anra_torch.selection import diagnose_terms


def small(names: list[str]):
    return hidden_effect_video(names, seed=1, size=48, duration=2.0, fps=20)


@pytest.mark.slow
@pytest.mark.parametrize(("name", "key"), [("linear_loss", "b"), ("advection", "vx")])
def test_refinement_recovers_a_perturbed_parameter(name: str, key: str) -> None:
    v = small([name])
    diagnosis = diagnose_terms(v.frames, v.dt, v.dx)
    assert diagnosis.names == [name]
    diagnosis.effects[0]["params"][key] *= 1.3
    result = refine_model(v.frames, v.dt, v.dx, diagnosis, iterations=8)
    truth = v.effects[0].params[key]
    assert result.effects_before[0].params[key] == pytest.approx(1.3 * truth, rel=0.02)
    assert result.effects_after[0].params[key] == pytest.approx(truth, rel=0.02)  # 0.9 % and 0.6 % here
    assert result.sse_after < 0.1 * result.sse_before
    assert result.evaluations >= result.iterations >= 1 and result.seconds > 0


@pytest.mark.slow
def test_plain_model_refines_a() -> None:
    v = small([])
    diagnosis = diagnose_terms(v.frames, v.dt, v.dx)
    assert diagnosis.names == []
    object.__setattr__(diagnosis, "a_plain", 0.8 * diagnosis.a_plain)
    result = refine_model(v.frames, v.dt, v.dx, diagnosis, iterations=6)
    assert result.effects_after == ()
    assert result.a_after == pytest.approx(0.15, rel=0.03)
    assert result.sse_after < result.sse_before


@pytest.mark.slow
def test_bad_arguments_are_one_line_errors() -> None:
    v = small(["linear_loss"])
    diagnosis = diagnose_terms(v.frames, v.dt, v.dx)
    with pytest.raises(ValueError, match="diagnosis was made on frames of another size"):
        refine_model(v.frames[:, :40, :40], v.dt, v.dx, diagnosis)
    with pytest.raises(ValueError, match="iterations must be an integer >= 1, got 0"):
        refine_model(v.frames, v.dt, v.dx, diagnosis, iterations=0)
    with pytest.raises(ValueError, match="scale_px must be a Gaussian sigma >= 0 in px, got nan"):
        refine_model(v.frames, v.dt, v.dx, diagnosis, scale_px=math.nan)
    with pytest.raises(ValueError, match=r"frames must have shape \(T >= 2, H, W\)"):
        refine_model(torch.zeros(48, 48), v.dt, v.dx, diagnosis)
