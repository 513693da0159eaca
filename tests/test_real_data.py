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


@needs_data
def test_csv_phase_gain_is_measured(tmp_path: Path) -> None:
    video = real_data.load("Sample2 RT M1", DATA / "flir_csv" / "Sample2 RT M1.csv")
    from anra_torch.phases import segment_phases

    cooling = segment_phases(video.frames)[-1]
    fit = real_data.box_phase(video, cooling)
    assert fit["extended_rmse"] < 0.5 * fit["base_rmse"]  # measured: 0.155 vs 1.76 degC
    assert fit["extended_rmse"] > fit["noise_floor"]


@needs_data
def test_laser_heating_source_map_forecasts_better_than_plain_and_gaussian_spot() -> None:
    """Nov19_2 heating: the measured beam map beats the plain model; the Gaussian spot does not."""
    from dataclasses import replace

    import torch

    from anra_torch.phases import segment_phases

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
