"""The simulation of a model with effects: method of lines, fixed-step RK4 with stable substeps.

:func:`simulate_effects` integrates the right-hand side of :mod:`anra_torch.effects.model` with
:func:`anra_torch.simulation.integrate`; :func:`step_rates` says what the model does to the stable step.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from anra_torch.checks import as_fields, check_int, number
from anra_torch.effects.base import Grid
from anra_torch.effects.model import Effect, ExtendedHeatRHS, check_effects
from anra_torch.simulation import BOUNDARIES, integrate, stable_substeps

__all__ = ["Boundary", "simulate_effects", "simulated_span", "step_rates"]


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
    span = simulated_span(low, high)
    rates = [e.spec.rates(e.params, span) for e in effects]
    diffusivity = [r.diffusivity for r in rates if r.diffusivity is not None]
    a_max = diffusivity[0] if diffusivity else a
    return a_max, sum(r.speed for r in rates), sum(r.decay for r in rates)


def simulated_span(low: float, high: float) -> tuple[float, float]:
    """The temperatures a simulation's rates must hold over: ``[low, high]`` (units of T; the range the
    effects' bounds give) widened by a tenth of its width on each side (central-difference advection can
    overshoot a little). The selection checks a fitted effect over the same range."""
    margin = 0.1 * (high - low)
    return low - margin, high + margin


@dataclass(frozen=True)
class Boundary:
    """The boundary condition of :func:`simulate_effects` at the frame's edge (one ghost pixel around it).

    Attributes:
        kind: a key of :data:`anra_torch.simulation.BOUNDARIES` (default zero flux).
        value: ghost temperature for ``"dirichlet"``.
    """

    kind: str = "neumann"
    value: float = 0.0


def simulate_effects(
    initial: Tensor,
    *,
    a: float,
    dx: float,
    dt: float,
    n_frames: int,
    effects: Sequence[Effect] = (),
    boundary: Boundary | None = None,
    substeps: int | None = None,
    forcing: Tensor | None = None,
    edges: Tensor | None = None,
) -> Tensor:
    """Simulate a thermal video of ``dT/dt = D[T] + sum of effect terms (+ forcing)`` (method of lines, RK4).

    Args:
        initial: first frame (temperatures).
        a: base diffusivity in mm^2/s, >= 0; ignored when an effect replaces the diffusion term.
        dx: pixel size in mm.
        dt: frame period in s.
        n_frames: number of frames T, >= 1.
        effects: distinct :class:`Effect` s, at most one replacing the diffusion term (a source's path is
            covered over ``(n_frames - 1) dt``).
        boundary: the frame edge's condition (:class:`Boundary`); default zero flux.
        substeps: RK4 steps per frame; default the fewest stable (:func:`step_rates`) and monotone.
        forcing: a stationary heat input in data units per s added at every pixel (e.g. a measured source
            map, :mod:`anra_torch.forecast.source_map`).
        edges: measured frames, shaped as the output, whose outermost pixel ring the simulation follows
            (linearly in time): a measured boundary that replaces ``boundary``.

    Returns:
        The video in the dtype of ``initial`` (with ``edges``, its ring is ``edges``' ring).

    Shape:
        ``initial`` ``(B, H, W)`` -> ``(B, T, H, W)`` (no ``B``: unbatched); ``forcing`` ``(H, W)``.

    Raises:
        TypeError: ``initial`` not real numbers, effects not :class:`Effect` s, ``boundary`` not a Boundary.
        ValueError: bad shapes or spacings, unknown boundary, duplicate effects, two effects replacing the
            diffusion term, an ill-posed model (see :func:`step_rates`), or ``substeps`` below the limit.

    Example:
        >>> u0 = torch.full((8, 8), 40.0, dtype=torch.float64)
        >>> loss = Effect("linear_loss", {"b": 0.5, "T_ref": 30.0})
        >>> video = simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=11, effects=[loss])
        >>> round(video[-1, 0, 0].item(), 6)  # 30 + 10 exp(-0.5)
        36.065307
    """
    u0, batched = as_fields(initial)
    a = number(a, "a", "mm^2/s", minimum=0.0)
    dx, dt = number(dx, "dx", "mm", positive=True), number(dt, "dt", "s", positive=True)
    n_frames = check_int(n_frames, "n_frames", 1)
    checked = check_effects(effects)
    grid = _grid(boundary, u0, dx, (n_frames - 1) * dt)
    substeps = None if substeps is None else check_int(substeps, "substeps", 1)
    forcing = None if forcing is None else _check_forcing(forcing, u0)
    substeps = _rk4_substeps(a, checked, u0, grid, dt, substeps)
    rhs = ExtendedHeatRHS(a, grid=grid, effects=checked, time_scale=dt / substeps)
    out = _integrated(rhs, u0, (forcing, edges, batched), n_frames=n_frames, substeps=substeps, dt=dt)
    return out if batched else out[0]


def _integrated(
    rhs: ExtendedHeatRHS,
    u0: Tensor,
    inputs: tuple[Tensor | None, object, bool],
    *,
    n_frames: int,
    substeps: int,
    dt: float,
) -> Tensor:
    """``rhs`` integrated from ``u0`` ``(B, H, W)`` to ``(B, T, H, W)``, plus a checked ``forcing`` and
    following ``edges`` (as given, for an input batched or not), ``inputs = (forcing, edges, batched)``."""
    forcing, edges, batched = inputs
    step: Callable[[Tensor, Tensor], Tensor] = rhs
    if forcing is not None:
        step_input = forcing * (dt / substeps)
        step = lambda t, u: rhs(t, u) + step_input  # noqa: E731
    if edges is not None:
        step, u0 = _following(step, u0, _check_edges(edges, u0, batched, n_frames), substeps)
    return integrate(step, u0, n_frames=n_frames, substeps=substeps, perturb=edges is not None).movedim(0, 1)


def _grid(boundary: object, u0: Tensor, dx: float, duration: float) -> Grid:
    """The grid of ``u0`` ``(B, H, W)`` with ``boundary`` (a :class:`Boundary`; None: zero flux), checked."""
    if boundary is None:
        boundary = Boundary()
    if not isinstance(boundary, Boundary):
        raise TypeError(f"boundary must be a Boundary, e.g. Boundary('dirichlet', 30.0), got {boundary!r}")
    return Grid((u0.shape[-2], u0.shape[-1]), dx, duration, boundary.kind, boundary.value)


def _rk4_substeps(
    a: float, effects: tuple[Effect, ...], u0: Tensor, grid: Grid, dt: float, substeps: int | None
) -> int:
    """RK4 steps per frame: ``substeps`` checked against the stable limit, or the automatic choice."""
    low, high = float(u0.min()), float(u0.max())
    if BOUNDARIES[grid.boundary].uses_value:
        low, high = min(low, grid.boundary_value), max(high, grid.boundary_value)
    a_max, speed, decay = step_rates(a, effects, low, high, grid.duration)
    count = stable_substeps(dt, grid.dx, diffusivity=a_max, speed=speed, decay=decay)
    rates = f"a_max={a_max:.4g} mm^2/s, speed={speed:.4g} mm/s, decay={decay:.4g} 1/s"
    return count.choose(substeps, context=f"RK4 here ({rates})")


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
