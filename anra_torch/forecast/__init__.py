"""Forecasts of held-out frames: does a diagnosed model predict the future, and by how much.

- :mod:`~anra_torch.forecast.core`: what every forecast shares (the split, the assimilated starting state,
  the evaluation scale, the errors, the noise floor, the diagnosed model as effects);
- :mod:`~anra_torch.forecast.gain`: :func:`assess_gain`, the plain and the extended model forecast;
- :mod:`~anra_torch.forecast.source_map`: :func:`fit_source_map` (``dT/dt = a Lap T - b T + q(x, y)``, a
  measured beam) and :func:`source_map_gain`, its forecast of the same held-out frames;
- :mod:`~anra_torch.forecast.refine`: :func:`refine_model`, Problem-1 refinement of a diagnosed model;
- :mod:`~anra_torch.forecast.small_box`: models for regions too small for the filters;
- :mod:`~anra_torch.forecast.recording`: :func:`diagnose_recording`, a recording phase by phase;
- :mod:`~anra_torch.forecast.decimate`: the block-averaged copy a camera-sized recording is diagnosed on
  (``anra diagnose`` makes it before the phases).

Source map, refinement and the small boxes call :mod:`~anra_torch.forecast.core`, not each other
(:func:`source_map_gain` reads the split and scale of a :class:`GainResult`).
"""

from anra_torch.forecast.core import (
    AT_FLOOR,
    TIME_WINDOW,
    assimilated_state,
    extended_effects,
    simulate_model,
    split_index,
)
from anra_torch.forecast.gain import GainResult, assess_gain
from anra_torch.forecast.recording import PhaseDiagnosis, diagnose_recording
from anra_torch.forecast.refine import Refinement, refine_model
from anra_torch.forecast.source_map import SourceMapGain, SourceMapModel, fit_source_map, source_map_gain

__all__ = [
    "AT_FLOOR",
    "TIME_WINDOW",
    "GainResult",
    "PhaseDiagnosis",
    "Refinement",
    "SourceMapGain",
    "SourceMapModel",
    "assess_gain",
    "assimilated_state",
    "diagnose_recording",
    "extended_effects",
    "fit_source_map",
    "refine_model",
    "simulate_model",
    "source_map_gain",
    "split_index",
]
