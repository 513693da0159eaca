"""Effects beyond ``dT/dt = a (d_xx + d_yy) T``: one module per effect, one registry.

A model is ``dT/dt = D[T] + sum of effect terms``, where ``D[T]`` is ``a Lap T`` (5-point Laplacian) unless
one effect replaces it. Each effect module (``linear_loss``, ``source``, ``advection``, ``anisotropy``,
``heterogeneity``, ``nonlinear_diffusion``, ``periodic_source``, ``depth_conduction``, ``delamination``)
holds one
:class:`~anra_torch.effects.base.EffectSpec`: its forward term and parameters (units, checks, random
detectable draws), its regressors or shape fit for the diagnosis, and how it is written, re-timed and
drawn. :data:`EFFECTS` lists them (registry order).

Coordinates: x along columns, y along rows, pixel centres at ``(j + 0.5) dx``; mm, s, mm^2/s;
temperatures in the data's unit (K for the rates).

Adding an effect: a module with ``SPEC = EffectSpec(...)``, its test, and one line in
:mod:`anra_torch.effects.registry`.
"""

from anra_torch.effects.base import EffectSpec, Geometry, Grid
from anra_torch.effects.model import (
    Effect,
    ExtendedHeatRHS,
    check_effects,
    effect_rhs,
    effects_from_json,
    effects_to_json,
    equation_text,
    simulate_effects,
    step_rates,
)
from anra_torch.effects.registry import DIFFUSION_EFFECTS, EFFECTS
from anra_torch.effects.scene import HiddenEffectVideo, hidden_effect_video

__all__ = [
    "DIFFUSION_EFFECTS",
    "EFFECTS",
    "Effect",
    "EffectSpec",
    "ExtendedHeatRHS",
    "Geometry",
    "Grid",
    "HiddenEffectVideo",
    "check_effects",
    "effect_rhs",
    "effects_from_json",
    "effects_to_json",
    "equation_text",
    "hidden_effect_video",
    "simulate_effects",
    "step_rates",
]
