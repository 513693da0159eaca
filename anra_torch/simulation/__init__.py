"""Forward models on the pixel grid: one integrator, the heat equation, exact solutions, the tissue model.

- :mod:`~anra_torch.simulation.integrator`: :func:`integrate` (the only caller of ``torchdiffeq``) and
  :func:`stable_substeps` (substeps per frame from the spectrum of the right-hand side).
"""

from anra_torch.simulation.integrator import (
    ADAPTIVE_METHODS,
    FIXED_STEP_METHODS,
    POLICIES,
    SAFETY,
    StabilityRegion,
    StepCount,
    StepPolicy,
    integrate,
    stable_substeps,
)

__all__ = [
    "ADAPTIVE_METHODS",
    "FIXED_STEP_METHODS",
    "POLICIES",
    "SAFETY",
    "StabilityRegion",
    "StepCount",
    "StepPolicy",
    "integrate",
    "stable_substeps",
]
