"""The tissue model's right-hand side: a Pennes-like bioheat equation on the pixel grid, and its simulator.

The model (per unit heat capacity)::

    dT/dt = div(a(x, y) grad T) - b(x, y) (T - T_body) + q(t, x, y)

* ``a`` diffusivity field in mm^2/s, conservative flux form of :class:`anra_torch.simulation.HeatRHS`
  (zero-flux edges);
* ``b`` perfusion / loss-rate field in 1/s pulling towards the body temperature ``T_body``;
* ``q`` an optional :class:`MovingSource` in K/s: a Gaussian spot moving along a straight path while it
  is on, e.g. an electrosurgical tip.

:func:`simulate_tissue` integrates it with fixed-step RK4 (:func:`anra_torch.simulation.integrate`), every
step inside RK4's stability limit (the ``"stable"`` policy of :func:`anra_torch.simulation.stable_substeps`);
gradients flow to tensor fields that require them. :class:`anra_torch.tissue.LearnedTissueModel`
learns ``a`` and ``b`` through it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from anra_torch.checks import check_int, positive
from anra_torch.simulation.heat import HeatRHS
from anra_torch.simulation.integrator import integrate, stable_substeps

__all__ = ["MovingSource", "TissueRHS", "simulate_tissue"]

_F64 = torch.float64


@dataclass(frozen=True)
class MovingSource:
    """A Gaussian heat source moving at constant speed from ``start`` to ``end`` while on.

    Attributes:
        start: ``(x, y)`` in mm at ``t = t_on``.
        end: ``(x, y)`` in mm at ``t = t_off``.
        width: Gaussian sigma in mm.
        power: heating rate at the spot centre in K/s.
        t_on: switch-on time in s.
        t_off: switch-off time in s (``> t_on``); on during ``[t_on, t_off)``. :func:`simulate_tissue`
            integrates the switching exactly when both fall on its RK4 substeps (multiples of
            ``dt / substeps``); otherwise with an error up to ``power`` times one substep.
    """

    start: tuple[float, float]
    end: tuple[float, float]
    width: float
    power: float
    t_on: float = 0.0
    t_off: float = 1.0

    def __post_init__(self) -> None:
        if not (self.width > 0 and math.isfinite(self.width)):
            raise ValueError(f"width must be a positive finite number in mm, got {self.width!r}")
        if not math.isfinite(self.power):
            raise ValueError(f"power must be a finite number in K/s, got {self.power!r}")
        if not (self.t_off > self.t_on):
            raise ValueError(f"t_off must be after t_on (s), got t_on={self.t_on!r}, t_off={self.t_off!r}")

    def field(self, t: Tensor, x: Tensor, y: Tensor) -> Tensor:
        """Heating rate in K/s at time ``t`` in s on the grid ``x`` ``(W,)``, ``y`` ``(H,)``: ``(H, W)``."""
        s = ((t - self.t_on) / (self.t_off - self.t_on)).clamp(0, 1)
        on = ((t >= self.t_on) & (t < self.t_off)).to(x.dtype)
        cx = self.start[0] + (self.end[0] - self.start[0]) * s
        cy = self.start[1] + (self.end[1] - self.start[1]) * s
        inv = 0.5 / self.width**2
        gx = torch.exp(-((x - cx) ** 2) * inv)
        gy = torch.exp(-((y - cy) ** 2) * inv)
        return on * self.power * gy[:, None] * gx[None, :]


class TissueRHS(nn.Module):
    """``dT/dt = div(a grad T) - b (T - T_body) + q`` for :func:`integrate`, time in ``time_scale`` s units.

    Args:
        diffusivity: ``a`` in mm^2/s, a number or a field ``(H, W)`` (kept as given: may require grad).
        perfusion: ``b`` in 1/s, a number or a field ``(H, W)``.
        dx: pixel size in mm.
        body_temperature: ``T_body``, units of T.
        source: optional :class:`MovingSource`.
        time_scale: seconds per unit of solver time (the attribute of that name; :func:`simulate_tissue`
            sets it to one substep once the fields' maxima have given the step).

    Shape:
        ``forward(t, T)``: ``T`` ``(H, W)`` or ``(B, H, W)``; output like ``T``.

    Raises:
        ValueError: negative or non-finite ``diffusivity`` or ``perfusion``.
    """

    def __init__(
        self,
        diffusivity: float | Tensor,
        perfusion: float | Tensor,
        *,
        dx: float,
        body_temperature: float | Tensor = 37.0,
        source: MovingSource | None = None,
        time_scale: float = 1.0,
    ) -> None:
        super().__init__()
        self.heat = HeatRHS(diffusivity, dx=dx)
        b = (
            perfusion
            if isinstance(perfusion, Tensor)
            else torch.tensor(float(perfusion), dtype=_F64, device="cpu")
        )
        if not bool(torch.isfinite(b.detach()).all()) or bool((b.detach() < 0).any()):
            shown = b.item() if b.numel() == 1 else f"min {b.detach().min().item():g}"
            raise ValueError(f"perfusion must be finite and non-negative in 1/s, got {shown}")
        self.perfusion, self.source = b, source
        self.body_temperature = (
            body_temperature
            if isinstance(body_temperature, Tensor)
            else torch.tensor(float(body_temperature), device="cpu")
        )
        self.dx, self.time_scale = float(dx), float(time_scale)

    def forward(self, t: Tensor, u: Tensor) -> Tensor:
        seconds = t * self.time_scale
        excess = u - self.body_temperature.to(u)
        out = self.heat(seconds, u).reshape(u.shape) - self.perfusion.to(u) * excess
        if self.source is not None:
            h, w = u.shape[-2:]
            x = (torch.arange(w, dtype=u.dtype, device=u.device) + 0.5) * self.dx
            y = (torch.arange(h, dtype=u.dtype, device=u.device) + 0.5) * self.dx
            out = out + self.source.field(seconds.to(u.dtype), x, y)
        return out * self.time_scale


def _max_value(v: float | Tensor) -> float:
    return float(v.detach().max()) if isinstance(v, Tensor) else float(v)


def simulate_tissue(
    initial: Tensor,
    diffusivity: float | Tensor,
    perfusion: float | Tensor = 0.0,
    *,
    dx: float,
    dt: float,
    n_frames: int,
    body_temperature: float | Tensor = 37.0,
    source: MovingSource | None = None,
    substeps: int | None = None,
) -> Tensor:
    """Simulate a thermal video of the tissue model (RK4, zero-flux edges); differentiable in the fields.

    Args:
        initial: first frame (temperatures).
        diffusivity: ``a`` in mm^2/s, number or ``(H, W)``, non-negative.
        perfusion: ``b`` in 1/s, number or ``(H, W)``, non-negative.
        dx: pixel size in mm.
        dt: frame period in s.
        n_frames: frames ``T`` (>= 2); frame 0 is ``initial``.
        body_temperature: ``T_body`` the perfusion pulls towards.
        source: optional :class:`MovingSource`.
        substeps: RK4 steps per frame; default the fewest inside ``0.9`` of RK4's stability limit
            ``(8 a_max / dx^2 + b_max) ds <= 2.785``, and no fewer are accepted (the ``"stable"`` policy
            of :func:`anra_torch.simulation.stable_substeps`).

    Returns:
        Video ``(T, H, W)`` in the dtype of ``initial``.

    Raises:
        ValueError: bad spacing, frame count, negative or non-finite fields, ``substeps`` below the limit.

    Shape:
        ``initial`` ``(H, W)``; fields scalar or ``(H, W)``; output ``(T, H, W)``.
    """
    if initial.ndim != 2:
        raise ValueError(f"initial must have shape (H, W), got {tuple(initial.shape)}")
    dx, dt = positive(dx, "dx", "mm"), positive(dt, "dt", "s")
    n_frames = check_int(n_frames, "n_frames", 2)
    # The right-hand side checks the fields first; their maxima then set the step, and its time unit.
    rhs = TissueRHS(diffusivity, perfusion, dx=dx, body_temperature=body_temperature, source=source)
    count = stable_substeps(
        dt, dx, diffusivity=_max_value(diffusivity), decay=_max_value(perfusion), policy="stable"
    )
    steps = count.choose(substeps, context="RK4 here")
    rhs.time_scale = dt / steps
    # perturb: each step sees t just after its start and just before its end, so a source switching on
    # or off on a substep boundary is integrated exactly.
    return integrate(rhs, initial, n_frames=n_frames, substeps=steps, perturb=True)
