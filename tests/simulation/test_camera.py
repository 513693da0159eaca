"""Camera artefacts: each planter puts exactly what its record says, reproducibly, and nothing else."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from anra_torch.effects import Sensor, hidden_effect_video
from anra_torch.simulation.camera import (
    ARTEFACTS,
    bad_elements,
    correlated_noise,
    default_levels,
    fixed_pattern,
    offset_steps,
    plant,
)


@pytest.fixture
def video(dtype: torch.dtype) -> torch.Tensor:
    return hidden_effect_video(
        (), seed=2, size=48, duration=1.0, sensor=Sensor(noise_frac=0.01, dtype=dtype)
    ).frames


def _rounding(dtype: torch.dtype, scale: float) -> float:
    """Absolute tolerance of one addition of values of size ``scale`` in ``dtype``."""
    return 4 * torch.finfo(dtype).eps * scale


@pytest.mark.parametrize("kind", list(ARTEFACTS))
def test_reproducible_json_and_input_untouched(kind: str, video: torch.Tensor) -> None:
    before = video.clone()
    one, record = plant(video, kind, seed=5, noise_sd=0.1, dt=0.05)
    two, again = plant(video, kind, seed=5, noise_sd=0.1, dt=0.05)
    other, _ = plant(video, kind, seed=6, noise_sd=0.1, dt=0.05)
    assert torch.equal(video, before)
    assert torch.equal(one, two) and record == again
    assert not torch.equal(one, other)
    assert one.dtype == video.dtype and one.shape == video.shape
    assert record["kind"] == kind and record["seed"] == 5
    assert json.loads(json.dumps(record, allow_nan=False)) == record
    generator = np.random.default_rng(5)  # a generator gives the same draws as its seed
    three, by_generator = plant(video, kind, seed=generator, noise_sd=0.1, dt=0.05)
    assert torch.equal(three, one) and by_generator["seed"] is None


def test_bad_elements(video: torch.Tensor) -> None:
    out, record = bad_elements(video, seed=3, spikes=12, dead=4, hot=6)
    assert (len(record["spikes"]), len(record["dead"]), len(record["hot"])) == (12, 4, 6)
    touched = torch.zeros(video.shape, dtype=torch.bool)
    low, high = float(video.min()), float(video.max())
    for d in record["dead"]:
        assert torch.all(out[:, d["row"], d["col"]] == torch.tensor(d["value"], dtype=video.dtype))
        assert low <= d["value"] <= high
        touched[:, d["row"], d["col"]] = True
    for h in record["hot"]:
        column = out[:, h["row"], h["col"]]
        if h["mode"] == "stuck":
            assert torch.all(column == torch.tensor(h["value"], dtype=video.dtype))
            assert high + 10 <= h["value"] <= high + 50
        else:
            excess = column - video[:, h["row"], h["col"]]
            torch.testing.assert_close(
                excess, torch.full_like(excess, h["value"]), rtol=0, atol=_rounding(video.dtype, 100)
            )
            assert 10 <= h["value"] <= 50
        touched[:, h["row"], h["col"]] = True
    assert {h["mode"] for h in record["hot"]} == {"stuck", "offset"}
    for s in record["spikes"]:
        f, r, c = s["frame"], s["row"], s["col"]
        assert abs(float(out[f, r, c] - video[f, r, c]) - s["size"]) <= _rounding(video.dtype, 400)
        assert 30 <= abs(s["size"]) <= 300
        touched[f, r, c] = True
    assert {math.copysign(1, s["size"]) for s in record["spikes"]} == {1.0, -1.0}
    pixels = [(x["row"], x["col"]) for x in record["dead"] + record["hot"] + record["spikes"]]
    assert len(set(pixels)) == len(pixels)  # distinct elements
    assert torch.equal(out[~touched], video[~touched])  # the rest is untouched
    assert int((out != video).sum()) <= int(touched.sum())


def test_fixed_pattern(video: torch.Tensor) -> None:
    out, record = fixed_pattern(video, seed=4, sd=0.3, stripe_sd=0.2)
    pattern = (out - video).double()
    tol = _rounding(video.dtype, float(video.abs().max()))
    torch.testing.assert_close(pattern, pattern[:1].expand_as(pattern), rtol=0, atol=2 * tol)  # static
    frame = pattern.mean(0)
    assert (record["pixel_sd"], record["stripe_sd"]) == (0.3, 0.2)
    assert abs(float(frame.std(unbiased=False)) - record["pattern_sd_realised"]) < 1e-3 * 0.3 + tol
    # the columns carry the stripes: their means spread like the stripes, the rest like the pixels
    columns = frame.mean(0)
    assert abs(float(columns.std(unbiased=False)) - record["stripe_sd_realised"]) < 0.3 / math.sqrt(48) * 3
    assert abs(float((frame - columns).std()) - record["pixel_sd_realised"]) < 0.05 * 0.3
    assert abs(record["pixel_sd_realised"] - 0.3) < 0.1 * 0.3
    assert abs(record["stripe_sd_realised"] - 0.2) < 0.35 * 0.2  # 48 columns only


def _correlation_length(noise: np.ndarray, axis: int) -> float:
    """``l`` of an autocorrelation ``exp(-d^2 / (2 l^2))`` from its value at lag 1 along ``axis``."""
    n = noise.shape[axis]
    lag = (np.take(noise, np.arange(n - 1), axis=axis) * np.take(noise, np.arange(1, n), axis=axis)).mean()
    return math.sqrt(-1.0 / (2.0 * math.log(lag / noise.var())))


def test_correlated_noise(dtype: torch.dtype) -> None:
    video = torch.full((81, 96, 96), 30.0, dtype=dtype)
    out, record = correlated_noise(video, seed=7, sd=0.2, length_px=1.5, length_frames=3.0)
    noise = (out - video).double().numpy()
    assert abs(noise.std() - 0.2) < 1e-3 * 0.2 + 10 * torch.finfo(dtype).eps * 30
    assert abs(noise.mean()) < 0.1 * 0.2
    for axis, requested in ((0, 3.0), (1, 1.5), (2, 1.5)):
        assert abs(_correlation_length(noise, axis) - requested) < 0.15 * requested
    assert record["length_px"] == 1.5 and record["length_frames"] == 3.0 and record["sd"] == 0.2
    white, _ = correlated_noise(video, seed=7, sd=0.2, length_px=0.0, length_frames=0.0)
    flat = (white - video).double()
    assert abs(float((flat[:, :, 1:] * flat[:, :, :-1]).mean() / flat.var())) < 0.02  # no correlation


def test_offset_steps(video: torch.Tensor) -> None:
    dt = 0.05
    out, record = offset_steps(video, seed=8, dt=dt, steps=4)
    diff = (out - video).double()
    tol = 2 * _rounding(video.dtype, float(video.abs().max()))
    offsets = torch.tensor(record["offsets"], dtype=torch.float64)
    torch.testing.assert_close(diff, offsets[:, None, None].expand_as(diff), rtol=0, atol=tol)  # uniform
    jumps = offsets.diff() - record["drift_rate"] * dt
    frames = {s["frame"]: s["size"] for s in record["steps"]}
    assert len(frames) == 4
    for k in range(1, video.shape[0]):
        assert abs(float(jumps[k - 1]) - frames.get(k, 0.0)) < 1e-12
    assert all(0.05 <= abs(s) <= 0.3 for s in frames.values())
    assert 0.02 <= abs(record["drift_rate"]) <= 0.1
    assert float(offsets[0]) == 0.0
    fixed, rec = offset_steps(video, seed=8, dt=dt, steps=0, drift=0.5)
    assert rec["steps"] == [] and rec["drift_rate"] == 0.5
    assert abs(rec["offsets"][-1] - 0.5 * dt * (video.shape[0] - 1)) < 1e-12


def test_default_levels() -> None:
    assert default_levels("fixed_pattern", noise_sd=0.1, dt=0.05) == pytest.approx(
        {"sd": 0.3, "stripe_sd": 0.15}
    )
    assert default_levels("correlated_noise", noise_sd=0.1, dt=0.05)["sd"] == pytest.approx(0.2)
    assert default_levels("offset_steps", noise_sd=0.1, dt=0.05) == {"dt": 0.05}


def test_errors() -> None:
    video = torch.zeros(5, 8, 8)
    with pytest.raises(
        ValueError, match=r"frames must have shape \(T, H, W\): one video, got \(2, 5, 8, 8\)"
    ):
        bad_elements(torch.zeros(2, 5, 8, 8), seed=0)
    with pytest.raises(ValueError, match="frames must be finite"):
        fixed_pattern(torch.full((5, 8, 8), math.nan), seed=0, sd=1.0)
    with pytest.raises(ValueError, match="dead \\+ hot \\+ spikes must be at most the 64 pixels"):
        bad_elements(video, seed=0, spikes=60, dead=5)
    with pytest.raises(ValueError, match="spike_range must be \\(low, high\\)"):
        bad_elements(video, seed=0, spike_range=(300.0, 30.0))
    with pytest.raises(ValueError, match="seed must be an integer >= 0"):
        bad_elements(video, seed=-1)
    with pytest.raises(ValueError, match="sd must be a finite number >= 0 in K"):
        correlated_noise(video, seed=0, sd=-1.0)
    with pytest.raises(ValueError, match="steps must be at most the 4 frames after the first, got 5"):
        offset_steps(video, seed=0, dt=0.1, steps=5)
    with pytest.raises(ValueError, match="unknown artefact kind 'blur'"):
        plant(video, "blur", seed=0, noise_sd=0.1, dt=0.1)
