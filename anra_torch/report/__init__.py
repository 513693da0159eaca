"""Markdown reports with figures, drawn by matplotlib on Agg, the ``anra_torch[plot]`` extra.

- :func:`write_estimate_report`, for ``anra demo``: one diffusivity estimate, its frames, RTC attention,
  windowed field and per-frame estimates;
- :func:`write_diagnosis_report`, for ``anra diagnose --report``: a hidden-effect diagnosis and its
  forecast test;
- :func:`write_phase_report`, for ``anra diagnose --report``: a recording's phases, their timeline and
  forecasts;
- :func:`write_depth_report`, for ``anra features --depth --report``: the damage-depth map and depth
  profiles;
- :func:`write_flash_report`, for ``anra diagnose --maps --report``: a flash recording's defect map and
  contrasts;
- shared helpers in :mod:`~anra_torch.report.figures`: number format, axes in mm, colour maps.

Each writer lives in the module of its name: :mod:`~anra_torch.report.estimate`,
:mod:`~anra_torch.report.diagnosis`, :mod:`~anra_torch.report.phases`, :mod:`~anra_torch.report.depth`,
:mod:`~anra_torch.report.flash`.
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
