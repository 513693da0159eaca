"""A recording's plan (:mod:`anra_torch.recording.plan`): which recordings are read in chunks, the phases
and the route of each, the groups of phases that share an estimator call."""

from __future__ import annotations

import torch
from scenes import DT, DX, heated_then_cooled

from anra_torch.balance import prepare_batch
from anra_torch.estimation import CHUNKED_VALUES, ANRAEstimator
from anra_torch.recording.plan import (
    CAMERA_SIZED,
    RecordingPlan,
    on_disk_above,
    plan_recording,
    reads_in_chunks,
    whole_groups,
)
from anra_torch.video import Video


def video(frames: torch.Tensor) -> Video:
    return Video(frames=frames, dt=DT, dx=DX)


def test_a_precision_target_reads_every_recording_in_chunks() -> None:
    assert on_disk_above(None) == CHUNKED_VALUES and on_disk_above(0.01) == 0
    small = video(torch.zeros(20, 16, 16))
    assert not reads_in_chunks(small, ANRAEstimator(), None)
    assert reads_in_chunks(small, ANRAEstimator(), 0.01)
    assert not reads_in_chunks(small, ANRAEstimator(mode="ratio"), 0.01)  # ratio cannot accumulate chunks


def test_a_heating_and_its_cooling_are_two_phases_estimated_whole() -> None:
    recording = video(torch.as_tensor(heated_then_cooled(off=40, n=80, size=24)))
    plan = plan_recording(recording, ANRAEstimator(strict=False), None, None)
    assert isinstance(plan, RecordingPlan) and plan.several
    assert [p.phase.name for p in plan.phases] == ["heating", "cooling"]
    assert {p.route for p in plan.phases} == {"whole"}
    assert sum(p.part.frames.shape[0] for p in plan.phases) == 80


def test_one_phase_is_the_recording_measured_once_and_a_tiny_region_a_small_box() -> None:
    still = video(20.0 + 0.01 * torch.randn(30, 24, 24, dtype=torch.float64))
    (only,) = plan_recording(still, ANRAEstimator(strict=False), None, None).phases
    assert only.route == "whole" and only.prepared is not None and only.part is still
    measured = prepare_batch(still.frames[None])  # made already (anra features): taken, not made again
    (given,) = plan_recording(still, ANRAEstimator(strict=False), None, None, measured).phases
    assert given.prepared is measured
    other = prepare_batch(still.frames[None].float())  # not of these frames (another dtype): measured anew
    (anew,) = plan_recording(still, ANRAEstimator(strict=False), None, None, other).phases
    assert anew.prepared is not other and anew.prepared is not None
    tiny = video(20.0 + 0.01 * torch.randn(30, 6, 6, dtype=torch.float64))
    (box,) = plan_recording(tiny, ANRAEstimator(strict=False), None, None).phases
    assert box.route == "small_box" and box.prepared is None


def test_same_shaped_phases_of_different_recordings_share_a_call_but_not_camera_sized_ones() -> None:
    est = ANRAEstimator(strict=False)
    plans: list[RecordingPlan | ValueError] = [
        plan_recording(video(torch.randn(30, 24, 24)), est, None, None) for _ in range(3)
    ]
    plans.append(ValueError("a failed recording"))
    (group,) = whole_groups(plans)
    assert len(group) == 3
    big = torch.zeros(CAMERA_SIZED // (64 * 64) + 1, 64, 64)
    alone = [plan_recording(video(big), est, None, None) for _ in range(2)]
    assert [len(g) for g in whole_groups(alone)] == [1, 1]
