"""The lateral conduction of a flash recording: local quadratic derivatives and the lateral diffusivities.

An intact plate's surface after a flash, whatever the flash's pattern, is ``S(x, y, t) theta(t)``: ``S``
spreads laterally by ``dS/dt = a_x S_xx + a_y S_yy + 2 a_xy S_xy`` and ``theta`` is the depth factor of
:mod:`~anra_torch.flash.cooling`. So

    d ln u / dt = (a_x u_xx + a_y u_yy + 2 a_xy u_xy) / u + d ln theta / dt,      u = T - T_ref,

and the lateral part, integrated over time (:func:`lateral_integrals`), can be taken off ``ln u`` before
the depth is fitted; a non-uniform flash and the anisotropy then do not read as a change of depth.

- :func:`local_quadratic`: a quadratic fitted around every pixel with Gaussian weights over the pixels of
  the frame (truncated at its edges, not padded): the smoothed value and the second derivatives, exact
  for any quadratic field, at the edges too.
- :func:`gaussian_derivatives`: the frames smoothed by a Gaussian and the smoothed frames' exact second
  derivatives (the same smoothing on both sides of the heat equation), valid away from the edges.
- :func:`fit_lateral`: ``(a_x, a_y, a_xy)`` from the increments of ``ln u`` over blocks of frames that
  grow geometrically; within a region of equal depth the depth factor is common to its pixels and drops
  out of the increments' differences between pixels. Late blocks' regressors are mostly noise: their
  expected noise parts are taken off the normal equations (errors in variables).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as nnf
from torch import Tensor

__all__ = [
    "fit_lateral",
    "lateral_integrals",
    "local_quadratic",
    "gaussian_derivatives",
    "gaussian_noise_covariance",
    "value_noise_gain",
]

_MONOMIALS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))  # powers of (x, y) in pixels
_CUBIC = ((3, 0), (2, 1), (1, 2), (0, 3))
_CHUNK = 64  # frames filtered at once
_STOP_CHI2 = 3.0  # a block whose residual is this many times its noise, ...
_STOP_R2 = 0.8  # ... and explains less than this share of its increments, ends the fit
_LATER_R2 = 0.5  # a run from a later block explains at least this share of its increments
RATIO = 1.25


def _weights(sigma: float, powers: int, like: Tensor) -> tuple[Tensor, int]:
    radius = int(math.ceil(3 * sigma))
    offsets = torch.arange(-radius, radius + 1, dtype=like.dtype, device=like.device)
    gauss = torch.exp(-(offsets**2) / (2 * sigma**2))
    return torch.stack([gauss * offsets**p for p in range(powers)]), radius


def _correlate(x: Tensor, taps: Tensor, radius: int, dim: int) -> Tensor:
    """``x`` ``(N, H, W)`` correlated with ``taps`` along ``dim`` (-1: W, -2: H), zero outside."""
    kernel = taps.view(1, 1, 1, -1) if dim == -1 else taps.view(1, 1, -1, 1)
    padding = (0, radius) if dim == -1 else (radius, 0)
    return nnf.conv2d(x[:, None], kernel, padding=padding)[:, 0]


def _inverse_gram(
    sigma: float, shape: tuple[int, int], like: Tensor, monomials: tuple[tuple[int, int], ...] = _MONOMIALS
) -> Tensor:
    """Rows (value, xx, yy, xy) of each pixel's inverse weighted Gram matrix of the monomials,
    ``(4, M, H, W)``."""
    top = 2 * max(a + b for a, b in monomials) + 1
    taps, radius = _weights(sigma, top, like)
    ones = torch.ones((1, *shape), dtype=like.dtype, device=like.device)
    along_x = [_correlate(ones, taps[p], radius, -1) for p in range(top)]
    moments = {
        (a, b): _correlate(along_x[a], taps[b], radius, -2)[0] for a in range(top) for b in range(top - a)
    }
    gram = torch.stack(
        [torch.stack([moments[(a + c, b + d)] for c, d in monomials], -1) for a, b in monomials], -2
    )  # (H, W, M, M)
    inverse = torch.linalg.inv(gram)
    return inverse[..., [0, 3, 5, 4], :].permute(2, 3, 0, 1)


def local_quadratic(frames: Tensor, sigma: float, dx: float, *, cubic: bool = False) -> tuple[Tensor, Tensor]:
    """The value and second derivatives of a local quadratic fit with Gaussian weights (``sigma`` px).

    With ``cubic`` the fit also has the cubic monomials: the same value and derivatives where the window
    is whole (odd and even monomials are orthogonal there), without the cubic terms' bias where the frame's
    edge cuts it (one-sided), at more noise there.

    Args:
        frames: ``(T, H, W)``, at least ``3 sigma`` px on each side... any size of at least 3 x 3 px.
        sigma: the weights' standard deviation in px (they reach ``3 sigma``).
        dx: pixel size in mm.

    Returns:
        The fitted value ``(T, H, W)`` and ``(d^2/dx^2, d^2/dy^2, d^2/dxdy)`` in data units per mm^2,
        ``(3, T, H, W)``, x along W; on the frames' device and dtype.
    """
    monomials = _MONOMIALS + _CUBIC if cubic else _MONOMIALS
    inverse = _inverse_gram(sigma, tuple(frames.shape[1:]), frames, monomials)
    taps, radius = _weights(sigma, 4 if cubic else 3, frames)
    scale = frames.new_tensor([1.0, 2 / dx**2, 2 / dx**2, 1 / dx**2]).view(4, 1, 1, 1)
    parts = []
    for chunk in frames.split(_CHUNK):
        along_x = [_correlate(chunk, taps[p], radius, -1) for p in range(len(taps))]
        moments = torch.stack([_correlate(along_x[a], taps[b], radius, -2) for a, b in monomials])
        parts.append(torch.einsum("kmhw,mthw->kthw", inverse, moments) * scale)
    out = torch.cat(parts, 1)
    return out[0], out[1:]


def value_noise_gain(sigma: float) -> float:
    """The standard deviation of :func:`local_quadratic`'s value in the frame's interior over that of
    white noise in the frames."""
    like = torch.zeros((), dtype=torch.float64, device="cpu")
    radius = int(math.ceil(3 * sigma))
    size = 2 * radius + 1
    inverse = _inverse_gram(sigma, (size, size), like)[0, :, radius, radius]  # (6,)
    taps, _ = _weights(sigma, 3, like)
    kernel = sum(inverse[m] * taps[a][None, :] * taps[b][:, None] for m, (a, b) in enumerate(_MONOMIALS))
    return float(kernel.square().sum().sqrt())


def _gaussian_taps(sigma: float, like: Tensor) -> tuple[Tensor, int]:
    """A Gaussian's taps and its first and second derivatives' (px), each exact on polynomials up to its
    order: ``sum g0 = 1``, ``sum k g1 = 1``, ``sum g2 = 0``, ``sum k^2 g2 / 2 = 1``; ``(3, 2 r + 1)``."""
    radius = int(math.ceil(3 * sigma))
    k = torch.arange(-radius, radius + 1, dtype=like.dtype, device=like.device)
    gauss = torch.exp(-(k**2) / (2 * sigma**2))
    g0 = gauss / gauss.sum()
    g1 = k * gauss
    g1 = g1 / (k * g1).sum()
    g2 = (k**2 / sigma**2 - 1) * gauss
    g2 = g2 - g0 * g2.sum()
    g2 = g2 / (k**2 * g2).sum() * 2
    return torch.stack([g0, g1, g2]), radius


_GAUSSIAN_PARTS = ((0, 0), (2, 0), (0, 2), (1, 1))  # (x, y) orders of the value, xx, yy and xy


def gaussian_derivatives(frames: Tensor, sigma: float, dx: float) -> tuple[Tensor, Tensor]:
    """The frames smoothed by a Gaussian (``sigma`` px) and the smoothed frames' second derivatives.

    The smoothing commutes with the heat equation's derivatives (the same kernel on both sides), so the
    smoothed frames obey the same lateral conduction as the frames; valid ``3 sigma`` px from the frame's
    edges (zeros are assumed beyond them).

    Returns:
        The smoothed value ``(T, H, W)`` and ``(d^2/dx^2, d^2/dy^2, d^2/dxdy)`` in data units per mm^2,
        ``(3, T, H, W)``, x along W.
    """
    taps, radius = _gaussian_taps(sigma, frames)
    parts = []
    for chunk in frames.split(_CHUNK):
        along_x = [_correlate(chunk, taps[p], radius, -1) for p in range(3)]
        parts.append(torch.stack([_correlate(along_x[a], taps[b], radius, -2) for a, b in _GAUSSIAN_PARTS]))
    out = torch.cat(parts, 1) / frames.new_tensor([1.0, dx**2, dx**2, dx**2]).view(4, 1, 1, 1)
    return out[0], out[1:]


def gaussian_noise_covariance(sigma: float, dx: float) -> Tensor:
    """The covariance of :func:`gaussian_derivatives`' value and the regressors' numerators ``(u_xx, u_yy,
    2 u_xy)`` per unit variance of white noise in the frames, ``(4, 4)`` float64 on the CPU."""
    taps, _ = _gaussian_taps(sigma, torch.zeros((), dtype=torch.float64, device="cpu"))
    kernels = torch.stack([taps[a][None, :] * taps[b][:, None] for a, b in _GAUSSIAN_PARTS]).flatten(1)
    kernels = kernels * torch.tensor([1.0, 1 / dx**2, 1 / dx**2, 2 / dx**2], dtype=torch.float64)[:, None]
    return kernels @ kernels.T


def lateral_integrals(second: Tensor, excess: Tensor, elapsed: Tensor) -> Tensor:
    """``int (u_xx, u_yy, 2 u_xy) / u dt`` from the first sample by the trapezoidal rule.

    Args:
        second: :func:`local_quadratic`'s derivatives, ``(3, N, ...)``.
        excess: ``u = T - T_ref``, positive, ``(N, ...)``.
        elapsed: the samples' times in s, increasing, ``(N,)``.

    Returns:
        ``(3, N, ...)`` in s per mm^2 (times a diffusivity: a change of ``ln u``).
    """
    ratio = second / excess[None]
    ratio[2] *= 2  # the mixed term enters twice: 2 a_xy u_xy
    steps = elapsed.diff().to(ratio).view(1, -1, *([1] * (ratio.dim() - 2)))
    out = torch.zeros_like(ratio)
    out[:, 1:] = torch.cumsum(0.5 * (ratio[:, 1:] + ratio[:, :-1]) * steps, 1)
    return out


def _demean(values: Tensor, labels: Tensor, regions: int) -> Tensor:
    """``values`` ``(P, ...)`` less the mean of its region (``labels`` ``(P,)`` in ``0 .. regions - 1``)."""
    sums = values.new_zeros((regions, *values.shape[1:])).index_add_(0, labels, values)
    counts = torch.bincount(labels, minlength=regions).to(values).clamp_min(1)
    return values - (sums / counts.view(-1, *([1] * (values.dim() - 1))))[labels]


def _blocks(elapsed: Tensor) -> list[int]:
    """Sample indices whose times grow by half each (at least one sample apart), from the first."""
    times, edges = elapsed.tolist(), [0]
    while edges[-1] < len(times) - 1:
        later = [j for j in range(edges[-1] + 1, len(times)) if times[j] >= RATIO * times[edges[-1]]]
        edges.append(later[0] if later else len(times) - 1)
    return edges


def _trapezoid(elapsed: Tensor, i0: int, i1: int) -> Tensor:
    """The trapezoidal rule's weights of the samples ``i0 .. i1`` in ``int_{t_i0}^{t_i1} f dt``."""
    steps = elapsed[i0 : i1 + 1].diff()
    weights = elapsed.new_zeros(i1 - i0 + 1)
    weights[:-1] += 0.5 * steps
    weights[1:] += 0.5 * steps
    return weights


@dataclass(frozen=True)
class _Block:
    """One block's sums over its pixels: ``A^T A`` and ``A^T dy`` less their expected noise parts (errors
    in variables), the noise parts, ``dy^T dy`` and the pixels' count."""

    gram: Tensor
    rhs: Tensor
    noise_aa: Tensor
    noise_ay: Tensor
    noise_yy: Tensor
    yy: Tensor
    pixels: int

    def residual(self, a: Tensor) -> tuple[float, float]:
        """The mean square residual at ``a`` and its expected noise part, per pixel."""
        noise = self.noise_yy - 2 * a @ self.noise_ay + a @ self.noise_aa @ a
        total = self.yy - 2 * a @ (self.rhs + self.noise_ay) + a @ (self.gram + self.noise_aa) @ a
        return float(total) / self.pixels, float(noise) / self.pixels


def _block(dy: Tensor, a: Tensor, steps: Tensor, spread: Tensor, covariance: Tensor) -> _Block:
    """One block's sums from its increments ``dy`` ``(P,)`` and regressors ``a`` ``(P, 3)`` (demeaned), its
    samples' trapezoidal weights ``steps`` and noise variances over ``u^2`` summed over the pixels
    ``spread`` (both ``(n,)``), and the filters' noise ``covariance`` ``(4, 4)``."""
    noise_aa = covariance[1:, 1:] * (steps.square() * spread).sum()
    noise_ay = covariance[1:, 0] * (steps[-1] * spread[-1] - steps[0] * spread[0])
    return _Block(
        gram=a.T @ a - noise_aa,
        rhs=a.T @ dy - noise_ay,
        noise_aa=noise_aa,
        noise_ay=noise_ay,
        noise_yy=covariance[0, 0] * (spread[-1] + spread[0]),
        yy=dy @ dy,
        pixels=len(dy),
    )


def _solve(blocks: list[_Block], weights: list[float]) -> Tensor:
    """The blocks' weighted errors-in-variables solution."""
    gram = torch.stack([w * b.gram for b, w in zip(blocks, weights, strict=True)]).sum(0)
    rhs = torch.stack([w * b.rhs for b, w in zip(blocks, weights, strict=True)]).sum(0)
    return torch.linalg.solve(gram, rhs)


def fit_lateral(
    frames: Tensor,
    elapsed: Tensor,
    counts: Tensor,
    *,
    dx: float,
    t_ref: float,
    noise_sd: float,
    sigma: float,
    labels: Tensor | None,
) -> tuple[Tensor, int]:
    """``(a_x, a_y, a_xy)`` in mm^2/s from the pixels' differences in the increments of ``ln u``.

    The regressors (the lateral integrals) are noisy as the increments are; late in a recording their
    noise outgrows their signal and would bias plain least squares towards zero. Each block's sums lose
    their expected noise parts (the local quadratic's noise covariance, :func:`noise_covariance`, over
    ``u^2`` and the bins' frame counts, through the trapezoidal rule: errors in variables), and the blocks
    are weighted by their residuals' mean square.

    Args:
        frames: the cooling averaged over bins of frames, ``(N, H, W)`` float64.
        elapsed: the bins' times since the flash in s, ``(N,)``.
        counts: frames per bin, ``(N,)``.
        dx: pixel size in mm.
        t_ref: the temperature the plate cools to.
        noise_sd: a frame's white noise sd.
        sigma: smoothing of the fit in px; pixels closer than ``3 sigma`` to the frame's edge are left out.
        labels: regions of equal depth, ``(H, W)`` integers, 0 left out; None: the whole frame one region.

    Returns:
        The diffusivities of the longest run of blocks from the first whose fit is physical
        (``a_x, a_y >= 0``, ``a_xy^2 <= a_x a_y``; late blocks where a large defect shows can turn it), or
        where none is, of the longest physical run from a later block (the edges of a shallow defect, whose
        layer differs from the plate from the first frames, break the first blocks); zeros where no run of
        two is; and the blocks of frames it used (negative when none was physical).
    """
    value, second = gaussian_derivatives(frames, sigma, dx)
    excess = (value - t_ref).clamp_min(torch.finfo(value.dtype).tiny)
    integrals = lateral_integrals(second, excess, elapsed).flatten(2)  # (3, N, P)
    logs, excess = excess.log().flatten(1), excess.flatten(1)
    keep, region, regions = _pixels(frames, sigma, labels)
    if len(region) < 50:
        return frames.new_zeros(3), 0
    # per bin: the noise variance of the local fit's outputs over u^2, summed over the pixels
    spread = (noise_sd**2 / counts.to(frames)) * excess[:, keep].pow(-2).sum(1)  # (N,)
    covariance = gaussian_noise_covariance(sigma, dx).to(frames)
    blocks: list[_Block] = []
    edges = _blocks(elapsed)
    for i0, i1 in zip(edges[:-1], edges[1:], strict=False):
        dy = _demean((logs[i1] - logs[i0])[keep], region, regions)
        a = _demean((integrals[:, i1] - integrals[:, i0])[:, keep].T, region, regions)
        blocks.append(_block(dy, a, _trapezoid(elapsed, i0, i1), spread[i0 : i1 + 1], covariance))
    first = _run(blocks, 0)
    if len(first) < 2:
        return frames.new_zeros(3), len(first)
    found = _physical(first) or _later(blocks)
    return found if found is not None else (frames.new_zeros(3), -len(first))


def _later(blocks: list[_Block]) -> tuple[Tensor, int] | None:
    """Where no run from the first block is physical (a shallow defect's edges break the first blocks): the
    longest physical run from a later block (the earliest of equal length) that explains at least
    :data:`_LATER_R2` of its increments (late blocks of a noisy recording are noise: R^2 -1.5 at 40 mK)."""
    found = None
    for start in range(1, len(blocks) - 1):
        run = _run(blocks, start)
        later = _physical(run)
        if later is None or (found is not None and later[1] <= found[1]):
            continue
        residual = sum(b.residual(later[0])[0] for b in run[: later[1]])
        if residual <= (1 - _LATER_R2) * sum(float(b.yy) / b.pixels for b in run[: later[1]]):
            found = later
    return found


def _run(blocks: list[_Block], start: int) -> list[_Block]:
    """The blocks from ``start`` up to the first whose increments the fit so far does not explain."""
    run: list[_Block] = []
    for block in blocks[start:]:
        if len(run) >= 2 and _breaks(block, _solve(run, [1.0] * len(run))):
            break
        run.append(block)
    return run


def _physical(run: list[_Block]) -> tuple[Tensor, int] | None:
    """The solution of the longest start of ``run`` (two blocks at least) that is physical and its length."""
    for used in range(len(run), 1, -1):
        a = _weighted(run[:used])
        if a[0] >= 0 and a[1] >= 0 and a[2] ** 2 <= a[0] * a[1]:
            return a, used
    return None


def _weighted(blocks: list[_Block]) -> Tensor:
    """The blocks' solution, each block weighted by its residuals' mean square."""
    a = _solve(blocks, [1.0] * len(blocks))
    for _ in range(3):
        a = _solve(blocks, [1 / max(b.residual(a)[0], torch.finfo(a.dtype).tiny) for b in blocks])
    return a


def _breaks(block: _Block, a: Tensor) -> bool:
    """A block the fit so far leaves a residual of :data:`_STOP_CHI2` times its noise and less than
    :data:`_STOP_R2` of its increments explained: the model no longer holds (a region changed depth)."""
    residual, noise = block.residual(a)
    return residual > _STOP_CHI2 * noise and residual > (1 - _STOP_R2) * float(block.yy) / block.pixels


def _pixels(frames: Tensor, sigma: float, labels: Tensor | None) -> tuple[Tensor, Tensor, int]:
    """The pixels the fit uses (``3 sigma`` from the edge, labelled), their regions and the regions' count."""
    height, width = frames.shape[1:]
    margin = int(math.ceil(3 * sigma))
    inside = torch.zeros((height, width), dtype=torch.long, device=frames.device)
    inside[margin : height - margin, margin : width - margin] = 1
    labels = inside if labels is None else labels.to(frames.device) * inside
    keep = labels.flatten() > 0
    region = labels.flatten()[keep]
    return keep, region, int(region.max()) + 1 if len(region) else 1
