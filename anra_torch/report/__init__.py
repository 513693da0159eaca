"""Markdown reports with figures (matplotlib on Agg: ``anra_torch[plot]``).

- :func:`write_estimate_report` (:mod:`~anra_torch.report.estimate`): one diffusivity estimate, its frames,
  RTC attention, windowed field and per-frame estimates (``anra demo``);
- :func:`write_diagnosis_report` (:mod:`~anra_torch.report.diagnosis`): a hidden-effect diagnosis and its
  forecast test (``anra diagnose --report``);
- :func:`write_phase_report` (:mod:`~anra_torch.report.phases`): a recording's phases, their timeline and
  forecasts (``anra diagnose --report``);
- :func:`write_depth_report` (:mod:`~anra_torch.report.depth`): the damage-depth map and depth profiles
  (``anra features --depth --report``);
- :func:`write_flash_report` (:mod:`~anra_torch.report.flash`): a flash recording's defect map and contrasts
  (``anra diagnose --maps --report``);
- shared helpers (number format, axes in mm, colour maps) in :mod:`~anra_torch.report.figures`.
"""

from anra_torch.report.depth import DEPTH_FIGURES, write_depth_report
from anra_torch.report.diagnosis import DIAGNOSIS_FIGURES, write_diagnosis_report
from anra_torch.report.estimate import FIGURES, attention_map, write_estimate_report
from anra_torch.report.figures import format_pm
from anra_torch.report.flash import FLASH_FIGURES, write_flash_report
from anra_torch.report.phases import write_phase_report

__all__ = [
    "DEPTH_FIGURES",
    "DIAGNOSIS_FIGURES",
    "FIGURES",
    "FLASH_FIGURES",
    "attention_map",
    "format_pm",
    "write_depth_report",
    "write_diagnosis_report",
    "write_estimate_report",
    "write_flash_report",
    "write_phase_report",
]
