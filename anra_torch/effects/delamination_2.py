"""``delamination_2``: a second delamination, over another defect of a flash defect map than the first's.

A model names each effect once; a plate with two defects needs two delaminations. This one is
:mod:`anra_torch.effects.delamination`'s term, parameters and fit under a second name and regressor
(``Y2``): tried only beside the first (:attr:`EffectSpec.requires`) and where the balance was given two
candidate regions or more (:attr:`EffectSpec.tried`: the defects of a flash defect map,
:func:`~anra_torch.recording.flash_hints`), held at the best region the first does not cover (the first,
refitted beside it, likewise at a region this one does not cover); it enters the model, or not, by the
same tests as every effect. Without regions (no defect map) it is never tried. Where the plate is
forecast through its thickness (:mod:`anra_torch.forecast.layered`) it is a face of its own at its depth.
"""

from __future__ import annotations

from anra_torch.effects.base import EffectSpec
from anra_torch.effects.delamination import spec_fields

__all__ = ["SPEC"]

SPEC = EffectSpec(
    **spec_fields("delamination_2"),
    requires=("depth_conduction", "delamination"),
    tried=lambda hints: len(hints.get("delamination", ())) >= 2,
)
