"""Holoborodko smooth noise-robust differentiators, built from binomial data rather than transcribed.

Every kernel here is a pure function of its size. Taps are in *correlation order* (increasing offset:
oldest frame first in time, left to right / top to bottom in space) and are for unit spacing: the layers in
:mod:`anra_torch.layers.derivatives` divide by ``dt`` or ``dx**order``.

The families (P. Holoborodko, *Smooth noise robust differentiators*, 2008, holoborodko.com; what they
are exact on and how they are tested: ``docs/architecture.md``), with ``B_n = binomial(n) / 2**n``:

* centred first derivative ``D1_N = [-1, 0, 1]/2 * B_{N-3}`` (exact on 1, x, x^2; zero at Nyquist);
* centred second derivative ``D2_N = [1, 0, -2, 0, 1]/4 * B_{N-5}`` (exact on 1..x^3; zero at Nyquist),
  and the plain ``[1, -2, 1]`` for ``N = 3``;
* one-sided hybrid differentiators (exact on 1, x, x^2 at the newest frame, no delay), from a table;
* 2D masks: gradient ``D1_N (x) B_{N-3}``, second derivatives ``D2_N (x) B_{N-3}``, mixed ``D1_N (x) D1_N``
  and the Laplacian ``D2_N (x) B_{N-3} + transpose``.

Each family is a registry entry (data), not a branch.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = [
    "TimeStencil",
    "TIME_FAMILIES",
    "SPATIAL_SIZES",
    "binomial",
    "first_derivative_taps",
    "second_derivative_taps",
    "time_stencil",
    "gradient_kernels",
    "second_derivative_kernels",
    "laplacian_kernel",
    "LAPLACIAN_FAMILIES",
    "laplacian_partner",
    "central_second_derivative_taps",
    "gaussian_taps",
]

_DTYPE = torch.float64


def binomial(n: int) -> Tensor:
    """Binomial smoothing taps ``B_n = binomial(n, k) / 2**n``, ``n + 1`` taps summing to 1.

    Shape:
        Output ``(n + 1,)``, float64.
    """
    if n < 0:
        raise ValueError(f"binomial order must be >= 0, got {n}")
    return torch.tensor([math.comb(n, k) for k in range(n + 1)], dtype=_DTYPE, device="cpu") / 2**n


def _convolve(a: Tensor, b: Tensor) -> Tensor:
    """Full 1D convolution of two tap vectors (commutative; symmetric factors keep correlation order)."""
    n = a.numel() + b.numel() - 1
    out = torch.zeros(n, dtype=_DTYPE, device="cpu")
    for i, ai in enumerate(a.tolist()):
        out[i : i + b.numel()] += ai * b
    return out


def first_derivative_taps(n: int) -> Tensor:
    """Centred smooth first-derivative taps ``D1_n`` for unit spacing, oldest/leftmost first.

    ``n = 3`` is the central difference; larger odd or even ``n`` add binomial smoothing ``B_{n-3}``.
    Exact on 1, x, x^2 about the window centre ``(n - 1) / 2``; zero response at Nyquist.

    Shape:
        Output ``(n,)``, float64.

    Example:
        >>> (first_derivative_taps(5) * 8).tolist()
        [-1.0, -2.0, 0.0, 2.0, 1.0]
    """
    if n < 3:
        raise ValueError(f"first-derivative length must be >= 3, got {n}")
    return _convolve(torch.tensor([-0.5, 0.0, 0.5], dtype=_DTYPE, device="cpu"), binomial(n - 3))


def second_derivative_taps(n: int) -> Tensor:
    """Centred smooth second-derivative taps ``D2_n`` for unit spacing (odd ``n >= 3``).

    ``n = 3`` is the plain ``[1, -2, 1]`` (no Nyquist zero); ``n >= 5`` is ``[1, 0, -2, 0, 1]/4 * B_{n-5}``,
    exact on 1..x^3 with a zero at Nyquist.

    Shape:
        Output ``(n,)``, float64.
    """
    if n < 3 or n % 2 == 0:
        raise ValueError(f"second-derivative size must be odd and >= 3, got {n}")
    if n == 3:
        return torch.tensor([1.0, -2.0, 1.0], dtype=_DTYPE, device="cpu")
    base = torch.tensor([0.25, 0.0, -0.5, 0.0, 0.25], dtype=_DTYPE, device="cpu")
    return _convolve(base, binomial(n - 5))


# One-sided hybrid differentiators (Holoborodko), taps NEWEST FIRST as published, denominators separate.
_HYBRID_TABLE: dict[int, tuple[tuple[int, ...], int]] = {
    4: ((2, -1, -2, 1), 2),
    5: ((7, 1, -10, -1, 3), 10),
    6: ((16, 1, -10, -10, -6, 9), 28),
    7: ((12, 5, -8, -6, -10, 1, 6), 28),
    8: ((22, 7, -6, -11, -14, -9, -2, 13), 60),
}


@dataclass(frozen=True)
class TimeStencil:
    """A time differentiator and the temporal average its spatial partner must use.

    Attributes:
        family: registry name (``"smooth"``, ``"centred"``, ``"hybrid"``).
        taps: derivative taps for unit ``dt``, oldest frame first, shape ``(L,)``.
        pair: temporal smoothing with the same centre, applied to the spatial terms so both sides of
            the PDE see the same time filter, shape ``(L,)``, sums to 1.
        centre: position (in frames after the oldest frame of the window) where the derivative applies.
        exact_degree: highest polynomial degree differentiated exactly at ``centre``.
    """

    family: str
    taps: Tensor
    pair: Tensor
    centre: float
    exact_degree: int

    @property
    def length(self) -> int:
        """Window length ``L`` in frames."""
        return int(self.taps.numel())

    @property
    def delay(self) -> float:
        """Frames between the newest frame of the window and the instant the estimate applies."""
        return (self.length - 1) - self.centre


def _smooth_stencil(length: int) -> TimeStencil:
    # D1_L = central difference * B_{L-3}; its spatial partner is B_{L-3} on the same centre.
    pair = torch.zeros(length, dtype=_DTYPE, device="cpu")
    pair[1 : length - 1] = binomial(length - 3)
    return TimeStencil("smooth", first_derivative_taps(length), pair, (length - 1) / 2, 2)


def _centred_stencil(length: int) -> TimeStencil:
    # The same taps used symmetrically about the frame they estimate (offline use, odd lengths).
    if length % 2 == 0:
        raise ValueError(f"the centred time family needs an odd length, got {length}")
    smooth = _smooth_stencil(length)
    return TimeStencil("centred", smooth.taps, smooth.pair, smooth.centre, smooth.exact_degree)


def _hybrid_stencil(length: int) -> TimeStencil:
    if length not in _HYBRID_TABLE:
        raise ValueError(f"hybrid time family has lengths {sorted(_HYBRID_TABLE)}, got {length}")
    newest_first, denominator = _HYBRID_TABLE[length]
    taps = torch.tensor(newest_first[::-1], dtype=_DTYPE, device="cpu") / denominator
    pair = torch.zeros(length, dtype=_DTYPE, device="cpu")
    pair[-1] = 1.0
    return TimeStencil("hybrid", taps, pair, float(length - 1), 2)


TIME_FAMILIES: dict[str, Callable[[int], TimeStencil]] = {
    "smooth": _smooth_stencil,
    "centred": _centred_stencil,
    "hybrid": _hybrid_stencil,
}
"""Registry of time-differentiator families: name -> builder taking the window length."""


def time_stencil(family: str = "smooth", length: int = 5) -> TimeStencil:
    """Build a time differentiator of the named family.

    Args:
        family: ``"smooth"`` (one-sided causal use of the centred taps, delay ``(L-1)/2``),
            ``"centred"`` (odd ``L``, same taps used symmetrically), or ``"hybrid"`` (no delay, L = 4..8).
        length: window length ``L`` in frames.

    Raises:
        ValueError: unknown family or unsupported length.
    """
    if family not in TIME_FAMILIES:
        raise ValueError(f"unknown time family {family!r}; expected one of: {', '.join(TIME_FAMILIES)}")
    if not isinstance(length, int) or length < 3:
        raise ValueError(f"time filter length must be an integer >= 3, got {length!r}")
    return TIME_FAMILIES[family](length)


SPATIAL_SIZES: tuple[int, ...] = (3, 5, 7, 9, 11)
"""Supported spatial kernel sizes ``N`` (the long side of each mask)."""


def _check_size(size: int) -> None:
    if size not in SPATIAL_SIZES:
        raise ValueError(f"spatial kernel size must be one of {SPATIAL_SIZES}, got {size!r}")


def _embed(kernel: Tensor, size: int) -> Tensor:
    """Zero-pad a (h, w) kernel to (size, size), keeping it centred."""
    h, w = kernel.shape
    out = torch.zeros(size, size, dtype=_DTYPE, device="cpu")
    top, left = (size - h) // 2, (size - w) // 2
    out[top : top + h, left : left + w] = kernel
    return out


def gradient_kernels(size: int = 5) -> Tensor:
    """Holoborodko 2D gradient masks ``(d/dx, d/dy)`` for unit spacing.

    ``d/dx = outer(B_{N-3} along y, D1_N along x)``; ``d/dy`` is its transpose. Zero on the Nyquist border.

    Shape:
        Output ``(2, N, N)`` (x first), float64.
    """
    _check_size(size)
    ddx = _embed(torch.outer(binomial(size - 3), first_derivative_taps(size)), size)
    return torch.stack([ddx, ddx.T.contiguous()])


def second_derivative_kernels(size: int = 5) -> Tensor:
    """Noise-robust 2D second-derivative masks ``(d11, d22, d12)`` for unit spacing.

    ``d11 = d^2/dx^2 = outer(B_{N-3} along y, D2_N along x)``, ``d22`` its transpose and
    ``d12 = outer(D1_N along y, D1_N along x)``. Exact on polynomials of total degree <= 3.

    Shape:
        Output ``(3, N, N)``, float64.
    """
    _check_size(size)
    d11 = _embed(torch.outer(binomial(size - 3), second_derivative_taps(size)), size)
    d1 = first_derivative_taps(size)
    d12 = torch.outer(d1, d1)
    return torch.stack([d11, d11.T.contiguous(), d12])


def central_second_derivative_taps(size: int) -> Tensor:
    """Maximal-order central second difference on ``size`` (odd) points, for unit spacing.

    Exact on polynomials up to degree ``size`` (order ``size - 1`` accuracy): 3 -> ``[1, -2, 1]``,
    5 -> ``[-1, 16, -30, 16, -1] / 12``. No noise suppression: meant for fields already smoothed, where
    accuracy at low wavenumbers is what counts.

    Shape:
        Output ``(size,)``, float64.
    """
    if size < 3 or size % 2 == 0:
        raise ValueError(f"central second difference needs an odd size >= 3, got {size}")
    offsets = torch.arange(size, dtype=_DTYPE, device="cpu") - size // 2
    powers = torch.stack([offsets**p for p in range(size)])
    rhs = torch.zeros(size, dtype=_DTYPE, device="cpu")
    rhs[2] = 2.0
    return torch.linalg.solve(powers, rhs)


def _holoborodko_laplacian(size: int) -> Tensor:
    d = second_derivative_kernels(size)
    return d[0] + d[1]


def _holoborodko_partner(size: int) -> Tensor:
    # D2_N (x) B_{N-3} + B_{N-3} (x) D2_N == (5-point Laplacian) o (B_{N-3} (x) B_{N-3}) exactly, since
    # D2_N = [1, -2, 1] * B_{N-3}: the Holoborodko Laplacian is the 5-point one of a smoothed field.
    _check_size(size)
    b = binomial(size - 3)
    return _embed(torch.outer(b, b), size)


def _identity_partner(size: int) -> Tensor:
    _check_size(size)
    return _embed(torch.ones(1, 1, dtype=_DTYPE, device="cpu"), size)


def _central_laplacian(size: int) -> Tensor:
    _check_size(size)
    kernel = torch.zeros(size, size, dtype=_DTYPE, device="cpu")
    taps = central_second_derivative_taps(size)
    kernel[size // 2, :] += taps
    kernel[:, size // 2] += taps
    return kernel


LAPLACIAN_FAMILIES: dict[str, tuple[Callable[[int], Tensor], Callable[[int], Tensor]]] = {
    "holoborodko": (_holoborodko_laplacian, _holoborodko_partner),
    "central": (_central_laplacian, _identity_partner),
}
"""Registry of Laplacian families, name -> (kernel builder, partner builder): ``"holoborodko"``
(noise-robust, zero at Nyquist) and ``"central"`` (maximal-order cross, most accurate at low wavenumbers;
for pre-smoothed fields). The partner is the smoothing built into the Laplacian, see
:func:`laplacian_partner`."""


def _laplacian_family(family: str) -> tuple[Callable[[int], Tensor], Callable[[int], Tensor]]:
    if family not in LAPLACIAN_FAMILIES:
        raise ValueError(
            f"unknown Laplacian family {family!r}; expected one of: {', '.join(LAPLACIAN_FAMILIES)}"
        )
    return LAPLACIAN_FAMILIES[family]


def laplacian_partner(size: int = 5, family: str = "holoborodko") -> Tensor:
    """The smoothing built into a Laplacian, for the other side of the PDE.

    The Holoborodko Laplacian of size N equals the 5-point Laplacian applied after a binomial smoothing
    ``B_{N-3} (x) B_{N-3}``; applying that same smoothing to dT/dt keeps ``dT/dt = a Lap T`` exact for the
    smoothed field, so the Laplacian's smoothing costs no bias. Central Laplacians have the identity.

    Shape:
        Output ``(N, N)``, float64, sums to 1, same centre as :func:`laplacian_kernel`.
    """
    return _laplacian_family(family)[1](size)


def laplacian_kernel(size: int = 5, family: str = "holoborodko") -> Tensor:
    """Laplacian ``d11 + d22`` for unit spacing.

    ``"holoborodko"``: ``D2_N (x) B_{N-3} + transpose``, exact on total degree <= 3, zero on the whole
    Nyquist border for ``N >= 5`` (``N = 3`` is the 5-point stencil). ``"central"``: the maximal-order
    central cross, exact on degree <= N in each variable.

    Shape:
        Output ``(N, N)``, float64.

    Example:
        >>> (laplacian_kernel(5) * 16).int().tolist()[2]
        [2, -2, -8, -2, 2]
    """
    return _laplacian_family(family)[0](size)


def gaussian_taps(sigma: float, *, truncate: float = 3.5) -> Tensor:
    """Sampled, normalised Gaussian smoothing taps with standard deviation ``sigma`` (pixels or frames).

    ``sigma = 0`` returns the identity ``[1.0]``. Radius ``ceil(truncate * sigma)``.

    Shape:
        Output ``(2 r + 1,)``, float64, sums to 1.
    """
    if not math.isfinite(sigma) or sigma < 0:
        raise ValueError(f"smoothing sigma must be a finite number >= 0 (pixels), got {sigma!r}")
    if sigma == 0:
        return torch.ones(1, dtype=_DTYPE, device="cpu")
    radius = math.ceil(truncate * sigma)
    offsets = torch.arange(-radius, radius + 1, dtype=_DTYPE, device="cpu")
    taps = torch.exp(-0.5 * (offsets / sigma) ** 2)
    return taps / taps.sum()
