"""A model of heat transfer with effects: validated effects and their right-hand side.

:class:`Effect` is a (name, parameters) pair checked against :data:`~anra_torch.effects.EFFECTS`;
:func:`effect_rhs` assembles ``dT/dt = D[T] + sum of effect terms`` (``D[T]`` is ``a`` times the 5-point
Laplacian unless an effect replaces it); :func:`anra_torch.effects.simulate_effects` integrates it;
:func:`equation_text` writes it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from anra_torch.checks import number
from anra_torch.effects.base import EffectSpec, Grid
from anra_torch.effects.registry import DIFFUSION_EFFECTS, EFFECTS, unknown_effect
from anra_torch.simulation import HeatRHS

__all__ = [
    "Effect",
    "ExtendedHeatRHS",
    "check_effects",
    "effect_rhs",
    "effects_from_json",
    "effects_to_json",
    "equation_text",
]


@dataclass(frozen=True)
class Effect:
    """One hidden effect with its parameters, checked against :data:`EFFECTS`.

    Attributes:
        name: a key of :data:`EFFECTS`.
        params: every parameter of that effect (finite numbers in the units of :attr:`EffectSpec.params`).

    Raises:
        ValueError: unknown name, missing or unknown parameters, non-finite or out-of-domain values.

    Example:
        >>> Effect("advection", {"vx": 0.5, "vy": 0.0}).to_dict()["units"]
        {'vx': 'mm/s', 'vy': 'mm/s'}
    """

    name: str
    params: dict[str, float]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or self.name not in EFFECTS:
            raise unknown_effect(self.name)
        spec = EFFECTS[self.name]
        if not isinstance(self.params, Mapping):
            raise TypeError(f"{self.name} params must be a mapping name -> number, got {self.params!r}")
        unknown = [k for k in self.params if k not in spec.params]
        if unknown:
            hint = " (derived, set from the others)" if unknown[0] in spec.derived_units else ""
            raise ValueError(
                f"effect {self.name!r} has no parameter {unknown[0]!r}{hint}; "
                f"expected: {', '.join(spec.params)}"
            )
        missing = [k for k in spec.params if k not in self.params]
        if missing:
            raise ValueError(
                f"effect {self.name!r} is missing {', '.join(missing)}; expected: "
                + ", ".join(f"{k} ({u})" for k, u in spec.params.items())
            )
        params = {k: number(self.params[k], f"{self.name}.{k}", unit) for k, unit in spec.params.items()}
        if spec.check is not None:
            spec.check(params)
        object.__setattr__(self, "params", params)

    def __hash__(self) -> int:
        return hash((self.name, tuple(self.params.items())))

    @property
    def spec(self) -> EffectSpec:
        """The registry entry."""
        return EFFECTS[self.name]

    @property
    def replaces_diffusion(self) -> bool:
        """Whether this effect replaces ``a Lap T``."""
        return self.spec.replaces_diffusion

    def derived(self) -> dict[str, float]:
        """Quantities derived from the parameters (``angle_deg`` and ``ratio`` for anisotropy)."""
        return self.spec.derived(self.params) if self.spec.derived is not None else {}

    def term(self, T: Tensor, t: float | Tensor, grid: Grid) -> Tensor:
        """The ``dT/dt`` contribution (or the replaced diffusion operator) at time ``t`` in s.

        Shape:
            ``T`` ``(H, W)`` or ``(B, H, W)`` on ``grid``; output like ``T``.
        """
        time = t if isinstance(t, Tensor) else torch.as_tensor(float(t), dtype=torch.float64, device=T.device)
        return self.spec.build(self.params, grid)(time, T)

    def to_dict(self) -> dict[str, Any]:
        """``{"name", "params" (with derived values), "units"}``, JSON-ready."""
        units = {**self.spec.params, **self.spec.derived_units}
        return {"name": self.name, "params": {**self.params, **self.derived()}, "units": units}

    @classmethod
    def from_dict(cls, record: Mapping[str, Any]) -> Effect:
        """Inverse of :meth:`to_dict` (derived values are checked, not stored; ``units`` is ignored).

        Raises:
            ValueError: not a record, or derived values that disagree with the parameters.
        """
        if not isinstance(record, Mapping) or "name" not in record or "params" not in record:
            raise ValueError(f"an effect record needs 'name' and 'params', got {record!r}")
        name, params = record["name"], dict(record["params"])
        if not isinstance(name, str) or name not in EFFECTS:
            raise unknown_effect(name)
        given = {k: params.pop(k) for k in EFFECTS[name].derived_units if k in params}
        effect = cls(name, params)
        for key, value in given.items():
            if not math.isclose(float(value), effect.derived()[key], rel_tol=1e-9, abs_tol=1e-12):
                raise ValueError(
                    f"{name}.{key}={value!r} disagrees with the parameters ({effect.derived()[key]!r})"
                )
        return effect


def effects_to_json(effects: Sequence[Effect]) -> str:
    """The truth as a JSON list of :meth:`Effect.to_dict` records (one line)."""
    return json.dumps([as_effect(e).to_dict() for e in effects], allow_nan=False)


def effects_from_json(text: str) -> tuple[Effect, ...]:
    """Parse :func:`effects_to_json` output back into effects.

    Raises:
        ValueError: not JSON, not a list of effect records, or invalid effects.
    """
    try:
        records = json.loads(text)
    except (TypeError, json.JSONDecodeError) as err:
        raise ValueError(f"effects must be a JSON list of effect records, got {str(text)[:60]!r}") from err
    if not isinstance(records, list):
        raise ValueError(f"effects must be a JSON list of effect records, got {type(records).__name__}")
    return tuple(Effect.from_dict(r) for r in records)


def as_effect(effect: object) -> Effect:
    if not isinstance(effect, Effect):
        raise TypeError(f"effects must be Effect instances, got {type(effect).__name__}")
    return effect


def check_effects(effects: object) -> tuple[Effect, ...]:
    """A tuple of distinct effects with at most one that replaces the diffusion term."""
    if isinstance(effects, Effect):
        effects = (effects,)
    if not isinstance(effects, Sequence) or isinstance(effects, str):
        raise TypeError(f"effects must be a sequence of Effect, got {type(effects).__name__}")
    checked = tuple(as_effect(e) for e in effects)
    names = [e.name for e in checked]
    for name in names:
        if names.count(name) > 1:
            raise ValueError(f"effect {name!r} is given {names.count(name)} times; give each effect once")
    diffusion = [e.name for e in checked if e.replaces_diffusion]
    if len(diffusion) > 1:
        raise ValueError(
            f"effects {' and '.join(diffusion)} both replace the diffusion term; a model may hold at most "
            f"one of {', '.join(DIFFUSION_EFFECTS)}"
        )
    return checked


def effect_rhs(
    a: float | Tensor,
    parts: Sequence[tuple[EffectSpec, Mapping[str, float | Tensor]]],
    grid: Grid,
    time_scale: float,
) -> Callable[[Tensor, Tensor], Tensor]:
    """``f(t, T) = (D[T] + sum of effect terms) * time_scale`` from ``(spec, params)`` pairs, unchecked.

    The one assembly of a model's right-hand side: :class:`ExtendedHeatRHS` calls it after validating its
    effects; :func:`anra_torch.forecast.refine_model` calls it with tensor parameters so that autograd
    reaches them. ``D`` is ``a`` times the 5-point Laplacian unless a part replaces the diffusion term;
    ``t`` is in units of ``time_scale`` seconds.
    """
    diffusion = None
    terms = []
    for spec, params in parts:
        term = spec.build(params, grid)
        if spec.replaces_diffusion:
            diffusion = term
        else:
            terms.append(term)
    if diffusion is None:
        heat = HeatRHS(a, dx=grid.dx, boundary=grid.boundary, boundary_value=grid.boundary_value)
        diffusion = lambda t, u: heat(t, u).reshape(u.shape)  # noqa: E731

    def rhs(t: Tensor, u: Tensor) -> Tensor:
        seconds = t * time_scale
        out = diffusion(seconds, u)
        for term in terms:
            out = out + term(seconds, u)
        return out * time_scale

    return rhs


class ExtendedHeatRHS(nn.Module):
    """Right-hand side ``dT/dt = D[T] + sum of effect terms`` on the pixel grid, for the integrator.

    ``D[T]`` is ``a`` times the 5-point Laplacian (:class:`anra_torch.simulation.HeatRHS`) unless an effect
    replaces it. Gradients are central differences; the ghost pixel around the frame comes from
    ``grid.boundary`` (zero flux by default). The solver's time ``t`` is in units of ``time_scale`` seconds
    (the output is multiplied by it), so a fixed step of 1 can be one substep exactly.

    Args:
        a: base diffusivity in mm^2/s, >= 0; unused when an effect replaces the diffusion term.
        grid: the pixel grid (shape, dx, duration of the source paths, boundary).
        effects: distinct :class:`Effect` s, at most one replacing the diffusion term.
        time_scale: seconds per unit of solver time.

    Shape:
        ``forward(t, T)``: ``T`` ``(H, W)`` or ``(B, H, W)`` (one model for every video); output like ``T``.

    Raises:
        ValueError: negative ``a``, bad effects (see :func:`simulate_effects`), non-positive ``time_scale``.
    """

    def __init__(
        self, a: float, *, grid: Grid, effects: Sequence[Effect] = (), time_scale: float = 1.0
    ) -> None:
        super().__init__()
        if not isinstance(grid, Grid):
            raise TypeError(f"grid must be a Grid, got {type(grid).__name__}")
        self.a = number(a, "a", "mm^2/s", minimum=0.0)
        self.grid = grid
        self.effects = check_effects(effects)
        self.time_scale = number(time_scale, "time_scale", "s", positive=True)
        self._rhs = effect_rhs(self.a, [(e.spec, e.params) for e in self.effects], grid, self.time_scale)

    def forward(self, t: Tensor, u: Tensor) -> Tensor:
        return self._rhs(t, u)

    def extra_repr(self) -> str:
        names = ", ".join(e.name for e in self.effects) or "none"
        return f"a={self.a:g}, shape={self.grid.shape}, boundary={self.grid.boundary!r}, effects=({names})"


def equation_text(a: float, effects: Sequence[Effect]) -> str:
    """A human-readable ``dT/dt = ...`` of a model: the diffusion term, then each effect's own term."""
    diffusion = f"{a:.3f} Lap T"
    terms = []
    for effect in effects:
        if effect.replaces_diffusion:
            diffusion = effect.spec.equation(effect.params)
        else:
            terms.append(effect.spec.equation(effect.params))
    return "dT/dt = " + " ".join([diffusion, *terms])
