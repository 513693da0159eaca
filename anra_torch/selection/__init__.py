"""Which effects act in a thermal video: model selection on the PDE balance, without solving the PDE.

:func:`diagnose_terms` balances candidate terms (:data:`anra_torch.effects.EFFECTS`) on the frames through
the balance core (:mod:`anra_torch.balance`), tests them with Wald tests against exactly propagated
standard errors (:mod:`~anra_torch.selection.statistics`) and selects them stepwise
(:mod:`~anra_torch.selection.stepwise`).
"""

from anra_torch.selection.depth_aware import DepthAwareFit, depth_aware_diffusivity
from anra_torch.selection.diagnose import (
    ALPHA,
    SMOOTHING,
    Diagnosis,
    diagnose_terms,
    fit_effects,
    minimum_frame_size,
)
from anra_torch.selection.stepwise import MIN_SHARE

__all__ = [
    "ALPHA",
    "MIN_SHARE",
    "SMOOTHING",
    "DepthAwareFit",
    "Diagnosis",
    "depth_aware_diffusivity",
    "diagnose_terms",
    "fit_effects",
    "minimum_frame_size",
]
