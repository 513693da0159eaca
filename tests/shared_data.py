"""The measured recordings beside the repository (``../shared/data``), for the tests that read real files."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
"""The shared data folder: ``flir_csv/``, ``laser_silicone/``, calibration tables (see its README)."""

needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"measured data folder {DATA} is absent")
"""Skips a test where the measured data folder is absent (a clone without ``../shared``)."""
