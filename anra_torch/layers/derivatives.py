"""Noise-robust derivative layers on fixed kernels: time as Conv3d, space as Conv2d, in physical units.

Time layers take a video ``(B, T, H, W)`` and apply an ``(L, 1, 1)`` Conv3d kernel over ``(B, 1, T, H, W)``;
the output has ``T - L + 1`` frames, frame ``k`` estimating the derivative at input frame ``k + centre``,
``centre = L - 1 - delay``. Spatial layers take ``(..., H, W)`` and return derivatives per unit length.
Borders are explicit: ``"crop"``, a valid convolution whose output is smaller by ``N - 1``, or a padding
mode of :data:`BORDERS` that keeps the size.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from anra_torch.checks import as_spacing, number
from anra_torch.layers import stencils
from anra_torch.layers.correlate import (
    BORDERS,
    check_border,
    check_spatial,
    correlate1d,
    correlate1d_adjoint,
    pad_frames,
    time_filter,
)

__all__ = [
    "BORDERS",
    "TimeDerivative",
    "Laplacian",
    "Gradient",
    "SecondDerivatives",
    "time_derivative",
    "laplacian",
    "gradient",
    "second_derivatives",
]


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
def _time_checked(frames: Tensor, dt: float | Tensor | None, length: int) -> Tensor:
    """``frames`` as ``(B, T, H, W)``, after checking their shape, length and ``dt``."""
    if frames.ndim not in (3, 4):
        raise ValueError(f"frames must have shape (T, H, W) or (B, T, H, W), got {tuple(frames.shape)}")
    video = frames if frames.ndim == 4 else frames.unsqueeze(0)
    if video.shape[1] < length:
        raise ValueError(
            f"need at least {length} frames for a time filter of length {length}, got {video.shape[1]}"
        )
    if dt is not None:
        _check_spacing(dt, "dt", "s", video)
    return video


def _time_filtered(frames: Tensor, taps: Tensor, dt: float | Tensor | None) -> Tensor:
    """Apply ``(C, L)`` taps; (T, H, W) in -> (C, K, H, W) out, (B, T, H, W) -> (B, C, K, H, W); channel 0
    divided by ``dt`` when given."""
    video = _time_checked(frames, dt, taps.shape[-1])
    out = time_filter(video, taps)
    if dt is not None:
        # channel 0 is the derivative (per s); the others are averages. In place: no copy of the rest.
        out[:, :1] /= _per_leading(dt, out, 4)
    return out if frames.ndim == 4 else out[0]


class TimeDerivative(nn.Module):
    """Holoborodko time derivative d/dt in units of the data per s, as a fixed ``(L, 1, 1)`` Conv3d.

    Args:
        family: ``"smooth"``, one-sided with delay ``(L-1)/2``; ``"centred"``, odd L; ``"hybrid"``, no delay.
        length: window length ``L`` in frames.

    Shape:
        Input ``(B, T, H, W)``, or one video ``(T, H, W)``, with ``T >= L``; output
        ``(B, T - L + 1, H, W)``, or ``(T - L + 1, H, W)``.
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
        """Offset in frames from the window's oldest frame to the instant the derivative applies."""
        return self.stencil.centre

    def forward(self, frames: Tensor, dt: float | Tensor) -> Tensor:
        return _time_filtered(frames, self.taps[None], dt).select(-4, 0)

    def average(self, frames: Tensor) -> Tensor:
        """Temporal average with the derivative's centre, for the spatial side of the PDE."""
        return _time_filtered(frames, self.pair[None], None).select(-4, 0)

    def with_average(self, frames: Tensor, dt: float | Tensor) -> tuple[Tensor, Tensor]:
        """``(forward(frames, dt), average(frames))`` as shifted-slice sums along T."""
        video = _time_checked(frames, dt, self.length)
        rate = correlate1d(video, self.taps.tolist(), 1)
        rate = rate / _per_leading(dt, rate, 3)
        average = correlate1d(video, self.pair.tolist(), 1)
        return (rate, average) if frames.ndim == 4 else (rate[0], average[0])

    def adjoint(self, rate_weights: Tensor, average_weights: Tensor, dt: float | Tensor) -> Tensor:
        """Transpose of :meth:`with_average`: maps output-space weights back onto the input frames.

        ``sum(rw * forward(x)) + sum(aw * average(x)) == sum(adjoint(rw, aw) * x)`` for any video x.

        Shape:
            Weights ``(B, T-L+1, H, W)``; output ``(B, T, H, W)``.
        """
        rate = correlate1d_adjoint(rate_weights, self.taps.tolist(), 1)
        rate = rate / _per_leading(dt, rate, 3)
        return rate + correlate1d_adjoint(average_weights, self.pair.tolist(), 1)

    def extra_repr(self) -> str:
        return f"family={self.stencil.family!r}, length={self.length}, delay={self.delay:g}"


def time_derivative(frames: Tensor, dt: float | Tensor, *, family: str = "smooth", length: int = 5) -> Tensor:
    """Noise-robust d/dt of a video in units of the data per second.

    Shape:
        Input ``(B, T, H, W)``; output ``(B, T - L + 1, H, W)``, frame k at input frame ``k + (L-1) - delay``.
    """
    dtype = frames.dtype if frames.is_floating_point() else torch.get_default_dtype()
    return _time_filtered(frames, _time_taps(family, length, dtype), dt).select(-4, 0)


@lru_cache(maxsize=64)
def _time_taps(family: str, length: int, dtype: torch.dtype) -> Tensor:
    """The derivative's taps ``(1, L)`` in ``dtype`` (on the CPU), built once per stencil."""
    return stencils.time_stencil(family, length).taps[None].to(dtype)


# ---------------------------------------------------------------------------------------------- space
def _filter2d(x: Tensor, weight: Tensor, border: str, taps: list | None = None) -> Tensor:
    """Correlate ``(..., H, W)`` with ``C`` kernels ``(C, kh, kw)``; output ``(..., C, H', W')``. With
    ``taps`` (``weight`` as lists), no gradient: shifted slices summed in place."""
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


def _separable_factors(kernel: Tensor, tol: float = 1e-13) -> list[tuple[list[float], list[float]]]:
    """Write a 2D kernel as a short sum of outer products ``ky (x) kx`` (exact to rounding)."""
    u, s, vh = torch.linalg.svd(kernel)
    rank = int((s > tol * s[0]).sum()) if s[0] > 0 else 0
    return [((u[:, i] * s[i]).tolist(), vh[i].tolist()) for i in range(rank)]


@dataclass(frozen=True)
class _Kernels:
    """A fixed stack of 2-D kernels ``(C, N, N)`` (float64, CPU) and the routes that apply it.

    A kernel of low rank runs as separable 1D passes (``factors``) when that needs fewer operations than
    the full kernel (``2 N r < N^2``); the others as shifted slices of ``taps``. Both give the same
    correlation.
    """

    kernels: Tensor
    factors: list[list[tuple[list[float], list[float]]]]
    taps: list
    separable: bool

    @staticmethod
    def of(kernels: Tensor) -> _Kernels:
        factors = [_separable_factors(k) for k in kernels]
        n = kernels.shape[-1]
        separable = all(2 * n * len(f) < n * n for f in factors)
        return _Kernels(kernels, factors, kernels.tolist(), separable)


_KERNELS = {
    "laplacian": lambda size, family: stencils.laplacian_kernel(size, family).unsqueeze(0),
    "gradient": lambda size, family: stencils.gradient_kernels(size),
    "second": lambda size, family: stencils.second_derivative_kernels(size),
}


@lru_cache(maxsize=64)
def _kernels(kind: str, size: int, family: str = "holoborodko") -> _Kernels:
    """The kernels of :func:`laplacian`, :func:`gradient` or :func:`second_derivatives`, built once."""
    return _Kernels.of(_KERNELS[kind](size, family))


def _filter(u: Tensor, k: _Kernels, weight: Tensor, border: str) -> Tensor:
    """Correlate ``(..., H, W)`` with the kernels ``k`` (``weight``: them in any dtype, for the Conv2d
    route); output ``(..., C, H', W')``."""
    if not k.separable:
        return _filter2d(u, weight, border, k.taps)
    u = pad_frames(u, weight.shape[-1] // 2, border)
    outputs = []
    for factors in k.factors:
        terms = [correlate1d(correlate1d(u, kx, -1), ky, -2) for ky, kx in factors]
        out = terms[0] if len(terms) == 1 else terms[0] + terms[1]
        for term in terms[2:]:
            out.add_(term)
        outputs.append(out)
    # one kernel (the Laplacian, its partner): a view, not a stacked copy
    return outputs[0].unsqueeze(-3) if len(outputs) == 1 else torch.stack(outputs, dim=-3)


def _spatial(u: Tensor, dx: float | Tensor, k: _Kernels, weight: Tensor, border: str, order: int) -> Tensor:
    """Check, filter and divide by ``dx ** order``: ``(..., H, W) -> (..., C, H', W')``."""
    check_spatial(u, weight.shape[-1], border)
    _check_spacing(dx, "dx", "mm", u)
    out = _filter(u, k, weight, border)
    if order == 0:  # unitless smoothing: no division (and no copy of a cropped view)
        return out
    return out / _per_leading(dx, out, out.ndim - 1) ** order


class _SpatialOperator(nn.Module):
    """Fixed stack of 2D kernels scaled by ``dx ** order``; subclasses only choose the kernels."""

    order: int = 1

    def __init__(self, kernels: Tensor | _Kernels, *, size: int, border: str) -> None:
        super().__init__()
        check_border(border)
        self.size, self.border = size, border
        self._kernels = kernels if isinstance(kernels, _Kernels) else _Kernels.of(kernels)
        self.register_buffer("kernels", self._kernels.kernels.clone(), persistent=False)
        self.separable = self._kernels.separable

    @property
    def support(self) -> int:
        """Kernel side in pixels; ``border='crop'`` trims ``support // 2`` px on each side."""
        return int(self.kernels.shape[-1])

    def adjoint(self, y: Tensor, dx: float | Tensor) -> Tensor:
        """Transpose of a single-kernel operator with ``border='crop'``.

        ``sum(y * op(u, dx)) == sum(op.adjoint(y, dx) * u)``; used to propagate noise exactly.

        Shape:
            ``(..., H', W') -> (..., H, W)``.

        Raises:
            ValueError: the operator has several kernels or a border other than ``"crop"``.
        """
        if self.border != "crop" or self.kernels.shape[0] != 1:
            raise ValueError("adjoint is defined for single-kernel operators with border='crop'")
        if self.separable:
            out = sum(
                correlate1d_adjoint(correlate1d_adjoint(y, ky, -2), kx, -1)
                for ky, kx in self._kernels.factors[0]
            )
        else:
            flat = y.reshape(-1, 1, *y.shape[-2:])
            out = F.conv_transpose2d(flat, self.kernels.to(y).unsqueeze(1))
            out = out.reshape(*y.shape[:-2], *out.shape[-2:])
        return out / _per_leading(dx, out, out.ndim - 1) ** self.order

    def _operate(self, u: Tensor, dx: float | Tensor) -> Tensor:
        return _spatial(u, dx, self._kernels, self.kernels, self.border, self.order)

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
    """Noise-robust Laplacian ``d11 + d22`` in units of the data per mm^2.

    Args:
        size: kernel size N in ``stencils.SPATIAL_SIZES``; 3 is the 5-point stencil.
        family: ``"holoborodko"``, noise-robust, or ``"central"``, of maximal order for smoothed fields.
        border: ``"crop"`` or a padding mode, see :data:`BORDERS`.

    Attributes:
        partner: module applying the smoothing built into this Laplacian, with the same output shape, for
            the other side of the PDE; see :func:`stencils.laplacian_partner`.

    Shape:
        Input ``(..., H, W)``; output ``(..., H - N + 1, W - N + 1)`` for ``"crop"``, else ``(..., H, W)``.
        ``dx`` is a float or a tensor ``(B,)`` matching the first input dimension.
    """

    order = 2

    def __init__(self, size: int = 5, *, family: str = "holoborodko", border: str = "crop") -> None:
        super().__init__(_kernels("laplacian", size, family), size=size, border=border)
        self.family = family
        self.partner = _PartnerSmoothing(stencils.laplacian_partner(size, family), border=border)

    def forward(self, u: Tensor, dx: float | Tensor) -> Tensor:
        return self._operate(u, dx).squeeze(-3)

    def extra_repr(self) -> str:
        return f"size={self.size}, family={self.family!r}, border={self.border!r}"


class Gradient(_SpatialOperator):
    """Holoborodko gradient ``(d/dx, d/dy)`` in units of the data per mm; x along W, y along H.

    Shape:
        Input ``(..., H, W)``; output ``(..., 2, H', W')``.
    """

    order = 1

    def __init__(self, size: int = 5, *, border: str = "crop") -> None:
        super().__init__(_kernels("gradient", size), size=size, border=border)

    def forward(self, u: Tensor, dx: float | Tensor) -> Tensor:
        return self._operate(u, dx)


class SecondDerivatives(_SpatialOperator):
    """Noise-robust ``(d11, d22, d12)`` = ``(d2/dx2, d2/dy2, d2/dxdy)`` in units of the data per mm^2.

    Shape:
        Input ``(..., H, W)``; output ``(..., 3, H', W')``.
    """

    order = 2

    def __init__(self, size: int = 5, *, border: str = "crop") -> None:
        super().__init__(_kernels("second", size), size=size, border=border)

    def forward(self, u: Tensor, dx: float | Tensor) -> Tensor:
        return self._operate(u, dx)


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
    k = _kernels("laplacian", size, family)
    check_border(border)
    return _spatial(u, dx, k, k.kernels, border, Laplacian.order).squeeze(-3)


def gradient(u: Tensor, dx: float | Tensor, *, size: int = 5, border: str = "crop") -> Tensor:
    """Noise-robust ``(d/dx, d/dy)``. See :class:`Gradient`.

    Shape:
        Input ``(..., H, W)``; output ``(..., 2, H', W')``.
    """
    k = _kernels("gradient", size)
    check_border(border)
    return _spatial(u, dx, k, k.kernels, border, Gradient.order)


def second_derivatives(u: Tensor, dx: float | Tensor, *, size: int = 5, border: str = "crop") -> Tensor:
    """Noise-robust ``(d11, d22, d12)``. See :class:`SecondDerivatives`.

    Shape:
        Input ``(..., H, W)``; output ``(..., 3, H', W')``.
    """
    k = _kernels("second", size)
    check_border(border)
    return _spatial(u, dx, k, k.kernels, border, SecondDerivatives.order)
