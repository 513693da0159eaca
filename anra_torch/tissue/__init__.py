"""Tissue: what heat did below the surface.

- :mod:`~anra_torch.tissue.depth`: the subsurface temperature under every pixel from the measured surface
  (:func:`subsurface_temperature`), the heat that entered through it (:func:`surface_heat_input`), Omega,
  CEM43 and the peak temperature in depth with the damage depth and its standard error
  (:func:`damage_in_depth`, :class:`DepthMaps`);
- :mod:`~anra_torch.tissue.depth_fit`: the diffusivity and perfusion the depth model needs, fitted on the
  recording's cooling, and the flag for volumetric heating (:func:`fit_depth_parameters`,
  :class:`DepthParameters`).
"""

from anra_torch.tissue.depth import (
    CEM43_THRESHOLD,
    DOSE_FLOOR,
    DepthMaps,
    damage_in_depth,
    subsurface_temperature,
    surface_heat_input,
    threshold_depth,
)
from anra_torch.tissue.depth_solver import depth_nodes

__all__ = [
    "CEM43_THRESHOLD",
    "DOSE_FLOOR",
    "DepthMaps",
    "damage_in_depth",
    "depth_nodes",
    "subsurface_temperature",
    "surface_heat_input",
    "threshold_depth",
]
