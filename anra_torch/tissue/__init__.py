"""Tissue: thermal dose, per-pixel damage features, tissue models learned from video, and what heat did
below the surface.

- :mod:`~anra_torch.tissue.dose`: CEM43 and the Arrhenius damage integral of temperature histories;
- :mod:`~anra_torch.tissue.features`: :class:`TissueFeatures`, per-pixel maps for damage classification,
  and :func:`feature_summary`, the ``anra features`` record; :mod:`~anra_torch.tissue.feature_maps`: what
  they return and write (:class:`TissueFeatureMaps`, :func:`save_feature_maps`);
- :mod:`~anra_torch.tissue.learned`: :class:`LearnedTissueModel`, fitted end to end through the simulator,
  and :func:`omega_with_constants`, the Arrhenius dose with per-pixel constants that learn;
- :mod:`~anra_torch.tissue.depth`: the subsurface temperature under every pixel from the measured surface
  (:func:`subsurface_temperature`) and the heat that entered through it (:func:`surface_heat_input`);
- :mod:`~anra_torch.tissue.depth_damage`: Omega, CEM43 and the peak temperature in depth with the damage
  depth and its standard error (:func:`damage_in_depth`, :class:`DepthMaps`, its settings
  :class:`DepthSettings` and :class:`StandardErrors`);
- :mod:`~anra_torch.tissue.depth_fit`: the diffusivity and perfusion the depth model needs, fitted on the
  recording's cooling, and the flag for volumetric heating (:func:`fit_depth_parameters`,
  :class:`DepthParameters`);
- :mod:`~anra_torch.tissue.depth_features`: both together, the maps of ``TissueFeatures(depth=True)`` and
  ``anra features --depth`` (:func:`depth_features`);
- :mod:`~anra_torch.tissue.depth_cooling`: what that fit sees of the cooling and the cooling it forecasts;
- :mod:`~anra_torch.tissue.depth_solver`: the engine the others share (depth grid, operator, the march);
- :mod:`~anra_torch.tissue.depth_window`: the frames continued beyond their edges (the frame is a window);
- :mod:`~anra_torch.tissue.depth_errors`: the maps' standard errors (perturbed copies, the noise's analytic
  part);
- :mod:`~anra_torch.tissue.depth_doses`: the doses of the depth march and the noise carried through them.
"""

from anra_torch.tissue.depth import subsurface_temperature, surface_heat_input
from anra_torch.tissue.depth_damage import (
    CEM43_THRESHOLD,
    DOSE_FLOOR,
    DepthMaps,
    DepthSettings,
    StandardErrors,
    damage_in_depth,
    threshold_depth,
)
from anra_torch.tissue.depth_features import DEPTH_MAPS, DepthFeatures, depth_features
from anra_torch.tissue.depth_fit import DepthParameters, fit_depth_parameters
from anra_torch.tissue.depth_solver import depth_nodes
from anra_torch.tissue.dose import (
    CEM43_R,
    GAS_CONSTANT,
    RULES,
    SKIN,
    UNITS,
    ArrheniusConstants,
    arrhenius_omega,
    cem43,
    count_masked,
    time_above,
    to_celsius,
)
from anra_torch.tissue.feature_maps import (
    DOSE_MAPS,
    MAPS,
    MAX_LOSS_ERROR,
    MIN_CONFIDENCE,
    TissueFeatureMaps,
    save_feature_maps,
)
from anra_torch.tissue.features import TissueFeatures, feature_summary
from anra_torch.tissue.learned import LearnedTissueModel, omega_with_constants, relative_error

__all__ = [
    "ArrheniusConstants",
    "CEM43_R",
    "CEM43_THRESHOLD",
    "DEPTH_MAPS",
    "DOSE_FLOOR",
    "DOSE_MAPS",
    "DepthFeatures",
    "DepthMaps",
    "DepthParameters",
    "DepthSettings",
    "GAS_CONSTANT",
    "LearnedTissueModel",
    "MAPS",
    "MAX_LOSS_ERROR",
    "MIN_CONFIDENCE",
    "RULES",
    "SKIN",
    "StandardErrors",
    "TissueFeatureMaps",
    "TissueFeatures",
    "UNITS",
    "arrhenius_omega",
    "cem43",
    "count_masked",
    "damage_in_depth",
    "depth_features",
    "depth_nodes",
    "feature_summary",
    "fit_depth_parameters",
    "omega_with_constants",
    "relative_error",
    "save_feature_maps",
    "subsurface_temperature",
    "surface_heat_input",
    "threshold_depth",
    "time_above",
    "to_celsius",
]
