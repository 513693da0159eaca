"""Phase segmentation (synthetic switch-on/off and the real recordings), calibration, units, ROI, masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch.video import Video, load_video
from anra_torch.video.calibration import (
    CalibrationTable,
    PixelSize,
    apply_calibration,
    load_calibration,
    to_unit,
)
from anra_torch.video.phases import segment_phases
from anra_torch.video.roi import apply_mask, crop, dead_pixel_mask, parse_roi, reflection_mask

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"measured data folder {DATA} is absent")


def spot_video(
    on: int = 30, off: int = 120, n: int = 200, noise: float = 0.05, tau: float = 30.0
) -> torch.Tensor:
    """A Gaussian spot heated from frame ``on`` to ``off`` (exponential approach over ``tau`` frames), then
    cooling."""
    k = np.arange(n, dtype=float)
    rise = np.where(k < on, 0, 1 - np.exp(-(np.minimum(k, off) - on) / tau))
    rise = np.where(k > off, rise[off] * np.exp(-(k - off) / 40), rise)
    y, x = np.mgrid[:24, :24]
    shape = np.exp(-((x - 12) ** 2 + (y - 10) ** 2) / 18)
    rng = np.random.default_rng(0)
    return torch.from_numpy(20 + 10 * rise[:, None, None] * shape + noise * rng.normal(size=(n, 24, 24)))


def test_synthetic_switch_on_and_off_are_found() -> None:
    phases = segment_phases(spot_video(), torch.arange(200) * 0.1)
    assert [p.name for p in phases] == ["baseline", "heating", "cooling"]
    baseline, heating, cooling = phases
    assert abs(heating.start - 30) <= 3 and abs(cooling.start - 120) <= 2
    assert cooling.stop == 200 and heating.t_start == pytest.approx(heating.start * 0.1)


def test_switch_off_after_a_noisy_plateau_is_the_start_of_the_fall() -> None:
    # Saturated after ~15 frames, then 75 frames of plateau: the noisy peak can fall anywhere on it.
    for seed_noise in (0.3, 0.5):
        phases = segment_phases(spot_video(tau=3.0, noise=seed_noise))
        heating, cooling = phases[1], phases[2]
        assert heating.stop - 1 == cooling.start and abs(cooling.start - 120) <= 2, cooling


def test_no_rise_is_an_error() -> None:
    with pytest.raises(ValueError, match="no heating found"):
        segment_phases(torch.full((10, 8, 8), 20.0))


@needs_data
def test_laser_runs_switch_off_near_60_s() -> None:
    for run in ("Nov19", "Nov19_2"):
        video = load_video(DATA / "laser_silicone" / run, timestamps="keep")
        names = [(p.name, p.t_start) for p in segment_phases(video.frames, video.t)]
        assert [n for n, _ in names] == ["heating", "cooling"]
        assert 54 < names[1][1] < 66  # the source notes: laser off at t = 60 s


@needs_data
def test_csv_heating_between_frames_150_and_1080() -> None:
    video = load_video(DATA / "flir_csv" / "Sample2 RT M1.csv", dt=0.1)
    baseline, heating, cooling = segment_phases(video.frames)
    assert 150 < heating.start < 250 and 1000 < cooling.start < 1100  # the source: ~200 and ~1080


# ------------------------------------------------------------------------------------------ calibration
def test_calibration_inverts_the_table() -> None:
    table = CalibrationTable(true=np.array([25.0, 100, 200]), apparent=np.array([24.0, 74.0, 142.0]))
    apparent = torch.tensor([24.0, 74.0, 108.0, 142.0, 210.0])
    expected = np.interp([24, 74, 108, 142], [24, 74, 142], [25, 100, 200])
    np.testing.assert_allclose(table.to_true(apparent)[:4].numpy(), expected)
    assert float(table.to_true(apparent)[4]) == pytest.approx(200 + 68 * 100 / 68)  # extrapolated
    assert table.outside(apparent) == pytest.approx(0.2)


@needs_data
def test_real_calibration_file_round_trips() -> None:
    table = load_calibration(DATA / "flir_csv" / "calibration_og.csv")
    np.testing.assert_allclose(table.to_true(torch.tensor([24.82, 142.73, 364.8])).numpy(), [25, 200, 500])
    video = apply_calibration(Video(torch.full((3, 4, 4), 217.38), dt=0.1, dx=0.25), table)
    assert (
        float(video.frames[0, 0, 0]) == pytest.approx(300.0)
        and video.meta["calibration"]["outside_fraction"] == 0
    )


def test_calibration_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="strictly increasing"):
        CalibrationTable(true=np.array([1.0, 2, 3]), apparent=np.array([1.0, 3, 2]))
    path = tmp_path / "c.csv"
    path.write_text("T,IR\n25,24\nx,y\n")
    with pytest.raises(ValueError, match=r"c\.csv: line 3: expected 'true,apparent'"):
        load_calibration(path)
    with pytest.raises(ValueError, match="no such calibration file"):
        load_calibration(tmp_path / "none.csv")


def test_units_and_pixel_size_interval() -> None:
    video = Video(torch.full((2, 3, 3), 25.0), dt=1.0, dx=0.5, meta={"unit": "degC"})
    kelvin = to_unit(video, "K")
    assert float(kelvin.frames[0, 0, 0]) == pytest.approx(298.15) and kelvin.unit == "K"
    assert float(to_unit(kelvin, "degC").frames[0, 0, 0]) == pytest.approx(25.0)
    lo, hi = PixelSize(0.55, 0.5, 0.6).diffusivity_interval(0.121)
    assert lo == pytest.approx(0.121 * (0.5 / 0.55) ** 2) and hi == pytest.approx(0.121 * (0.6 / 0.55) ** 2)
    with pytest.raises(ValueError, match="cannot convert"):
        to_unit(Video(torch.zeros(2, 3, 3), dt=1.0, dx=0.5), "K")


# ------------------------------------------------------------------------------------------- ROI, masks
def test_roi_crop_and_errors() -> None:
    frames = torch.arange(2 * 6 * 8, dtype=torch.float64).reshape(2, 6, 8)
    video = crop(Video(frames, dt=1.0, dx=1.0), parse_roi("2,1,4,3"))
    torch.testing.assert_close(video.frames, frames[:, 1:4, 2:6])
    assert video.meta["roi"] == [2, 1, 4, 3]
    with pytest.raises(ValueError, match="does not fit in the 8 x 6 px frame"):
        crop(Video(frames, dt=1.0, dx=1.0), (5, 0, 4, 2))
    with pytest.raises(ValueError, match="four integers"):
        parse_roi("1,2,3")


def test_dead_pixels_and_reflections_are_masked() -> None:
    frames = spot_video(n=60, off=50)
    frames[:, 3, 20] = 55.0  # stuck
    frames[:, 20, 3] += 15.0  # hot spike
    mask = dead_pixel_mask(frames)
    assert bool(mask[3, 20]) and bool(mask[20, 3]) and int(mask.sum()) == 2
    masked = apply_mask(Video(frames, dt=0.1, dx=0.5), mask)
    assert masked.meta["masked_px"] == 2 and bool(masked.frames[:, 3, 20].isnan().all())
    mirror = frames.clone()
    mirror[:, 18:21, 18:21] = frames[:, 9:12, 11:14]  # a detached copy of the hot spot
    hot = torch.zeros(24, 24, dtype=torch.bool)
    hot[10, 12] = True
    reflection = reflection_mask(mirror, hot)
    assert bool(reflection[19, 19]) and not bool(reflection[10, 12])
