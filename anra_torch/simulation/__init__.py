"""Forward models on the pixel grid: one integrator, the heat equation, exact solutions, the tissue model.

- :mod:`~anra_torch.simulation.integrator`: :func:`integrate` (fixed steps in
  :mod:`~anra_torch.simulation.fixed_grid`, adaptive and adjoint ones by ``torchdiffeq``) and
  :func:`stable_substeps`, the substeps per frame from the spectrum of a right-hand side.
- :mod:`~anra_torch.simulation.heat`: :class:`HeatRHS` (5-point Laplacian or flux form, :data:`BOUNDARIES`)
  and :func:`simulate_heat`.
- :mod:`~anra_torch.simulation.analytic`: :func:`gaussian_blob`, :func:`gaussian_blobs` (infinite plane)
  and :func:`heat_spectral` (the frame's rectangle), exact solutions the simulators are tested against.
- :mod:`~anra_torch.simulation.tissue`: :class:`TissueRHS` (the Pennes-like tissue model with a
  :class:`MovingSource`) and :func:`simulate_tissue`.
- :mod:`~anra_torch.simulation.synthetic`: :func:`paper_video` (the paper's case) and :func:`blobs_video`,
  videos of known diffusivity from the exact solutions.
- :mod:`~anra_torch.simulation.camera`: what real infrared cameras add (:data:`ARTEFACTS`, :func:`plant`).
- Independent references, sharing none of the operators above: :mod:`~anra_torch.simulation.independent`
  (:func:`simulate_continuum`, the continuous PDE by spectral and finite-volume methods, pixel averages) and
  :mod:`~anra_torch.simulation.plate` (conduction into a plate below the surface, exact);
  :mod:`~anra_torch.simulation.bioheat_reference` (:func:`simulate_bioheat`, 3-D Pennes bioheat by finite
  volumes with the Arrhenius damage in depth) and its scenes, :mod:`~anra_torch.simulation.bioheat_scenes`
  (:func:`random_scene`); :mod:`~anra_torch.simulation.bioheat_green` (:func:`simulate_spot`, a Gaussian
  spot on a half-space by its Green's function: no grid, the frame a window onto an unbounded tissue);
  :mod:`~anra_torch.simulation.plate_reference` (:func:`reference_plate_video`, a 3-D
  anisotropic flash-thermography plate by finite volumes on an irregular mesh, with defects of any shape).

:func:`anra_torch.effects.simulate_effects` and :func:`anra_torch.forecast.refine_model` integrate their
right-hand sides with the same :func:`integrate`. Units: mm, s, mm^2/s.
"""

from anra_torch.simulation.analytic import SPECTRAL_BOUNDARIES, gaussian_blob, gaussian_blobs, heat_spectral
from anra_torch.simulation.bioheat_green import GreenResult, GreenScene, simulate_spot, spot_peak
from anra_torch.simulation.bioheat_reference import camera_frames, simulate_bioheat
from anra_torch.simulation.bioheat_scenes import random_scene
from anra_torch.simulation.bioheat_setup import (
    BioheatResult,
    BioheatScene,
    Contact,
    DepthGrid,
    SurfaceFlux,
    Tissue,
)
from anra_torch.simulation.camera import ARTEFACTS, plant
from anra_torch.simulation.heat import BOUNDARIES, HeatRHS, simulate_heat
from anra_torch.simulation.independent import (
    METHODS,
    Continuum,
    ContinuumGrid,
    gaussian_cells,
    simulate_continuum,
)
from anra_torch.simulation.integrator import (
    ADAPTIVE_METHODS,
    FIXED_STEP_METHODS,
    POLICIES,
    SAFETY,
    Solver,
    StabilityRegion,
    StepCount,
    StepPolicy,
    integrate,
    stable_substeps,
)
from anra_torch.simulation.plate import FlashPlate, flash_plate_video, plate_factor, with_depth
from anra_torch.simulation.plate_reference import (
    DEFECT_KINDS,
    Defect,
    PlateSetup,
    ReferencePlate,
    default_flash,
    reference_plate_video,
)
from anra_torch.simulation.synthetic import Blobs, PaperSpot, SyntheticVideo, blobs_video, paper_video
from anra_torch.simulation.tissue import MovingSource, TissueRHS, simulate_tissue

__all__ = [
    "ADAPTIVE_METHODS",
    "ARTEFACTS",
    "BOUNDARIES",
    "DEFECT_KINDS",
    "FIXED_STEP_METHODS",
    "METHODS",
    "POLICIES",
    "SAFETY",
    "SPECTRAL_BOUNDARIES",
    "BioheatResult",
    "Blobs",
    "BioheatScene",
    "Contact",
    "Continuum",
    "ContinuumGrid",
    "Defect",
    "FlashPlate",
    "GreenResult",
    "GreenScene",
    "DepthGrid",
    "HeatRHS",
    "MovingSource",
    "PaperSpot",
    "ReferencePlate",
    "Solver",
    "StabilityRegion",
    "StepCount",
    "StepPolicy",
    "SurfaceFlux",
    "SyntheticVideo",
    "Tissue",
    "TissueRHS",
    "blobs_video",
    "camera_frames",
    "default_flash",
    "flash_plate_video",
    "gaussian_blob",
    "gaussian_blobs",
    "gaussian_cells",
    "heat_spectral",
    "integrate",
    "paper_video",
    "plant",
    "plate_factor",
    "random_scene",
    "PlateSetup",
    "reference_plate_video",
    "simulate_bioheat",
    "simulate_continuum",
    "simulate_heat",
    "simulate_spot",
    "spot_peak",
    "simulate_tissue",
    "stable_substeps",
    "with_depth",
]
