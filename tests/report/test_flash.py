"""write_flash_report: the defect map, the contrasts and the table of defects in flash.md."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from anra_torch.flash import DefectMap, FlashMaps, FoundDefect
from anra_torch.report import FLASH_FIGURES, write_flash_report

pytest.importorskip("matplotlib")


def _maps(found: tuple[FoundDefect, ...]) -> FlashMaps:
    mask = torch.zeros(12, 16, dtype=torch.bool)
    if found:
        mask[3:7, 4:9] = True
    fraction = torch.where(mask, 0.4, torch.nan).double()
    defects = DefectMap(
        depth_time=torch.full((12, 16), 8.0).double(),
        plate_time=8.0,
        plate_time_se=0.2,
        back_wall_reached=bool(found),
        defect_score=mask.double(),
        defect_mask=mask,
        depth_fraction=fraction,
        defects=found,
        lateral=(7.1, 1.2, 0.0),
        t_ref=20.0,
        first_time=0.03,
        noise_sd=0.02,
    )
    return FlashMaps(
        defects=defects,
        flash_frame=2,
        tsr_d2=torch.randn(4, 12, 16).double(),
        tsr_times=torch.tensor([0.1, 0.3, 1.0, 3.0]).double(),
        pct=torch.randn(6, 12, 16),
        ppt=torch.randn(8, 12, 16),
        ppt_frequencies=torch.arange(1, 9) * 0.1,
    )


@pytest.mark.slow
def test_the_report_draws_the_maps_and_lists_the_defects(tmp_path: Path) -> None:
    found = (FoundDefect(x=2.0, y=1.5, area=1.8, depth_fraction=0.4, touches_edge=True),)
    path = write_flash_report(tmp_path / "r", _maps(found), 0.3)
    text = path.read_text()
    assert path.name == "flash.md" and (tmp_path / "r" / FLASH_FIGURES[0]).stat().st_size > 0
    assert "| plate L^2 / a_z (front-face data fix only this ratio) | 8.00 ± 0.20 s |" in text
    assert "| 1 | 2.00 | 1.50 | 1.8 | 0.40 | yes |" in text
    assert "back wall reached in the recording | yes" in text


@pytest.mark.slow
def test_an_intact_plate_and_a_short_recording_say_so(tmp_path: Path) -> None:
    text = write_flash_report(tmp_path, _maps(()), 0.3).read_text()
    assert "No defect found." in text and "a lower bound" in text
