"""How every command reads a recording (:mod:`anra_torch.recording.read`): left on disk above a size,
loaded and prepared otherwise, with the record of what the reading did."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scenes import random_frames

from anra_torch.recording import input_record, open_recording
from anra_torch.video import CalibrationTable, SingleFrameError, save_npz


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    return save_npz(tmp_path / "r.npz", random_frames(12, 10, 14), dt=0.1, dx=0.5)


def test_a_large_file_stays_on_disk_and_reads_the_same_values(recording: Path) -> None:
    lazy = open_recording(recording, on_disk_above=0)
    assert lazy.on_disk and lazy.frames.shape == (12, 10, 14) and (lazy.dt, lazy.dx) == (0.1, 0.5)
    np.testing.assert_array_equal(lazy.frames.window(3, 7)[0:4], random_frames(12, 10, 14)[3:7])
    whole = open_recording(recording, on_disk_above=12 * 10 * 14)  # not above: loaded
    assert not whole.on_disk
    torch.testing.assert_close(whole.frames, torch.as_tensor(random_frames(12, 10, 14)))
    assert not open_recording(recording).on_disk  # None: never left on disk


def test_a_region_or_a_calibration_always_loads_the_recording(recording: Path) -> None:
    cropped = open_recording(recording, roi="2,1,8,6", on_disk_above=0)
    assert not cropped.on_disk and cropped.frames.shape == (12, 6, 8)
    torch.testing.assert_close(cropped.frames, torch.as_tensor(random_frames(12, 10, 14)[:, 1:7, 2:10]))
    table = CalibrationTable(true=np.array([0.0, 200.0]), apparent=np.array([0.0, 100.0]), source="t")
    doubled = open_recording(recording, calibration=table, on_disk_above=0)
    assert not doubled.on_disk
    torch.testing.assert_close(doubled.frames, 2 * torch.as_tensor(random_frames(12, 10, 14)))
    record = input_record(doubled)
    assert set(record) == {
        "timestamps",
        "resampled",
        "roi",
        "calibration",
        "masked_values",
        "object_parameters",
    }
    assert record["calibration"]["table"] == "t" and record["roi"] is None


def test_spacing_arguments_override_the_file_and_errors_are_one_line(recording: Path, tmp_path: Path) -> None:
    assert open_recording(recording, dt=0.2, dx=1.0, on_disk_above=0).dt == 0.2
    assert open_recording(recording, dt=0.2, dx=1.0).dx == 1.0
    np.save(tmp_path / "bare.npy", random_frames())
    with pytest.raises(ValueError, match=r"bare\.npy: no frame period") as info:
        open_recording(tmp_path / "bare.npy", on_disk_above=0)
    assert "\n" not in str(info.value)
    assert open_recording(tmp_path / "bare.npy", dt=0.1, need_dx=False).dx is None


def test_a_single_frame_is_refused_where_time_is_needed(tmp_path: Path) -> None:
    one = save_npz(tmp_path / "one.npz", random_frames(1, 10, 14), dt=0.1, dx=0.5)
    for dt in (None, 0.2):
        with pytest.raises(ValueError, match=r"one\.npz: a single frame has no time axis; this needs frames"):
            open_recording(one, dt=dt, on_disk_above=0)
    assert open_recording(one, need_time=False).frames.shape == (1, 10, 14)
    np.savez(tmp_path / "stamp.npz", frames=random_frames(1, 10, 14), t=np.zeros(1))
    with pytest.raises(
        SingleFrameError, match=r"stamp\.npz: a single frame has no time axis, so no frame period"
    ):
        open_recording(tmp_path / "stamp.npz", need_dx=False, need_time=False)
