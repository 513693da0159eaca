"""The depth maps' standard errors: the perturbed copies and their spread (unit checks), the noise's
analytic variance and correlation at depth against a noise video through the solver, and the noise's part
of the damage depth's standard error against the spread over independent noisy copies of a video."""

from __future__ import annotations

import math

import pytest
import torch
from depth_scenes import BODY, F64, A, burn_video

from anra_torch.tissue import StandardErrors, damage_in_depth, subsurface_temperature
from anra_torch.tissue.depth_errors import noise_correlation, perturbed_copies, spread


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    return burn_video()


def test_copies_and_weights() -> None:
    rise = torch.zeros(2, 3, 4, 5, dtype=F64)
    a, b = torch.tensor([0.1, 0.2], dtype=F64), torch.tensor([0.0, 0.01], dtype=F64)
    errors = (torch.tensor([0.01, 0.02], dtype=F64), torch.zeros(2, dtype=F64))
    stacked, rates, losses, weights = perturbed_copies(rise, a, b, errors)
    assert stacked.shape == (4, 3, 4, 5)  # base and a + se (b: no error)
    torch.testing.assert_close(rates[2:], a + errors[0])
    torch.testing.assert_close(losses, torch.cat([b, b]))
    torch.testing.assert_close(weights, torch.ones(1, dtype=F64))
    assert len(perturbed_copies(rise, a, b, (torch.zeros(2, dtype=F64),) * 2)[3]) == 0


def test_spread_is_the_weighted_root_sum_of_squares() -> None:
    base, up, down = 1.0, 1.3, 0.6  # changes 0.3 and -0.4
    values = torch.tensor([base, up, down], dtype=F64).view(3, 1)
    value, error = spread(values, torch.ones(2, dtype=F64))
    assert float(value) == base and float(error) == pytest.approx(0.5)
    _, with_rules = spread(values, torch.ones(2, dtype=F64), torch.tensor([[base + 0.8]], dtype=F64))
    assert float(with_rules) == pytest.approx((0.25 + 0.16) ** 0.5)  # half the rules' difference


def test_the_noise_at_depth_is_the_noise_video_through_the_solver() -> None:
    """A white noise video of sd 1 K through :func:`subsurface_temperature`: at every depth the variance
    over pixels and frames and the sum of the autocovariance over all lags (the zero-frequency power) are
    the analytic ones within the sampling scatter; at the surface the noise itself."""
    n, size, dt, dx = 300, 24, 0.1, 0.1
    depths = [0.0, 0.05, 0.1, 0.2, 0.4]
    noise = torch.randn(n, size, size, dtype=F64, generator=torch.Generator().manual_seed(3))
    below = subsurface_temperature(BODY + noise, dt, dx, depths, diffusivity=A, body_temperature=BODY)
    x = below[60:] - BODY  # past the start: stationary
    one = torch.ones(1, dtype=F64)
    variance, rho = noise_correlation(
        torch.tensor(depths), A * one, 0 * one, dt * one, dx * one, (size, size), one
    )
    measured = x.var((0, 2, 3))
    assert float(variance[0, 0]) == pytest.approx(1.0) and float(rho[0, 0]) == 0.0
    # At 0.05 mm the frames' own instants still show (the noise is cyclostationary there): 19 % apart.
    torch.testing.assert_close(measured[2:], variance[0, 2:], rtol=0.12, atol=0)
    # the zero-frequency power: the variance of each pixel's mean over blocks of 80 frames, times 80
    blocks = x[:240].reshape(3, 80, len(depths), size, size).mean(1)
    power = 80 * blocks.var((0, 2, 3), unbiased=True)
    expected = variance[0] * (1 + rho[0]) / (1 - rho[0])
    torch.testing.assert_close(power[1:3], expected[1:3], rtol=0.15, atol=0)
    assert bool((variance[0].diff() < 0).all()) and bool((rho[0].diff() > 0).all())


@pytest.mark.slow
def test_the_noise_part_of_the_standard_error_is_the_spread_over_noisy_videos(
    burn: tuple[torch.Tensor, float, float],
) -> None:
    """The noise's standard error of the damage depth (propagated analytically, no noise copies) against
    the spread of the damage depth over 16 independent noisy copies of the video: the same size, pixel by
    pixel, within the scatter of an estimate with 16 degrees of freedom."""
    frames, dt, dx = burn
    args = {"diffusivity": A, "loss_rate": 0.003, "body_temperature": BODY}
    sd = 0.3
    total = damage_in_depth(frames, dt, dx, errors=StandardErrors(noise_sd=sd), **args).damage_depth_std
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
    spread_ = copies.std(0)
    deep = (copies > 0.05).all(0)
    assert int(deep.sum()) >= 20
    ratio = (error[deep] / spread_[deep]).median()
    assert 0.75 < float(ratio) < 1.33, float(ratio)
    assert math.isfinite(float(error.max()))


def test_the_frames_sampling_copy_switches_off_a_frame_later() -> None:
    t = torch.arange(8, dtype=F64)
    heating = torch.where(t <= 4, 10.0 * torch.sqrt(t), 10.0 * math.sqrt(4.0) * 0.5 ** (t - 4))  # off after 4
    rise = heating.view(1, -1, 1, 1).expand(1, 8, 2, 3).clone()
    one = torch.ones(1, dtype=F64)
    stacked, a, b, weights = perturbed_copies(rise, one, one, (one * 0, one * 0), switch=torch.tensor([4]))
    assert stacked.shape == (2, 8, 2, 3) and weights.tolist() == pytest.approx([1 / 3])
    late = stacked[1, :, 0, 0]
    bend = heating[2:] - 2 * heating[1:-1] + heating[:-2]
    assert torch.allclose(late[[1, 2, 3, 4, 6]], (heating[1:-1] - bend / 12)[[0, 1, 2, 3, 5]])
    assert float(late[5]) == pytest.approx(2 * heating[4] - heating[3])  # the heating went on a frame longer
    assert torch.equal(late[[0, 7]], heating[[0, 7]]) and torch.equal(a, one.repeat(2))
