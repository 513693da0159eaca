"""Forward models on the pixel grid: one integrator, the heat equation, exact solutions, the tissue model.

- :mod:`~anra_torch.simulation.integrator`: :func:`integrate`, the only caller of ``torchdiffeq``, and
  :func:`stable_substeps`, the substeps per frame from the spectrum of a right-hand side.
- :mod:`~anra_torch.simulation.heat`: :class:`HeatRHS` (5-point Laplacian or flux form, :data:`BOUNDARIES`)
  and :func:`simulate_heat`.
- :mod:`~anra_torch.simulation.analytic`: :func:`gaussian_blob`, :func:`gaussian_blobs` (infinite plane)
  and :func:`heat_spectral` (the frame's rectangle), exact solutions the simulators are tested against.
- :mod:`~anra_torch.simulation.tissue`: :class:`TissueRHS` (the Pennes-like tissue model with a
  :class:`MovingSource`) and :func:`simulate_tissue`.

:func:`anra_torch.effects.simulate_effects` and :func:`anra_torch.forecast.refine_model` integrate their
right-hand sides with the same :func:`integrate`. Units: mm, s, mm^2/s.
"""

from anra_torch.simulation.analytic import SPECTRAL_BOUNDARIES, gaussian_blob, gaussian_blobs, heat_spectral
from anra_torch.simulation.heat import BOUNDARIES, HeatRHS, simulate_heat
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
from anra_torch.simulation.tissue import MovingSource, TissueRHS, simulate_tissue

__all__ = [
    "ADAPTIVE_METHODS",
    "BOUNDARIES",
    "FIXED_STEP_METHODS",
    "POLICIES",
    "SAFETY",
    "SPECTRAL_BOUNDARIES",
    "HeatRHS",
    "MovingSource",
    "StabilityRegion",
    "StepCount",
    "StepPolicy",
    "TissueRHS",
    "gaussian_blob",
    "gaussian_blobs",
    "heat_spectral",
    "integrate",
    "simulate_heat",
    "simulate_tissue",
    "stable_substeps",
]
