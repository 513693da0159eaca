"""The 2D heat equation ``dT/dt = div(a grad T)`` on a video's pixel grid, by the method of lines.

:class:`HeatRHS` is the right-hand side: the 5-point Laplacian for a scalar or per-video ``a``, the
conservative flux form for a diffusivity field, with the ghost pixels of :data:`BOUNDARIES` around the
frame. :func:`simulate_heat` integrates it with :func:`anra_torch.simulation.integrate`; differentiable
w.r.t. ``a`` and the initial field. The exact solutions it is tested against are in
:mod:`anra_torch.simulation.analytic`.

Pixel centres sit at ``x = (j + 0.5) dx`` (column j) and ``y = (i + 0.5) dx`` (row i), so the frame
spans ``[0, W dx] x [0, H dx]``. Units: mm, s, mm^2/s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import torch
from torch import Tensor, nn

from anra_torch.checks import as_fields, as_spacing, check_choice, check_int
from anra_torch.simulation.integrator import (
    FIXED_STEP_METHODS,
    Solver,
    integrate,
    stable_substeps,
)

__all__ = ["BOUNDARIES", "HeatRHS", "as_diffusivity", "simulate_heat"]


# ------------------------------------------------------------------------------------- boundaries
def _pad_neumann(u: Tensor, value: Tensor | float) -> Tensor:
    """Ghost = edge pixel: the mirror image about the frame edge, so no heat crosses it."""
    u = torch.cat([u[..., :1, :], u, u[..., -1:, :]], dim=-2)
    return torch.cat([u[..., :, :1], u, u[..., :, -1:]], dim=-1)


def _pad_dirichlet(u: Tensor, value: Tensor | float) -> Tensor:
    """Ghost = ``value``: the ring of pixels just outside the frame is held at that value."""
    row = torch.zeros_like(u[..., :1, :]) + value
    u = torch.cat([row, u, row], dim=-2)
    col = torch.zeros_like(u[..., :, :1]) + value
    return torch.cat([col, u, col], dim=-1)


def _pad_periodic(u: Tensor, value: Tensor | float) -> Tensor:
    """Ghost = the pixel on the opposite edge."""
    u = torch.cat([u[..., -1:, :], u, u[..., :1, :]], dim=-2)
    return torch.cat([u[..., :, -1:], u, u[..., :, :1]], dim=-1)


@dataclass(frozen=True)
class _Boundary:
    """How to pad ``(..., H, W)`` by one ghost pixel: the temperature, and a diffusivity field."""

    field: Callable[[Tensor, Tensor | float], Tensor]
    coefficient: Callable[[Tensor, Tensor | float], Tensor]
    uses_value: bool = False


BOUNDARIES: dict[str, _Boundary] = {
    "neumann": _Boundary(_pad_neumann, _pad_neumann),
    "dirichlet": _Boundary(_pad_dirichlet, _pad_neumann, uses_value=True),
    "periodic": _Boundary(_pad_periodic, _pad_periodic),
}
"""Boundary conditions of :func:`simulate_heat` (one ghost pixel around the frame):
``"neumann"`` zero flux (ghost mirrors the edge pixel), ``"dirichlet"`` ghost pixels (centres half a
pixel outside the frame edge) held at ``boundary_value``, ``"periodic"`` wrap-around."""


# ------------------------------------------------------------------------------------- validation
def as_diffusivity(
    a: object, *, batch: int, height: int, width: int, like: Tensor, allow_field: bool = True
) -> tuple[Tensor, bool]:
    """Return a diffusivity ``a`` in mm^2/s cast to ``like`` (graph kept) and whether it is a spatial field.

    The one check of ``a`` for :func:`simulate_heat` and :func:`anra_torch.simulation.heat_spectral`.

    Shape:
        ``a`` a number, ``(B,)``, or (``allow_field``) ``(H, W)`` or ``(B, H, W)``; returned as given.

    Raises:
        TypeError: not real numbers.
        ValueError: another shape, non-finite or negative values.
    """
    if not isinstance(a, Tensor):
        try:
            a = torch.as_tensor(a, dtype=like.dtype, device=like.device)
        except (TypeError, ValueError, RuntimeError) as err:
            raise TypeError(f"a must be a number or a tensor in mm^2/s, got {a!r}") from err
    if a.is_complex() or a.dtype == torch.bool:
        raise TypeError(f"a must be a real diffusivity in mm^2/s, got dtype {a.dtype}")
    a = a.to(dtype=like.dtype, device=like.device)
    allowed = {0: (), 1: (batch,)}
    if allow_field:
        allowed.update({2: (height, width), 3: (batch, height, width)})
    if allowed.get(a.ndim) != tuple(a.shape):
        fields = f", a field ({height}, {width}) or ({batch}, {height}, {width})" if allow_field else ""
        raise ValueError(
            f"a must be a number, a tensor ({batch},){fields} in mm^2/s, got shape {tuple(a.shape)}"
        )
    values = a.detach()
    if not bool(torch.isfinite(values).all()) or bool((values < 0).any()):
        shown = values.item() if values.numel() == 1 else f"min {values.min().item():g}"
        raise ValueError(f"a must be finite and non-negative in mm^2/s, got {shown}")
    return a, a.ndim >= 2


# ---------------------------------------------------------------------------------- right-hand side
class HeatRHS(nn.Module):
    """Right-hand side ``dT/dt = div(a grad T)`` on the pixel grid, for :func:`integrate`.

    A scalar or per-video ``a`` uses the 5-point Laplacian ``a (sum of 4 neighbours - 4 T) / dx^2``;
    a field ``a`` uses the conservative flux form with the face diffusivity the mean of the two
    pixels it joins. The ghost pixel around the frame comes from ``boundary`` (:data:`BOUNDARIES`).
    The module holds no parameters: ``a`` is kept as given (not copied), and :attr:`adjoint_params`
    names it for the adjoint method.

    Args:
        a: diffusivity in mm^2/s: a number, a tensor ``(B,)``, or a field ``(H, W)`` or
            ``(B, H, W)``.
        dx: pixel size in mm, a number or a tensor ``(B,)``.
        boundary: a key of :data:`BOUNDARIES`.
        boundary_value: temperature of the ghost pixels for ``"dirichlet"``, a number or a tensor
            ``(B,)``.
        time_scale: seconds per unit of the solver's time (the output is multiplied by it).

    Shape:
        ``forward(t, u)``: ``u`` ``(B, H, W)``; output ``(B, H, W)``, units of T per unit of time.

    Raises:
        ValueError: unknown boundary, negative ``a``, or non-positive ``dx`` / ``time_scale``.
    """

    def __init__(
        self,
        a: float | Tensor,
        *,
        dx: float | Tensor,
        boundary: str = "neumann",
        boundary_value: float | Tensor = 0.0,
        time_scale: float | Tensor = 1.0,
    ) -> None:
        super().__init__()
        check_choice(boundary, "boundary", list(BOUNDARIES))
        a_tensor = (
            a if isinstance(a, Tensor) else torch.as_tensor(float(a), dtype=torch.float64, device="cpu")
        )
        values = a_tensor.detach()
        if not bool(torch.isfinite(values).all()) or bool((values < 0).any()):
            shown = values.item() if values.numel() == 1 else f"min {values.min().item():g}"
            raise ValueError(f"a must be finite and non-negative in mm^2/s, got {shown}")
        if a_tensor.ndim > 3:
            raise ValueError(f"a must have at most 3 dimensions, got {tuple(a_tensor.shape)}")
        self.a = a_tensor
        self.boundary = boundary
        self.dx = self._per_video(dx, "dx", "mm", positive=True)
        self.time_scale = self._per_video(time_scale, "time_scale", "s", positive=True)
        self.boundary_value = self._per_video(boundary_value, "boundary_value", "units of T", positive=False)

    @staticmethod
    def _per_video(value: float | Tensor, name: str, unit: str, *, positive: bool) -> Tensor:
        if isinstance(value, Tensor):
            tensor = value
        else:  # float64 so that a float64 state sees the exact value
            tensor = torch.as_tensor(float(value), dtype=torch.float64, device="cpu")
        if tensor.ndim > 1:
            raise ValueError(f"{name} must be a number or a (B,) tensor, got {tuple(tensor.shape)}")
        values = tensor.detach()
        if not bool(torch.isfinite(values).all()) or (positive and bool((values <= 0).any())):
            kind = "a positive finite" if positive else "a finite"
            raise ValueError(f"{name} must be {kind} number in {unit}, got {values.tolist()}")
        return tensor.reshape(-1, 1, 1)

    @property
    def adjoint_params(self) -> tuple[Tensor, ...]:
        """The tensors this right-hand side uses that require grad (``a``, the Dirichlet value)."""
        return tuple(x for x in (self.a, self.boundary_value) if x.requires_grad)

    @property
    def is_field(self) -> bool:
        """Whether ``a`` varies in space (flux form) rather than per video."""
        return self.a.ndim >= 2

    def forward(self, t: Tensor, u: Tensor) -> Tensor:
        bc = BOUNDARIES[self.boundary]
        value = self.boundary_value.to(u)
        p = bc.field(u, value)
        if self.is_field:
            a = bc.coefficient(self.a.to(u), 0.0)
            ax = 0.5 * (a[..., 1:-1, :-1] + a[..., 1:-1, 1:])  # faces between columns, (.., H, W+1)
            ay = 0.5 * (a[..., :-1, 1:-1] + a[..., 1:, 1:-1])  # faces between rows, (.., H+1, W)
            fx = ax * (p[..., 1:-1, 1:] - p[..., 1:-1, :-1])
            fy = ay * (p[..., 1:, 1:-1] - p[..., :-1, 1:-1])
            div = (fx[..., 1:] - fx[..., :-1]) + (fy[..., 1:, :] - fy[..., :-1, :])
        else:
            a = self.a.to(u).reshape(-1, 1, 1)
            neighbours = p[..., 1:-1, 2:] + p[..., 1:-1, :-2] + p[..., 2:, 1:-1] + p[..., :-2, 1:-1]
            div = a * (neighbours - 4.0 * u)
        return div * (self.time_scale.to(u) / self.dx.to(u) ** 2)

    def extra_repr(self) -> str:
        kind = "field" if self.is_field else ("per-video" if self.a.ndim == 1 else "scalar")
        return f"a={kind} {tuple(self.a.shape)}, boundary={self.boundary!r}"


# ---------------------------------------------------------------------------------- method of lines
def simulate_heat(
    initial: Tensor,
    *,
    a: float | Tensor,
    dx: float | Tensor,
    dt: float | Tensor,
    n_frames: int,
    boundary: str = "neumann",
    boundary_value: float | Tensor = 0.0,
    solver: Solver | None = None,
) -> Tensor:
    """Simulate a thermal video: 5-point Laplacian in space, :func:`~anra_torch.simulation.integrate` in time.

    Fixed-step methods take by default the fewest substeps per frame that keep it stable and monotone
    (:func:`~anra_torch.simulation.stable_substeps`), a step function of ``a``: fix ``substeps`` to fit ``a``
    by gradient descent. The result differs from the continuous equation by O(dx^2) (``heat_spectral``).

    Args:
        initial: first frame, temperature in any unit.
        a: diffusivity in mm^2/s, >= 0: a number, a tensor ``(B,)`` (per video), or a field
            ``(H, W)`` or ``(B, H, W)`` (then ``dT/dt = div(a grad T)``). Gradients flow to it.
        dx: pixel size in mm, a number or ``(B,)``.
        dt: frame period in s, a number or ``(B,)``.
        n_frames: number of output frames; frame 0 is ``initial``, frame k is at ``t = k dt``.
        boundary: a key of :data:`BOUNDARIES` (``"neumann"``, ``"dirichlet"``, ``"periodic"``).
        boundary_value: ghost-pixel temperature for ``"dirichlet"``, a number or ``(B,)``.
        solver: the time integration (:class:`~anra_torch.simulation.Solver`: method, substeps,
            tolerances, adjoint); default ``Solver()``, RK4 with automatic substeps.

    Returns:
        The video, in the dtype of ``initial``.

    Shape:
        ``initial`` ``(H, W)`` or ``(B, H, W)``; output ``(n_frames, H, W)`` or ``(B, n_frames, H, W)``.

    Raises:
        TypeError: ``initial`` or ``a`` not real numbers.
        ValueError: bad shapes, non-positive ``dx``/``dt``, negative ``a``, unknown ``boundary``, a bad
            ``solver`` (:meth:`Solver.checked`), or ``substeps`` below the stability limit.

    Example:
        >>> u0 = torch.zeros(16, 16, dtype=torch.float64); u0[8, 8] = 1.0
        >>> video = simulate_heat(u0, a=0.2, dx=0.1, dt=0.05, n_frames=3)
        >>> video.shape, round(video[-1].sum().item(), 12)
        (torch.Size([3, 16, 16]), 1.0)
    """
    s = (Solver() if solver is None else solver).checked()
    u0, batched = as_fields(initial)
    batch, height, width = u0.shape
    n_frames, _ = check_int(n_frames, "n_frames", 1), check_choice(boundary, "boundary", list(BOUNDARIES))
    dx_b = as_spacing(dx, name="dx", unit="mm", batch=batch, like=u0)
    dt_b = as_spacing(dt, name="dt", unit="s", batch=batch, like=u0)
    a_t, _ = as_diffusivity(a, batch=batch, height=height, width=width, like=u0)
    value = _boundary_value(boundary_value, boundary, batch=batch, like=u0)
    if n_frames == 1:
        return u0.unsqueeze(1) if batched else u0
    substeps, time_scale = _time_step(a_t, dx_b, dt_b, method=s.method, substeps=s.substeps)
    rhs = HeatRHS(a_t, dx=dx_b, boundary=boundary, boundary_value=value, time_scale=time_scale)
    out = integrate(rhs, u0, n_frames=n_frames, **vars(replace(s, substeps=substeps))).movedim(0, 1)
    return out if batched else out[0]  # (T, B, H, W) -> (B, T, H, W)


def _time_step(
    a: Tensor, dx: Tensor, dt: Tensor, *, method: str, substeps: int | None
) -> tuple[int | None, Tensor]:
    """Substeps per frame (None for adaptive methods) and seconds per unit of solver time, ``(B,)``."""
    if method not in FIXED_STEP_METHODS:
        return None, dt
    # The largest a dt / dx^2 in the batch sets the step: every video shares the solver's grid. It is the
    # diffusivity in units of dx^2 / dt, hence dt = dx = 1 below.
    a_max = a.detach().reshape(a.shape[0] if a.ndim in (1, 3) else 1, -1).amax(dim=1)
    courant = float((a_max * dt / dx**2).max())
    count = stable_substeps(1.0, 1.0, diffusivity=courant, method=method)
    substeps = count.choose(substeps, context=f"{method} at a*dt/dx^2={courant:.4g}")
    return substeps, dt / substeps


def _boundary_value(value: object, boundary: str, *, batch: int, like: Tensor) -> Tensor:
    """The Dirichlet value as a ``(B,)`` tensor (graph kept); rejected for other boundaries."""
    tensor = value if isinstance(value, Tensor) else None
    if tensor is None:
        try:
            tensor = torch.as_tensor(value, dtype=like.dtype, device=like.device)
        except (TypeError, ValueError, RuntimeError) as err:
            raise TypeError(f"boundary_value must be a number or a tensor, got {value!r}") from err
    tensor = tensor.to(dtype=like.dtype, device=like.device)
    if tensor.ndim > 1 or tensor.numel() not in (1, batch):
        raise ValueError(
            f"boundary_value must be a number or have shape ({batch},), got {tuple(tensor.shape)}"
        )
    if not bool(torch.isfinite(tensor.detach()).all()):
        raise ValueError(f"boundary_value must be finite, got {tensor.detach().tolist()}")
    if not BOUNDARIES[boundary].uses_value and bool((tensor.detach() != 0).any()):
        raise ValueError(f"boundary_value applies to boundary='dirichlet' only, got boundary={boundary!r}")
    return tensor.reshape(-1).expand(batch)
