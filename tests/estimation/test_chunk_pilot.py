"""The pilot of a recording read in chunks (:mod:`anra_torch.estimation.chunk_pilot`): where its blocks lie
and what it chooses."""

from __future__ import annotations

import pytest
import torch

from anra_torch.estimation import ANRAEstimator, estimate_chunked
from anra_torch.estimation.chunk_pilot import choose_on_pilot, pilot_starts
from anra_torch.simulation import gaussian_blob

DT, DX, NOISE = 1 / 27, 0.1, 0.01


def _video(frames: int, side: int = 44, seed: int = 0) -> torch.Tensor:
    t = torch.arange(frames, dtype=torch.float64) * DT
    generator = torch.Generator().manual_seed(seed)
    clean = gaussian_blob(t, shape=(side - 4, side), dx=DX, a=0.2, peak=3.0, sigma=1.0)
    return clean + NOISE * torch.randn(clean.shape, generator=generator, dtype=torch.float64)


def test_pilot_blocks_are_spread_evenly_without_overlap() -> None:
    assert pilot_starts(200, 16, 3) == [0, 92, 184]
    assert pilot_starts(40, 16, 3) == [12]  # a third of 40 frames holds no block of 16: one, in the middle


def test_the_pilot_chooses_a_measurable_smoothing_and_finds_no_artefact_on_a_clean_blob() -> None:
    est = ANRAEstimator(strict=False)
    blocks = torch.stack([_video(40)[s : s + 16] for s in (0, 24)])
    spacing = torch.tensor([DT], dtype=torch.float64), torch.tensor([DX], dtype=torch.float64)
    pilot = choose_on_pilot(est, blocks, *spacing, side=256, total=40)
    assert pilot.index in est.usable(40, 44) and not pilot.repair and not bool(pilot.dead.any())
    assert pilot.a == pytest.approx(0.2, rel=0.05)


@pytest.mark.parametrize(("frames", "blocks"), [(30, 1), (96, 2), (200, 3)])
def test_the_pilot_reads_at_most_a_third_of_a_recording(frames: int, blocks: int) -> None:
    """Three blocks of 16 frames where they fit in a third of the recording, fewer (at least one) below."""
    pilot = estimate_chunked(_video(frames), DT, DX, estimator=ANRAEstimator(strict=False)).pilot
    assert len(pilot) == blocks
    assert all(stop - start == 16 for start, stop in pilot)
    assert pilot[0][0] >= 0 and pilot[-1][1] <= frames
    if blocks > 1:  # spread from the first frame to the last
        assert pilot[0][0] == 0 and pilot[-1][1] == frames
