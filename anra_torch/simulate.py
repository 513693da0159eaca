"""Forward models of the 2D heat equation ``dT/dt = a (d_xx + d_yy) T`` on a video's pixel grid.

Three solvers, from exact to discrete:

- :func:`gaussian_blob` / :func:`gaussian_blobs`: the analytic solution on the infinite plane for
  Gaussian initial fields, sampled at the pixel centres (no discretisation error).
- :func:`heat_spectral`: the exact solution of the continuous equation on the frame's rectangle for
  the trigonometric interpolant of the initial frame (periodic: FFT; Neumann: DCT-II as an FFT).
- :func:`simulate_heat`: method of lines with the 5-point Laplacian (or the flux form
  ``div(a grad T)`` for a diffusivity field), integrated by ``torchdiffeq``; differentiable w.r.t.
  ``a`` and the initial field.

Pixel centres sit at ``x = (j + 0.5) dx`` (column j) and ``y = (i + 0.5) dx`` (row i), so the frame
spans ``[0, W dx] x [0, H dx]``. Units: mm, s, mm^2/s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torchdiffeq import odeint, odeint_adjoint

from anra_torch.checks import as_fields, as_spacing, check_choice, check_int, check_shape, positive

__all__ = [
    "ADAPTIVE_METHODS",
    "BOUNDARIES",
    "FIXED_STEP_METHODS",
    "SPECTRAL_BOUNDARIES",
    "HeatRHS",
    "gaussian_blob",
    "gaussian_blobs",
    "heat_spectral",
    "simulate_heat",
]


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


def _extend_periodic(u: Tensor) -> Tensor:
    return u


def _extend_even(u: Tensor) -> Tensor:
    # The half-sample-symmetric extension has period 2L and only cosine modes cos(pi m x / L) with
    # x = (j + 1/2) dx: its FFT is the DCT-II of u, and the evolved field stays even (zero flux at
    # the edges).
    u = torch.cat([u, u.flip(-1)], dim=-1)
    return torch.cat([u, u.flip(-2)], dim=-2)


SPECTRAL_BOUNDARIES: dict[str, Callable[[Tensor], Tensor]] = {
    "periodic": _extend_periodic,
    "neumann": _extend_even,
}
"""Boundary conditions of :func:`heat_spectral`: each extends the frame to a periodic field."""


# ------------------------------------------------------------------------------------ time stepping
@dataclass(frozen=True)
class _StepLimit:
    """Largest ``a ds / dx^2`` of one step on the 5-point Laplacian (spectrum in ``[-8/dx^2, 0]``).

    ``stable``: |R(z)| <= 1 on ``z in [-8 c, 0]``. ``monotone``: the step is a non-negative
    combination of neighbours (no overshoot: discrete maximum principle); the automatic step
    respects it.
    """

    stable: float
    monotone: float


FIXED_STEP_METHODS: dict[str, _StepLimit] = {
    # Euler: 1 - 4c >= 0. Midpoint: R'(z) = 1 + z >= 0 on z = -4c. Both equal the stability limit.
    "euler": _StepLimit(stable=0.25, monotone=0.25),
    "midpoint": _StepLimit(stable=0.25, monotone=0.25),
    # RK4 is stable up to |z| = 2.7853 (c = 0.348) but the S^3 coefficient of R(c (S - 4I)), with S
    # the neighbour sum, is c^3/6 (1 - 4c): above c = 0.25 a sharp peak overshoots.
    "rk4": _StepLimit(stable=2.7853 / 8.0, monotone=0.25),
}
"""Fixed-step ``torchdiffeq`` methods accepted by :func:`simulate_heat`, with their step limits."""

ADAPTIVE_METHODS: tuple[str, ...] = ("dopri5", "dopri8", "bosh3", "adaptive_heun", "fehlberg2")
"""Adaptive ``torchdiffeq`` methods accepted by :func:`simulate_heat` (use rtol and atol)."""

_SAFETY = 0.9
"""The automatic step uses this fraction of the monotone limit."""


# ------------------------------------------------------------------------------------- validation


def _as_diffusivity(
    a: object, *, batch: int, height: int, width: int, like: Tensor, allow_field: bool = True
) -> tuple[Tensor, bool]:
    """Return ``a`` cast to ``like`` (graph kept) and whether it is a spatial field."""
    if not isinstance(a, Tensor):
        try:
            a = torch.as_tensor(a, dtype=like.dtype)
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


def _as_times(times: object, *, like_dtype: torch.dtype, name: str = "times") -> Tensor:
    """Return non-negative finite times (s) as a ``(T,)`` tensor."""
    try:
        t = torch.as_tensor(times, dtype=like_dtype)
    except (TypeError, ValueError, RuntimeError) as err:
        raise TypeError(f"{name} must be a sequence or tensor of times in s, got {times!r}") from err
    if t.ndim > 1 or t.numel() == 0:
        raise ValueError(f"{name} must be a non-empty (T,) sequence of times in s, got {tuple(t.shape)}")
    t = t.reshape(-1)
    if not bool(torch.isfinite(t).all()) or bool((t < 0).any()):
        raise ValueError(f"{name} must be finite and non-negative in s, got {t.tolist()[:8]}")
    return t


# ---------------------------------------------------------------------------------- right-hand side
class HeatRHS(nn.Module):
    """Right-hand side ``dT/dt = div(a grad T)`` on the pixel grid, for ``torchdiffeq``.

    A scalar or per-video ``a`` uses the 5-point Laplacian ``a (sum of 4 neighbours - 4 T) / dx^2``;
    a field ``a`` uses the conservative flux form with the face diffusivity the mean of the two
    pixels it joins. The ghost pixel around the frame comes from ``boundary`` (:data:`BOUNDARIES`).
    The module holds no parameters: ``a`` is kept as given (not copied), so pass it as
    ``adjoint_params`` to ``odeint_adjoint``.

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
        a_tensor = a if isinstance(a, Tensor) else torch.as_tensor(float(a), dtype=torch.float64)
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
            tensor = torch.as_tensor(float(value), dtype=torch.float64)
        if tensor.ndim > 1:
            raise ValueError(f"{name} must be a number or a (B,) tensor, got {tuple(tensor.shape)}")
        values = tensor.detach()
        if not bool(torch.isfinite(values).all()) or (positive and bool((values <= 0).any())):
            kind = "a positive finite" if positive else "a finite"
            raise ValueError(f"{name} must be {kind} number in {unit}, got {values.tolist()}")
        return tensor.reshape(-1, 1, 1)

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
    method: str = "rk4",
    substeps: int | None = None,
    rtol: float = 1e-7,
    atol: float = 1e-9,
    adjoint: bool = False,
) -> Tensor:
    """Simulate a thermal video: 5-point Laplacian in space, torchdiffeq in time (method of lines).

    Fixed-step methods (:data:`FIXED_STEP_METHODS`) take an integer number of substeps per frame, by
    default the fewest with ``a_max dt / (substeps dx^2) <= 0.9 * 0.25``: stable, and monotone (no
    new extrema, so the maximum principle holds). The substep count is a step function of ``a``:
    when fitting ``a`` by gradient descent pass ``substeps`` explicitly so the objective stays
    smooth. Adaptive methods (:data:`ADAPTIVE_METHODS`) use ``rtol`` / ``atol`` instead. The
    semi-discrete system is solved, so the result differs from the continuous equation by O(dx^2)
    (see :func:`heat_spectral`).

    Args:
        initial: first frame, temperature in any unit.
        a: diffusivity in mm^2/s (>= 0): a number, a tensor ``(B,)`` (per video), or a field
            ``(H, W)`` or ``(B, H, W)`` (then ``dT/dt = div(a grad T)``). Gradients flow to it.
        dx: pixel size in mm, a number or ``(B,)``.
        dt: frame period in s, a number or ``(B,)``.
        n_frames: number of output frames; frame 0 is ``initial``, frame k is at ``t = k dt``.
        boundary: a key of :data:`BOUNDARIES` (``"neumann"``, ``"dirichlet"``, ``"periodic"``).
        boundary_value: ghost-pixel temperature for ``"dirichlet"``, a number or ``(B,)``.
        method: a key of :data:`FIXED_STEP_METHODS` or one of :data:`ADAPTIVE_METHODS`.
        substeps: solver steps per frame for fixed-step methods (default: automatic, see above).
        rtol: relative tolerance of adaptive methods.
        atol: absolute tolerance of adaptive methods (units of T).
        adjoint: use ``odeint_adjoint`` (memory O(1) in the number of steps) instead of
            backpropagating through the solver.

    Returns:
        The video, in the dtype of ``initial``.

    Shape:
        ``initial`` ``(H, W)`` or ``(B, H, W)``;
        output ``(n_frames, H, W)`` or ``(B, n_frames, H, W)``.

    Raises:
        TypeError: ``initial`` or ``a`` not real numbers.
        ValueError: bad shapes, non-positive ``dx``/``dt``, negative ``a``, unknown
            ``boundary``/``method``, or ``substeps`` below the stability limit.

    Example:
        >>> u0 = torch.zeros(16, 16, dtype=torch.float64); u0[8, 8] = 1.0
        >>> video = simulate_heat(u0, a=0.2, dx=0.1, dt=0.05, n_frames=3)
        >>> video.shape, round(video[-1].sum().item(), 12)
        (torch.Size([3, 16, 16]), 1.0)
    """
    u0, batched = as_fields(initial)
    batch, height, width = u0.shape
    n_frames = check_int(n_frames, "n_frames", 1)
    check_choice(boundary, "boundary", list(BOUNDARIES))
    check_choice(method, "method", [*FIXED_STEP_METHODS, *ADAPTIVE_METHODS])
    dx_b = as_spacing(dx, name="dx", unit="mm", batch=batch, like=u0)
    dt_b = as_spacing(dt, name="dt", unit="s", batch=batch, like=u0)
    a_t, is_field = _as_diffusivity(a, batch=batch, height=height, width=width, like=u0)
    value = _boundary_value(boundary_value, boundary, batch=batch, like=u0)
    if substeps is not None:
        if method not in FIXED_STEP_METHODS:
            raise ValueError(f"substeps applies to fixed-step methods only, got method={method!r}")
        substeps = check_int(substeps, "substeps", 1)
    rtol = positive(rtol, "rtol", "relative units")
    atol = positive(atol, "atol", "units of T")
    if n_frames == 1:
        out = u0.unsqueeze(1)
        return out if batched else out[0]

    # The largest a dt / dx^2 in the batch sets the step: every video shares the solver's grid.
    a_max = a_t.detach().reshape(a_t.shape[0] if a_t.ndim in (1, 3) else 1, -1).amax(dim=1)
    courant = float((a_max * dt_b / dx_b**2).max())
    options: dict[str, float] | None = None
    kwargs: dict[str, object] = {}
    if method in FIXED_STEP_METHODS:
        limit = FIXED_STEP_METHODS[method]
        needed = max(1, math.ceil(courant / limit.stable))
        if substeps is None:
            substeps = max(1, math.ceil(courant / (_SAFETY * limit.monotone)))
        elif substeps < needed:
            raise ValueError(
                f"substeps={substeps} is unstable for {method} at a*dt/dx^2={courant:.4g}; "
                f"need at least {needed} (or leave substeps=None)"
            )
        # Integrate in units of one substep so that the solver grid hits every frame exactly.
        t = torch.arange(n_frames, dtype=u0.dtype, device=u0.device) * substeps
        options = {"step_size": 1.0}
        time_scale = dt_b / substeps
    else:
        t = torch.arange(n_frames, dtype=u0.dtype, device=u0.device)
        time_scale = dt_b
        kwargs.update(rtol=rtol, atol=atol)

    rhs = HeatRHS(a_t, dx=dx_b, boundary=boundary, boundary_value=value, time_scale=time_scale)
    if adjoint:
        params = tuple(x for x in (rhs.a, rhs.boundary_value) if x.requires_grad)
        out = odeint_adjoint(rhs, u0, t, method=method, options=options, adjoint_params=params, **kwargs)
    else:
        out = odeint(rhs, u0, t, method=method, options=options, **kwargs)
    out = out.movedim(0, 1)  # (T, B, H, W) -> (B, T, H, W)
    return out if batched else out[0]


def _boundary_value(value: object, boundary: str, *, batch: int, like: Tensor) -> Tensor:
    """The Dirichlet value as a ``(B,)`` tensor (graph kept); rejected for other boundaries."""
    tensor = value if isinstance(value, Tensor) else None
    if tensor is None:
        try:
            tensor = torch.as_tensor(value, dtype=like.dtype)
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


# ----------------------------------------------------------------------------------------- spectral
def heat_spectral(
    initial: Tensor,
    *,
    a: float | Tensor,
    dx: float | Tensor,
    times: Sequence[float] | Tensor,
    boundary: str = "periodic",
) -> Tensor:
    """Exact solution of the continuous heat equation on the frame's rectangle, mode by mode.

    The initial frame is read as its trigonometric interpolant on ``[0, W dx] x [0, H dx]``; each
    mode ``exp(i k . x)`` is multiplied by ``exp(-a |k|^2 t)`` with the continuous wavenumbers
    ``k = 2 pi m / L``. ``"periodic"`` uses the FFT of the frame; ``"neumann"`` (zero flux through
    the frame edges) the DCT-II, computed as the FFT of the half-sample mirror image (period ``2L``,
    ``k = pi m / L``). No time stepping and no spatial truncation error beyond the sampling of the
    initial frame; differentiable w.r.t. ``a`` and ``initial``.

    Args:
        initial: first frame.
        a: diffusivity in mm^2/s (>= 0), a number or a tensor ``(B,)``.
        dx: pixel size in mm, a number or ``(B,)``.
        times: output times in s (>= 0), any order.
        boundary: a key of :data:`SPECTRAL_BOUNDARIES`.

    Returns:
        The field at ``times``, in the dtype of ``initial``.

    Shape:
        ``initial`` ``(H, W)`` or ``(B, H, W)``; output ``(T, H, W)`` or ``(B, T, H, W)``.

    Raises:
        ValueError: bad shapes, an ``a`` field, negative ``a`` or times, unknown ``boundary``.

    Example:
        >>> x = (torch.arange(32, dtype=torch.float64) + 0.5) * 0.25
        >>> u0 = torch.cos(2 * torch.pi * x / 8.0).expand(32, 32)
        >>> u = heat_spectral(u0, a=0.1, dx=0.25, times=[0.0, 1.0])
        >>> torch.allclose(u[1], u0 * math.exp(-0.1 * (math.pi / 4) ** 2))
        True
    """
    u0, batched = as_fields(initial)
    batch, height, width = u0.shape
    check_choice(boundary, "boundary", list(SPECTRAL_BOUNDARIES))
    dx_b = as_spacing(dx, name="dx", unit="mm", batch=batch, like=u0)
    a_t, _ = _as_diffusivity(a, batch=batch, height=height, width=width, like=u0, allow_field=False)
    t = _as_times(times, like_dtype=u0.dtype).to(u0.device)

    extended = SPECTRAL_BOUNDARIES[boundary](u0)
    rows, cols = extended.shape[-2:]
    # Wavenumbers in rad per pixel; divided by dx per video below.
    ky = 2.0 * math.pi * torch.fft.fftfreq(rows, dtype=u0.dtype, device=u0.device)
    kx = 2.0 * math.pi * torch.fft.rfftfreq(cols, dtype=u0.dtype, device=u0.device)
    k2 = ky[:, None] ** 2 + kx[None, :] ** 2  # (rows, cols // 2 + 1)
    rate = a_t.reshape(-1, 1, 1, 1) / dx_b.reshape(-1, 1, 1, 1) ** 2  # (B, 1, 1, 1)
    decay = torch.exp(-rate * t.reshape(1, -1, 1, 1) * k2)  # (B, T, rows, cols // 2 + 1)
    spectrum = torch.fft.rfft2(extended).unsqueeze(1)  # (B, 1, rows, cols // 2 + 1)
    out = torch.fft.irfft2(spectrum * decay, s=(rows, cols))[..., :height, :width]
    return out if batched else out[0]


# ----------------------------------------------------------------------------------------- analytic
def gaussian_blobs(
    times: Sequence[float] | Tensor,
    *,
    shape: tuple[int, int],
    dx: float,
    a: float | Tensor,
    peaks: Sequence[float] | Tensor,
    sigmas: Sequence[float] | Tensor,
    centres: Sequence[Sequence[float]] | Tensor,
    background: float | Tensor = 0.0,
    dtype: torch.dtype = torch.float64,
) -> Tensor:
    """Exact solution on the infinite plane for a sum of Gaussians, sampled at the pixel centres.

    Each blob evolves as ``peak s0^2 / (s0^2 + 2 a t) exp(-r^2 / (2 (s0^2 + 2 a t)))`` (variance
    grows by ``2 a t`` per axis, heat is conserved); the equation is linear, so blobs add. A batch
    of geometries gives a batch of videos. Differentiable w.r.t. tensor arguments.

    Args:
        times: sample times in s (>= 0).
        shape: frame size ``(H, W)`` in pixels.
        dx: pixel size in mm.
        a: diffusivity in mm^2/s (>= 0), a number or (batched geometry) a tensor ``(B,)``.
        peaks: initial peak temperature of each blob above ``background``.
        sigmas: initial standard deviation of each blob in mm (> 0).
        centres: ``(x, y)`` of each blob in mm (x along W, y along H; the frame spans
            ``[0, W dx] x [0, H dx]``).
        background: uniform temperature added everywhere, a number or ``(B,)``.
        dtype: floating dtype of the result.

    Shape:
        ``peaks``, ``sigmas``: ``(N,)`` or ``(B, N)``; ``centres``: ``(N, 2)`` or ``(B, N, 2)``;
        output ``(T, H, W)`` or ``(B, T, H, W)``.

    Raises:
        ValueError: bad shapes or non-positive ``sigmas``/``dx``, negative ``a`` or times.
    """
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    height, width = check_shape(shape)
    step = positive(dx, "dx", "mm")
    t = _as_times(times, like_dtype=dtype)
    peak = _as_param(peaks, "peaks", dtype)
    sigma = _as_param(sigmas, "sigmas", dtype)
    centre = _as_param(centres, "centres", dtype)
    if peak.ndim not in (1, 2) or peak.shape[-1] == 0:
        raise ValueError(f"peaks must have shape (N,) or (B, N), got {tuple(peak.shape)}")
    lead = peak.shape[:-1]
    if tuple(sigma.shape) != tuple(peak.shape):
        raise ValueError(f"sigmas must have the shape of peaks {tuple(peak.shape)}, got {tuple(sigma.shape)}")
    if tuple(centre.shape) != (*peak.shape, 2):
        raise ValueError(
            f"centres must have shape {(*peak.shape, 2)} (x, y in mm), got {tuple(centre.shape)}"
        )
    if bool((sigma.detach() <= 0).any()):
        raise ValueError(f"sigmas must be positive in mm, got min {sigma.detach().min().item():g}")
    a_t = _as_param(a, "a", dtype)
    if a_t.ndim > 1 or a_t.numel() not in (1, *lead):
        raise ValueError(f"a must be a number or have shape {tuple(lead)}, got {tuple(a_t.shape)}")
    if bool((a_t.detach() < 0).any()):
        raise ValueError(f"a must be finite and non-negative in mm^2/s, got {a_t.detach().tolist()}")
    bg = _as_param(background, "background", dtype)
    if bg.ndim > 1 or bg.numel() not in (1, *lead):
        raise ValueError(f"background must be a number or have shape {tuple(lead)}, got {tuple(bg.shape)}")

    a_t = a_t.reshape(*lead, 1, 1) if lead and a_t.numel() > 1 else a_t.reshape(())
    variance = sigma.unsqueeze(-1) ** 2 + 2.0 * a_t * t  # (..., N, T)
    amplitude = peak.unsqueeze(-1) * sigma.unsqueeze(-1) ** 2 / variance
    x = (torch.arange(width, dtype=dtype) + 0.5) * step
    y = (torch.arange(height, dtype=dtype) + 0.5) * step
    cx = centre[..., 0, None, None]
    cy = centre[..., 1, None, None]
    # Separable: exp(-r^2 / 2v) = exp(-dx^2 / 2v) exp(-dy^2 / 2v), so no (N, T, H, W) intermediate.
    gx = torch.exp(-((x - cx) ** 2) / (2.0 * variance.unsqueeze(-1)))  # (..., N, T, W)
    gy = torch.exp(-((y - cy) ** 2) / (2.0 * variance.unsqueeze(-1)))  # (..., N, T, H)
    field = torch.einsum("...nt,...nth,...ntw->...thw", amplitude, gy, gx)
    bg = bg.reshape(*lead, 1, 1, 1) if lead and bg.numel() > 1 else bg.reshape(())
    return field + bg


def gaussian_blob(
    times: Sequence[float] | Tensor,
    *,
    shape: tuple[int, int],
    dx: float,
    a: float | Tensor,
    peak: float | Tensor,
    sigma: float | Tensor,
    centre: tuple[float, float] | None = None,
    background: float = 0.0,
    dtype: torch.dtype = torch.float64,
) -> Tensor:
    """Exact heat-equation solution on the infinite plane for one Gaussian, at the pixel centres.

    ``T(x, y, t) = background + peak s0^2 / (s0^2 + 2 a t) exp(-r^2 / (2 (s0^2 + 2 a t)))`` with
    ``s0 = sigma`` and ``r`` the distance to ``centre``. The full width at half maximum at t = 0 is
    ``2 sqrt(2 ln 2) sigma``.

    Args:
        times: sample times in s (>= 0).
        shape: frame size ``(H, W)`` in pixels.
        dx: pixel size in mm.
        a: diffusivity in mm^2/s (>= 0).
        peak: initial peak temperature above ``background``.
        sigma: initial standard deviation in mm (> 0).
        centre: ``(x, y)`` in mm; default the frame centre ``(W dx / 2, H dx / 2)``.
        background: uniform temperature added everywhere.
        dtype: floating dtype of the result.

    Shape:
        Output ``(T, H, W)``.

    Raises:
        ValueError: non-positive ``sigma``/``dx``, negative ``a`` or times, bad ``shape``.

    Example:
        >>> u = gaussian_blob([0.0, 1.0], shape=(64, 64), dx=0.1, a=0.2, peak=1.0, sigma=0.5,
        ...                   centre=(3.25, 3.25))  # on the centre of pixel (32, 32)
        >>> u[0, 32, 32].item(), round(u[1, 32, 32].item(), 4)  # 0.25 / (0.25 + 2 * 0.2 * 1.0)
        (1.0, 0.3846)
    """
    height, width = check_shape(shape)
    step = positive(dx, "dx", "mm")
    if centre is None:
        centre = (width * step / 2.0, height * step / 2.0)
    if len(centre) != 2:
        raise ValueError(f"centre must be (x, y) in mm, got {centre!r}")
    if not isinstance(sigma, Tensor) and not (math.isfinite(float(sigma)) and float(sigma) > 0):
        raise ValueError(f"sigma must be a positive finite number in mm, got {sigma!r}")
    peaks = peak.reshape(1) if isinstance(peak, Tensor) else [peak]
    sigmas = sigma.reshape(1) if isinstance(sigma, Tensor) else [sigma]
    return gaussian_blobs(
        times,
        shape=(height, width),
        dx=step,
        a=a,
        peaks=peaks,
        sigmas=sigmas,
        centres=[list(centre)],
        background=background,
        dtype=dtype,
    )


def _as_param(value: object, name: str, dtype: torch.dtype) -> Tensor:
    """A finite float tensor (graph kept for tensors)."""
    try:
        tensor = value.to(dtype) if isinstance(value, Tensor) else torch.as_tensor(value, dtype=dtype)
    except (TypeError, ValueError, RuntimeError) as err:
        raise TypeError(f"{name} must be numbers or a tensor, got {value!r}") from err
    if not bool(torch.isfinite(tensor.detach()).all()):
        raise ValueError(f"{name} must be finite, got {tensor.detach().tolist()}")
    return tensor
