"""Forecasting's shared pieces (:mod:`anra_torch.forecast.core`): the assimilated state, the diagnosed
effects as a simulatable model (re-timed), the split and the forecast errors.
"""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.effects import Sensor, hidden_effect_video, simulate_effects
from anra_torch.forecast.core import assimilated_state, extended_effects, forecast_errors, split_index
from anra_torch.selection import diagnose_terms


def video(names: list[str], seed: int, size: int = 64, **kwargs: object):
    return hidden_effect_video(names, seed=seed, size=size, duration=3.0, **kwargs)


def test_assimilated_state_is_the_mean_of_forecasts_from_each_frame() -> None:
    """For a linear one-frame model the running mean equals mean_j M^j y_(s-j), exactly."""
    frames = torch.randn(6, 5, 7, dtype=torch.float64)
    step = lambda frame, state: 0.9 * state.roll(1, -1) + 0.01 * frame  # noqa: E731 - affine in the state
    state = assimilated_state(frames, step, 4)
    forecasts = []
    for start in range(2, 6):
        x = frames[start]
        for frame in range(start, 5):
            x = step(frame, x)
        forecasts.append(x)
    assert torch.allclose(state, torch.stack(forecasts).mean(0), atol=1e-12)
    assert torch.equal(assimilated_state(frames, step, 1), frames[-1])


@pytest.mark.slow
@pytest.mark.parametrize("name", ["anisotropy", "linear_loss"])
def test_extended_effects_round_trip_on_noiseless_video(name: str) -> None:
    # 48 px: round trips 6e-8 to 1e-5 of the rise over seeds 0-3 (64 px: 3e-7, 1e-6); a 1 % error in the
    # loss rate or a flipped a_xy between the diagnosis and the simulator fails it
    v = video([name], 0, 48, sensor=Sensor(noise_frac=1e-4))
    diagnosis = diagnose_terms(v.clean, v.dt, v.dx)
    effects = extended_effects(diagnosis)
    assert [e.name for e in effects] == [name]
    n = v.clean.shape[0]
    ours = simulate_effects(v.clean[0], a=diagnosis.base, dx=v.dx, dt=v.dt, n_frames=n, effects=effects)
    truth = simulate_effects(v.clean[0], a=0.15, dx=v.dx, dt=v.dt, n_frames=n, effects=v.effects)
    rise = float(v.clean[0].max() - v.clean[0].min())
    assert float((ours - truth).abs().max()) < 1e-4 * rise


@pytest.mark.slow
def test_source_path_is_retimed_for_the_forecast() -> None:
    v = video(["source"], 0)
    split = split_index(v.frames.shape[0], 0.6)
    diagnosis = diagnose_terms(v.frames[: split + 1], v.dt, v.dx)
    fit = split * v.dt
    (plain,) = extended_effects(diagnosis)
    (moved,) = extended_effects(diagnosis, fit_duration=fit, start=fit, duration=2 * fit)
    p, q = plain.params, moved.params
    assert math.isclose(q["x0"], p["x1"], abs_tol=1e-12) and math.isclose(q["y0"], p["y1"], abs_tol=1e-12)
    assert math.isclose(q["x1"] - q["x0"], 2 * (p["x1"] - p["x0"]), abs_tol=1e-9)
    true = v.effects[0].params  # the truth moves over the whole video
    at_split = true["x0"] + (true["x1"] - true["x0"]) * split / (v.frames.shape[0] - 1)
    assert abs(q["x0"] - at_split) < 0.2 * v.dx
    with pytest.raises(ValueError, match="fit_duration must be a positive number"):
        extended_effects(diagnosis, start=1.0)


@pytest.mark.slow
def test_unmappable_effect_raises_clear_error() -> None:
    v = video(["linear_loss"], 1, 32)  # any diagnosis naming an effect will do: a small frame
    diagnosis = diagnose_terms(v.frames[:40], v.dt, v.dx)
    diagnosis.effects[0]["name"] = "perfusion"
    with pytest.raises(ValueError, match="diagnosed effect 'perfusion' has no simulator"):
        extended_effects(diagnosis)
    diagnosis.effects[0].update(name="linear_loss", params={"b": 0.2})
    with pytest.raises(ValueError, match="'linear_loss' cannot be simulated: .*missing T_ref"):
        extended_effects(diagnosis)


@pytest.mark.parametrize("fraction", [0.0, 1.0, -0.2, float("nan")])
def test_bad_fit_fraction(fraction: float) -> None:
    with pytest.raises(ValueError, match="fit_fraction must be a number in"):
        split_index(90, fraction)


def test_forecast_errors_exclude_margin() -> None:
    measured = torch.zeros(3, 10, 10, dtype=torch.float64)
    predicted = measured.clone()
    predicted[:, 0, :] = 100.0  # only on the edge
    predicted[1, 5, 5] = 2.0
    per_frame, rmse, sse = forecast_errors(predicted, measured, 2)
    assert per_frame.tolist() == [0.0, math.sqrt(4 / 36), 0.0]
    assert sse == 4.0 and math.isclose(rmse, math.sqrt(4 / 108))


def test_forecast_errors_within_pixels_and_frames_leave_out_a_static_pattern_and_offsets() -> None:
    """A static pattern (a camera's fixed pattern, which every model smooths away) and a global offset per
    frame are no forecast error with the per-pixel and per-frame fixed effects; what changes over both
    stays."""
    gen = torch.Generator().manual_seed(0)
    measured = torch.zeros(4, 8, 8, dtype=torch.float64)
    change = torch.randn(4, 8, 8, generator=gen, dtype=torch.float64)
    change = change - change.mean(0) - change.mean((1, 2), keepdim=True) + change.mean()  # neither part
    pattern = torch.randn(8, 8, generator=gen, dtype=torch.float64)
    offsets = torch.tensor([0.0, 0.3, 0.3, -0.2], dtype=torch.float64)[:, None, None]
    predicted = measured + change + pattern + offsets
    _, rmse, _ = forecast_errors(predicted, measured, 0, within_pixels=True, within_frames=True)
    assert math.isclose(rmse, float(change.pow(2).mean().sqrt()))
    _, pattern_only, _ = forecast_errors(measured + pattern, measured, 0, within_pixels=True)
    assert pattern_only < 1e-12 < forecast_errors(measured + pattern, measured, 0)[1]
