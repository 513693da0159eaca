"""Tissue: thermal dose, per-pixel damage features, and tissue models learned from video.

- :mod:`~anra_torch.tissue.dose`: CEM43 and the Arrhenius damage integral of temperature histories;
- :mod:`~anra_torch.tissue.features`: :class:`TissueFeatures`, per-pixel maps for damage classification;
- :mod:`~anra_torch.tissue.learned`: :class:`LearnedTissueModel`, fitted end to end through the simulator.
"""

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
from anra_torch.tissue.features import (
    DOSE_MAPS,
    LOSS_REPLICATES,
    MAPS,
    MAX_LOSS_ERROR,
    MIN_CONFIDENCE,
    TissueFeatureMaps,
    TissueFeatures,
    feature_summary,
    save_feature_maps,
)
from anra_torch.tissue.learned import LearnedTissueModel, relative_error

__all__ = [
    "CEM43_R",
    "DOSE_MAPS",
    "GAS_CONSTANT",
    "LOSS_REPLICATES",
    "MAPS",
    "MAX_LOSS_ERROR",
    "MIN_CONFIDENCE",
    "RULES",
    "SKIN",
    "UNITS",
    "arrhenius_omega",
    "cem43",
    "count_masked",
    "feature_summary",
    "relative_error",
    "save_feature_maps",
    "time_above",
    "to_celsius",
    "ArrheniusConstants",
    "LearnedTissueModel",
    "TissueFeatureMaps",
    "TissueFeatures",
]
