"""Separable Gaussian smoothing of frames, as a function and as a layer.

Smoothing the frames before any derivative acts identically on both sides of a linear PDE (convolutions
commute): it lowers the noise without biasing the estimated coefficients.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import torch
from torch import Tensor, nn

from anra_torch.layers import stencils
from anra_torch.layers.correlate import (
    check_border,
    check_spatial,
    correlate1d,
    correlate1d_adjoint,
    pad_frames,
)

__all__ = ["GaussianSmoothing", "gaussian_smooth"]

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


def _slices(taps: Tensor, u: Tensor) -> bool:
    """Shifted slices (cost ~ taps per pixel) or banded matrix products (cost ~ frame side per pixel, but
    BLAS-fast): slices for short kernels and for frames much wider than the kernel."""
    return taps.numel() <= _SLICE_TAPS or max(u.shape[-2:]) > _BANDED_SIDES * taps.numel()


def _smooth(u: Tensor, taps: Tensor, border: str, matrix: Callable[[int], Tensor]) -> Tensor:
    """Correlate ``(..., H, W)`` with ``taps`` along W and H after padding by ``border``;
    ``matrix(n)`` gives the banded matrix of a side of ``n`` px (on ``u``'s device and dtype)."""
    check_spatial(u, taps.numel(), border)
    u = pad_frames(u, (taps.numel() - 1) // 2, border)
    if _slices(taps, u):
        values = taps.tolist()
        return correlate1d(correlate1d(u, values, -1), values, -2)
    lead, (h, w) = u.shape[:-2], u.shape[-2:]
    mx, my = matrix(w), matrix(h)
    rows = (u.reshape(-1, w) @ mx).reshape(-1, h, mx.shape[1])
    cols = rows.transpose(1, 2).reshape(-1, h) @ my
    return cols.reshape(-1, mx.shape[1], my.shape[1]).transpose(1, 2).reshape(*lead, my.shape[1], mx.shape[1])


@lru_cache(maxsize=64)
def _taps(sigma: float, truncate: float, dtype: torch.dtype) -> Tensor:
    """The Gaussian's taps in ``dtype`` (on the CPU), built once per configuration."""
    return stencils.gaussian_taps(sigma, truncate=truncate).to(dtype)


@lru_cache(maxsize=64)
def _matrix(sigma: float, truncate: float, n: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """The banded matrix of :func:`_banded` for :func:`gaussian_smooth`, built once per configuration."""
    return _banded(_taps(sigma, truncate, dtype).to(device), n)


def gaussian_smooth(u: Tensor, sigma: float, *, border: str = "crop") -> Tensor:
    """Separable Gaussian smoothing, ``sigma`` in pixels (0 is the identity); see :class:`GaussianSmoothing`.

    Shape:
        Input ``(..., H, W)``; output ``(..., H - 2r, W - 2r)`` for ``"crop"``.

    Raises:
        ValueError: ``sigma`` negative or not finite, an unknown ``border``, frames too small for the kernel.
    """
    check_border(border)
    sigma, truncate = float(sigma), 3.5
    dtype = u.dtype if u.is_floating_point() else torch.get_default_dtype()
    taps = _taps(sigma, truncate, dtype)
    if taps.numel() == 1:
        return u
    return _smooth(u, taps, border, lambda n: _matrix(sigma, truncate, n, dtype, u.device))


class GaussianSmoothing(nn.Module):
    """Separable Gaussian smoothing over (H, W) with ``sigma`` in pixels (0 is the identity).

    Narrow kernels run as shifted-slice sums, wide ones as two banded matrix products.

    Shape:
        Input ``(..., H, W)``; output ``(..., H - 2r, W - 2r)`` for ``"crop"`` (``r = radius``).
    """

    taps: Tensor

    def __init__(self, sigma: float, *, truncate: float = 3.5, border: str = "crop") -> None:
        super().__init__()
        check_border(border)
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

    def forward(self, u: Tensor) -> Tensor:
        if self.radius == 0:
            return u
        return _smooth(u, self.taps, self.border, lambda n: self._matrix(n, u))

    def adjoint(self, y: Tensor) -> Tensor:
        """Transpose of the ``border='crop'`` smoothing: ``(..., H - 2r, W - 2r) -> (..., H, W)``.

        Raises:
            ValueError: the layer's border is not ``"crop"``.
        """
        if self.border != "crop":
            raise ValueError("adjoint is defined for border='crop'")
        if self.radius == 0:
            return y
        if _slices(self.taps, y):
            taps = self.taps.tolist()
            return correlate1d_adjoint(correlate1d_adjoint(y, taps, -2), taps, -1)
        lead, (h1, w1) = y.shape[:-2], y.shape[-2:]
        h, w = h1 + 2 * self.radius, w1 + 2 * self.radius
        mx, my = self._matrix(w, y), self._matrix(h, y)
        rows = (y.reshape(-1, w1) @ mx.T).reshape(-1, h1, w)
        cols = rows.transpose(1, 2).reshape(-1, h1) @ my.T
        return cols.reshape(-1, w, h).transpose(1, 2).reshape(*lead, h, w)

    def extra_repr(self) -> str:
        return f"sigma={self.sigma:g}, radius={self.radius}, border={self.border!r}"
