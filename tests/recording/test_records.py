"""The records of a recording's estimate (:mod:`anra_torch.recording.records`): the phase head, the shape
record, and one phase's record whatever its route."""

from __future__ import annotations

import torch
from scenes import DT, DX

from anra_torch.recording.records import PHASE_KEYS, PhaseEstimate, phase_head, shape_record
from anra_torch.video import Phase, Video


def test_the_phase_head_places_the_phase_in_its_recording() -> None:
    head = phase_head(Phase("cooling", 40, 80, 4.0, 7.9))
    assert head == {"kind": "cooling", "start_frame": 40, "stop_frame": 80, "t_start": 4.0, "t_stop": 7.9}


def test_the_shape_record_names_the_frames_and_their_spacing() -> None:
    video = Video(frames=torch.zeros(30, 12, 16), dt=DT, dx=DX)
    assert shape_record(video.frames.shape, video) == {
        "frames": 30,
        "height": 12,
        "width": 16,
        "dt": DT,
        "dx": DX,
    }


def test_a_phase_too_short_or_estimated_in_a_small_box_keeps_the_phase_keys() -> None:
    video = Video(frames=torch.zeros(5, 12, 16), dt=DT, dx=DX)
    short = PhaseEstimate(Phase("heating", 0, 5, 0.0, 0.4), video, "too_short")
    record = short.to_record()
    assert not short.valid and record["message"] == "too short" and record["diffusivity"] is None
    small = {"diffusivity": 0.3, "std_error": 0.01, "valid": True, "message": "", "method": "small_box"}
    boxed = PhaseEstimate(Phase("cooling", 5, 40, 0.5, 3.9), video, "small_box", small_box=small)
    record = boxed.to_record()
    assert boxed.valid and record["diffusivity"] == 0.3 and record["kind"] == "cooling"
    assert set(PHASE_KEYS) <= set(record)
    assert record["warnings"] == [] and record["method"] == "small_box"
