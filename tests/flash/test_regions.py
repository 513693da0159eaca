"""Connected components, dilation and erosion of boolean maps against small drawn cases."""

from __future__ import annotations

import torch

from anra_torch.flash.regions import components, dilate, edge_scatter, erode, plate_level, smooth


def _mask(rows: list[str]) -> torch.Tensor:
    return torch.tensor([[c == "#" for c in r] for r in rows])


def test_components_are_four_connected_and_numbered_by_their_first_pixel() -> None:
    mask = _mask(
        [
            "##..#",
            ".#..#",
            "...#.",
            "###.#",
            "#...#",
        ]
    )
    labels, count = components(mask)
    expected = torch.tensor(
        [
            [1, 1, 0, 0, 2],
            [0, 1, 0, 0, 2],
            [0, 0, 0, 3, 0],
            [4, 4, 4, 0, 5],
            [4, 0, 0, 0, 5],
        ]
    )
    assert count == 5 and torch.equal(labels, expected)  # diagonal neighbours are apart


def test_a_spiral_is_one_component_and_an_empty_map_none() -> None:
    spiral = _mask(["#######", "......#", "#####.#", "#...#.#", "#.###.#", "#.....#", "#######"])
    labels, count = components(spiral)
    assert count == 1 and torch.equal(labels > 0, spiral)
    labels, count = components(torch.zeros(4, 6, dtype=torch.bool))
    assert count == 0 and labels.eq(0).all()


def test_dilate_and_erode_by_squares() -> None:
    point = torch.zeros(7, 7, dtype=torch.bool)
    point[3, 3] = True
    assert torch.equal(dilate(point, 2), _mask(["......."] + [".#####."] * 5 + ["......."]))
    block = dilate(point, 2)
    assert torch.equal(erode(block, 2), point)
    full = torch.ones(5, 5, dtype=torch.bool)
    assert torch.equal(erode(full, 1), full)  # the frame's edge does not erode


def test_smooth_keeps_a_constant_to_the_edges_and_a_spot_sums_to_one() -> None:
    flat = torch.full((9, 12), 2.5, dtype=torch.float64)
    assert torch.allclose(smooth(flat, 2.0), flat)
    spot = torch.zeros(31, 31, dtype=torch.float64)
    spot[15, 15] = 1.0
    out = smooth(spot, 2.0)
    assert (
        abs(float(out.sum()) - 1) < 1e-12 and torch.allclose(out, out.T) and torch.allclose(out, out.flip(0))
    )
    # the Gaussian's width: the second moment along a row is sigma^2
    k = torch.arange(-15, 16, dtype=torch.float64)
    assert abs(float((out.sum(0) * k**2).sum()) - 4.0) < 0.05


def test_edge_scatter_sees_a_noisy_edge_that_a_cut_to_sound_pixels_would_hide() -> None:
    generator = torch.Generator().manual_seed(0)
    values = 0.1 * torch.randn(40, 40, generator=generator, dtype=torch.float64)
    border = torch.ones(40, 40, dtype=torch.bool)
    border[1:-1, 1:-1] = False
    values[border] = 0.5 * torch.randn(int(border.sum()), generator=generator, dtype=torch.float64)
    values[0, 10:25] += 5.0  # a defect running out of the frame
    sound = values.abs() < 0.3
    spread = edge_scatter(values, sound, 10, 29)
    assert abs(float(spread[0, 20]) / 0.5 - 1) < 0.25  # 0.19 from the sound pixels
    assert abs(float(spread[20, 20]) / 0.1 - 1) < 0.2  # the interior, from the sound pixels
    assert float(spread[5, 20]) < 0.15


def test_the_plate_is_the_longest_large_region_whose_back_wall_the_recording_reaches() -> None:
    # a defect covering 60 % of the frame at ln tau 0.8 beside the sound plate at 2.2 (the median alone
    # takes the defect for the plate); pixel noise 0.3 on a flat plate moves nothing
    noise = 0.3 * torch.randn((40, 40), generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    log_tau = torch.full((40, 40), 2.2, dtype=torch.float64)
    log_tau[:, :24] = 0.8
    level, sound = plate_level(log_tau + 0.05 * noise, 0.3, sigma=3.0, share=0.25, longest=3.0)
    assert abs(float(level) - 2.2) < 0.02 and bool(sound[:, 26:].all()) and not bool(sound[:, :22].any())
    level, _ = plate_level(log_tau + 0.05 * noise, 0.3, sigma=3.0, share=0.25, longest=2.0)
    assert abs(float(level) - 0.8) < 0.02  # the longer region's back wall not in the recording: kept
    level, _ = plate_level(2.2 + noise, 0.3, sigma=3.0, share=0.25, longest=3.0)
    assert abs(float(level) - 2.2) < 0.05
