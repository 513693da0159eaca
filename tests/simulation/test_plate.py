"""Flash plates (:mod:`anra_torch.simulation.plate`): the depth factor against its image series, and the 3-D
plate against the exact depth factor."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from anra_torch.simulation.plate import FlashPlate, flash_plate_video, plate_factor, with_depth


def test_3d_plate_without_lateral_flow_follows_the_exact_depth_factor() -> None:
    """The independent 3-D simulator itself: with no lateral diffusion every column is a 1-D plate, and its
    top cell follows the continuous plate's surface factor once heat has crossed a few cells."""
    frames, dt, _ = flash_plate_video(
        size=16, n_frames=60, rate=20.0, t_heat=-0.05, noise_sd=0.0, pad=4,
        plate=FlashPlate(diffusivity=(0.0, 0.0, 0.45), thickness=1.5, layers=60),
    )  # fmt: skip
    excess = frames[:, 8, 8].double().numpy() - 20.0
    t = np.arange(60) * dt + 0.05
    exact = plate_factor(t, 1.5**2 / 0.45)
    late = t >= 0.5  # the top cell (0.025 mm deep) against the surface: measured 2e-4 from 0.5 s on
    ratio = excess[late] / excess[late][0]
    np.testing.assert_allclose(ratio, exact[late] / exact[late][0], rtol=2e-3)


@pytest.mark.parametrize("depth_time", [0.3, 2.0, 50.0])
def test_plate_factor_is_the_poisson_summed_image_series(depth_time: float) -> None:
    """Jacobi's identity: ``1 + 2 sum_n exp(-n^2 pi^2 t / tau) = sqrt(tau / (pi t)) sum_m exp(-m^2 tau / t)``
    (images of the heated face mirrored in both faces), summed over m = -30..30."""
    elapsed = np.geomspace(1e-3, 20.0, 40) * depth_time
    m = np.arange(-30, 31, dtype=np.float64)
    images = np.sqrt(depth_time / (np.pi * elapsed)) * np.exp(-np.outer(depth_time / elapsed, m**2)).sum(1)
    np.testing.assert_allclose(plate_factor(elapsed, depth_time), images, rtol=1e-12)


def test_with_depth_scales_the_excess_by_the_factors_ratio() -> None:
    times = np.arange(5) * 0.1
    clean = torch.full((5, 2, 3), 32.0, dtype=torch.float64)
    out = with_depth(clean, times, (0.5, -0.2, 3.0, 30.0))
    theta = plate_factor(times + 0.2, 3.0) / plate_factor(np.array(0.2), 3.0)
    np.testing.assert_allclose(out[:, 1, 2].numpy(), 30.0 + 2.0 * np.sqrt(theta), rtol=1e-14)
    assert float(out[0, 0, 0]) == pytest.approx(32.0, rel=1e-15)  # no depth change at the first frame
