"""TissueFeatures (:mod:`anra_torch.tissue.features`): maps against the dose functions, planted loss and
source, masking, units, batching, traces, extremes from confident windows.
"""

from __future__ import annotations

import math

import pytest
import torch
from reference import cem43_constant, omega_constant

from anra_torch.simulation import MovingSource, gaussian_blob, simulate_tissue
from anra_torch.simulation.synthetic import paper_video
from anra_torch.tissue.dose import arrhenius_omega, cem43, time_above
from anra_torch.tissue.feature_maps import MAPS, MAX_LOSS_ERROR, MIN_CONFIDENCE
from anra_torch.tissue.features import TissueFeatures, feature_summary

DX, DT = 0.2, 0.1


POWER, ON = 10.0, 2.0  # K/s at the spot centre, s


@pytest.fixture(scope="module")
def heated() -> torch.Tensor:
    """A static spot heats tissue at 37 C for 2 s, then it cools for 4 s (a = 0.1, b = 0.3)."""
    u0 = torch.full((40, 40), 37.0, dtype=torch.float64)
    source = MovingSource(start=(4.0, 4.0), end=(4.0, 4.0), width=0.8, power=POWER, t_off=ON)
    clean = simulate_tissue(u0, 0.1, 0.3, dx=DX, dt=DT, n_frames=61, source=source)
    generator = torch.Generator().manual_seed(1)
    return clean + 0.02 * torch.randn(clean.shape, generator=generator, dtype=torch.float64)


def test_maps_shapes_units_and_finiteness(heated: torch.Tensor) -> None:
    out = TissueFeatures()(heated, DT, DX)
    assert tuple(out.maps) == MAPS
    for name, m in out.maps.items():
        assert m.shape == (40, 40), name
        assert bool(torch.isfinite(m).all()), name
        assert name in out.units
    assert out.stack().shape == (len(MAPS), 40, 40)
    assert out.stack(["omega", "cem43_minutes"]).shape == (2, 40, 40)
    assert out.units["cem43_minutes_max"] == "min" and out.units["peak_temperature_max"] == "C"
    assert out.messages == ("",) or out.messages == ""
    with pytest.raises(ValueError, match="unknown feature map 'burn'"):
        out.stack(["burn"])


def test_dose_maps_equal_the_dose_functions_on_the_raw_history(heated: torch.Tensor) -> None:
    out = TissueFeatures(smoothing=0.0, rule="linear")(heated, DT, DX)
    torch.testing.assert_close(
        out.maps["cem43_minutes"], cem43(heated, DT, rule="linear"), rtol=1e-12, atol=0
    )
    torch.testing.assert_close(
        out.maps["omega"], arrhenius_omega(heated, DT, rule="linear"), rtol=1e-12, atol=0
    )
    torch.testing.assert_close(
        out.maps["time_above_43"], time_above(heated, DT, 43.0, rule="linear"), rtol=1e-12, atol=0
    )
    torch.testing.assert_close(out.maps["peak_temperature"], heated.amax(0), rtol=1e-12, atol=0)
    assert float(out.summary["omega_max"]) == float(out.maps["omega"].max())
    assert float(out.summary["damaged_fraction"]) == float((out.maps["omega"] >= 1).double().mean())


def test_planted_loss_rate_and_source(heated: torch.Tensor) -> None:
    out = TissueFeatures()(heated, DT, DX)
    centre = (slice(18, 22), slice(18, 22))
    # b = 0.3 1/s: measured 0.33-0.35 on the spot (the 5-point balance of a smoothed spot)
    assert out.maps["loss_rate"][centre].median().item() == pytest.approx(0.3, rel=0.25)
    # The source deposits POWER * ON = 20 K at its centre before the 2 px smoothing (16 K after it,
    # less the 0.2 s before the first derivative frame): measured 13.9 K.
    source = out.maps["source"]
    assert 12.0 < source[centre].max().item() < 16.5
    assert source[:5, :5].abs().max().item() < 0.5  # nothing far from the spot
    row, col = divmod(int(source.argmax()), 40)
    assert abs(row - 19.5) <= 1 and abs(col - 19.5) <= 1
    # RTC attention (1 = uniform) sits on the spot, where the temperature changes fastest.
    attention = out.maps["rtc_attention"]
    assert attention[centre].min().item() > 10.0 and attention[:5, :5].max().item() < 0.1


def test_cooling_diffusivity_is_not_biased_by_the_source(heated: torch.Tensor) -> None:
    """The estimator's map fits ``a`` over every frame, heating included: the source drives it below zero on
    the spot. The cooling fit's ``a`` (a = 0.1 mm^2/s planted) is measured 0.12-0.14 there, the same
    smoothed-spot bias as the loss rate's."""
    out = TissueFeatures()(heated, DT, DX)
    centre = (slice(18, 22), slice(18, 22))
    assert out.maps["diffusivity"][centre].median().item() < 0.0
    cooling = out.cooling_diffusivity
    assert cooling.shape == (40, 40) and bool(torch.isfinite(cooling).all())
    assert cooling[centre].median().item() == pytest.approx(0.1, rel=0.4)
    batched = TissueFeatures()(heated[None], DT, DX).cooling_diffusivity
    torch.testing.assert_close(batched[0], cooling, rtol=1e-12, atol=1e-12)
    assert TissueFeatures()(heated, DT).cooling_diffusivity is None  # no pixel size: no ANRA maps


def test_heating_and_cooling_rates_of_a_linear_ramp() -> None:
    # Every pixel: +3 K/s for 2 s then -1 K/s: the Holoborodko derivative is exact on lines.
    t = torch.arange(41, dtype=torch.float64) * DT
    history = 37.0 + torch.where(t <= 2.0, 3.0 * t, 6.0 - (t - 2.0))
    ramp = history.view(-1, 1, 1) + 0.1 * torch.randn(1, 24, 24, dtype=torch.float64).clamp(-1, 1)
    out = TissueFeatures(smoothing=0.0)(ramp, DT, DX)
    torch.testing.assert_close(out.maps["heating_rate"], torch.full((24, 24), 3.0, dtype=torch.float64))
    torch.testing.assert_close(out.maps["cooling_rate"], torch.full((24, 24), 1.0, dtype=torch.float64))


def test_diffusivity_map_of_a_pure_heat_video() -> None:
    t = torch.arange(16, dtype=torch.float64) * 0.05
    video = 37.0 + gaussian_blob(t, shape=(48, 48), dx=0.1, a=0.2, peak=10.0, sigma=0.6)
    out = TissueFeatures()(video, 0.05, 0.1)
    assert float(out.summary["diffusivity_global"]) == pytest.approx(0.2, rel=1e-3)
    confident = out.maps["confidence"] > 0.5
    assert int(confident.sum()) > 100
    assert out.maps["diffusivity"][confident].median().item() == pytest.approx(0.2, rel=0.02)


def test_kelvin_input_gives_the_same_maps(heated: torch.Tensor) -> None:
    celsius = TissueFeatures()(heated[:30], DT, DX)
    kelvin = TissueFeatures(units="K")(heated[:30] + 273.15, DT, DX)
    for name in ("peak_temperature", "cem43_minutes", "omega", "heating_rate", "source"):
        torch.testing.assert_close(kelvin.maps[name], celsius.maps[name], rtol=1e-6, atol=1e-9)


def test_batch_equals_single_videos(heated: torch.Tensor) -> None:
    pair = torch.stack([heated[:30], heated[:30].flip(-1)])
    batch = TissueFeatures()(pair, torch.tensor([DT, 2 * DT]), DX)
    for i, dt in enumerate((DT, 2 * DT)):
        single = TissueFeatures()(pair[i], dt, DX)
        for name in ("omega", "cem43_minutes", "source", "loss_rate", "diffusivity"):
            torch.testing.assert_close(batch.maps[name][i], single.maps[name], rtol=1e-7, atol=1e-9)


def test_non_finite_samples_are_masked_and_reported(heated: torch.Tensor) -> None:
    video = heated[:30].clone()
    video[10, 5, 7] = math.nan
    video[11:13, 30, 30] = math.inf
    out = TissueFeatures()(video, DT, DX)
    assert int(out.summary["n_masked"]) == 3
    assert int(out.masked[5, 7]) == 1 and int(out.masked[30, 30]) == 2
    assert "3 non-finite samples masked" in out.messages
    for name, m in out.maps.items():
        assert bool(torch.isfinite(m).all()), name


def test_units_that_do_not_fit_are_refused(heated: torch.Tensor) -> None:
    with pytest.raises(ValueError, match=r"--units C.*only makes sense in K"):
        TissueFeatures()(heated[:10] + 273.15, DT, DX)
    with pytest.raises(ValueError, match=r"--units K.*below absolute zero"):
        TissueFeatures(units="K")(heated[:10] - 400.0, DT, DX)
    with pytest.raises(ValueError, match="units must be one of 'C', 'K', got 'F'"):
        TissueFeatures(units="F")
    with pytest.raises(ValueError, match="window must be an odd number"):
        TissueFeatures(window=4)


def test_extremes_keep_a_planted_loss_and_source(heated: torch.Tensor) -> None:
    # Confident windows hold the planted b = 0.3 1/s (0.33-0.37 measured on the spot) and the source.
    out = TissueFeatures()(heated, DT, DX)
    assert 0.25 < float(out.summary["loss_rate_max"]) < 0.45
    assert float(out.summary["source_max"]) == pytest.approx(float(out.maps["source"].max()), rel=1e-12)
    assert float(out.summary["confident_fraction"]) > 0.3
    error = out.loss_rate_std_error
    assert error is not None and error.shape == (40, 40)
    assert float(error[18:22, 18:22].max()) < 0.01  # 1/s: b of the spot is measured tightly


@pytest.mark.slow
def test_loss_rate_std_error_matches_the_spread_over_noise_draws() -> None:
    # Independent reference: the spread of b over 24 noise draws of one clean heated-then-cooling video.
    u0 = torch.full((32, 32), 37.0, dtype=torch.float64)
    source = MovingSource(start=(3.2, 3.2), end=(3.2, 3.2), width=0.8, power=POWER, t_off=ON)
    clean = simulate_tissue(u0, 0.1, 0.3, dx=DX, dt=DT, n_frames=41, source=source)
    generator = torch.Generator().manual_seed(3)
    noise = 0.05 * torch.randn((24, *clean.shape), generator=generator, dtype=torch.float64)
    out = TissueFeatures()(clean + noise, DT, DX)
    spread = out.maps["loss_rate"].std(0)
    error = out.loss_rate_std_error
    measured = torch.isfinite(error).all(0) & (out.maps["confidence"] > 0.5).all(0)
    assert int(measured.sum()) > 100
    ratio = (error.median(0).values / spread)[measured]
    # 24 draws: the spread itself is known to ~15 % per window; the median over the windows to a few %. The
    # propagated error is conservative on the spot, whose Laplacian turns over within a window.
    assert 0.8 < float(ratio.median()) < 1.25  # measured 1.20


def test_a_one_dimensional_trace_is_a_one_pixel_video() -> None:
    trace = torch.full((301,), 44.0, dtype=torch.float64)  # a thermocouple: 5 min at 44 C, 1 s apart
    out = TissueFeatures()(trace, dt=1.0)
    assert out.maps["cem43_minutes"].shape == (1, 1)
    assert float(out.summary["cem43_minutes_max"]) == pytest.approx(cem43_constant(44.0, 300.0), rel=1e-12)
    assert float(out.summary["omega_max"]) == pytest.approx(omega_constant(44.0, 300.0), rel=1e-12)
    assert out.absent["diffusivity"].startswith("no pixel size") and "diffusivity" not in out.maps
    with pytest.raises(ValueError, match=r"unknown feature map 'source' \(no pixel size"):
        out.stack(["source"])
    record, _ = feature_summary(trace, 1.0)
    assert (record["frames"], record["height"], record["width"], record["dx"]) == (301, 1, 1, None)


# -------------------------------------------------------------- map extremes over confident windows
def _extremes(video) -> dict:
    record, maps = feature_summary(video.frames[0], video.dt, video.dx)
    record["span"] = (video.frames.shape[1] - 1) * video.dt
    record["maps"] = maps
    return record


def test_pure_heat_video_extremes_come_from_confident_windows() -> None:
    # The paper's Gaussian on 64 px, 40 frames: before, loss_rate_max was 2.25 1/s (no loss here).
    video = paper_video(n_videos=1, seed=0, size=64, duration=39 / 27)
    record = _extremes(video)
    assert record["diffusivity_global"] == pytest.approx(0.2, rel=0.01)
    assert record["diffusivity_max"] == pytest.approx(0.2, rel=0.1)
    # b is measured to within MAX_LOSS_ERROR / span (1 sd) where it counts: no window beyond 3 sd of 0.
    assert abs(record["loss_rate_max"]) <= 3 * MAX_LOSS_ERROR / record["span"]
    assert abs(record["source_max"]) < 0.02 * 3.8  # K, against a 3.8 K peak
    assert 0.2 < record["confident_fraction"] <= 1 and 0 < record["loss_confident_fraction"] <= 1
    assert "confidence >= 0.9" in record["extremes"]["diffusivity_max"]
    maps = record["maps"]
    best = int(maps.maps["diffusivity"].masked_fill(maps.maps["confidence"] < MIN_CONFIDENCE, -1).argmax())
    assert maps.maps["diffusivity"].flatten()[best] == pytest.approx(record["diffusivity_max"], rel=1e-12)


@pytest.mark.slow
def test_paper_case_extremes_come_from_confident_windows() -> None:
    # The measurement (224 px, 28 frames): diffusivity_max 2.33 mm^2/s and loss_rate_max 227 1/s
    # for a = 0.2 and no loss, source_max 8.4 K.
    video = paper_video(n_videos=1, seed=0)
    record = _extremes(video)
    assert record["diffusivity_max"] == pytest.approx(0.2, rel=0.25)  # measured 0.238
    assert abs(record["loss_rate_max"]) <= 3 * MAX_LOSS_ERROR / record["span"]  # measured 0.23
    assert abs(record["source_max"]) < 0.05 * 3.8  # measured 0.13 K
