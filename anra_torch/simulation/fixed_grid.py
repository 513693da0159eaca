"""Fixed-step integration on a grid of whole solver time units: torchdiffeq's arithmetic, without its set-up.

:func:`fixed_grid` is what torchdiffeq's solver computes with ``options={"step_size": 1.0}`` for its
fixed-grid methods ``euler``, ``midpoint`` and ``rk4`` (torchdiffeq's ``rk4`` is the 3/8 rule,
``rk4_alt_step_func``): the same grid, stage times and operations in the same order, so the frames are
the same bit for bit. It spares the per-call set-up (input checks, a wrapping module, the time perturbation
through an autograd function), which dominates many short calls such as the one-frame steps of a forecast's
assimilation, and it does not import torchdiffeq (which loads ``scipy.integrate``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch
from torch import Tensor

__all__ = ["fixed_grid"]

Rhs = Callable[[Tensor, Tensor], Tensor]

_ONE_THIRD, _TWO_THIRDS = 1 / 3, 2 / 3


def fixed_grid(rhs: Rhs, initial: Tensor, t: Tensor, method: str, *, perturb: bool = False) -> Tensor:
    """Integrate ``dU/dt = rhs(t, U)`` in steps of one time unit and return ``U`` at the times ``t``.

    Args:
        rhs: the right-hand side ``(t, U) -> dU/dt`` (``t`` a 0-d tensor in ``U``'s real dtype).
        initial: ``U`` at ``t[0]``.
        t: increasing output times, ``t[0]`` the start; between grid points the state is interpolated
            linearly.
        method: ``"euler"``, ``"midpoint"`` or ``"rk4"``.
        perturb: evaluate ``rhs`` one float inside each step at its first and last stage (a forcing that
            switches on a step boundary is integrated exactly), as torchdiffeq's ``perturb``.

    Returns:
        ``U`` at every time of ``t``, the first being ``initial``.

    Shape:
        ``initial`` any shape ``S``; ``t`` ``(K,)``, ``K >= 2``; output ``(K, *S)``.

    Raises:
        KeyError: an unknown ``method`` (:func:`~anra_torch.simulation.integrate` checks it first).
    """
    step = _STEPS[method]
    niters = torch.ceil((t[-1] - t[0]) / 1.0 + 1).item()  # torchdiffeq's grid, built as it builds it
    grid = torch.arange(0, niters, dtype=t.dtype, device=t.device) * 1.0 + t[0]
    grid[-1] = t[-1]
    stages = _Stages.of(grid, initial.real.dtype, perturb)
    # Filled in place as torchdiffeq fills it: the gradients then sum in the same order too.
    solution = torch.empty(len(t), *initial.shape, dtype=initial.dtype, device=initial.device)
    solution[0] = initial
    state, j = initial, 1
    for i, (t0, t1) in enumerate(zip(grid[:-1], grid[1:], strict=True)):
        following = state + step(rhs, stages, i, state)
        while j < len(t) and t1 >= t[j]:
            solution[j] = _linear(t0, t1, state, following, t[j])
            j += 1
        state = following
    return solution


class _Stages(NamedTuple):
    """Every step's stage times, computed at once as torchdiffeq computes them one by one (the same
    elementwise operations): step ``i`` spans ``start[i] .. end[i]`` of length ``dt[i]``; ``first`` and
    ``last`` are ``start`` and ``end`` as the right-hand side sees them (one float inwards with
    ``perturb``), ``third`` and ``two_thirds`` the inner stages; all in the state's real dtype."""

    dt: Tensor
    first: Tensor
    third: Tensor
    half: Tensor
    two_thirds: Tensor
    last: Tensor

    @classmethod
    def of(cls, grid: Tensor, dtype: torch.dtype, perturb: bool) -> _Stages:
        start, end = grid[:-1], grid[1:]
        dt = end - start
        inner = (start + dt * _ONE_THIRD, start + 0.5 * dt, start + dt * _TWO_THIRDS)
        first, third, half, two_thirds, last = (x.to(dtype) for x in (start, *inner, end))
        if perturb:
            with torch.no_grad():
                first, last = torch.nextafter(first, first + 1), torch.nextafter(last, last - 1)
        return cls(dt, first, third, half, two_thirds, last)


def _euler(rhs: Rhs, stages: _Stages, i: int, y0: Tensor) -> Tensor:
    """Step ``i``'s increment (torchdiffeq's ``Euler``)."""
    return stages.dt[i] * rhs(stages.first[i], y0)


def _midpoint(rhs: Rhs, stages: _Stages, i: int, y0: Tensor) -> Tensor:
    """Step ``i``'s increment (torchdiffeq's ``Midpoint``)."""
    dt = stages.dt[i]
    half_dt = 0.5 * dt
    y_mid = y0 + rhs(stages.first[i], y0) * half_dt
    return dt * rhs(stages.half[i], y_mid)


def _rk4(rhs: Rhs, stages: _Stages, i: int, y0: Tensor) -> Tensor:
    """Step ``i``'s increment by the 3/8 rule (torchdiffeq's ``RK4``: ``rk4_alt_step_func``)."""
    dt = stages.dt[i]
    k1 = rhs(stages.first[i], y0)
    k2 = rhs(stages.third[i], y0 + dt * k1 * _ONE_THIRD)
    k3 = rhs(stages.two_thirds[i], y0 + dt * (k2 - k1 * _ONE_THIRD))
    k4 = rhs(stages.last[i], y0 + dt * (k1 - k2 + k3))
    return (k1 + 3 * (k2 + k3) + k4) * dt * 0.125


_STEPS = {"euler": _euler, "midpoint": _midpoint, "rk4": _rk4}


def _linear(t0: Tensor, t1: Tensor, y0: Tensor, y1: Tensor, t: Tensor) -> Tensor:
    """The state at ``t`` in ``[t0, t1]``, linearly interpolated (torchdiffeq's ``_linear_interp``)."""
    if t == t0:
        return y0
    if t == t1:
        return y1
    return y0 + (t - t0) / (t1 - t0) * (y1 - y0)
