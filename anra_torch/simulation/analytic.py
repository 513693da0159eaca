"""Exact solutions of the 2D heat equation ``dT/dt = a (d_xx + d_yy) T`` on a video's pixel grid.

- :func:`gaussian_blob` / :func:`gaussian_blobs`: the analytic solution on the infinite plane for
  Gaussian initial fields, sampled at the pixel centres (no discretisation error).
- :func:`heat_spectral`: the exact solution of the continuous equation on the frame's rectangle for
  the trigonometric interpolant of the initial frame (periodic: FFT; Neumann: DCT-II as an FFT).

They are the references the method-of-lines simulator (:func:`anra_torch.simulation.simulate_heat`) is
tested against. Pixel centres sit at ``x = (j + 0.5) dx`` (column j) and ``y = (i + 0.5) dx`` (row i), so
the frame spans ``[0, W dx] x [0, H dx]``. Units: mm, s, mm^2/s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from anra_torch.checks import as_fields, as_spacing, check_choice, check_dtype, check_shape, positive
from anra_torch.simulation.heat import as_diffusivity

__all__ = ["SPECTRAL_BOUNDARIES", "gaussian_blob", "gaussian_blobs", "heat_spectral"]


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


def _as_times(times: object, *, like_dtype: torch.dtype, name: str = "times") -> Tensor:
    """Return non-negative finite times in s as a ``(T,)`` tensor."""
    try:
        t = (
            times.to(like_dtype)
            if isinstance(times, Tensor)
            else torch.as_tensor(times, dtype=like_dtype, device="cpu")
        )
    except (TypeError, ValueError, RuntimeError) as err:
        raise TypeError(f"{name} must be a sequence or tensor of times in s, got {times!r}") from err
    if t.ndim > 1 or t.numel() == 0:
        raise ValueError(f"{name} must be a non-empty (T,) sequence of times in s, got {tuple(t.shape)}")
    t = t.reshape(-1)
    if not bool(torch.isfinite(t).all()) or bool((t < 0).any()):
        raise ValueError(f"{name} must be finite and non-negative in s, got {t.tolist()[:8]}")
    return t


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
        a: diffusivity in mm^2/s, >= 0, a number or a tensor ``(B,)``.
        dx: pixel size in mm, a number or ``(B,)``.
        times: output times in s, >= 0, any order.
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
    a_t, _ = as_diffusivity(a, batch=batch, height=height, width=width, like=u0, allow_field=False)
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
def _check_blobs(peak: Tensor, sigma: Tensor, centre: Tensor, a: Tensor, bg: Tensor) -> torch.Size:
    """The leading (batch) shape of :func:`gaussian_blobs`' parameters, after checking them (its
    ``Raises``)."""
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
    if a.ndim > 1 or a.numel() not in (1, *lead):
        raise ValueError(f"a must be a number or have shape {tuple(lead)}, got {tuple(a.shape)}")
    if bool((a.detach() < 0).any()):
        raise ValueError(f"a must be finite and non-negative in mm^2/s, got {a.detach().tolist()}")
    if bg.ndim > 1 or bg.numel() not in (1, *lead):
        raise ValueError(f"background must be a number or have shape {tuple(lead)}, got {tuple(bg.shape)}")
    return lead


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
        times: sample times in s, >= 0.
        shape: frame size ``(H, W)`` in pixels.
        dx: pixel size in mm.
        a: diffusivity in mm^2/s, >= 0, a number or (batched geometry) a tensor ``(B,)``.
        peaks: initial peak temperature of each blob above ``background``.
        sigmas: initial standard deviation of each blob in mm, > 0.
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
    check_dtype(dtype)
    height, width = check_shape(shape)
    step = positive(dx, "dx", "mm")
    t = _as_times(times, like_dtype=dtype)
    peak = _as_param(peaks, "peaks", dtype)
    sigma = _as_param(sigmas, "sigmas", dtype)
    centre = _as_param(centres, "centres", dtype)
    a_t, bg = _as_param(a, "a", dtype), _as_param(background, "background", dtype)
    lead = _check_blobs(peak, sigma, centre, a_t, bg)

    a_t = a_t.reshape(*lead, 1, 1) if lead and a_t.numel() > 1 else a_t.reshape(())
    variance = sigma.unsqueeze(-1) ** 2 + 2.0 * a_t * t  # (..., N, T)
    amplitude = peak.unsqueeze(-1) * sigma.unsqueeze(-1) ** 2 / variance
    x = (torch.arange(width, dtype=dtype, device=peak.device) + 0.5) * step
    y = (torch.arange(height, dtype=dtype, device=peak.device) + 0.5) * step
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

    ``T(x, y, t) = background + peak s0^2 / (s0^2 + 2 a t) exp(-r^2 / (2 (s0^2 + 2 a t)))``, ``s0 = sigma``
    and ``r`` the distance to ``centre`` (full width at half maximum at t = 0: ``2 sqrt(2 ln 2) sigma``).

    Args:
        times: sample times in s, >= 0.
        shape: frame size ``(H, W)`` in pixels.
        dx: pixel size in mm.
        a: diffusivity in mm^2/s, >= 0.
        peak: initial peak temperature above ``background``.
        sigma: initial standard deviation in mm, > 0.
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
    peaks, sigmas = (x.reshape(1) if isinstance(x, Tensor) else [x] for x in (peak, sigma))
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
        tensor = (
            value.to(dtype)
            if isinstance(value, Tensor)
            else torch.as_tensor(value, dtype=dtype, device="cpu")
        )
    except (TypeError, ValueError, RuntimeError) as err:
        raise TypeError(f"{name} must be numbers or a tensor, got {value!r}") from err
    if not bool(torch.isfinite(tensor.detach()).all()):
        raise ValueError(f"{name} must be finite, got {tensor.detach().tolist()}")
    return tensor
