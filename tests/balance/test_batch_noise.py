"""The noise context of a batch (:mod:`anra_torch.balance.batch_noise`) as the estimator uses it: dead
elements repaired, not cut out; a fixed pattern taken out by per-pixel fixed effects; the standard error
under correlated noise matching the spread over noise seeds.
"""

from __future__ import annotations

import pytest
import torch
from scenes import camera_scene, white_beside_correlated, with_artefacts

from anra_torch import ANRAEstimator
from anra_torch.balance.artefacts import find_artefacts
from anra_torch.simulation.camera import correlated_noise

F64 = torch.float64


@pytest.fixture(scope="module")
def pure():
    return camera_scene()


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_estimator_keeps_dead_elements_repaired_not_cut_out(pure, seed: int) -> None:
    """Dead elements (constant in time) take their repair and stay in the fit. Cut out, each took its
    filters' support out of every frame: on the artefact benchmark a pure video with 3 dead and 3 hot
    elements moved by 2.7 % from its clean estimate, with 4x its standard error (here: 0.27 % and 1.4x)."""
    frames, _ = with_artefacts(pure, "bad_elements", seed=seed)
    clean = ANRAEstimator()(pure.frames, pure.dt, pure.dx)
    found = ANRAEstimator()(frames, pure.dt, pure.dx)
    assert float(found.diffusivity) == pytest.approx(float(clean.diffusivity), rel=2e-3)
    assert float(found.std_error) == pytest.approx(float(clean.std_error), rel=0.1)


def test_a_fixed_pattern_is_taken_out_by_per_pixel_fixed_effects(pure) -> None:
    """Three noise sds of static pattern: the estimate with per-pixel fixed effects is the clean one's
    (measured 0.09 % apart); measured as a static part of the noise model instead it was 0.6 % off here
    and up to 11 % on the artefact benchmark's videos."""
    frames, _ = with_artefacts(pure, "fixed_pattern")
    _, found = find_artefacts(frames)
    assert found.within == ("pixel",)
    clean = ANRAEstimator()(pure.frames, pure.dt, pure.dx)
    planted = ANRAEstimator()(frames, pure.dt, pure.dx)
    assert float(planted.diffusivity) == pytest.approx(float(clean.diffusivity), rel=0.003)


_SEEDS = 192  # the spread over n seeds is itself known to 1 / sqrt(2 (n - 1)): 5 % here, 15 % over 24


@pytest.mark.slow
@pytest.mark.parametrize("white", [False, True], ids=["correlated", "white_beside_correlated"])
def test_standard_error_under_correlated_noise_matches_the_spread_over_seeds(white: bool) -> None:
    """The reported standard error against the spread of the estimate over 192 noise seeds.

    On 48 x 48 px and 31 frames (the cost is per video, so the seeds, which set the power, stay; at 40 px
    the correlated case's spread doubled), measured: correlated noise alone, a mean of 0.1499 (true 0.15),
    a spread of 0.00372 mm^2/s and a mean standard error of 0.00349 (0.94 of it); beside white noise,
    0.1499, 0.00331 and 0.00332 (1.00). On 64 x 64 px and 41 frames the ratios were 0.94 and 0.95. A spread
    over 24 seeds is itself uncertain by 15 % (24-seed blocks gave 0.74-1.15). Beside white noise, before
    the time correlation was solved with the white part (see above), a third of the videos had their noise
    taken for white: the smallest smoothing was chosen, the spread was 0.067 mm^2/s and the standard error
    0.03 of it."""
    video = camera_scene(seed=3, size=48, frames=31)

    def noisy(seed: int) -> torch.Tensor:
        if white:
            return white_beside_correlated(video, seed)
        sd = 2 * video.noise_sd
        return correlated_noise(video.clean, seed=seed, sd=sd, length_px=1.5, length_frames=3.0)[0]

    results = [
        ANRAEstimator()(torch.stack([noisy(s) for s in range(start, start + 48)]), video.dt, video.dx)
        for start in range(0, _SEEDS, 48)
    ]
    estimate = torch.cat([r.diffusivity for r in results])
    std_error = torch.cat([r.std_error for r in results])
    assert float(estimate.mean()) == pytest.approx(0.15, rel=0.02)
    assert float(std_error.mean()) == pytest.approx(float(estimate.std()), rel=0.2)
