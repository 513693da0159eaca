"""The measured recordings beside the repository (``../shared/data``), for the tests that read real files and
for ``experiments/real_data.py``: where they are, the spacings a user passes for them, how they are read."""

from __future__ import annotations

from pathlib import Path

import pytest

from anra_torch.video import Video, prepare_video
from anra_torch.video.calibration import PixelSize

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
"""The shared data folder: ``flir_csv/``, ``laser_silicone/``, calibration tables (see its README)."""

LASER_DX = PixelSize(0.55, 0.5, 0.6)  # mm/px, C3-X 41 x 31 deg over 128 x 96 px at about 10 cm
CSV_DT, CSV_DX = 0.1, 0.25  # s, mm: the source's assumptions, not documented facts

needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"measured data folder {DATA} is absent")
"""Skips a test where the measured data folder is absent (a clone without ``../shared``)."""


def load(path: Path) -> Video:
    """``prepare_video`` with what a user passes on the command line for these files."""
    if path.is_dir():
        return prepare_video(path, dx=LASER_DX.value, timestamps="resample")
    return prepare_video(
        path,
        dt=CSV_DT,
        dx=CSV_DX,
        timestamps="resample",
        calibration=DATA / "flir_csv" / "calibration_og.csv",
    )
