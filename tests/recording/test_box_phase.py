"""The small-box family of a phase diagnosis (:mod:`anra_torch.recording.box_phase`): on a box too small for
the filters, a phase whose interior follows its edges is diagnosed, its choice validated inside the fit
frames."""

from __future__ import annotations

import pytest
import torch
from scenes import DT, DX, quasi_steady_box

from anra_torch.recording.box_phase import small_box_phase
from anra_torch.video import Phase


def test_a_quasi_steady_box_is_diagnosed_by_the_small_box_family() -> None:
    frames = torch.as_tensor(quasi_steady_box(n=120))
    phase = Phase("heating", 0, 120, 0.0, 119 * DT)
    diagnosis = small_box_phase(phase, frames, DT, DX, 0.6)
    assert diagnosis.family == "small_box" and diagnosis.model in ("loss", "quasi_steady")
    assert set(diagnosis.candidates) == {"loss", "quasi_steady"}
    assert diagnosis.effects[0]["name"] in ("source", "linear_loss")
    assert diagnosis.forecasts is not None and set(diagnosis.forecasts) == {"measured", "plain", "extended"}


def test_a_box_under_3_px_is_refused() -> None:
    with pytest.raises(ValueError, match="frames must be at least 3 x 3 px, got 2 x 5"):
        small_box_phase(Phase("heating", 0, 30, 0.0, 2.9), torch.zeros(30, 2, 5), DT, DX, 0.6)
