"""A recording that is diagnosed (:mod:`anra_torch.recording.diagnose`): the memory check, the copy it is
diagnosed on, the phase described and its record, and the one-line errors naming the file."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from scenes import DT, DX, heated_then_cooled, short_heating_phases

from anra_torch.recording import decimate
from anra_torch.recording.diagnose import (
    DIAGNOSE_BYTES_PER_VALUE,
    check_memory,
    diagnose_video,
    diagnosis_copy,
)
from anra_torch.video import Video


def test_a_diagnosis_that_cannot_fit_in_memory_is_refused_with_the_way_out() -> None:
    huge = Video(torch.zeros(1, 1, 1).expand(100_000, 1000, 1000), 0.1, 0.5, source=Path("big.npy"))
    need = (330 * 2**20 + DIAGNOSE_BYTES_PER_VALUE * 10**11) / 2**30  # about 24 TB
    expected = (
        rf"^big\.npy: diagnosing 100000 frames of 1000 x 1000 px needs about {need:.1f} GB of memory, .* GB "
        r"are available; diagnose a region \(--roi X0,Y0,W,H\) or fewer frames, or without --full-resolution$"
    )
    with pytest.raises(ValueError, match=expected):
        check_memory(huge, full_resolution=True)
    check_memory(Video(torch.zeros(10, 8, 8), 0.1, 0.5))  # a small one passes


def test_the_copy_is_the_recording_within_the_budget_and_a_block_average_above(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    video = Video(torch.as_tensor(heated_then_cooled(off=60, n=80)), DT, DX)  # 80 x 40 x 40 values
    assert diagnosis_copy(video) == (video, None)
    assert diagnosis_copy(video, full_resolution=True) == (video, None)
    monkeypatch.setattr(decimate, "DIAGNOSE_VALUES", 80 * 40 * 40 // 4)
    copy, record = diagnosis_copy(video)
    assert record is not None and tuple(copy.frames.shape) == tuple(record["shape"])
    assert copy.frames.numel() <= 80 * 40 * 40 // 4
    assert diagnosis_copy(video, full_resolution=True) == (video, None)


@pytest.mark.slow
def test_the_longest_analysed_phase_is_described_and_every_phase_recorded() -> None:
    frames = torch.as_tensor(heated_then_cooled(off=7, n=30))  # 8 heating frames, 22 cooling
    done = diagnose_video(Video(frames, DT, DX))
    heating, cooling = short_heating_phases(7)  # the same analysis, phase by phase
    assert done.main.phase == cooling.phase and done.video.frames.shape[0] == cooling.phase.frames
    assert [p.phase for p in done.phases] == [heating.phase, cooling.phase]
    record = done.to_record()
    assert record["phase"] == "cooling" and [p["kind"] for p in record["phases"]] == ["heating", "cooling"]
    assert record["gain"] == pytest.approx(cooling.result.gain, rel=1e-9)
    assert record["base"]["diffusivity"] == pytest.approx(cooling.result.diagnosis.a_plain, rel=1e-9)
    # Counted in the recording's frames when the diagnosis ran on a copy of 2-frame blocks.
    copied = diagnose_video(Video(frames, DT, DX), decimated={"time_frames": 2, "shape": [30, 40, 40]})
    assert [p["start_frame"] for p in copied.to_record()["phases"]] == [0, 2 * cooling.phase.start]


def test_errors_name_the_file() -> None:
    short = Video(torch.as_tensor(heated_then_cooled(n=4)), DT, DX, source=Path("short.npz"))
    with pytest.raises(ValueError, match=r"^--fit-fraction must be in \(0, 1\), got 1$"):
        diagnose_video(short, fit_fraction=1.0)
    with pytest.raises(ValueError, match=r"^short\.npz: ") as info:
        diagnose_video(short)
    assert "\n" not in str(info.value)
