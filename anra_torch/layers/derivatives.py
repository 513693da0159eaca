"""Noise-robust derivative layers on fixed kernels: time as Conv3d, space as Conv2d, in physical units.

Time layers take a video ``(B, T, H, W)`` and apply an ``(L, 1, 1)`` Conv3d kernel over ``(B, 1, T, H, W)``;
the output has ``T - L + 1`` frames, frame ``k`` estimating the derivative at input frame ``k + centre``
(``centre = L - 1 - delay``). Spatial layers take ``(..., H, W)`` and return derivatives per unit length.
Borders are explicit: ``"crop"`` (valid convolution, output smaller by ``N - 1``) or a padding mode
(``"reflect"``, ``"replicate"``, ``"circular"``, ``"zeros"``) that keeps the size.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from anra_torch.checks import as_spacing, number
from anra_torch.layers import stencils

__all__ = [
    "BORDERS",
    "TimeDerivative",
    "Laplacian",
    "Gradient",
    "SecondDerivatives",
    "GaussianSmoothing",
    "time_derivative",
    "laplacian",
    "gradient",
    "second_derivatives",
    "gaussian_smooth",
]

BORDERS: dict[str, str | None] = {
    "crop": None,
    "reflect": "reflect",
    "replicate": "replicate",
    "circular": "circular",
    "zeros": "constant",
}
"""Border handling: ``"crop"`` keeps only fully supported pixels; the others pad (``F.pad`` modes)."""


def _check_border(border: str) -> None:
    if border not in BORDERS:
        raise ValueError(f"unknown border {border!r}; expected one of: {', '.join(BORDERS)}")


def _per_leading(spacing: float | Tensor, x: Tensor, extra_dims: int) -> Tensor | float:
    """Broadcast a float or ``(B,)`` spacing against ``x`` whose first dim is B."""
    if isinstance(spacing, Tensor):
        return spacing.to(x.dtype).reshape(-1, *([1] * extra_dims))
    return float(spacing)


def _check_spacing(spacing: float | Tensor, name: str, unit: str, x: Tensor) -> None:
    """The one spacing check (:func:`~anra_torch.checks.as_spacing`): positive, finite, one value or one
    per video of ``x`` (its leading dim when it has more than two)."""
    if isinstance(spacing, Tensor) and spacing.numel() > 1:
        as_spacing(spacing, name=name, unit=unit, batch=x.shape[0] if x.ndim > 2 else 1, like=x)
    else:
        number(spacing, name, unit, positive=True)


# ----------------------------------------------------------------------------------------------- time
def _time_filter(frames: Tensor, taps: Tensor) -> Tensor:
    """Correlate ``(B, T, H, W)`` with ``C`` tap vectors ``(C, L)`` along T as one Conv3d.

    Output ``(B, C, T-L+1, H, W)``. Differentiated through shifted-slice sums (:class:`_TimeFilter`): the
    Conv3d's own backward runs several times slower on CPU.
    """
    if frames.requires_grad and torch.is_grad_enabled():
        return _TimeFilter.apply(frames, taps)
    return _time_conv(frames, taps)


def _time_conv(frames: Tensor, taps: Tensor) -> Tensor:
    """The forward of :func:`_time_filter`: one Conv3d."""
    weight = taps.to(frames).reshape(taps.shape[0], 1, -1, 1, 1)
    return F.conv3d(frames.unsqueeze(1), weight)


class _TimeFilter(torch.autograd.Function):
    """:func:`_time_filter` with the transposed taps, summed over the channels, as the backward."""

    @staticmethod
    def forward(ctx: Any, frames: Tensor, taps: Tensor) -> Tensor:
        ctx.taps = taps.tolist()
        return _time_conv(frames, taps)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None]:
        channels = [_correlate1d_adjoint(grad[:, c], taps, 1) for c, taps in enumerate(ctx.taps)]
        return sum(channels[1:], channels[0]), None


class TimeDerivative(nn.Module):
    """Holoborodko time derivative d/dt (units of the data per s) as a fixed ``(L, 1, 1)`` Conv3d.

    Args:
        family: ``"smooth"`` (one-sided, delay ``(L-1)/2``), ``"centred"`` (odd L), ``"hybrid"`` (no delay).
        length: window length ``L`` in frames.

    Shape:
        Input ``(B, T, H, W)`` (or one video ``(T, H, W)``) with ``T >= L``; output ``(B, T - L + 1, H, W)``
        (or ``(T - L + 1, H, W)``).
        :meth:`average` applies the matching temporal average, same output shape, for the spatial terms.
    """

    def __init__(self, family: str = "smooth", length: int = 5) -> None:
        super().__init__()
        self.stencil = stencils.time_stencil(family, length)
        self.register_buffer("taps", self.stencil.taps.clone(), persistent=False)
        self.register_buffer("pair", self.stencil.pair.clone(), persistent=False)

    @property
    def length(self) -> int:
        """Window length in frames."""
        return self.stencil.length

    @property
    def delay(self) -> float:
        """Frames between the newest frame of the window and the instant the derivative applies."""
        return self.stencil.delay

    @property
    def centre(self) -> float:
        """Offset (frames) from the window's oldest frame to the instant the derivative applies."""
        return self.stencil.centre

    def _checked(self, frames: Tensor, dt: float | Tensor | None) -> Tensor:
        """``frames`` as ``(B, T, H, W)``, after checking their shape, length and ``dt``."""
        if frames.ndim not in (3, 4):
            raise ValueError(f"frames must have shape (T, H, W) or (B, T, H, W), got {tuple(frames.shape)}")
        video = frames if frames.ndim == 4 else frames.unsqueeze(0)
        if video.shape[1] < self.length:
            raise ValueError(
                f"need at least {self.length} frames for a time filter of length {self.length}, "
                f"got {video.shape[1]}"
            )
        if dt is not None:
            _check_spacing(dt, "dt", "s", video)
        return video

    def _filter(self, frames: Tensor, taps: Tensor, dt: float | Tensor | None) -> Tensor:
        """Apply ``(C, L)`` taps; (T, H, W) in -> (C, K, H, W) out, (B, T, H, W) -> (B, C, K, H, W)."""
        video = self._checked(frames, dt)
        out = _time_filter(video, taps)
        if dt is not None:
            # channel 0 is the derivative (per s); the others are averages. In place: no copy of the rest.
            out[:, :1] /= _per_leading(dt, out, 4)
        return out if frames.ndim == 4 else out[0]

    def forward(self, frames: Tensor, dt: float | Tensor) -> Tensor:
        return self._filter(frames, self.taps[None], dt).select(-4, 0)

    def average(self, frames: Tensor) -> Tensor:
        """Temporal average with the derivative's centre, for the spatial side of the PDE."""
        return self._filter(frames, self.pair[None], None).select(-4, 0)

    def with_average(self, frames: Tensor, dt: float | Tensor) -> tuple[Tensor, Tensor]:
        """``(forward(frames, dt), average(frames))`` as shifted-slice sums along T (a two-channel Conv3d
        over a cropped frame ran ~10x slower on CPU)."""
        video = self._checked(frames, dt)
        rate = _correlate1d(video, self.taps.tolist(), 1)
        rate = rate / _per_leading(dt, rate, 3)
        average = _correlate1d(video, self.pair.tolist(), 1)
        return (rate, average) if frames.ndim == 4 else (rate[0], average[0])

    def adjoint(self, rate_weights: Tensor, average_weights: Tensor, dt: float | Tensor) -> Tensor:
        """Transpose of :meth:`with_average`: maps output-space weights back onto the input frames.

        ``sum(rw * forward(x)) + sum(aw * average(x)) == sum(adjoint(rw, aw) * x)`` for any video x.

        Shape:
            Weights ``(B, T-L+1, H, W)``; output ``(B, T, H, W)``.
        """
        # Shifted-slice sums along T (a 2-channel conv_transpose3d runs ~10x slower on CPU).
        rate = _correlate1d_adjoint(rate_weights, self.taps.tolist(), 1)
        rate = rate / _per_leading(dt, rate, 3)
        return rate + _correlate1d_adjoint(average_weights, self.pair.tolist(), 1)

    def extra_repr(self) -> str:
        return f"family={self.stencil.family!r}, length={self.length}, delay={self.delay:g}"


def time_derivative(frames: Tensor, dt: float | Tensor, *, family: str = "smooth", length: int = 5) -> Tensor:
    """Noise-robust d/dt of a video in units of the data per second.

    Shape:
        Input ``(B, T, H, W)``; output ``(B, T - L + 1, H, W)``, frame k at input frame ``k + (L-1) - delay``.
    """
    return _cached(TimeDerivative, frames, family, length)(frames, dt)


# ---------------------------------------------------------------------------------------------- space
def _filter2d(x: Tensor, weight: Tensor, border: str, taps: list | None = None) -> Tensor:
    """Correlate ``(..., H, W)`` with ``C`` kernels ``(C, kh, kw)``; output ``(..., C, H', W')``. With
    ``taps`` (``weight`` as lists), no gradient: shifted slices summed in place (float64 conv2d: 7x slower)"""
    lead = x.shape[:-2]
    flat = x.reshape(-1, 1, *x.shape[-2:])
    kh, kw = weight.shape[-2:]
    mode = BORDERS[border]
    if mode is not None:
        flat = F.pad(flat, (kw // 2, kw // 2, kh // 2, kh // 2), mode=mode)
    if taps is None or (flat.requires_grad and torch.is_grad_enabled()):
        out = F.conv2d(flat, weight.to(x).unsqueeze(1))  # its backward: one transposed convolution
    else:
        h, w = flat.shape[-2] - kh + 1, flat.shape[-1] - kw + 1
        out = flat.new_zeros(flat.shape[0], len(taps), h, w)
        for c, kernel in enumerate(taps):
            for i, j, v in ((i, j, v) for i, row in enumerate(kernel) for j, v in enumerate(row) if v):
                out[:, c].add_(flat[:, 0, i : i + h, j : j + w], alpha=v)
    return out.reshape(*lead, *out.shape[1:])


def _check_spatial(x: Tensor, support: int, border: str) -> None:
    if x.ndim < 2:
        raise ValueError(f"input must have shape (..., H, W), got {tuple(x.shape)}")
    # 'crop' needs the whole kernel inside the frame; 'reflect' and 'circular' more than its radius.
    need = {"crop": support, "reflect": support // 2 + 1, "circular": support // 2 + 1}.get(border, 1)
    if min(x.shape[-2:]) < need:
        raise ValueError(
            f"need frames of at least {need} x {need} px for a {support}-px kernel with "
            f"border={border!r}, got {x.shape[-2]} x {x.shape[-1]}"
        )


def _correlate1d(x: Tensor, taps: list[float], dim: int) -> Tensor:
    """Valid correlation along ``dim`` as an in-place sum of shifted slices (zero taps skipped).

    Accumulating in place keeps it to ~3 memory passes per tap: 5x faster than summing temporaries on
    batches that do not fit in cache. Differentiated through its adjoint (:class:`_Correlate1d`): the
    slices' own backward would fill and copy a whole input-sized tensor per tap.
    """
    nonzero = [tap for tap in taps if tap != 0.0]
    if x.requires_grad and torch.is_grad_enabled() and not (len(nonzero) == 1 and nonzero[0] == 1.0):
        return _Correlate1d.apply(x, taps, dim)
    return _correlate1d_slices(x, taps, dim)


class _Correlate1d(torch.autograd.Function):
    """:func:`_correlate1d` with its transpose as the backward (itself differentiable the same way)."""

    @staticmethod
    def forward(ctx: Any, x: Tensor, taps: list[float], dim: int) -> Tensor:
        ctx.taps, ctx.dim = taps, dim
        return _correlate1d_slices(x, taps, dim)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None, None]:
        return _correlate1d_adjoint(grad, ctx.taps, ctx.dim), None, None


def _correlate1d_slices(x: Tensor, taps: list[float], dim: int) -> Tensor:
    """The forward of :func:`_correlate1d`."""
    n = x.shape[dim] - len(taps) + 1
    nonzero = [(i, tap) for i, tap in enumerate(taps) if tap != 0.0]
    if not nonzero:
        return x.narrow(dim, 0, n) * 0.0
    first, tap = nonzero[0]
    if len(nonzero) == 1 and tap == 1.0:  # a shifted identity: a view, no pass over memory
        return x.narrow(dim, first, n)
    out = x.narrow(dim, first, n) * tap
    for i, tap in nonzero[1:]:
        out.add_(x.narrow(dim, i, n), alpha=tap)
    return out


def _correlate1d_adjoint(y: Tensor, taps: list[float], dim: int) -> Tensor:
    """Transpose of :func:`_correlate1d`: each tap's shifted copy of ``y`` added into a longer output (by
    ``k - 1``), in place; with gradients, zero-padding and a correlation with the reversed taps (the same
    map, differentiable again). In place there is no padded copy to write and read ``k`` times."""
    k = len(taps)
    if y.requires_grad and torch.is_grad_enabled():
        pad = [0, 0] * (y.ndim - (dim % y.ndim) - 1) + [k - 1, k - 1]
        return _correlate1d(F.pad(y, pad), taps[::-1], dim)
    n = y.shape[dim]
    shape = list(y.shape)
    shape[dim] = n + k - 1
    nonzero = [(i, tap) for i, tap in enumerate(taps) if tap != 0.0]
    if not nonzero:
        return y.new_zeros(shape)
    out = y.new_empty(shape)
    first, tap = nonzero[0]
    out.narrow(dim, 0, first).zero_()
    out.narrow(dim, first + n, k - 1 - first).zero_()
    torch.mul(y, tap, out=out.narrow(dim, first, n))
    for i, tap in nonzero[1:]:
        out.narrow(dim, i, n).add_(y, alpha=tap)
    return out


def _separable_factors(kernel: Tensor, tol: float = 1e-13) -> list[tuple[list[float], list[float]]]:
    """Write a 2D kernel as a short sum of outer products ``ky (x) kx`` (exact to rounding)."""
    u, s, vh = torch.linalg.svd(kernel)
    rank = int((s > tol * s[0]).sum()) if s[0] > 0 else 0
    return [((u[:, i] * s[i]).tolist(), vh[i].tolist()) for i in range(rank)]


class _SpatialOperator(nn.Module):
    """Fixed stack of 2D kernels scaled by ``dx ** order``; subclasses only choose the kernels.

    A kernel of low rank runs as separable 1D passes when that needs fewer operations than the full
    Conv2d (``2 N r < N^2``); both give the same correlation.
    """

    order: int = 1

    def __init__(self, kernels: Tensor, *, size: int, border: str) -> None:
        super().__init__()
        _check_border(border)
        self.size, self.border = size, border
        self.register_buffer("kernels", kernels.clone(), persistent=False)
        self._factors = [_separable_factors(k) for k in kernels]
        self._taps = kernels.tolist()  # the direct route's shifted slices (see _filter2d)
        n = kernels.shape[-1]
        self.separable = all(2 * n * len(f) < n * n for f in self._factors)

    @property
    def support(self) -> int:
        """Kernel side in pixels; ``border='crop'`` trims ``support // 2`` px on each side."""
        return int(self.kernels.shape[-1])

    def _filter(self, u: Tensor) -> Tensor:
        if not self.separable:
            return _filter2d(u, self.kernels, self.border, self._taps)
        mode, r = BORDERS[self.border], self.support // 2
        if mode is not None:
            u = F.pad(u.reshape(-1, 1, *u.shape[-2:]), (r, r, r, r), mode=mode).reshape(
                *u.shape[:-2], u.shape[-2] + 2 * r, u.shape[-1] + 2 * r
            )
        outputs = []
        for factors in self._factors:
            terms = [_correlate1d(_correlate1d(u, kx, -1), ky, -2) for ky, kx in factors]
            out = terms[0] if len(terms) == 1 else terms[0] + terms[1]
            for term in terms[2:]:
                out.add_(term)
            outputs.append(out)
        # one kernel (the Laplacian, its partner): a view, not a stacked copy
        return outputs[0].unsqueeze(-3) if len(outputs) == 1 else torch.stack(outputs, dim=-3)

    def adjoint(self, y: Tensor, dx: float | Tensor) -> Tensor:
        """Transpose of a single-kernel operator with ``border='crop'``: ``(..., H', W') -> (..., H, W)``.

        ``sum(y * op(u, dx)) == sum(op.adjoint(y, dx) * u)``; used to propagate noise exactly.
        """
        if self.border != "crop" or self.kernels.shape[0] != 1:
            raise ValueError("adjoint is defined for single-kernel operators with border='crop'")
        if self.separable:
            out = sum(
                _correlate1d_adjoint(_correlate1d_adjoint(y, ky, -2), kx, -1) for ky, kx in self._factors[0]
            )
        else:
            flat = y.reshape(-1, 1, *y.shape[-2:])
            out = F.conv_transpose2d(flat, self.kernels.to(y).unsqueeze(1))
            out = out.reshape(*y.shape[:-2], *out.shape[-2:])
        return out / _per_leading(dx, out, out.ndim - 1) ** self.order

    def _operate(self, u: Tensor, dx: float | Tensor) -> Tensor:
        _check_spatial(u, self.support, self.border)
        _check_spacing(dx, "dx", "mm", u)
        out = self._filter(u)
        if self.order == 0:  # unitless smoothing: no division (and no copy of a cropped view)
            return out
        return out / _per_leading(dx, out, out.ndim - 1) ** self.order

    def extra_repr(self) -> str:
        return f"size={self.size}, border={self.border!r}"


class _PartnerSmoothing(_SpatialOperator):
    """The smoothing built into a Laplacian, to apply to the other side of the PDE (unitless)."""

    order = 0

    def __init__(self, kernel: Tensor, *, border: str) -> None:
        super().__init__(kernel.unsqueeze(0), size=kernel.shape[-1], border=border)

    def forward(self, u: Tensor) -> Tensor:
        return self._operate(u, 1.0).squeeze(-3)


class Laplacian(_SpatialOperator):
    """Noise-robust Laplacian ``d11 + d22`` (units of the data per mm^2).

    Args:
        size: kernel size N in ``stencils.SPATIAL_SIZES`` (3 is the 5-point stencil).
        family: ``"holoborodko"`` (noise-robust) or ``"central"`` (maximal-order, for smoothed fields).
        border: ``"crop"`` or a padding mode, see :data:`BORDERS`.

    Attributes:
        partner: module applying the smoothing built into this Laplacian (same output shape), for the
            other side of the PDE; see :func:`stencils.laplacian_partner`.

    Shape:
        Input ``(..., H, W)``; output ``(..., H - N + 1, W - N + 1)`` for ``"crop"``, else ``(..., H, W)``.
        ``dx`` is a float or a tensor ``(B,)`` matching the first input dimension.
    """

    order = 2

    def __init__(self, size: int = 5, *, family: str = "holoborodko", border: str = "crop") -> None:
        kernel = stencils.laplacian_kernel(size, family)
        super().__init__(kernel.unsqueeze(0), size=size, border=border)
        self.family = family
        self.partner = _PartnerSmoothing(stencils.laplacian_partner(size, family), border=border)

    def forward(self, u: Tensor, dx: float | Tensor) -> Tensor:
        return self._operate(u, dx).squeeze(-3)

    def extra_repr(self) -> str:
        return f"size={self.size}, family={self.family!r}, border={self.border!r}"


class Gradient(_SpatialOperator):
    """Holoborodko gradient ``(d/dx, d/dy)`` (units of the data per mm); x along W, y along H.

    Shape:
        Input ``(..., H, W)``; output ``(..., 2, H', W')``.
    """

    order = 1

    def __init__(self, size: int = 5, *, border: str = "crop") -> None:
        super().__init__(stencils.gradient_kernels(size), size=size, border=border)

    def forward(self, u: Tensor, dx: float | Tensor) -> Tensor:
        return self._operate(u, dx)


class SecondDerivatives(_SpatialOperator):
    """Noise-robust ``(d11, d22, d12)`` = ``(d2/dx2, d2/dy2, d2/dxdy)`` (units of the data per mm^2).

    Shape:
        Input ``(..., H, W)``; output ``(..., 3, H', W')``.
    """

    order = 2

    def __init__(self, size: int = 5, *, border: str = "crop") -> None:
        super().__init__(stencils.second_derivative_kernels(size), size=size, border=border)

    def forward(self, u: Tensor, dx: float | Tensor) -> Tensor:
        return self._operate(u, dx)


_SLICE_TAPS = 15  # up to this many taps, shifted slices beat banded matrix products on CPU
_BANDED_SIDES = 4  # banded products only for frames at most this many kernel lengths wide


def _banded(taps: Tensor, n: int) -> Tensor:
    """``(n, n - k + 1)`` matrix M with ``(x @ M)[j] = sum_i taps[i] x[j + i]`` (valid correlation)."""
    k, m = taps.numel(), n - taps.numel() + 1
    rows = torch.arange(m, device=taps.device)
    matrix = torch.zeros(n, m, dtype=taps.dtype, device=taps.device)
    for i in range(k):
        matrix[rows + i, rows] = taps[i]
    return matrix


class GaussianSmoothing(nn.Module):
    """Separable Gaussian smoothing over (H, W) with ``sigma`` in pixels (0 is the identity).

    Applied to the frames before any derivative, it acts identically on both sides of a linear PDE
    (convolutions commute), so it lowers noise without biasing the estimated coefficients. Narrow kernels
    run as shifted-slice sums, wide ones as two banded matrix products (BLAS), both far faster on CPU
    than a direct convolution.

    Shape:
        Input ``(..., H, W)``; output ``(..., H - 2r, W - 2r)`` for ``"crop"`` (``r = radius``).
    """

    def __init__(self, sigma: float, *, truncate: float = 3.5, border: str = "crop") -> None:
        super().__init__()
        _check_border(border)
        self.sigma, self.border = float(sigma), border
        self.register_buffer("taps", stencils.gaussian_taps(sigma, truncate=truncate), persistent=False)
        self._matrices: dict[tuple, Tensor] = {}

    @property
    def radius(self) -> int:
        """Pixels trimmed on each side with ``border='crop'``."""
        return (self.taps.numel() - 1) // 2

    def _matrix(self, n: int, like: Tensor) -> Tensor:
        key = (n, like.dtype, like.device)
        if key not in self._matrices:
            self._matrices[key] = _banded(self.taps.to(like), n)
        return self._matrices[key]

    def _slices(self, u: Tensor) -> bool:
        """Shifted slices (cost ~ taps per pixel) or banded matrix products (cost ~ frame side per pixel,
        but BLAS-fast): slices for short kernels and for frames much wider than the kernel."""
        return self.taps.numel() <= _SLICE_TAPS or max(u.shape[-2:]) > _BANDED_SIDES * self.taps.numel()

    def forward(self, u: Tensor) -> Tensor:
        if self.radius == 0:
            return u
        _check_spatial(u, self.taps.numel(), self.border)
        r, mode = self.radius, BORDERS[self.border]
        if mode is not None:
            u = F.pad(u.reshape(-1, 1, *u.shape[-2:]), (r, r, r, r), mode=mode).reshape(
                *u.shape[:-2], u.shape[-2] + 2 * r, u.shape[-1] + 2 * r
            )
        if self._slices(u):
            taps = self.taps.tolist()
            return _correlate1d(_correlate1d(u, taps, -1), taps, -2)
        lead, (h, w) = u.shape[:-2], u.shape[-2:]
        mx, my = self._matrix(w, u), self._matrix(h, u)
        rows = (u.reshape(-1, w) @ mx).reshape(-1, h, mx.shape[1])
        cols = rows.transpose(1, 2).reshape(-1, h) @ my
        return (
            cols.reshape(-1, mx.shape[1], my.shape[1])
            .transpose(1, 2)
            .reshape(*lead, my.shape[1], mx.shape[1])
        )

    def adjoint(self, y: Tensor) -> Tensor:
        """Transpose of the ``border='crop'`` smoothing: ``(..., H - 2r, W - 2r) -> (..., H, W)``."""
        if self.border != "crop":
            raise ValueError("adjoint is defined for border='crop'")
        if self.radius == 0:
            return y
        if self._slices(y):
            taps = self.taps.tolist()
            return _correlate1d_adjoint(_correlate1d_adjoint(y, taps, -2), taps, -1)
        lead, (h1, w1) = y.shape[:-2], y.shape[-2:]
        h, w = h1 + 2 * self.radius, w1 + 2 * self.radius
        mx, my = self._matrix(w, y), self._matrix(h, y)
        rows = (y.reshape(-1, w1) @ mx.T).reshape(-1, h1, w)
        cols = rows.transpose(1, 2).reshape(-1, h1) @ my.T
        return cols.reshape(-1, w, h).transpose(1, 2).reshape(*lead, h, w)

    def extra_repr(self) -> str:
        return f"sigma={self.sigma:g}, radius={self.radius}, border={self.border!r}"


@lru_cache(maxsize=64)
def _built(cls: type, device: torch.device, dtype: torch.dtype, *args: object, **kwargs: object) -> nn.Module:
    """A layer with its kernels on ``device`` in ``dtype``, built once per configuration."""
    return cls(*args, **kwargs).to(device=device, dtype=dtype)


def _cached(cls: type, like: Tensor, *args: object, **kwargs: object) -> nn.Module:
    """The layer for inputs like ``like`` (a cached module is never moved: each device and dtype has its
    own)."""
    dtype = like.dtype if like.is_floating_point() else torch.get_default_dtype()
    return _built(cls, like.device, dtype, *args, **kwargs)


def laplacian(
    u: Tensor,
    dx: float | Tensor,
    *,
    size: int = 5,
    family: str = "holoborodko",
    border: str = "crop",
) -> Tensor:
    """Laplacian in units of the data per mm^2. See :class:`Laplacian`.

    Shape:
        Input ``(..., H, W)``; output ``(..., H', W')``.
    """
    return _cached(Laplacian, u, size, family=family, border=border)(u, dx)


def gradient(u: Tensor, dx: float | Tensor, *, size: int = 5, border: str = "crop") -> Tensor:
    """Noise-robust ``(d/dx, d/dy)``. See :class:`Gradient`.

    Shape:
        Input ``(..., H, W)``; output ``(..., 2, H', W')``.
    """
    return _cached(Gradient, u, size, border=border)(u, dx)


def second_derivatives(u: Tensor, dx: float | Tensor, *, size: int = 5, border: str = "crop") -> Tensor:
    """Noise-robust ``(d11, d22, d12)``. See :class:`SecondDerivatives`.

    Shape:
        Input ``(..., H, W)``; output ``(..., 3, H', W')``.
    """
    return _cached(SecondDerivatives, u, size, border=border)(u, dx)


def gaussian_smooth(u: Tensor, sigma: float, *, border: str = "crop") -> Tensor:
    """Separable Gaussian smoothing with ``sigma`` in pixels. See :class:`GaussianSmoothing`.

    Shape:
        Input ``(..., H, W)``; output ``(..., H - 2r, W - 2r)`` for ``"crop"``.
    """
    return _cached(GaussianSmoothing, u, float(sigma), border=border)(u)
