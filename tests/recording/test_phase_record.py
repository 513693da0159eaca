"""What the diagnosis of one phase holds (:mod:`anra_torch.recording.phase_record`): its record, its gain,
the flags and warnings set on it."""

from __future__ import annotations

from anra_torch.recording.phase_record import PhaseDiagnosis, flag_implausible, gain_of, implausible
from anra_torch.video import Phase


def test_the_gain_is_one_minus_the_rmse_ratio_and_zero_without_a_base() -> None:
    assert gain_of(0.25, 1.0) == 0.75 and gain_of(1.0, 0.0) == 0.0


def test_an_implausible_diffusivity_is_flagged_unless_another_flag_qualifies_it() -> None:
    phase = Phase("cooling", 0, 40, 0.0, 3.9)
    odd = PhaseDiagnosis(phase, "small_box", diffusivity=1e-5)
    flag_implausible(odd, dt=0.1, dx=0.25)
    assert odd.flags == ["implausible"] and len(odd.warnings) == 1
    unresolved = PhaseDiagnosis(phase, "small_box", diffusivity=1e-5, flags=["unresolved"])
    flag_implausible(unresolved, dt=0.1, dx=0.25)
    assert unresolved.flags == ["unresolved"] and unresolved.warnings == []
    record = odd.to_record()
    assert record["kind"] == "cooling" and "implausible" in record["base"]["flags"]


def test_effects_that_do_not_forecast_or_sit_outside_the_frame_are_flagged() -> None:
    effects = [
        {"name": "source", "params": {"x0": 400.0, "y0": 5.0, "x1": 401.0, "y1": 5.0}, "gain": 0.3},
        {"name": "advection", "params": {"vx": 1.0, "vy": 0.0}, "gain": -4.0},
        {"name": "linear_loss", "params": {"b": 0.1, "T_ref": 20.0}, "gain": 0.5},
    ]
    flagged = implausible(effects, height=20.0, width=20.0)
    assert len(flagged) == 3  # the source's start and end outside the 20 mm frame, the advection's gain
    assert all("missing" in line for line in flagged)
    assert flagged[0].startswith("source: x0, y0 = (400, 5) mm lies outside the 20 x 20 mm field of view")
    assert flagged[2].startswith("advection: its own held-out gain is -4")
