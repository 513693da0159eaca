"""Phase segmentation (:mod:`anra_torch.video.phases`): synthetic switch-on and off, sparse frames, the real
recordings.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depth_references import conduct
from scenes import heated_then_cooled, spot_video
from shared_data import DATA, needs_data

from anra_torch.video import load_video, recording_phases
from anra_torch.video.phases import segment_phases


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


def test_phases_find_the_switch_off_of_a_source() -> None:
    frames = torch.as_tensor(heated_then_cooled(off=60))
    kinds = [(p.name, p.start, p.stop) for p in recording_phases(frames)]
    assert [k[0] for k in kinds] == ["heating", "cooling"]
    assert abs(kinds[1][1] - 60) <= 2  # the switch-off frame, measured 59-60


def test_single_phase_recordings_stay_whole() -> None:
    frames = torch.as_tensor(heated_then_cooled(off=200, n=60))  # the source never switches off
    (phase,) = recording_phases(frames)
    assert (phase.name, phase.start, phase.stop) == ("heating", 0, 60)
    flat = torch.randn(30, 16, 16) * 0.01 + 20
    assert [p.name for p in recording_phases(flat)] == ["steady"]


@pytest.mark.slow
def test_a_heating_and_cooling_30_s_apart_are_two_phases() -> None:
    """Frames 30 s apart of a beam on a thick body (independent explicit 3-D conduction): the frame mean's
    steps are all signal, so its noise is bounded by one pixel's (before, the steps' 'noise' hid the heating
    and the recording read as one steady phase)."""
    y, x = np.mgrid[:96, :96] * 0.5
    flux = 0.5 / (2 * np.pi * 2.0**2) * np.exp(-((x - 20) ** 2 + (y - 24) ** 2) / (2 * 2.0**2))  # W/mm^2
    u, frames, rng = np.full((24, 96, 96), 22.0), [], np.random.default_rng(0)
    times = np.arange(0.0, 301.0, 30.0)
    for k, when in enumerate(times):
        if k:
            u = conduct(u, times[k - 1], when, 0.12, 0.5, lambda top, now: flux if now < 170.0 else 0.0 * top)
        frames.append(u[0] + rng.normal(0, 0.1, (96, 96)))
    phases = recording_phases(torch.as_tensor(np.asarray(frames)), torch.as_tensor(times))
    assert [(p.name, p.t_stop) for p in phases] == [("heating", 150.0), ("cooling", 300.0)]
    assert phases[1].t_start == 180.0
