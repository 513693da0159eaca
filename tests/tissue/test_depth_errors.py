"""The depth maps' standard errors: the perturbed copies and their spread (unit checks), and the noise's part
against the spread of the damage depth over independent noisy copies of a video."""

from __future__ import annotations

import pytest
import torch
from depth_scenes import BODY, F64, A, burn_video

from anra_torch.tissue import NOISE_DRAWS, damage_in_depth
from anra_torch.tissue.depth_errors import perturbed_copies, spread


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    return burn_video()


def test_copies_and_weights() -> None:
    rise = torch.zeros(2, 3, 4, 5, dtype=F64)
    a, b = torch.tensor([0.1, 0.2], dtype=F64), torch.tensor([0.0, 0.01], dtype=F64)
    errors = (torch.tensor([0.01, 0.02], dtype=F64), torch.zeros(2, dtype=F64), torch.ones(2, dtype=F64))
    stacked, rates, losses, weights = perturbed_copies(rise, a, b, errors, seed=3)
    assert stacked.shape == ((2 + NOISE_DRAWS) * 2, 3, 4, 5)  # base, a + se, the noise draws (b: no error)
    torch.testing.assert_close(rates[2:4], a + errors[0])
    torch.testing.assert_close(weights, torch.tensor([1.0] + [1 / NOISE_DRAWS] * NOISE_DRAWS, dtype=F64))
    draws = stacked[4:].reshape(NOISE_DRAWS, -1)
    assert 0.9 < float(draws.std()) < 1.1 and not torch.equal(draws[0], draws[1])  # sd 1, independent
    again = perturbed_copies(rise, a, b, errors, seed=3)[0]
    torch.testing.assert_close(again, stacked)  # seeded
    assert len(perturbed_copies(rise, a, b, (torch.zeros(2, dtype=F64),) * 3, seed=3)[3]) == 0


def test_spread_is_the_weighted_root_sum_of_squares() -> None:
    base, up, n1, n2 = 1.0, 1.3, 1.2, 0.6  # changes 0.3 (weight 1) and the draws' 0.2, -0.4 (mean square 0.1)
    values = torch.tensor([base, up, n1, n2], dtype=F64).view(4, 1)
    weights = torch.tensor([1.0, 0.5, 0.5], dtype=F64)
    value, error = spread(values, weights)
    assert float(value) == base and float(error) == pytest.approx((0.09 + 0.1) ** 0.5)
    _, with_rules = spread(values, weights, torch.tensor([[base + 0.8]], dtype=F64))
    assert float(with_rules) == pytest.approx((0.09 + 0.1 + 0.16) ** 0.5)  # half the rules' difference


@pytest.mark.slow
def test_the_noise_part_of_the_standard_error_is_the_spread_over_noisy_videos(
    burn: tuple[torch.Tensor, float, float],
) -> None:
    """The noise's standard error (a mean square over :data:`NOISE_DRAWS` seeded draws) against the
    spread of the damage depth over 16 independent noisy copies of the video (other seeds): the same size,
    pixel by pixel, within the scatter of estimates with 8 and 16 degrees of freedom."""
    frames, dt, dx = burn
    args = {"diffusivity": A, "loss_rate": 0.003, "body_temperature": BODY}
    sd = 0.3
    total = damage_in_depth(frames, dt, dx, noise_sd=sd, seed=7, **args).damage_depth_std
    sampling = damage_in_depth(frames, dt, dx, **args).damage_depth_std  # the frames' sampling in time alone
    error = (total**2 - sampling**2).clamp_min(0.0).sqrt()
    generator = torch.Generator().manual_seed(11)
    copies = torch.stack(
        [
            damage_in_depth(
                frames + sd * torch.randn(frames.shape, generator=generator, dtype=F64), dt, dx, **args
            ).damage_depth
            for _ in range(16)
        ]
    )
    spread = copies.std(0)
    deep = (copies > 0.05).all(0)
    assert int(deep.sum()) >= 20
    ratio = (error[deep] / spread[deep]).median()
    assert 0.7 < float(ratio) < 1.4, float(ratio)
    # One draw alone would be a one-degree-of-freedom estimate: its ratios scatter far more widely.
    assert float((error[deep] / spread[deep]).quantile(0.1)) > 0.4
