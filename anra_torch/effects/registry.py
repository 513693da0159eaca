"""The registry of effects: one line per effect module.

A new effect is one module in :mod:`anra_torch.effects` holding its
:class:`~anra_torch.effects.EffectSpec` as ``SPEC``, plus its test, plus one line here.
"""

from __future__ import annotations

from anra_torch.effects import (
    advection,
    anisotropy,
    delamination,
    delamination_2,
    depth_conduction,
    heterogeneity,
    linear_loss,
    nonlinear_diffusion,
    periodic_source,
    source,
)
from anra_torch.effects.base import EffectSpec

__all__ = ["DIFFUSION_EFFECTS", "EFFECTS", "unknown_effect"]

EFFECTS: dict[str, EffectSpec] = {
    spec.name: spec
    for spec in (
        linear_loss.SPEC,
        source.SPEC,
        advection.SPEC,
        anisotropy.SPEC,
        heterogeneity.SPEC,
        nonlinear_diffusion.SPEC,
        periodic_source.SPEC,
        depth_conduction.SPEC,
        delamination.SPEC,
        delamination_2.SPEC,
    )
}
"""The effects by name (the names and parameter names of every truth record and diagnosis)."""

DIFFUSION_EFFECTS: tuple[str, ...] = tuple(name for name, spec in EFFECTS.items() if spec.replaces_diffusion)
"""The effects that replace ``a Lap T`` (at most one per model)."""


def unknown_effect(name: object) -> ValueError:
    """The one-line error for a name that is not in :data:`EFFECTS`."""
    return ValueError(f"unknown effect {name!r}; expected one of: {', '.join(EFFECTS)}")
