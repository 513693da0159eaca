import math

import pytest
import torch

from anra_torch.flash.cooling import log_surface, windowed_tau
from anra_torch.flash.spread import reflected_share, spread_depth_time

F64 = torch.float64


def _disc(size: int, radius_px: float) -> torch.Tensor:
    rows, cols = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    centre = size // 2
    return (rows - centre) ** 2 + (cols - centre) ** 2 <= radius_px**2


@pytest.mark.parametrize("dx, size", [(0.05, 81), (0.01, 401)])
def test_the_share_at_a_disc_centre_is_the_gaussian_outside_its_radius(dx: float, size: int) -> None:
    # isotropic a: a 2-D Gaussian of variance a t per axis has 1 - exp(-R^2 / 2 a t) inside radius R; at
    # 0.01 mm pixels the Gaussians reach 760 px (without cells (N, 1521^2) weights; in cells of 7 px)
    radius = 1.0
    outline = _disc(size, radius / dx)
    elapsed = torch.tensor([0.05, 0.3, 1.0, 3.0], dtype=F64)
    share = reflected_share(outline, (size // 2, size // 2), torch.tensor([1.2, 1.2, 0.0]), dx, elapsed)
    exact = 1 - torch.exp(-(radius**2) / (2 * 1.2 * elapsed))
    torch.testing.assert_close(share, exact, atol=0.02, rtol=0)


def test_an_edge_across_the_columns_sees_only_a_x_and_the_frame_edge_continues_the_defect() -> None:
    # a defect over the left half of the frame, running out of it: along a row only a_x spreads the edge
    outline = torch.zeros(40, 40, dtype=torch.bool)
    outline[:, :20] = True
    dx, elapsed = 0.1, torch.tensor([0.1, 0.5], dtype=F64)
    lateral = torch.tensor([4.0, 0.5, 0.6])
    share = reflected_share(outline, (20, 16), lateral, dx, elapsed)  # 3.5 px inside the edge
    exact = 0.5 * (1 + torch.erf(3.5 * dx / torch.sqrt(2 * 4.0 * elapsed)))
    torch.testing.assert_close(share, exact, atol=0.01, rtol=0)
    # at the frame's edge only the edge 19.5 px to the right counts: the defect goes on to the left
    at_the_frame_edge = reflected_share(outline, (20, 0), lateral, dx, elapsed)
    exact = 0.5 * (1 + torch.erf(19.5 * dx / torch.sqrt(2 * 4.0 * elapsed)))
    torch.testing.assert_close(at_the_frame_edge, exact, atol=0.01, rtol=0)


def _first_order(tau: float, plate: float, share, elapsed):
    """The surface excess over a defect whose reflected excess reaches the pixel by ``share``, less the
    lateral term the map takes off, written out here as the module's docstring states it."""
    layer = torch.exp(log_surface(elapsed, torch.tensor([tau], dtype=F64)))[0]
    sound = torch.exp(log_surface(elapsed, torch.tensor([plate], dtype=F64)))[0]
    excess = sound + share * (layer - sound)
    ratio = (layer - sound) / excess
    taken_off = torch.cat(
        [torch.zeros(1, dtype=F64), torch.cumsum(0.5 * (ratio[1:] + ratio[:-1]) * share.diff(), 0)]
    )
    return excess.log() - taken_off


@pytest.mark.parametrize("radius", [2.0, 4.0])
def test_a_small_deep_disc_reads_deeper_and_the_correction_recovers_its_depth(radius: float) -> None:
    dx, lateral = 0.2, torch.tensor([7.3, 1.1, 0.0])
    outline = _disc(81, radius / dx)
    elapsed = torch.logspace(-1.3, math.log10(30.0), 120, dtype=F64)
    plate, tau = 36.0, 9.0  # L^2 / a_z; d / L 0.5
    share = reflected_share(outline, (40, 40), lateral, dx, elapsed.clamp(max=0.4 * 11.0))
    y = _first_order(tau, plate, share, elapsed)
    weights = torch.full_like(y, 1e4)
    read = float(windowed_tau(y[None], weights[None], elapsed, 0.4)[0][0])
    assert read > 1.1 * tau  # the spread makes it read deeper
    series = (elapsed, weights)
    found = spread_depth_time(read, plate, (outline, (40, 40)), lateral, dx, series, 0.4)
    assert abs(math.sqrt(found / plate) - 0.5) < 0.01 < abs(math.sqrt(read / plate) - 0.5)


def test_where_the_first_order_model_does_not_hold_tau_is_left_as_it_is() -> None:
    dx, outline = 0.2, _disc(41, 5.0)
    elapsed = torch.logspace(-1.3, math.log10(30.0), 120, dtype=F64)
    weights, at = torch.ones_like(elapsed), (outline, (20, 20))
    lateral = torch.tensor([7.3, 1.1, 0.0])
    # the window's floor (5 % of the recording, 1.5 s) past 0.4 tau: the layer evens out within the fit
    assert spread_depth_time(2.0, 36.0, at, lateral, dx, (elapsed, weights), 0.4) == 2.0
    assert spread_depth_time(9.0, 36.0, at, torch.zeros(3), dx, (elapsed, weights), 0.4) == 9.0  # no a
    everywhere = (torch.ones(41, 41, dtype=torch.bool), (20, 20))  # nothing to spread into
    assert spread_depth_time(9.0, 36.0, everywhere, lateral, dx, (elapsed, weights), 0.4) == 9.0
    assert math.isinf(spread_depth_time(math.inf, 36.0, at, lateral, dx, (elapsed, weights), 0.4))
