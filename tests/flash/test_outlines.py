import math

import torch

from anra_torch.flash.outlines import OUTLINE_SHARE, outline_defects


def _blob(size: int, centre: tuple[float, float], radius: float, height: float) -> torch.Tensor:
    rows, cols = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    r2 = (rows - centre[0]) ** 2 + (cols - centre[1]) ** 2
    return height * torch.exp(-r2 / (2 * radius**2)).to(torch.float64)


def test_each_defect_is_outlined_at_a_share_of_its_own_peak_strongest_first() -> None:
    contrast = _blob(40, (12, 12), 4.0, 1.0) + _blob(40, (30, 0), 3.0, 0.5)  # the second runs out
    candidate = contrast > 0.3
    seen = []

    def depth_of(outline: torch.Tensor, peak: torch.Tensor) -> float:
        seen.append((int(outline.sum()), float(peak)))
        return math.exp(-0.5 * float(peak))

    significance = torch.full_like(contrast, 10.0)
    found = outline_defects(contrast, candidate, significance, (0.2, 9, 0.5), depth_of)
    assert len(found.defects) == 2 and [d.touches_edge for d in found.defects] == [False, True]
    first, second = found.defects
    assert abs(first.x - 12.5 * 0.5) < 0.05 and abs(first.y - 12.5 * 0.5) < 0.05
    for (outline, peak), (pixels, seen_peak) in zip(found.peaks, seen, strict=True):
        assert int(outline.sum()) == pixels and float(peak) == seen_peak
        assert bool((contrast[outline] >= OUTLINE_SHARE * peak).all())  # the outline: above the share
        assert abs(first.area - pixels * 0.25) < 1e-9 or abs(second.area - pixels * 0.25) < 1e-9
    assert first.depth_fraction == math.exp(-0.5 * seen[0][1])
    assert torch.equal(found.mask, found.peaks[0][0] | found.peaks[1][0])
    assert bool(torch.isnan(found.depth_fraction[~found.mask]).all())


def test_a_weaker_region_inside_a_stronger_outline_is_part_of_it_and_small_or_faint_ones_are_none() -> None:
    contrast = _blob(30, (15, 15), 5.0, 1.0)
    candidate = (contrast > 0.9) | ((contrast > 0.65) & (contrast < 0.7))  # a core and a ring around it
    candidate[0:2, 0:2] = True  # too small
    significance = torch.full_like(contrast, 10.0)
    found = outline_defects(contrast, candidate, significance, (0.2, 9, 1.0), lambda o, p: 0.5)
    assert len(found.defects) == 1
    faint = outline_defects(contrast * 0.1, candidate, significance, (0.2, 9, 1.0), lambda o, p: 0.5)
    assert faint.defects == [] and not faint.mask.any()
