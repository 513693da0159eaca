"""Effects beyond ``dT/dt = a (d_xx + d_yy) T``: one module per effect, one registry.

A model is ``dT/dt = D[T] + sum of effect terms``, where ``D[T]`` is ``a Lap T`` (5-point Laplacian) unless
one effect replaces it. Each effect module (``linear_loss``, ``source``, ``advection``, ``anisotropy``,
``heterogeneity``, ``nonlinear_diffusion``, ``periodic_source``, ``depth_conduction``, ``delamination``,
``delamination_2``) holds one
:class:`~anra_torch.effects.EffectSpec`: its forward term and parameters (units, checks, random
detectable draws), its regressors or shape fit for the diagnosis, and how it is written, re-timed and
drawn. :data:`EFFECTS` lists them (registry order).

Coordinates: x along columns, y along rows, pixel centres at ``(j + 0.5) dx``; mm, s, mm^2/s;
temperatures in the data's unit (K for the rates).

:mod:`~anra_torch.effects.independent` simulates the effects' continuous models with the independent solver
of :mod:`anra_torch.simulation.independent` (a scene's video that shares none of the operators above).

Adding an effect: a module with ``SPEC = EffectSpec(...)``, its test, and one line in
:mod:`anra_torch.effects.registry`.
"""

from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Shape
from anra_torch.effects.independent import (
    continuum_of,
    independent_effect_video,
    simulate_independent,
    simulate_scene,
)
from anra_torch.effects.model import (
    Effect,
    ExtendedHeatRHS,
    check_effects,
    effect_rhs,
    effects_from_json,
    effects_to_json,
    equation_text,
)
from anra_torch.effects.registry import DIFFUSION_EFFECTS, EFFECTS
from anra_torch.effects.scene import HiddenEffectVideo, Medium, Sensor, hidden_effect_video
from anra_torch.effects.simulate import Boundary, simulate_effects, simulated_span, step_rates

__all__ = [
    "Boundary",
    "Context",
    "DIFFUSION_EFFECTS",
    "EFFECTS",
    "Effect",
    "EffectSpec",
    "ExtendedHeatRHS",
    "Geometry",
    "Grid",
    "HiddenEffectVideo",
    "Medium",
    "Sensor",
    "Shape",
    "check_effects",
    "continuum_of",
    "effect_rhs",
    "effects_from_json",
    "effects_to_json",
    "equation_text",
    "hidden_effect_video",
    "independent_effect_video",
    "simulate_effects",
    "simulated_span",
    "simulate_independent",
    "simulate_scene",
    "step_rates",
]
