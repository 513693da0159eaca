"""The matched filters of the PDE balance and the term bank they produce.

ANRA balances ``dT/dt = a Lap T (+ effect terms)`` on the measured frames. Every term passes through the
SAME filters, so a linear PDE stays exact for the filtered field and the filters lower noise without
biasing the coefficients:

* in time, the Holoborodko derivative ``D_t`` for the left side and its partner average ``S_t`` (same
  centre: no time misalignment) for every right-side term;
* in space, one Gaussian ``G`` (sigma in px) on everything, then the spatial operator of each term, and
  the Laplacian's built-in smoothing (its partner ``P``) on the terms without a derivative.

The built-in terms (:data:`TERMS`), for centred frames ``T`` (the caller subtracts a reference ``Tbar``):

========  =======================================  =====================================================
name      definition                               used by
========  =======================================  =====================================================
``U``     ``P G D_t T``  (data units / s)          every balance: the left side
``L``     ``Lap G S_t T`` (data units / mm^2)      every balance: ``a Lap T``
``T``     ``P G S_t T``                            loss ``- b (T - T_ref)``
``1``     ones                                     loss (its constant)
``T_x``   ``d/dx G S_t T``                         advection
``T_y``   ``d/dy G S_t T``                         advection
``D``     ``(d_xx - d_yy) G S_t T``                anisotropy
``T_xy``  ``d_xy G S_t T``                         anisotropy
``N``     ``Lap G S_t T^2 / 2``                    temperature-dependent diffusivity
========  =======================================  =====================================================

Each term's noise is known from the filters' impulse responses (:meth:`MatchedFilters.impulse_responses`):
a linear term's noise is the sensor noise through its own kernel; ``N``'s is linearised as ``T`` times
``L``'s. :mod:`anra_torch.balance.moments` turns them into the errors-in-variables corrections.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from anra_torch.balance.noise_model import NoiseModel
from anra_torch.layers import GaussianSmoothing, Gradient, Laplacian, SecondDerivatives, TimeDerivative

__all__ = ["TERMS", "MatchedFilters", "TermSpec"]

_F64 = torch.float64


class _Stages:
    """Filtered fields of one video (or batch), computed once and shared by the terms that need them."""

    def __init__(
        self,
        filters: MatchedFilters,
        rate: Tensor,
        average: Tensor,
        dx: float | Tensor,
        *,
        smoothed: bool = False,
    ) -> None:
        self.filters, self.dx = filters, dx
        self.rate, self.average = rate, average
        self.square_source: Tensor | None = None  # S_t (T^2 / 2), set when N is asked for
        if smoothed:  # G came first (it commutes with the time filters): one spatial pass, not two
            self.__dict__["smooth_rate"], self.__dict__["smooth_average"] = rate, average

    @cached_property
    def smooth_rate(self) -> Tensor:
        return self.filters.smoother(self.rate)

    @cached_property
    def smooth_average(self) -> Tensor:
        return self.filters.smoother(self.average)

    @cached_property
    def gradient(self) -> Tensor:
        return self.filters.gradient(self.smooth_average, self.dx)

    @cached_property
    def second(self) -> Tensor:
        return self.filters.second(self.smooth_average, self.dx)


@dataclass(frozen=True)
class TermSpec:
    """One term of the bank.

    Attributes:
        build: ``stages -> term``.
        time_order: power of ``1/dt`` in the term's unit (1 for ``U``).
        space_order: power of ``1/dx`` (2 for ``L``).
        noise_kernel: the term whose impulse response carries this term's noise (itself for a linear
            term, ``"L"`` for ``N``), or None for a term without noise (``1``).
        noise_weight: for a term whose noise is ``weight`` times ``noise_kernel``'s (``N``: ``T``), the
            name of the weighting term.
    """

    build: Callable[[_Stages], Tensor]
    time_order: int = 0
    space_order: int = 0
    noise_kernel: str | None = None
    noise_weight: str | None = None


def _square(stages: _Stages) -> Tensor:
    f = stages.filters
    assert stages.square_source is not None  # set by MatchedFilters.terms when N is requested
    return f.laplacian(f.smoother(stages.square_source), stages.dx)


TERMS: dict[str, TermSpec] = {
    "U": TermSpec(lambda s: s.filters.laplacian.partner(s.smooth_rate), time_order=1, noise_kernel="U"),
    "L": TermSpec(lambda s: s.filters.laplacian(s.smooth_average, s.dx), space_order=2, noise_kernel="L"),
    "T": TermSpec(lambda s: s.filters.laplacian.partner(s.smooth_average), noise_kernel="T"),
    "1": TermSpec(lambda s: torch.ones_like(s.filters.laplacian.partner(s.smooth_average))),
    "T_x": TermSpec(lambda s: s.gradient.select(-3, 0), space_order=1, noise_kernel="T_x"),
    "T_y": TermSpec(lambda s: s.gradient.select(-3, 1), space_order=1, noise_kernel="T_y"),
    "D": TermSpec(lambda s: s.second.select(-3, 0) - s.second.select(-3, 1), space_order=2, noise_kernel="D"),
    "T_xy": TermSpec(lambda s: s.second.select(-3, 2), space_order=2, noise_kernel="T_xy"),
    "N": TermSpec(_square, space_order=2, noise_kernel="L", noise_weight="T"),
}
"""The built-in term bank (module docs); an effect with a fitted shape adds its own term on the same grid."""


class MatchedFilters(nn.Module):
    """The filters shared by both sides of the PDE balance; ``terms`` computes the term bank.

    Args:
        sigma: spatial Gaussian sigma in px (0: none).
        time_family: Holoborodko time family (``"smooth"``, ``"centred"``, ``"hybrid"``).
        time_length: time window in frames.
        laplacian_size: size of the Laplacian (and of the gradient and second derivatives).
        laplacian_family: ``"central"`` or ``"holoborodko"`` (see :mod:`anra_torch.layers.stencils`).
        border: border of the spatial operators (``"crop"`` or a padding mode).
        smoothing_border: border of the Gaussian (default ``border``).

    Shape:
        ``terms``: centred frames ``(B, T, H, W)`` or ``(T, H, W)``; each term ``(B, K, h, w)`` (or
        ``(K, h, w)``) with ``K = T - time_length + 1`` and ``h = H - 2 margin`` for cropping borders.
    """

    def __init__(
        self,
        sigma: float = 0.0,
        *,
        time_family: str = "smooth",
        time_length: int = 5,
        laplacian_size: int = 5,
        laplacian_family: str = "central",
        border: str = "crop",
        smoothing_border: str | None = None,
    ) -> None:
        super().__init__()
        self.time = TimeDerivative(time_family, time_length)
        self.smoother = GaussianSmoothing(
            sigma, border=border if smoothing_border is None else smoothing_border
        )
        self.laplacian = Laplacian(laplacian_size, family=laplacian_family, border=border)
        self.gradient = Gradient(laplacian_size, border=border)
        self.second = SecondDerivatives(laplacian_size, border=border)
        self._inner: dict[tuple[str, ...], Tensor] = {}
        self._spectral: dict[tuple, tuple[Tensor, Tensor]] = {}  # transfers by frame size, device, dtype

    @property
    def sigma(self) -> float:
        """The Gaussian sigma in px."""
        return self.smoother.sigma

    @property
    def reach(self) -> int:
        """Pixels on each side that an output pixel's value depends on (the filters' half support)."""
        return self.smoother.radius + self.laplacian.support // 2

    @property
    def margin(self) -> int:
        """Pixels lost on each side (0 for padding borders)."""
        crop = (self.smoother.radius if self.smoother.border == "crop" else 0) + (
            self.laplacian.support // 2 if self.laplacian.border == "crop" else 0
        )
        return crop

    def time_stage(self, frames: Tensor, dt: float | Tensor) -> tuple[Tensor, Tensor]:
        """``(D_t T, S_t T)`` of centred frames: the time filtering, shared by every smoothing.

        Shape:
            ``(B, T, H, W)`` -> two ``(B, K, H, W)``.
        """
        return self.time.with_average(frames, dt)

    def smoothed_stage(self, frames: Tensor, dt: float | Tensor) -> tuple[Tensor, Tensor]:
        """``(G D_t T, G S_t T)``: the Gaussian on the frames first, then the time filtering. One spatial
        pass over ``T`` frames instead of two over ``K`` (the filters commute); pass it to :meth:`terms`
        with ``smoothed=True``.

        Shape:
            ``(B, T, H, W)`` -> two ``(B, K, H - 2r, W - 2r)`` (``r`` the Gaussian's radius, crop border).
        """
        return self.time.with_average(self.smoother(frames).contiguous(), dt)

    def terms(
        self,
        frames: Tensor | None,
        dt: float | Tensor,
        dx: float | Tensor,
        names: Sequence[str],
        *,
        time_stage: tuple[Tensor, Tensor] | None = None,
        smoothed: bool = False,
    ) -> dict[str, Tensor]:
        """The named terms of centred ``frames`` (or of a precomputed :meth:`time_stage`, or with
        ``smoothed`` of a :meth:`smoothed_stage`).

        Raises:
            ValueError: an unknown term name.
        """
        unknown = [n for n in names if n not in TERMS]
        if unknown:
            raise ValueError(f"unknown balance term {unknown[0]!r}; expected one of: {', '.join(TERMS)}")
        if time_stage is None:
            assert frames is not None
            time_stage = self.time_stage(frames, dt)
        stages = _Stages(self, *time_stage, dx, smoothed=smoothed)
        if "N" in names:
            assert frames is not None, "N needs the frames (it is not linear in them)"
            stages.square_source = self.time.average(0.5 * frames * frames)
        return {name: TERMS[name].build(stages) for name in names}

    def impulse_responses(self, names: Sequence[str]) -> Tensor:
        """Space-time impulse responses of the named terms at one output point, unit ``dt`` and ``dx``.

        Their inner products are the noise covariances per output point for unit white noise. A term
        whose noise is carried by another's kernel (``N``) gets that kernel; a noiseless one zeros.

        Shape:
            ``(P, L, S, S)`` with ``S = 2 reach + 1``, float64.
        """
        side = 2 * self.reach + 1
        with torch.enable_grad():
            probe = torch.zeros(self.time.length, side, side, dtype=_F64, device="cpu", requires_grad=True)
            kernels = sorted({TERMS[n].noise_kernel for n in names} - {None})
            out = self.terms(probe, 1.0, 1.0, kernels)
            responses = {}
            for name, term in out.items():
                h, w = term.shape[-2:]
                (grad,) = torch.autograd.grad(term[0, h // 2, w // 2], probe, retain_graph=True)
                responses[name] = grad.detach()
        zero = torch.zeros(self.time.length, side, side, dtype=_F64, device="cpu")
        return torch.stack([responses.get(TERMS[n].noise_kernel, zero) for n in names])

    def noise_inner(self, names: Sequence[str]) -> Tensor:
        """``<k_a, k_b>`` of the named terms' impulse responses for unit ``dt`` and ``dx`` (cached).

        Multiply by the noise variance and by :meth:`spacing_factor` for the noise covariance per point.

        Shape:
            ``(P, P)`` float64.
        """
        key = tuple(names)
        if key not in self._inner:
            k = self.impulse_responses(names).flatten(1)
            self._inner[key] = k @ k.T
        return self._inner[key]

    def noise_covariance(
        self,
        names: Sequence[str],
        variance: float | Tensor,
        dt: float | Tensor,
        dx: float | Tensor,
        *,
        noise: NoiseModel | None = None,
        within: Sequence[str] = (),
        extent: tuple[int, int] | None = None,
    ) -> Tensor:
        """Noise covariance per output point of the named terms.

        ``variance <k_a, k_b>`` with each impulse response in physical units (``1/dt`` per time
        derivative, ``1/dx`` per space derivative of the term carrying the noise) for white noise;
        ``variance <k_a, R k_b>`` with the correlation ``R`` of a correlated ``noise`` model; and, when the
        terms are taken ``within`` pixels (each pixel's mean over ``extent[0]`` frames removed) and/or
        frames (each frame's mean over ``extent[1]`` pixels removed), the noise those means carry away is
        removed too (from the cross-correlations of the impulse responses at every time lag, and their sums
        over space).

        Shape:
            ``variance``, ``dt``, ``dx`` numbers or ``(B,)``; output ``(P, P)`` or ``(B, P, P)``.
        """
        correlated = noise is not None and not noise.white
        inner = (
            self.noise_inner(names)
            if not (correlated or within)
            else self._inner_within(names, noise if correlated else None, within, extent)
        )
        carriers = [TERMS[TERMS[n].noise_kernel or n] for n in names]
        t = torch.tensor([c.time_order for c in carriers], dtype=_F64, device="cpu")
        x = torch.tensor([c.space_order for c in carriers], dtype=_F64, device="cpu")
        t_pairs, x_pairs = t[:, None] + t[None, :], x[:, None] + x[None, :]
        batched = any(isinstance(v, Tensor) and v.ndim > 0 for v in (variance, dt, dx))
        if not batched:
            return float(variance) * inner / (float(dt) ** t_pairs * float(dx) ** x_pairs)

        # On the spacings' device (the batch's): the inner products are data on the CPU.
        device = next(v.device for v in (variance, dt, dx) if isinstance(v, Tensor) and v.ndim > 0)

        def per_video(v: float | Tensor) -> Tensor:
            return torch.as_tensor(v, dtype=_F64, device=device).reshape(-1, 1, 1)

        inner, t_pairs, x_pairs = inner.to(device), t_pairs.to(device), x_pairs.to(device)
        return per_video(variance) * inner / (per_video(dt) ** t_pairs * per_video(dx) ** x_pairs)

    def _inner_within(
        self,
        names: Sequence[str],
        noise: NoiseModel | None,
        within: Sequence[str],
        extent: tuple[int, int] | None,
    ) -> Tensor:
        """``<k_a, R k_b>`` per point after the within transforms, unit spacing, ``(P, P)``."""
        if within and extent is None:
            raise ValueError("extent=(frames, pixels) is needed to correct the noise for fixed effects")
        m = len(noise.time_corr) if noise is not None else 0
        r = noise.space_kernel().numel() // 2 if noise is not None else 0
        kernels = F.pad(self.impulse_responses(names), (r, r, r, r, m, m))  # (P, L', S', S')
        correlated = noise.correlate(kernels) if noise is not None else kernels
        flat_a, flat_b = kernels.flatten(1), correlated.flatten(1)
        inner = flat_a @ flat_b.T
        frames, pixels = extent if extent is not None else (1, 1)
        if "pixel" in within:  # E[mean over the pixel's frames] products: all time lags
            length = kernels.shape[1]
            for lag in range(1 - length, length):
                a = kernels[:, max(0, -lag) : length - max(0, lag)].flatten(1)
                b = correlated[:, max(0, lag) : length - max(0, -lag)].flatten(1)
                inner = inner - (1.0 - abs(lag) / frames) / frames * (a @ b.T)
        if "frame" in within:  # E[mean over the frame's pixels] products: all space lags at equal time
            a, b = kernels.sum((-2, -1)), correlated.sum((-2, -1))
            inner = inner - (a @ b.T) / pixels
        if "pixel" in within and "frame" in within:
            inner = inner + (kernels.flatten(1).sum(1)[:, None] * correlated.flatten(1).sum(1)[None]) / (
                frames * pixels
            )
        return inner

    def adjoint(self, levers: dict[str, Tensor], dt: float | Tensor, dx: float | Tensor) -> Tensor:
        """``A^T``: the sum over the named terms of their transposed filters applied to each lever.

        Exact for the linear terms ``U``, ``L`` and ``T`` with ``border="crop"``: pushes output-space
        weights back onto the frames, so that ``sum_j <lever_j, term_j(frames)> = <adjoint, frames>``.
        The standard error of a linear statistic of the terms is the noise model applied to it.

        Shape:
            levers ``(B, K, h, w)``; output ``(B, T, H, W)``.

        Raises:
            ValueError: a term without an explicit adjoint here (use
                :func:`anra_torch.balance.moments.pushback` through the autograd graph).
        """
        unknown = [n for n in levers if n not in ("U", "L", "T")]
        if unknown:
            raise ValueError(f"no explicit adjoint for term {unknown[0]!r}; push it back through autograd")
        # The time adjoint first, then one transposed Gaussian for both sides (they commute).
        rate_back = average_back = None
        if "U" in levers:
            rate_back = self.laplacian.partner.adjoint(levers["U"], 1.0)
        for name in ("L", "T"):
            if name in levers:
                op = self.laplacian if name == "L" else self.laplacian.partner
                back = op.adjoint(levers[name], dx if name == "L" else 1.0)
                average_back = back if average_back is None else average_back + back
        some = rate_back if rate_back is not None else average_back
        assert some is not None
        zero = torch.zeros_like(some)
        return self.smoother.adjoint(
            self.time.adjoint(
                zero if rate_back is None else rate_back, zero if average_back is None else average_back, dt
            )
        )

    def extra_repr(self) -> str:
        return f"sigma={self.sigma:g}, margin={self.margin}"
