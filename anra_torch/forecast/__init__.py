"""Forecasts of held-out frames: does a diagnosed model predict the future, and by how much.

- :mod:`~anra_torch.forecast.core`: what every forecast shares (the split, the assimilated starting state,
  the evaluation scale, the errors, the noise floor, the diagnosed model as effects);
- :mod:`~anra_torch.forecast.gain`: :func:`assess_gain`, the plain and the extended model forecast;
- :mod:`~anra_torch.forecast.source_map`: :func:`fit_source_map` (``dT/dt = a Lap T - b T + q(x, y)``, a
  measured beam) and :func:`source_map_gain`, its forecast of the same held-out frames;
- :mod:`~anra_torch.forecast.refine`: :func:`refine_model`, Problem-1 refinement of a diagnosed model;

Source map and refinement call :mod:`~anra_torch.forecast.core`, not each other
(:func:`source_map_gain` reads the split and scale of a :class:`GainResult`).
"""

from anra_torch.forecast.core import (
    AT_FLOOR,
    DIAGNOSED_FRAMES,
    INNER_SPLITS,
    TIME_WINDOW,
    assimilated_state,
    extended_effects,
    simulate_model,
    split_index,
)
from anra_torch.forecast.earn import EARN_MARGIN, EARN_SPLITS, WEAK_SIGNAL, earned_diagnosis, signal_to_noise
from anra_torch.forecast.gain import GainResult, assess_gain
from anra_torch.forecast.refine import Refinement, refine_model
from anra_torch.forecast.source_map import SourceMapGain, SourceMapModel, fit_source_map, source_map_gain

__all__ = [
    "AT_FLOOR",
    "EARN_MARGIN",
    "EARN_SPLITS",
    "DIAGNOSED_FRAMES",
    "GainResult",
    "INNER_SPLITS",
    "Refinement",
    "SourceMapGain",
    "SourceMapModel",
    "TIME_WINDOW",
    "WEAK_SIGNAL",
    "assess_gain",
    "earned_diagnosis",
    "assimilated_state",
    "extended_effects",
    "fit_source_map",
    "refine_model",
    "signal_to_noise",
    "simulate_model",
    "source_map_gain",
    "split_index",
]
