"""A plate's surface cooling after a flash, fitted per pixel for its through-thickness time constant.

After an instantaneous flash ``Q`` on an insulated plate of thickness ``L`` the surface excess is

    T - T_ref = Q / L (1 + 2 sum_n exp(-n^2 pi^2 t / tau))
              = Q / sqrt(pi a_z t) (1 + 2 sum_n exp(-n^2 tau / t)),    tau = L^2 / a_z

(the two sums are one function by Poisson summation; each converges in a few terms on its side of
``t = tau / 4``). In the second form the constant ``ln (Q / sqrt(a_z))`` does not depend on ``tau``, so a
fit of ``ln (T - T_ref)`` by ``c + g(t; tau)`` over a grid of ``tau`` profiles ``c`` out in closed form
and leaves one weighted residual per pixel and grid point (:func:`profile_rss`). Above a defect at depth
``d`` (no heat crosses it) the layer is a thinner plate: its ``tau`` is ``d^2 / a_z``. ``tau = inf`` is
the half-space (the back wall beyond the recording).

:func:`time_bins` averages the frames over bins that grow geometrically (the cooling is a function of
``ln t``), with each bin's weight from the noise. :func:`nelder_mead` is the small two-parameter search
of the defect map's shared unknowns.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = [
    "TauGrid",
    "TimeBins",
    "log_surface",
    "nelder_mead",
    "profile_rss",
    "refine_minimum",
    "smooth_minimum",
    "tau_grid",
    "time_bins",
    "window_floor",
    "windowed_tau",
]

_TERMS = 8  # each series' terms on its side of t = tau / 4: the first left out is below exp(-39)
_TIES = 1e-12  # rss within this share of its row's range of the minimum: equal to rounding (refine_minimum)


def log_surface(elapsed: Tensor, tau: Tensor) -> Tensor:
    """``g(t; tau) = -ln(pi t) / 2 + ln(1 + 2 sum_n exp(-n^2 tau / t))``: the log surface excess of an
    insulated plate after a flash, less ``ln (Q / sqrt(a_z))``; ``tau = inf`` gives the half-space.

    Args:
        elapsed: times since the flash in s, positive, ``(N,)``.
        tau: time constants ``L^2 / a_z`` in s, positive or ``inf``, ``(K,)``.

    Returns:
        ``(K, N)``, on ``elapsed``'s device and dtype.
    """
    tau = tau.to(elapsed)
    s = elapsed[None, :] / tau[:, None]  # t / tau: 0 for tau = inf
    early = s < 0.25
    s_early = torch.where(early, s, torch.ones_like(s))
    s_late = torch.where(early, torch.ones_like(s), s)
    dual = torch.log1p(2 * _theta_sum(torch.exp(-1 / s_early)))  # 0 for the half-space
    direct = torch.log1p(2 * _theta_sum(torch.exp(-(math.pi**2) * s_late)))
    # the direct series is the dual one times sqrt(pi t / tau): back to the dual form's constant
    direct = direct + 0.5 * torch.log(math.pi * s_late)
    return -0.5 * torch.log(math.pi * elapsed)[None, :] + torch.where(early, dual, direct)


def _theta_sum(q: Tensor) -> Tensor:
    """``sum_n q^(n^2)`` over the first :data:`_TERMS` terms, by products (``q^(n^2) = q^((n-1)^2)
    q^(2n - 1)``): two exponentials per element instead of one per term."""
    step, square, term, total = q, q * q, q, q
    for _ in range(_TERMS - 1):
        step = step * square
        term = term * step
        total = total + term
    return total


@dataclass(frozen=True)
class TauGrid:
    """Time constants and their log surface curves.

    Attributes:
        taus: ``K`` log-spaced time constants in s, then ``inf``, ``(K + 1,)``.
        curves: :func:`log_surface` at the bins' times, ``(K + 1, N)``.
    """

    taus: Tensor
    curves: Tensor


def tau_grid(elapsed: Tensor, *, points: int = 160) -> TauGrid:
    """``points`` time constants from half the first time to 30 times the last, and ``inf``.

    Shape:
        ``elapsed`` ``(N,)``; ``taus`` ``(points + 1,)``; ``curves`` ``(points + 1, N)``.
    """
    lo, hi = math.log10(max(float(elapsed[0]) * 0.5, 1e-9)), math.log10(float(elapsed[-1]) * 30)
    finite = torch.logspace(lo, hi, points, dtype=elapsed.dtype, device=elapsed.device)
    taus = torch.cat([finite, torch.full((1,), math.inf, dtype=elapsed.dtype, device=elapsed.device)])
    return TauGrid(taus, log_surface(elapsed, taus))


def profile_rss(y: Tensor, w: Tensor, curves: Tensor) -> Tensor:
    """Weighted residual sum of squares of ``y - c - curve`` with ``c`` profiled out, per pixel and curve.

    Args:
        y: log excess per pixel and bin, ``(P, N)``.
        w: weights (inverse variances; 0 leaves a bin out), ``(P, N)``.
        curves: ``(K, N)``.

    Returns:
        ``(P, K)``.
    """
    sw = w.sum(1, keepdim=True).clamp_min(torch.finfo(w.dtype).tiny)
    wy = w * y
    cross = wy.sum(1, keepdim=True) - w @ curves.T  # sum w (y - g)
    return (wy * y).sum(1, keepdim=True) - 2 * wy @ curves.T + w @ (curves * curves).T - cross**2 / sw


def refine_minimum(rss: Tensor, taus: Tensor) -> tuple[Tensor, Tensor]:
    """Each row's minimum over the grid, refined by a parabola in ``ln tau``; ``inf`` at the grid's top.

    Args:
        rss: ``(P, K + 1)`` from :func:`profile_rss` on a :class:`TauGrid`.
        taus: the grid's ``(K + 1,)``, the last ``inf``.

    Returns:
        ``tau`` in s ``(P,)`` and the index of the grid's minimum ``(P,)``.
    """
    k = rss.argmin(1)
    points = rss.shape[1] - 1
    # a half-space's row is flat at the grid's top to rounding (its terms cancel to ~1e-14 of its range, and
    # which point is lowest then depends on the machine's summation order): within _TIES of the row's range
    # of its minimum, the half-space is the minimum
    low = rss.gather(1, k[:, None])[:, 0]
    k = torch.where(rss[:, -1] <= low + _TIES * (rss.amax(1) - low), torch.full_like(k, points), k)
    log_taus = torch.log(taus[:-1])
    step = log_taus[1] - log_taus[0]
    kk = k.clamp(1, points - 2)
    r0, r1, r2 = (rss.gather(1, (kk + o)[:, None])[:, 0] for o in (-1, 0, 1))
    curvature = r0 - 2 * r1 + r2
    shift = torch.where(curvature > 0, 0.5 * (r0 - r2) / curvature, torch.zeros_like(r1)).clamp(-1, 1)
    tau = torch.exp(log_taus[kk] + shift * step)
    unresolved = k >= points - 1  # at the grid's top or the half-space: beyond the recording
    return torch.where(unresolved, torch.full_like(tau, math.inf), tau), k


def window_floor(elapsed: Tensor) -> float:
    """The shortest fit window in s: the first 5 % of the recording, at least its first 9 bins."""
    return max(float(elapsed[min(8, len(elapsed) - 1)]), 0.05 * float(elapsed[-1]))


def windowed_tau(
    y: Tensor, weights: Tensor, elapsed: Tensor, window: float
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Each row's ``tau`` fitted by ``c + g(t; tau)`` over the bins up to ``window tau``, the window grown
    from :func:`window_floor` in three rounds (a row's own ``tau`` says how far its fit reaches).

    Args:
        y: ``ln u`` per row and bin, ``(P, N)``.
        weights: the bins' inverse variances, ``(P, N)``.
        elapsed: the bins' times since the flash in s, ``(N,)``.
        window: the share of its ``tau`` a row's fit reaches.

    Returns:
        ``tau`` in s ``(P,)``, the residuals over the grid ``(P, K + 1)``, the windowed weights ``(P, N)``
        and the grid's ``taus`` ``(K + 1,)`` (:func:`tau_grid`).
    """
    grid = tau_grid(elapsed)
    floor = window_floor(elapsed)
    limit = torch.full((len(y),), floor, dtype=y.dtype, device=y.device)
    for _ in range(3):
        windowed = weights * (elapsed[None, :] <= limit[:, None])
        rss = profile_rss(y, windowed, grid.curves)
        tau, _ = refine_minimum(rss, grid.taus)
        limit = (window * tau).clamp(min=floor)
    return tau, rss, windowed, grid.taus


@dataclass(frozen=True)
class TimeBins:
    """Frames averaged over bins growing geometrically in time (see :func:`time_bins`).

    Attributes:
        index: each frame's bin (``-1`` before the first), ``(T,)``.
        counts: frames per bin, ``(N,)``.
        elapsed: each bin's mean time since the flash in s, ``(N,)``.
    """

    index: Tensor
    counts: Tensor
    elapsed: Tensor

    def average(self, values: Tensor) -> Tensor:
        """Bin means of ``values`` ``(T, ...)`` -> ``(N, ...)``."""
        index = self.index.to(values.device)
        used = index >= 0
        out = values.new_zeros((len(self.counts), *values.shape[1:]))
        out.index_add_(0, index[used], values[used])
        return out / self.counts.to(values).view(-1, *([1] * (values.dim() - 1)))


def time_bins(frames: int, dt: float, first: float, *, start: int = 3, ratio: float = 1.03) -> TimeBins:
    """Bins from frame ``start`` on, each at least one frame and ending ``ratio`` times later than it began.

    Args:
        frames: frames in the recording.
        dt: frame period in s.
        first: time of frame 0 since the flash in s (positive).
        start: frames left out at the start (the flash's own frames).
        ratio: a bin's end time over its start time.

    Shape:
        ``index`` ``(frames,)``; ``counts``, ``elapsed`` ``(N,)``.
    """
    edges = [start]
    while edges[-1] < frames:
        t = first + edges[-1] * dt
        edges.append(min(frames, max(edges[-1] + 1, math.ceil((t * ratio - first) / dt))))
    cpu = torch.device("cpu")  # a few numbers, moved to the frames' device where they are used
    sizes = torch.tensor(edges, device=cpu).diff()
    index = torch.cat(
        [
            torch.full((start,), -1, device=cpu),
            torch.repeat_interleave(torch.arange(len(sizes), device=cpu), sizes),
        ]
    )
    counts = sizes.to(torch.float64)
    times = first + torch.arange(frames, dtype=torch.float64, device=cpu) * dt
    elapsed = (
        torch.zeros(len(sizes), dtype=torch.float64, device=cpu).index_add_(0, index[start:], times[start:])
        / counts
    )
    return TimeBins(index, counts, elapsed)


def nelder_mead(
    loss: Callable[[Tensor], float],
    start: Tensor,
    value: float,
    *,
    step: float,
    tolerance: float,
    iterations: int,
) -> Tensor:
    """Minimise ``loss`` over two parameters by Nelder-Mead from ``start`` (whose loss is ``value``), the
    first simplex's edges ``step``; stops when the simplex is smaller than ``tolerance`` or after
    ``iterations``. Returns the best vertex, ``(2,)`` float64 on the CPU."""
    simplex = [
        start,
        start + torch.tensor([step, 0.0], dtype=torch.float64, device="cpu"),
        start + torch.tensor([0.0, step], dtype=torch.float64, device="cpu"),
    ]
    values = [value, loss(simplex[1]), loss(simplex[2])]
    for _ in range(iterations):
        order = sorted(range(3), key=values.__getitem__)
        simplex, values = [simplex[i] for i in order], [values[i] for i in order]
        centre = (simplex[0] + simplex[1]) / 2
        reflected = 2 * centre - simplex[2]
        v_r = loss(reflected)
        if v_r < values[0]:
            expanded = 3 * centre - 2 * simplex[2]
            v_e = loss(expanded)
            simplex[2], values[2] = (expanded, v_e) if v_e < v_r else (reflected, v_r)
        elif v_r < values[1]:
            simplex[2], values[2] = reflected, v_r
        else:
            contracted = (centre + simplex[2]) / 2
            v_c = loss(contracted)
            if v_c < values[2]:
                simplex[2], values[2] = contracted, v_c
            else:
                simplex = [simplex[0]] + [(simplex[0] + s) / 2 for s in simplex[1:]]
                values = [values[0]] + [loss(s) for s in simplex[1:]]
        if max(float((s - simplex[0]).abs().max()) for s in simplex[1:]) < tolerance:
            break
    return simplex[min(range(3), key=values.__getitem__)]


def smooth_minimum(rss: Tensor) -> Tensor:
    """Each row's minimum of ``rss`` ``(P, K + 1)`` over the grid of ``ln tau`` (:func:`tau_grid`), refined by
    a parabola through it and its two neighbours (a continuous function of the data: the grid's own minimum
    jumps between points)."""
    k = rss[:, :-1].argmin(1).clamp(1, rss.shape[1] - 3)[:, None]
    r0, r1, r2 = rss.gather(1, k - 1)[:, 0], rss.gather(1, k)[:, 0], rss.gather(1, k + 1)[:, 0]
    curvature = (r0 - 2 * r1 + r2).clamp_min(torch.finfo(rss.dtype).tiny)
    refined = r1 - (r0 - r2) ** 2 / (8 * curvature)
    return torch.minimum(refined.clamp_min(0), rss.min(1).values)
