"""experiments/real_data.py: the small-box model against an exact solution, and the CLI on the real files."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from anra_torch.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import real_data  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"measured data folder {DATA} is absent")


def mode_video(a: float, b: float, c: float, dt: float, dx: float, n: int = 120) -> np.ndarray:
    """Exact solution of dT/dt = a Lap T - b (T - 20) + c: a cosine mode plus a relaxing mean."""
    y, x = np.mgrid[:12, :14] * dx
    k = 2 * np.pi / (14 * dx)
    t = np.arange(n)[:, None, None] * dt
    mean = 20 + c / b + (5 - c / b) * np.exp(-b * t)
    return mean + 3 * np.cos(k * x + 0.3) * np.exp(-(a * k**2 + b) * t) + 0 * y


def test_box_fit_recovers_known_coefficients() -> None:
    a, b, c, dt, dx = 0.15, 0.05, 0.4, 0.1, 0.25
    video = mode_video(a, b, c, dt, dx)
    fit = real_data.box_fit(video, dt, dx, extended=True)
    # The 5-point Laplacian reads a cos mode of 14 px low by (sin(k dx/2)/(k dx/2))^2 = 0.983.
    assert fit["a"] == pytest.approx(a / 0.983, rel=0.02)
    assert fit["b"] == pytest.approx(b, rel=0.02)
    assert fit["c"] - fit["b"] * (20 - fit["T_ref"]) == pytest.approx(c, rel=0.05)


def test_box_forecast_follows_the_exact_solution() -> None:
    a, b, c, dt, dx = 0.15, 0.05, 0.4, 0.1, 0.25
    video = mode_video(a, b, c, dt, dx)
    fit = {"a": a, "b": b, "c": c, "T_ref": 20.0}  # dT/dt = a Lap T - b (T - 20) + c
    predicted = real_data.box_forecast(video, dt, dx, fit, start=10, n=50)
    error = np.abs(predicted - video[11:61])[:, 1:-1, 1:-1].max()
    assert error < 0.05  # degC over 5 s (5-point Laplacian and Euler errors)
    plain = real_data.box_forecast(video, dt, dx, {"a": a, "b": 0.0, "c": 0.0, "T_ref": 0.0}, start=10, n=50)
    assert np.abs(plain - video[11:61])[:, 1:-1, 1:-1].max() > 10 * error


def test_harmonic_interior_is_exact_on_harmonic_polynomials() -> None:
    y, x = np.mgrid[:9, :13].astype(float)
    frames = np.stack([x**2 - y**2 + 3 * x * y + 2 * x, 5 - y + 0.5 * (x * x - y * y)])  # Lap = 0
    np.testing.assert_allclose(real_data.harmonic_interior(frames), frames[:, 1:-1, 1:-1], atol=1e-10)
    bump = frames.copy()
    bump[:, 4, 6] += 1.0  # not harmonic inside: the steady state for the same edges does not see it
    np.testing.assert_allclose(real_data.harmonic_interior(bump), frames[:, 1:-1, 1:-1], atol=1e-10)


def test_quasi_steady_forecast_is_exact_for_a_stationary_source_under_moving_edges() -> None:
    """T = harmonic(edges(t)) + S: the limit a -> infinity of dT/dt = a Lap T + q with Lap S = -q / a."""
    y, x = np.mgrid[:9, :13].astype(float)
    source = np.sin(np.pi * x / 12) * np.sin(np.pi * y / 8)  # zero on the edges
    t = np.arange(80)[:, None, None] * 0.1
    frames = 100 + 0.3 * np.sin(2 * t) + 0.1 * t * (x - 6) + 0.05 * (x * y - 3 * y) * np.cos(t) + 4 * source
    predicted = real_data.quasi_steady_forecast(frames, slice(0, 41), start=40, n=39)
    np.testing.assert_allclose(predicted, frames[41:80], atol=1e-9)
    assert real_data.edge_explained(frames) == pytest.approx(1.0, abs=1e-9)


@needs_data
def test_csv_phase_gain_is_measured(tmp_path: Path) -> None:
    video = real_data.load("Sample2 RT M1", DATA / "flir_csv" / "Sample2 RT M1.csv")
    from anra_torch.video.phases import segment_phases

    cooling = segment_phases(video.frames)[-1]
    fit = real_data.box_phase(video, cooling)
    assert fit["extended_model"] == "loss"
    assert fit["extended_rmse"] < 0.5 * fit["base_rmse"]  # measured: 0.194 vs 1.76 degC
    assert fit["extended_rmse"] > fit["noise_floor"]


@needs_data
def test_csv_heating_plateau_is_forecast_by_the_quasi_steady_source() -> None:
    """Q 100 Silver 1 heating: a plateau the loss model cannot forecast; the edges and a source map can."""
    from anra_torch.video.phases import segment_phases

    video = real_data.load("Q 100 Silver 1", DATA / "flir_csv" / "Q 100 Silver 1.csv")
    heating = segment_phases(video.frames)[1]
    assert 1070 <= heating.stop <= 1085  # the source notes: switched off at roughly frame 1,080
    fit = real_data.box_phase(video, heating)
    assert fit["extended_model"] == "quasi-steady source" and fit["effects"] == ["source"]
    assert abs(fit["a_plain"]) < 0.01  # mm^2/s: diffusion not resolved in the 9 px box
    assert fit["gain"] > 0.4  # measured +0.56 (RMSE 0.244 -> 0.108 degC)
    assert fit["other_gain"] < 0.0  # the loss model: measured -0.25
    assert fit["edge_explained_fit"] > 0.5  # measured 0.64


@needs_data
def test_laser_heating_source_map_forecasts_better_than_plain_and_gaussian_spot() -> None:
    """Nov19_2 heating: the measured beam map beats the plain model; the Gaussian spot does not."""
    from dataclasses import replace

    import torch

    from anra_torch.video.phases import segment_phases

    video = real_data.load("Nov19_2", DATA / "laser_silicone" / "Nov19_2")
    video = replace(video, t=torch.arange(video.frames.shape[0], dtype=torch.float64) * video.dt)
    heating = [p for p in segment_phases(video.frames, video.t) if p.name == "heating"][0]
    fit = real_data.anra_phase(video, heating)
    assert fit["effects"][0] == "source"
    assert fit["gain"] > 0.2  # measured +0.32 (RMSE 5.27 -> 3.58 degC)
    assert fit["parametric_gain"] < 0.0  # measured -0.28
    assert fit["source_map"]["forcing_max_per_s"] > 1.0  # the beam heats by K/s at its centre


@needs_data
def test_cli_estimates_a_flir_folder_and_says_it_resampled(capsys: pytest.CaptureFixture[str]) -> None:
    folder = DATA / "laser_silicone" / "Nov19_2"
    assert (
        main(["estimate", str(folder), "--dx", "0.55", "--resample", "--roi", "30,20,70,60", "--json"]) == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert out["input"]["resampled"]["from_frames"] == 25 and out["frames"] == 24
    assert (out["height"], out["width"]) == (60, 70) and out["input"]["roi"] == [30, 20, 70, 60]
    assert out["dt"] == pytest.approx(4.994, abs=1e-3)


@needs_data
def test_cli_one_line_errors_on_real_files(capsys: pytest.CaptureFixture[str]) -> None:
    csv = DATA / "flir_csv" / "Sample2 RT M1.csv"
    assert main(["estimate", str(csv), "--dt", "0.1", "--dx", "0.25", "--calibration", str(csv)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected 'true,apparent'" in err
    assert main(["diagnose", str(csv), "--dx", "0.25"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no frame period" in err
