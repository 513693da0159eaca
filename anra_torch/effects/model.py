"""A model of heat transfer with effects: validated effects, their right-hand side and its simulation.

:class:`Effect` is a (name, parameters) pair checked against :data:`~anra_torch.effects.EFFECTS`;
:func:`effect_rhs` assembles ``dT/dt = D[T] + sum of effect terms`` (``D[T]`` is ``a`` times the 5-point
Laplacian unless an effect replaces it); :func:`simulate_effects` integrates it (method of lines, fixed-step
RK4 with stable substeps, :func:`anra_torch.simulation.integrate`); :func:`equation_text` writes it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from anra_torch.checks import as_fields, check_int, number
from anra_torch.effects.base import EffectSpec, Grid
from anra_torch.effects.registry import DIFFUSION_EFFECTS, EFFECTS, unknown_effect
from anra_torch.simulation import BOUNDARIES, HeatRHS, integrate, stable_substeps

__all__ = [
    "Effect",
    "ExtendedHeatRHS",
    "check_effects",
    "effect_rhs",
    "effects_from_json",
    "effects_to_json",
    "equation_text",
    "simulate_effects",
    "step_rates",
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
    """Right-hand side ``dT/dt = D[T] + sum of effect terms`` on the pixel grid, for ``torchdiffeq``.

    ``D[T]`` is ``a`` times the 5-point Laplacian (:class:`anra_torch.simulation.HeatRHS`) unless an effect
    replaces it. Gradients are central differences; the ghost pixel around the frame comes from
    ``grid.boundary`` (zero flux by default). The solver's time ``t`` is in units of ``time_scale`` seconds
    (the output is multiplied by it), so a fixed step of 1 can be one substep exactly.

    Args:
        a: base diffusivity in mm^2/s (>= 0); unused when an effect replaces the diffusion term.
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


# --------------------------------------------------------------------------------------- simulate
def step_rates(
    a: float, effects: Sequence[Effect], low: float, high: float, duration: float
) -> tuple[float, float, float]:
    """What a model does to the stable step: its largest diffusivity, speed and decay rate.

    Each effect bounds the temperatures (``low`` .. ``high``, units of T, widened by what it can add over
    ``duration`` s) and reports its rates over that range (:attr:`EffectSpec.rates`). The result is what
    :func:`anra_torch.simulation.stable_substeps` takes.

    Args:
        a: base diffusivity in mm^2/s (the diffusivity unless an effect replaces the diffusion term).
        effects: validated :class:`Effect` s (as :func:`simulate_effects` and the refinement hold them).
        low: lowest initial temperature (units of T).
        high: highest initial temperature (units of T).
        duration: simulated time in s.

    Returns:
        ``(diffusivity mm^2/s, speed mm/s, decay 1/s)``.

    Raises:
        ValueError: a model that is ill-posed over the temperature range (e.g. a nonlinear diffusivity
            that turns negative).

    Shape:
        No tensors.
    """
    effects, a = check_effects(effects), number(a, "a", "mm^2/s", minimum=0.0)
    low, high = number(low, "low", "units of T"), number(high, "high", "units of T")
    duration = number(duration, "duration", "s", minimum=0.0)
    for effect in effects:  # a range the temperatures cannot leave
        low, high = effect.spec.bounds(effect.params, low, high, duration)
    margin = 0.1 * (high - low)  # central-difference advection can overshoot a little
    span = (low - margin, high + margin)
    rates = [e.spec.rates(e.params, span) for e in effects]
    diffusivity = [r.diffusivity for r in rates if r.diffusivity is not None]
    a_max = diffusivity[0] if diffusivity else a
    return a_max, sum(r.speed for r in rates), sum(r.decay for r in rates)


def simulate_effects(
    initial: Tensor,
    *,
    a: float,
    dx: float,
    dt: float,
    n_frames: int,
    effects: Sequence[Effect] = (),
    boundary: str = "neumann",
    boundary_value: float = 0.0,
    substeps: int | None = None,
    forcing: Tensor | None = None,
    edges: Tensor | None = None,
) -> Tensor:
    """Simulate a thermal video of ``dT/dt = D[T] + sum of effect terms (+ forcing)`` (method of lines, RK4).

    Fixed-step RK4 with an integer number of substeps per frame, by default the fewest stable for the whole
    spectrum (the largest diffusivity the model reaches, advection ``|v| ds / dx``, the loss rate ``b``: see
    :func:`step_rates`) and monotone for diffusion. The source moves over ``(n_frames - 1) dt``.

    Args:
        initial: first frame (temperatures).
        a: base diffusivity in mm^2/s (>= 0); ignored when an effect replaces the diffusion term.
        dx: pixel size in mm.
        dt: frame period in s.
        n_frames: number of frames T (>= 1).
        effects: distinct :class:`Effect` s, at most one of ``anisotropy``, ``heterogeneity``,
            ``nonlinear_diffusion``.
        boundary: a key of :data:`anra_torch.simulation.BOUNDARIES` (default zero flux).
        boundary_value: ghost temperature for ``"dirichlet"``.
        substeps: RK4 steps per frame; default automatic (see above).
        forcing: a stationary heat-input map in data units per s, added to the right-hand side at every
            pixel (e.g. a measured source map, :mod:`anra_torch.forecast.source_map`); it does not change
            stability.
        edges: measured frames whose outermost pixel ring the simulation follows (linearly in time): a
            measured boundary for the pixels inside (``boundary`` then no longer matters).

    Returns:
        The video in the dtype of ``initial`` (with ``edges``, its ring is ``edges``' ring).

    Shape:
        ``initial`` ``(B, H, W)`` -> output ``(B, T, H, W)`` (no ``B``: unbatched); ``forcing`` ``(H, W)``;
        ``edges`` ``(B, T, H, W)`` (no ``B``: ``(T, H, W)``).

    Raises:
        TypeError: ``initial`` not real numbers, effects not :class:`Effect`.
        ValueError: bad shapes or spacings, unknown boundary, duplicate effects, two effects replacing the
            diffusion term, an ill-posed model (see :func:`step_rates`), or ``substeps`` below the limit.

    Example:
        >>> u0 = torch.full((8, 8), 40.0, dtype=torch.float64)
        >>> loss = Effect("linear_loss", {"b": 0.5, "T_ref": 30.0})
        >>> video = simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=11, effects=[loss])
        >>> round(video[-1, 0, 0].item(), 6), round(30 + 10 * math.exp(-0.5), 6)
        (36.065307, 36.065307)
    """
    u0, batched = as_fields(initial)
    height, width = u0.shape[-2:]
    a = number(a, "a", "mm^2/s", minimum=0.0)
    dx, dt = number(dx, "dx", "mm", positive=True), number(dt, "dt", "s", positive=True)
    n_frames = check_int(n_frames, "n_frames", 1)
    checked = check_effects(effects)
    grid = Grid((height, width), dx, (n_frames - 1) * dt, boundary, boundary_value)
    substeps = None if substeps is None else check_int(substeps, "substeps", 1)
    forcing = None if forcing is None else _check_forcing(forcing, u0)
    low, high = float(u0.min()), float(u0.max())
    if BOUNDARIES[boundary].uses_value:
        low, high = min(low, grid.boundary_value), max(high, grid.boundary_value)
    a_max, speed, decay = step_rates(a, checked, low, high, grid.duration)
    count = stable_substeps(dt, dx, diffusivity=a_max, speed=speed, decay=decay)
    rates = f"a_max={a_max:.4g} mm^2/s, speed={speed:.4g} mm/s, decay={decay:.4g} 1/s"
    substeps = count.choose(substeps, context=f"RK4 here ({rates})")
    rhs = ExtendedHeatRHS(a, grid=grid, effects=checked, time_scale=dt / substeps)
    if forcing is not None:
        heat, step_input = rhs, forcing * (dt / substeps)
        rhs = lambda t, u: heat(t, u) + step_input  # noqa: E731
    if edges is not None:
        rhs, u0 = _following(rhs, u0, _check_edges(edges, u0, batched, n_frames), substeps)
    out = integrate(rhs, u0, n_frames=n_frames, substeps=substeps, perturb=edges is not None).movedim(0, 1)
    return out if batched else out[0]


def _check_edges(edges: object, like: Tensor, batched: bool, n_frames: int) -> Tensor:
    """Finite frames ``(T, B, H, W)`` in ``like``'s dtype, from ``(B, T, H, W)`` (or ``(T, H, W)``)."""
    edges = edges if isinstance(edges, Tensor) else torch.as_tensor(edges, device="cpu")
    batch, height, width = like.shape
    shape = (batch, n_frames, height, width) if batched else (n_frames, height, width)
    if tuple(edges.shape) != shape:
        raise ValueError(
            f"edges must be the measured frames of shape {shape} (frames, rows, columns), "
            f"got shape {tuple(edges.shape)}"
        )
    if not bool(torch.isfinite(edges).all()):
        raise ValueError("edges must be finite measured frames, got non-finite values; repair them first")
    edges = edges.to(like.dtype)
    return edges.movedim(1, 0) if batched else edges.unsqueeze(1)


def _following(
    rhs: Callable[[Tensor, Tensor], Tensor], u0: Tensor, edges: Tensor, substeps: int
) -> tuple[Callable[[Tensor, Tensor], Tensor], Tensor]:
    """``rhs`` whose outermost ring follows ``edges`` ``(T, B, H, W)``, and ``u0`` with their first ring.

    The ring's rate is the measured change over the frame interval the solver's time is in (constant
    there, so RK4 follows the linear interpolation exactly; the integrator perturbs stage times into
    the step so each stage sees its own interval).
    """
    ring = torch.ones(u0.shape[-2:], dtype=torch.bool, device=u0.device)
    ring[1:-1, 1:-1] = False
    per_substep = (edges[1:] - edges[:-1]) / substeps  # (T - 1, B, H, W), change per solver time unit
    last = max(per_substep.shape[0] - 1, 0)

    def following(t: Tensor, u: Tensor) -> Tensor:
        interval = min(max(int(float(t) // substeps), 0), last)
        return torch.where(ring, per_substep[interval], rhs(t, u))

    return following, torch.where(ring, edges[0], u0)


def _check_forcing(forcing: object, like: Tensor) -> Tensor:
    """A finite stationary input map of the frame's shape, in ``like``'s dtype."""
    forcing = forcing if isinstance(forcing, Tensor) else torch.as_tensor(forcing, device="cpu")
    height, width = like.shape[-2:]
    need = f"forcing must be a finite map of the frame's shape ({height}, {width}) in data units per s"
    if forcing.shape != (height, width):
        raise ValueError(f"{need}, got shape {tuple(forcing.shape)}")
    if not bool(torch.isfinite(forcing).all()):
        raise ValueError(f"{need}, got non-finite values")
    return forcing.to(like.dtype)


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
