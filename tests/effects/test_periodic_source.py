"""The periodic source: the effect added as one module plus one registry line (the plug-in proof).

Its forward term against the closed form, its re-timing against a simulation started later, and the
diagnosis finding it, with its place, width, frequency and phase, when asked to look for it.
"""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.effects import EFFECTS, Effect, equation_text, hidden_effect_video, simulate_effects
from anra_torch.effects.base import Grid
from anra_torch.selection import diagnose_terms

F64 = torch.float64


PARAMS = {"x": 4.0, "y": 3.0, "width": 0.8, "rate": 6.0, "frequency": 0.5, "phase": 1.0}


def test_term_is_the_modulated_spot() -> None:
    grid = Grid((16, 20), 0.5, duration=4.0)
    term = Effect("periodic_source", PARAMS).term(torch.zeros(16, 20, dtype=F64), 0.7, grid)
    x = (torch.arange(20, dtype=F64) + 0.5) * 0.5
    y = (torch.arange(16, dtype=F64) + 0.5) * 0.5
    spot = torch.exp(-((x[None, :] - 4.0) ** 2 + (y[:, None] - 3.0) ** 2) / (2 * 0.8**2))
    modulation = 0.5 * (1 + math.sin(2 * math.pi * 0.5 * 0.7 + 1.0))
    torch.testing.assert_close(term, 6.0 * modulation * spot, rtol=1e-12, atol=1e-12)


def test_heat_added_without_diffusion_is_the_integral_of_the_input() -> None:
    u0 = torch.zeros(12, 12, dtype=F64)
    params = {**PARAMS, "x": 3.0, "y": 3.0}
    video = simulate_effects(
        u0, a=0.0, dx=0.5, dt=0.1, n_frames=31, effects=[Effect("periodic_source", params)]
    )
    t = 3.0
    w = 2 * math.pi * 0.5
    integral = 0.5 * (t - (math.cos(w * t + 1.0) - math.cos(1.0)) / w)  # of (1 + sin(w s + phase)) / 2
    centre = math.exp(-2 * (0.25**2) / (2 * 0.8**2))  # pixel (5, 5) sits 0.25 mm off the spot on each axis
    assert float(video[-1, 5, 5]) == pytest.approx(6.0 * integral * centre, rel=1e-6)


def test_retiming_continues_the_same_oscillation() -> None:
    spec = EFFECTS["periodic_source"]
    u0 = 30.0 + torch.zeros(16, 16, dtype=F64)
    whole = simulate_effects(
        u0, a=0.1, dx=0.5, dt=0.1, n_frames=21, effects=[Effect("periodic_source", PARAMS)]
    )
    later = Effect("periodic_source", spec.retime(PARAMS, 2.0, 1.0, 1.0))
    rest = simulate_effects(whole[10], a=0.1, dx=0.5, dt=0.1, n_frames=11, effects=[later])
    torch.testing.assert_close(rest, whole[10:], rtol=1e-10, atol=1e-10)


def test_plugged_in_through_its_hooks_only() -> None:
    spec = EFFECTS["periodic_source"]
    assert spec.name == "periodic_source" and not spec.searched and spec.regressors == ("P",)
    text = equation_text(0.15, [Effect("periodic_source", PARAMS)])
    assert text.startswith("dT/dt = 0.150 Lap T + 6.00 (1 + sin(2 pi 0.5 t + 1.00)) / 2")
    from matplotlib.figure import Figure

    axes = Figure().subplots()
    assert spec.draw(axes, PARAMS).startswith("periodic source at (4.00, 3.00) mm")
    assert len(axes.lines) == 1


@pytest.mark.slow
def test_diagnosis_finds_it_when_asked() -> None:
    video = hidden_effect_video(["periodic_source"], seed=1, size=48, duration=2.0, dx=0.15)
    truth = video.effects[0].params
    found = diagnose_terms(video.frames, video.dt, video.dx, effects=list(EFFECTS))
    assert found.names == ["periodic_source"]
    params = found.effects[0]["params"]
    assert params["frequency"] == pytest.approx(truth["frequency"], rel=0.02)
    assert params["rate"] == pytest.approx(truth["rate"], rel=0.05)
    assert math.hypot(params["x"] - truth["x"], params["y"] - truth["y"]) < 0.2 * video.dx
    assert abs(math.remainder(params["phase"] - truth["phase"], 2 * math.pi)) < 0.1
