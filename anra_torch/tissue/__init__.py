"""Tissue: what heat did below the surface.

- :mod:`~anra_torch.tissue.depth`: the subsurface temperature under every pixel from the measured surface
  (:func:`subsurface_temperature`), the heat that entered through it (:func:`surface_heat_input`), Omega,
  CEM43 and the peak temperature in depth with the damage depth and its standard error
  (:func:`damage_in_depth`, :class:`DepthMaps`);
- :mod:`~anra_torch.tissue.depth_fit`: the diffusivity and perfusion the depth model needs, fitted on the
  recording's cooling, and the flag for volumetric heating (:func:`fit_depth_parameters`,
  :class:`DepthParameters`);
- :mod:`~anra_torch.tissue.depth_features`: both together, the maps of ``TissueFeatures(depth=True)`` and
  ``anra features --depth`` (:func:`depth_features`);
- :mod:`~anra_torch.tissue.depth_solver`: the engine the others share (depth grid, operator, the march).
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
from anra_torch.tissue.depth_features import DEPTH_MAPS, DepthFeatures, depth_features
from anra_torch.tissue.depth_fit import DepthParameters, fit_depth_parameters
from anra_torch.tissue.depth_solver import depth_nodes

__all__ = [
    "CEM43_THRESHOLD",
    "DEPTH_MAPS",
    "DOSE_FLOOR",
    "DepthFeatures",
    "DepthMaps",
    "DepthParameters",
    "damage_in_depth",
    "depth_features",
    "depth_nodes",
    "fit_depth_parameters",
    "subsurface_temperature",
    "surface_heat_input",
    "threshold_depth",
]
