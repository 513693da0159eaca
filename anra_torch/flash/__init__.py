"""Flash (pulsed) thermography of plates: the standard contrasts.

- :mod:`~anra_torch.flash.contrasts`: :func:`tsr` (thermographic signal reconstruction), :func:`pct`
  (principal component thermography), :func:`ppt` (pulsed phase thermography), each a batched tensor
  operation on the video, on its device and dtype.

The plates to try them on: :func:`anra_torch.simulation.flash_plate_video` (exact, the package's own) and
:func:`anra_torch.simulation.reference_plate_video` (an independent 3-D finite-volume simulator).
"""

from anra_torch.flash.contrasts import PCT_STANDARDISE, PCTResult, PPTResult, TSRResult, pct, ppt, tsr

__all__ = [
    "PCT_STANDARDISE",
    "PCTResult",
    "PPTResult",
    "TSRResult",
    "pct",
    "ppt",
    "tsr",
]
