"""The stationary source map: the simulator's forcing, recovery of a, b and q, and the forecast it gives."""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor

from anra_torch.effects import Effect, simulate_effects
from anra_torch.forecast import assess_gain, fit_source_map, source_map_gain
from anra_torch.forecast.core import at_scale

F64 = torch.float64


def _ring_beam(size: int, dx: float) -> tuple[Tensor, Tensor]:
    """A ring-shaped heat input (K/s): not a Gaussian spot, as a fibre-tip beam is not."""
    y, x = torch.meshgrid(torch.arange(size, dtype=F64), torch.arange(size, dtype=F64), indexing="ij")
    r = torch.sqrt((x - 0.45 * size) ** 2 + (y - 0.55 * size) ** 2) * dx
    ring = 6.0 * torch.exp(-((r - 4.0) ** 2) / (2 * 1.2**2))
    return ring, r


def _beam_video(noise: float, seed: int = 0) -> tuple[Tensor, float, float, dict]:
    size, dx, dt, a, b = 64, 0.5, 0.5, 0.12, 0.05
    ring, _ = _ring_beam(size, dx)
    u0 = torch.full((size, size), 25.0, dtype=F64)
    loss = Effect("linear_loss", {"b": b, "T_ref": 25.0})
    clean = simulate_effects(u0, a=a, dx=dx, dt=dt, n_frames=40, effects=[loss], forcing=ring)
    g = torch.Generator().manual_seed(seed)
    frames = clean + noise * torch.randn(clean.shape, generator=g, dtype=F64)
    return frames, dt, dx, {"a": a, "b": b, "q": ring + b * 25.0}


def test_forcing_matches_the_exact_relaxation() -> None:
    """Uniform field, loss b, forcing q: T(t) = q/b + (T0 - q/b) exp(-b t) to RK4 error (50 substeps)."""
    u0 = torch.full((6, 7), 30.0, dtype=F64)
    q = torch.full((6, 7), 2.0, dtype=F64)
    loss = Effect("linear_loss", {"b": 0.4, "T_ref": 0.0})
    video = simulate_effects(u0, a=0.3, dx=0.5, dt=0.25, n_frames=21, effects=[loss], forcing=q, substeps=50)
    t = torch.arange(21, dtype=F64) * 0.25
    exact = 5.0 + (30.0 - 5.0) * torch.exp(-0.4 * t)
    assert torch.allclose(video[:, 3, 3], exact, rtol=1e-10, atol=0)
    assert float((video - video[:, :1, :1]).abs().max()) < 1e-12  # stays uniform


def test_forcing_must_match_the_frame() -> None:
    u0 = torch.zeros(6, 7, dtype=F64)
    message = r"forcing must be a finite map of the frame's shape \(6, 7\).*got shape \(7, 6\)"
    with pytest.raises(ValueError, match=message):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, forcing=torch.zeros(7, 6))
    bad = torch.zeros(6, 7)
    bad[0, 0] = math.nan
    with pytest.raises(ValueError, match="non-finite"):
        simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=3, forcing=bad)


def test_recovers_diffusivity_loss_and_the_beam_map() -> None:
    frames, dt, dx, truth = _beam_video(noise=0.02)
    model = fit_source_map(frames, dt, dx, scale_px=1.0, margin=4)
    assert model.a == pytest.approx(truth["a"], rel=0.05)
    assert model.b == pytest.approx(truth["b"], rel=0.05)
    assert model.n_rates == 38
    inner = (slice(8, -8), slice(8, -8))
    q_true = at_scale(truth["q"][None], 1.0)[0][inner]
    q_fit = model.forcing[inner]
    corr = torch.corrcoef(torch.stack([q_true.reshape(-1), q_fit.reshape(-1)]))[0, 1]
    assert float(corr) > 0.99
    assert torch.equal(model.forcing[:4, 10], model.forcing[4, 10].expand(4))  # the margin repeats the edge
    assert torch.allclose(model.equilibrium * model.b, model.forcing)


@pytest.mark.slow
def test_map_forecast_beats_plain_and_gaussian_source_on_a_ring_beam() -> None:
    """Fit on 25 frames, forecast 15: the map model is near the noise floor, a Gaussian spot is not."""
    frames, dt, dx, _ = _beam_video(noise=0.05)
    result = assess_gain(frames, dt, dx, fit_fraction=0.625, assimilate=1)  # split at frame 24
    mapped = source_map_gain(frames, dt, dx, result)
    assert result.split == 24 and mapped.predicted.shape == result.measured.shape
    assert mapped.gain == pytest.approx(1 - mapped.rmse / result.base_rmse)
    assert mapped.gain > 0.98  # measured 0.994 (map 0.016 K, plain 2.64 K)
    assert "source" in [e["name"] for e in result.diagnosis.effects]
    assert mapped.rmse < 0.05 * result.extended_rmse  # the Gaussian spot: 1.29 K


def test_pure_diffusion_gives_no_loss_and_a_flat_map() -> None:
    y, x = torch.meshgrid(torch.arange(48, dtype=F64), torch.arange(48, dtype=F64), indexing="ij")
    u0 = 20 + 30 * torch.exp(-((x - 24) ** 2 + (y - 22) ** 2) / (2 * 5.0**2))
    video = simulate_effects(u0, a=0.2, dx=0.4, dt=0.2, n_frames=20)
    model = fit_source_map(video, 0.2, 0.4, scale_px=0, margin=2)
    assert model.a == pytest.approx(0.2, rel=1e-3)
    assert model.b < 1e-4
    assert float(model.forcing.abs().max()) < 1e-2 * float((video[1] - video[0]).abs().max() / 0.2)


@pytest.mark.parametrize(
    ("frames", "kwargs", "message"),
    [
        (torch.zeros(3, 10, 10), {}, r"at least 4 frames for a per-pixel source map \(2 rates\), got 3"),
        (torch.zeros(10, 10), {}, r"frames must have shape \(T, H, W\), got \(10, 10\)"),
        (torch.zeros(5, 10, 10), {"margin": 4}, r"margin must be .* inside 10 x 10 frames, got 4"),
        (torch.zeros(5, 10, 10), {"margin": 0}, "got 0"),
        (torch.zeros(5, 10, 10), {"scale_px": -1.0}, r"scale_px must be a Gaussian sigma >= 0 in px"),
    ],
)
def test_bad_input_gets_a_one_line_error(frames: Tensor, kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        fit_source_map(frames, 0.1, 0.5, **kwargs)


def test_bad_spacing_and_non_finite_frames() -> None:
    frames = torch.zeros(5, 10, 10)
    with pytest.raises(ValueError, match=r"dt must be a positive finite number in s, got 0"):
        fit_source_map(frames, 0, 0.5)
    frames[2, 5, 5] = math.inf
    with pytest.raises(ValueError, match="frames must be finite"):
        fit_source_map(frames, 0.1, 0.5)


def _decaying_beam(n: int = 16, dt: float = 1.0, dx: float = 0.5, a: float = 0.12, size: int = 48) -> Tensor:
    """Explicit FTCS (0.05 s steps, zero-flux edges) of a ring beam whose input falls like ``t^(-1/2)`` from
    its switch-on at 0.5 s (a flux into a half-space), sampled every ``dt``."""
    ring, _ = _ring_beam(size, dx)
    u, now, frames, h = torch.full((size, size), 20.0, dtype=F64), 0.0, [], 0.05
    for k in range(n):
        while now < k * dt - 1e-9:
            p = torch.nn.functional.pad(u[None, None], (1, 1, 1, 1), mode="replicate")[0, 0]
            lap = (p[1:-1, 2:] + p[1:-1, :-2] + p[2:, 1:-1] + p[:-2, 1:-1] - 4 * u) / dx**2
            on = now + h / 2 - 0.5  # s since the switch-on
            u, now = u + h * (a * lap + (ring * on**-0.5 if on > 0 else 0.0)), now + h
        frames.append(u.clone())
    return torch.stack(frames)


@pytest.mark.slow
def test_a_decaying_map_assimilated_over_every_fit_frame_does_not_step_over_its_switch_on() -> None:
    """A dense recording assimilates all its fit frames; frame 0's interval holds the switch-on, where the
    input ``(t - t_on)^-p`` is unbounded (stepped there, the forecast erred 1e3 times the plain one)."""
    frames = _decaying_beam(n=30)
    result = assess_gain(frames, 1.0, 0.5)
    assert result.assimilated == result.split + 1
    decaying = source_map_gain(frames, 1.0, 0.5, result, decay=0.5, t_on=0.5)
    stationary = source_map_gain(frames, 1.0, 0.5, result)
    assert decaying.rmse < stationary.rmse < result.base_rmse


def test_a_decaying_input_is_recovered_and_forecasts_where_a_stationary_map_overshoots() -> None:
    """Fitted on frames 3-12 (the clock starts at frame 3: the switch-on is at -2.5 s), away from the
    input's singular start, which no 3-frame difference resolves."""
    frames = _decaying_beam(n=20)
    fit = fit_source_map(frames[3:13], 1.0, 0.5, scale_px=0.0, margin=2, decay=0.5, t_on=-2.5)
    assert fit.a == pytest.approx(0.12, rel=0.05) and fit.t_ref == 8.0
    ring, _ = _ring_beam(48, 0.5)
    inner = (slice(4, -4), slice(4, -4))
    q = ring * (11.0 - 0.5) ** -0.5  # the input at t_ref (11 s after the first frame)
    assert float((fit.forcing - q)[inner].abs().max()) < 0.05 * float(q.max())
    # From frame 12 on: the stationary map keeps an input of the fit frames and overshoots.
    decaying = fit.forecast(frames[12], dt=1.0, dx=0.5, n_frames=8, start=9.0)
    stationary = fit_source_map(frames[3:13], 1.0, 0.5, scale_px=0.0, margin=2)
    constant = stationary.forecast(frames[12], dt=1.0, dx=0.5, n_frames=8)
    errors = [float((f[1:] - frames[13:])[(slice(None), *inner)].abs().max()) for f in (decaying, constant)]
    assert errors[0] < 0.2 * errors[1]
    with pytest.raises(ValueError, match=r"start must put the first interval's middle after the input's"):
        fit.forecast(frames[3], dt=1.0, dx=0.5, n_frames=2, start=-3.0)  # frame 3's interval holds t_on
    with pytest.raises(ValueError, match=r"decay must be >= 0 and t_on before frame 1"):
        fit_source_map(frames[:10], 1.0, 0.5, decay=0.5, t_on=1.5)
