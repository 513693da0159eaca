"""Flash (pulsed) thermography of plates: the standard contrasts.

- :mod:`~anra_torch.flash.contrasts`: :func:`tsr` (thermographic signal reconstruction), :func:`pct`
  (principal component thermography), :func:`ppt` (pulsed phase thermography), each a batched tensor
  operation on the video, on its device and dtype.

- :mod:`~anra_torch.flash.defects`: :func:`defect_map`, per pixel the through-thickness time constant of
  the cooling with the lateral conduction taken off (:mod:`~anra_torch.flash.lateral`,
  :mod:`~anra_torch.flash.cooling`), the plate's ``L^2 / a_z``, the defects' outlines
  (:mod:`~anra_torch.flash.outlines`) and depth fractions (the spread of the heat a defect reflects taken
  off, :mod:`~anra_torch.flash.spread`);
  :func:`flash_maps` (:mod:`~anra_torch.flash.maps`) adds the contrasts on the same frames
  (``anra diagnose --maps``).

The plates to try them on: :func:`anra_torch.simulation.flash_plate_video` (exact, the package's own) and
:func:`anra_torch.simulation.reference_plate_video` (an independent 3-D finite-volume simulator).
"""

from anra_torch.flash.contrasts import PCT_STANDARDISE, PCTResult, PPTResult, TSRResult, pct, ppt, tsr
from anra_torch.flash.defects import DefectMap, FoundDefect, defect_map
from anra_torch.flash.maps import TSR_FRAMES, FlashMaps, flash_maps

__all__ = [
    "TSR_FRAMES",
    "DefectMap",
    "FlashMaps",
    "FoundDefect",
    "PCT_STANDARDISE",
    "PCTResult",
    "PPTResult",
    "TSRResult",
    "defect_map",
    "flash_maps",
    "pct",
    "ppt",
    "tsr",
]
