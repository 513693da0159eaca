"""A recording's phases as every command finds them (:mod:`anra_torch.recording.phases`): camera artefacts
repaired first, recordings on disk looked at through a copy, and which phase describes the recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from scenes import DT, heated_then_cooled

from anra_torch.recording.phases import (
    SOURCE_FREE,
    find_phases,
    phase_preference,
    recording_phases_of,
    repaired,
    whole_recording,
)
from anra_torch.video import LazyFrames, Phase, Video, recording_phases


def spans(phases: list[Phase]) -> list[tuple[str, int, int]]:
    return [(p.name, p.start, p.stop) for p in phases]


def test_a_spike_or_a_hot_element_is_not_a_heat_source() -> None:
    frames = torch.as_tensor(heated_then_cooled(off=60, n=110))
    clean = find_phases(frames, dt=DT)
    assert [p.name for p in clean] == ["heating", "cooling"] and abs(clean[1].start - 60) <= 2
    assert clean[1].t_start == clean[1].start * DT
    hit = frames.clone()
    hit[90, 20, 20] += 60.0  # a spike in the cooling
    hit[91:, 5, 5] = 200.0  # an element that turns hot
    assert spans(recording_phases(hit)) == [("heating", 0, 110)]  # taken as the data say, one heating
    assert spans(find_phases(hit, dt=DT)) == spans(clean)
    assert bool(torch.isfinite(repaired(hit)).all()) and float(repaired(hit)[95, 5, 5]) < 30.0


def test_a_recording_on_disk_has_the_phases_of_the_same_frames_in_memory(tmp_path: Path) -> None:
    frames = heated_then_cooled(off=60, n=110)
    np.save(tmp_path / "r.npy", frames)
    assert spans(find_phases(LazyFrames(tmp_path / "r.npy"), dt=DT)) == spans(
        find_phases(torch.as_tensor(frames))
    )


def test_a_source_free_phase_describes_the_recording_before_a_longer_heating() -> None:
    heating, cooling = Phase("heating", 0, 80, 0.0, 7.9), Phase("cooling", 80, 110, 8.0, 10.9)
    baseline, steady = Phase("baseline", 0, 40, 0.0, 3.9), Phase("steady", 0, 120, 0.0, 11.9)
    ranked = sorted([heating, steady, baseline, cooling], key=phase_preference, reverse=True)
    assert ranked == [cooling, baseline, steady, heating]  # SOURCE_FREE's order, the heating last
    assert SOURCE_FREE == ("cooling", "baseline", "steady")
    assert phase_preference(Phase("cooling", 0, 50, 0.0, 4.9)) > phase_preference(
        Phase("cooling", 0, 40, 0, 3.9)
    )


def test_the_whole_recording_is_one_phase_and_resampled_phases_keep_their_samples_frames() -> None:
    video = Video(torch.zeros(30, 4, 4), 0.5, 0.1)
    assert whole_recording(video) == Phase("recording", 0, 30, 0.0, 14.5)
    frames = torch.as_tensor(heated_then_cooled(off=60, n=110))
    t = torch.arange(110, dtype=torch.float64) * DT
    assert spans(recording_phases_of(frames, t, None)) == spans(recording_phases(frames, t))
    samples = [float(x) for x in t[::10]] + [float(t[-1])]  # measured every 10th frame: no blended frame
    kept = recording_phases_of(frames, t, samples)
    assert [p.name for p in kept] == ["heating", "cooling"]
    assert all(p.frames <= q.frames for p, q in zip(kept, recording_phases(frames, t), strict=True))
    small = torch.ones(2, 3, 3)
    assert repaired(small) is small  # too few frames to look for artefacts
