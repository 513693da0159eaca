"""Flash plates (:mod:`anra_torch.simulation.plate`): the 3-D plate against the exact depth factor."""

from __future__ import annotations

import numpy as np

from anra_torch.simulation.plate import flash_plate_video, plate_factor


def test_3d_plate_without_lateral_flow_follows_the_exact_depth_factor() -> None:
    """The independent 3-D simulator itself: with no lateral diffusion every column is a 1-D plate, and its
    top cell follows the continuous plate's surface factor once heat has crossed a few cells."""
    frames, dt, _ = flash_plate_video(
        size=16, n_frames=60, rate=20.0, diffusivity=(0.0, 0.0, 0.45), thickness=1.5, layers=60,
        t_heat=-0.05, noise_sd=0.0, pad=4,
    )  # fmt: skip
    excess = frames[:, 8, 8].double().numpy() - 20.0
    t = np.arange(60) * dt + 0.05
    exact = plate_factor(t, 1.5**2 / 0.45)
    late = t >= 0.5  # the top cell (0.025 mm deep) against the surface: measured 2e-4 from 0.5 s on
    ratio = excess[late] / excess[late][0]
    np.testing.assert_allclose(ratio, exact[late] / exact[late][0], rtol=2e-3)
