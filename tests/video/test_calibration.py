"""Calibration tables, units and pixel-size intervals (:mod:`anra_torch.video.calibration`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from shared_data import DATA, needs_data

from anra_torch.video import Video
from anra_torch.video.calibration import (
    CalibrationTable,
    PixelSize,
    apply_calibration,
    load_calibration,
    to_unit,
)


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
