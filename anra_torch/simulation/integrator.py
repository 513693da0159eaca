"""The one time integrator of the package's method-of-lines simulators, and the stability limit of its steps.

Every simulator (:func:`~anra_torch.simulation.simulate_heat`, :func:`~anra_torch.effects.simulate_effects`,
:func:`~anra_torch.simulation.simulate_tissue`, :func:`~anra_torch.forecast.refine_model`) turns its PDE into
an ODE system ``dU/dt = f(t, U)`` on the pixel grid and hands it to :func:`integrate`: fixed-step methods
run in :mod:`~anra_torch.simulation.fixed_grid` (torchdiffeq's arithmetic), adaptive and adjoint
integration in ``torchdiffeq``. Fixed-step methods take an integer number of substeps per frame, chosen by
:func:`stable_substeps` from where the eigenvalues of ``f`` lie:

- diffusion on the 5-point Laplacian: real, in ``[-8 a / dx^2, 0]`` in 1/s;
- a loss rate ``b``: shifts them left by ``b`` in 1/s;
- central-difference advection at speed ``|vx| + |vy|``: imaginary, up to ``speed / dx`` in 1/s.

One step of size ``ds`` is stable when every ``lambda ds`` lies in the method's stability region
(:data:`FIXED_STEP_METHODS`); it is monotone (no new extrema, the discrete maximum principle) when the
diffusion part keeps ``a ds / dx^2`` under the method's monotone limit. Units: mm, s, mm^2/s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import torch
from torch import Tensor

from anra_torch.checks import check_choice, check_int, number, positive
from anra_torch.simulation.fixed_grid import fixed_grid

__all__ = [
    "Solver",
    "ADAPTIVE_METHODS",
    "FIXED_STEP_METHODS",
    "POLICIES",
    "SAFETY",
    "StabilityRegion",
    "StepCount",
    "StepPolicy",
    "integrate",
    "stable_substeps",
]


@dataclass(frozen=True)
class StabilityRegion:
    """Where one step of a fixed-step method keeps ``|R(z)| <= 1``, ``z = lambda ds`` (dimensionless).

    Attributes:
        real: the largest ``|z|`` on the negative real axis that is stable.
        half_disc: radius of the largest half-disc ``{|z| <= r, Re z <= 0}`` inside the region; None
            when the region holds no part of the imaginary axis (then no advection is stable).
        monotone: the largest ``a ds / dx^2`` for which one step on the 5-point Laplacian is a
            non-negative combination of the neighbours (no overshoot).

    Shape:
        No tensors.
    """

    real: float
    half_disc: float | None
    monotone: float


FIXED_STEP_METHODS: dict[str, StabilityRegion] = {
    # One step is R(c (S - 4I)) with c = a ds / dx^2 and S the neighbour sum. Euler R = 1 + z: stable on
    # [-2, 0], centre weight 1 - 4c. Midpoint R = 1 + z + z^2 / 2: stable on [-2, 0], neighbour weight
    # c (1 - 4c). Neither reaches the imaginary axis: |R(iy)| > 1 for every y != 0.
    "euler": StabilityRegion(real=2.0, half_disc=None, monotone=0.25),
    "midpoint": StabilityRegion(real=2.0, half_disc=None, monotone=0.25),
    # RK4 crosses the real axis at -2.7853 and the imaginary at 2.8284; its boundary comes closest to 0
    # at about 123 degrees, |z| = 2.6156. Stable up to c = 0.348, but the S^3 coefficient is
    # c^3/6 (1 - 4c): above c = 0.25 a sharp peak overshoots three pixels away.
    "rk4": StabilityRegion(real=2.7853, half_disc=2.6155, monotone=0.25),
}
"""Fixed-step ``torchdiffeq`` methods :func:`integrate` accepts, with their stability regions."""

ADAPTIVE_METHODS: tuple[str, ...] = ("dopri5", "dopri8", "bosh3", "adaptive_heun", "fehlberg2")
"""Adaptive ``torchdiffeq`` methods :func:`integrate` accepts (they use ``rtol`` and ``atol``)."""

SAFETY = 0.9
"""The automatic step uses this fraction of each limit."""


@dataclass(frozen=True)
class StepPolicy:
    """How :func:`stable_substeps` turns the limits into substep counts.

    Attributes:
        monotone: the automatic count also keeps the diffusion part inside ``SAFETY`` of the monotone limit.
        strict: the fewest accepted is the automatic count itself, not the bare stability limit.

    Shape:
        No tensors.
    """

    monotone: bool
    strict: bool


POLICIES: dict[str, StepPolicy] = {
    # Heat, effects and refinement: no overshoot by default, any stable count on request.
    "monotone": StepPolicy(monotone=True, strict=False),
    # The tissue model, fitted through the solver: the fewest steps with the safety margin, and no fewer.
    "stable": StepPolicy(monotone=False, strict=True),
}
"""Step policies of :func:`stable_substeps`. Both use the same stability limit; the tissue model's
``"stable"`` drops the monotone limit (about 30 % fewer steps for pure diffusion) and keeps the safety
margin in the minimum."""


@dataclass(frozen=True)
class Solver:
    """How a simulation integrates in time (:func:`integrate`'s settings).

    Attributes:
        method: a key of :data:`FIXED_STEP_METHODS` or one of :data:`ADAPTIVE_METHODS`.
        substeps: solver steps per frame for fixed-step methods (None: automatic, :func:`stable_substeps`).
        rtol: relative tolerance of adaptive methods.
        atol: absolute tolerance of adaptive methods (units of the state).
        adjoint: integrate by the adjoint method (memory O(1) in the number of steps).
    """

    method: str = "rk4"
    substeps: int | None = None
    rtol: float = 1e-7
    atol: float = 1e-9
    adjoint: bool = False

    def checked(self) -> Solver:
        """These settings checked (``substeps`` an int).

        Raises:
            ValueError: an unknown method, ``substeps`` not an integer >= 1 or given for an adaptive
                method, non-positive tolerances.
        """
        check_choice(self.method, "method", [*FIXED_STEP_METHODS, *ADAPTIVE_METHODS])
        if self.substeps is not None and self.method not in FIXED_STEP_METHODS:
            raise ValueError(f"substeps applies to fixed-step methods only, got method={self.method!r}")
        substeps = None if self.substeps is None else check_int(self.substeps, "substeps", 1)
        rtol, atol = positive(self.rtol, "rtol", "relative units"), positive(self.atol, "atol", "units of T")
        return replace(self, substeps=substeps, rtol=rtol, atol=atol)


class StepCount(NamedTuple):
    """Substeps per frame: the automatic choice and the fewest accepted (both ``>= 1``).

    Shape:
        No tensors.
    """

    automatic: int
    minimum: int

    def choose(self, substeps: int | None, *, context: str) -> int:
        """``automatic`` for None, else ``substeps`` if it is an integer ``>= minimum``.

        Args:
            substeps: the caller's count, or None.
            context: what is being integrated, for the message (``"rk4 at a*dt/dx^2=100"``).

        Raises:
            ValueError: not an integer ``>= 1``, or below ``minimum``.
        """
        if substeps is None:
            return self.automatic
        substeps = check_int(substeps, "substeps", 1)
        if substeps < self.minimum:
            raise ValueError(
                f"substeps={substeps} is unstable for {context}; "
                f"need at least {self.minimum} (or leave substeps=None)"
            )
        return substeps


def stable_substeps(
    dt: float,
    dx: float,
    *,
    diffusivity: float,
    speed: float = 0.0,
    decay: float = 0.0,
    method: str = "rk4",
    policy: str = "monotone",
) -> StepCount:
    """Substeps per frame that keep a method-of-lines simulation stable (and, by default, monotone).

    The eigenvalues lie in the box ``[-(8 a / dx^2 + b), 0] x i [-speed / dx, speed / dx]`` in 1/s; one
    frame of ``n`` substeps is stable when ``|lambda| dt / n`` fits the method's region: its real-axis
    limit for a real spectrum, else its largest left half-disc. With ``dt = dx = 1`` the diffusivity is
    the mesh Fourier number ``a dt / dx^2`` (how a batch with different spacings passes its largest).

    Args:
        dt: frame period in s.
        dx: pixel size in mm.
        diffusivity: the largest diffusivity in mm^2/s (>= 0) the right-hand side can reach.
        speed: the largest ``|vx| + |vy|`` of central-difference advection in mm/s, >= 0.
        decay: the largest loss rate ``b`` in 1/s, >= 0.
        method: a key of :data:`FIXED_STEP_METHODS`.
        policy: a key of :data:`POLICIES`.

    Returns:
        ``(automatic, minimum)`` substeps per frame.

    Raises:
        ValueError: non-positive ``dt`` / ``dx``, negative rates, unknown ``method`` / ``policy``, or
            advection with a method that is unstable on the imaginary axis.

    Example:
        >>> stable_substeps(0.1, 0.1, diffusivity=1.0)  # a dt / dx^2 = 10: monotone needs 10 / 0.225
        StepCount(automatic=45, minimum=29)
        >>> stable_substeps(0.1, 0.1, diffusivity=1.0, policy="stable")  # 80 / (0.9 * 2.7853)
        StepCount(automatic=32, minimum=32)
    """
    dt, dx = positive(dt, "dt", "s"), positive(dx, "dx", "mm")
    diffusivity = number(diffusivity, "diffusivity", "mm^2/s", minimum=0.0)
    speed, decay = number(speed, "speed", "mm/s", minimum=0.0), number(decay, "decay", "1/s", minimum=0.0)
    region = FIXED_STEP_METHODS[check_choice(method, "method", list(FIXED_STEP_METHODS))]
    rule = POLICIES[check_choice(policy, "policy", list(POLICIES))]
    real, imag = 8.0 * diffusivity / dx**2 + decay, speed / dx
    radius = region.half_disc if imag else region.real
    if radius is None:
        raise ValueError(
            f"speed must be 0 mm/s for method {method!r} (unstable for advection), got {speed:g}"
        )
    size = math.hypot(real, imag) * dt  # the box's far corner: the largest |lambda| dt over one frame
    stable, safe = max(1, math.ceil(size / radius)), max(1, math.ceil(size / (SAFETY * radius)))
    minimum = safe if rule.strict else stable
    if not rule.monotone:
        return StepCount(max(minimum, safe), minimum)
    monotone = math.ceil(diffusivity * dt / dx**2 / (SAFETY * region.monotone))
    return StepCount(max(minimum, safe, monotone), minimum)


def integrate(
    rhs: Callable[[Tensor, Tensor], Tensor],
    initial: Tensor,
    *,
    n_frames: int,
    method: str = "rk4",
    substeps: int | None = None,
    rtol: float = 1e-7,
    atol: float = 1e-9,
    adjoint: bool = False,
    adjoint_params: Sequence[Tensor] | None = None,
    perturb: bool = False,
) -> Tensor:
    """Integrate ``dU/dt = rhs(t, U)`` from ``initial`` and return ``U`` at every frame.

    Fixed-step methods (:data:`FIXED_STEP_METHODS`) take ``substeps`` steps per frame, in time units of one
    substep (``rhs`` scales its time and output by ``dt / substeps``; frame ``k`` is at ``t = k substeps``);
    adaptive methods (:data:`ADAPTIVE_METHODS`) count time in frames (``rhs`` scales by ``dt``). Gradients
    flow to ``initial`` and to whatever ``rhs`` closes over.

    Args:
        rhs: the right-hand side ``(t, U) -> dU/dt`` in the solver's time unit.
        initial: ``U`` at frame 0.
        n_frames: number of frames, >= 1, frame 0 included.
        method: a key of :data:`FIXED_STEP_METHODS` or one of :data:`ADAPTIVE_METHODS`.
        substeps: steps per frame (>= 1) of a fixed-step method (e.g. :func:`stable_substeps`), else None.
        rtol: relative tolerance of adaptive methods.
        atol: absolute tolerance of adaptive methods (units of ``U``).
        adjoint: integrate by ``odeint_adjoint`` (memory O(1) in the number of steps).
        adjoint_params: with ``adjoint``, the tensors ``rhs`` uses that need gradients (default
            ``rhs.adjoint_params`` when it names them, else the parameters of ``rhs``).
        perturb: fixed-step methods evaluate ``rhs`` just inside each step, so that a forcing switching on
            a step boundary is integrated exactly.

    Returns:
        ``U`` at frames ``0 .. n_frames - 1``, frame 0 being ``initial``.

    Shape:
        ``initial`` any shape ``S`` (e.g. ``(B, H, W)``); output ``(n_frames, *S)``.

    Raises:
        TypeError: ``initial`` not a tensor.
        ValueError: unknown ``method``; ``substeps`` missing, not an integer ``>= 1`` or given to an
            adaptive method; non-positive tolerances; ``adjoint_params`` without ``adjoint``.

    Example:
        >>> dt, n = 0.5, 5  # 0.5 s frames in 5 substeps: the solver's time unit is dt / n s
        >>> cooling = lambda t, u: -0.4 * u * (dt / n)  # dU/dt = -0.4 U per s
        >>> u = integrate(cooling, torch.ones(2, dtype=torch.float64), n_frames=3, substeps=n)
        >>> u.shape, round(u[-1, 0].item(), 6), round(math.exp(-0.4 * 2 * dt), 6)
        (torch.Size([3, 2]), 0.67032, 0.67032)
    """
    n_frames = _checked_call(initial, n_frames, method, adjoint=adjoint, adjoint_params=adjoint_params)
    t, kwargs = _solver_grid(
        initial, n_frames, method=method, substeps=substeps, rtol=rtol, atol=atol, perturb=perturb
    )
    if n_frames == 1:
        return initial.unsqueeze(0)
    return _odeint(rhs, initial, t, kwargs, adjoint=adjoint, adjoint_params=adjoint_params)


def _checked_call(
    initial: Tensor,
    n_frames: int,
    method: str,
    *,
    adjoint: bool,
    adjoint_params: Sequence[Tensor] | None,
) -> int:
    """``n_frames`` checked, after ``initial``'s type, and then ``method`` and ``adjoint_params``."""
    if not isinstance(initial, Tensor):
        raise TypeError(f"initial must be a tensor, got {type(initial).__name__}")
    n_frames = check_int(n_frames, "n_frames", 1)
    check_choice(method, "method", [*FIXED_STEP_METHODS, *ADAPTIVE_METHODS])
    if adjoint_params is not None and not adjoint:
        raise ValueError("adjoint_params applies to adjoint=True only; pass adjoint=True or drop them")
    return n_frames


def _odeint(
    rhs: Callable[[Tensor, Tensor], Tensor],
    initial: Tensor,
    t: Tensor,
    kwargs: dict[str, object],
    *,
    adjoint: bool,
    adjoint_params: Sequence[Tensor] | None,
) -> Tensor:
    """torchdiffeq's ``odeint`` (or ``odeint_adjoint``) on the grid ``t`` with the solver's ``kwargs``; fixed
    steps without the adjoint by :func:`~anra_torch.simulation.fixed_grid.fixed_grid` (its arithmetic)."""
    method, options = kwargs["method"], kwargs["options"]
    steps = options if isinstance(options, dict) else {}
    # fixed_grid steps one time unit, as the fixed-step options ask.
    if (
        not adjoint
        and steps.get("step_size") == 1.0
        and isinstance(method, str)
        and method in FIXED_STEP_METHODS
    ):
        return fixed_grid(rhs, initial, t, method, perturb=bool(steps.get("perturb", False)))
    # Imported here: torchdiffeq loads scipy.integrate (~0.4 s), which only adaptive and adjoint
    # integration need.
    from torchdiffeq import odeint, odeint_adjoint

    if adjoint:
        params = getattr(rhs, "adjoint_params", None) if adjoint_params is None else adjoint_params
        return odeint_adjoint(
            rhs, initial, t, adjoint_params=None if params is None else tuple(params), **kwargs
        )
    return odeint(rhs, initial, t, **kwargs)


def _solver_grid(
    initial: Tensor,
    n_frames: int,
    *,
    method: str,
    substeps: int | None,
    rtol: float,
    atol: float,
    perturb: bool,
) -> tuple[Tensor, dict[str, object]]:
    """The frame times in solver units ``(n_frames,)`` and the solver's keyword arguments, checked."""
    kwargs: dict[str, object] = {"method": method}
    if method in FIXED_STEP_METHODS:
        if substeps is None:
            raise ValueError(f"substeps must be an integer >= 1 for method {method!r}, got None")
        substeps = check_int(substeps, "substeps", 1)
        t = torch.arange(n_frames, dtype=initial.dtype, device=initial.device) * substeps
        kwargs["options"] = {"step_size": 1.0, "perturb": True} if perturb else {"step_size": 1.0}
        return t, kwargs
    if substeps is not None:
        raise ValueError(f"substeps applies to fixed-step methods only, got method={method!r}")
    kwargs.update(
        options=None, rtol=positive(rtol, "rtol", "relative units"), atol=positive(atol, "atol", "units of U")
    )
    return torch.arange(n_frames, dtype=initial.dtype, device=initial.device), kwargs
