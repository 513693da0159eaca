"""The frame is a window, not the world: the frames continued beyond their edges (:func:`widen`) so that
the depth model's lateral modes let the heat cross the frame's edges as it does in the tissue, instead of
holding it in (the cosine modes of the frame alone have no flux through its edges).

Units: K (temperature rises over the body temperature), px.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.tissue.depth_solver import (
    ModalProblem,
    dct_matrices,
    dct_matrix,
    modal_problem,
    node_temperatures,
    wavenumbers,
)

__all__ = [
    "Beyond",
    "LOW_WAVENUMBER",
    "Window",
    "pooled_window",
    "widen",
    "widened_modes",
    "window_problem",
    "window_temperatures",
]

LOW_WAVENUMBER = 4.0
"""1/mm: the widened frame's lateral modes up to this wavenumber carry the heat across the frame's edges;
the rest of the surface (the frame minus those modes at its pixels: its detail and noise, which reaches
under ``1 / LOW_WAVENUMBER`` sideways) goes through the frame's own cosine modes (:func:`window_problem`)."""

_FIT_PIXELS = 6  # the edge's value and slope: a least-squares line through its last pixels
_CURVED_PIXELS = 16  # the curved tail: a parabola through the logarithm of the last pixels


def widen(
    rise: Tensor,
    margin: int,
    *,
    mirrored: bool = False,
    noise: Tensor | None = None,
    curved: bool = False,
) -> Tensor:
    """The frames continued ``margin`` px beyond every edge: the frame is a window, not the world.

    Each row (then each column) is continued by the straight line fitted (least squares) to its last
    :data:`_FIT_PIXELS` values of the frames' 5 x 5 px means (the frame's edge replicated for them, which
    flattens the line's slope: a spot's tail falls more slowly beyond the frame than at its edge), kept
    between 0 (the body temperature) and the frame's largest rise. No curvature is guessed: a spot wider than
    the frame or off its centre keeps falling outside as it falls at the edge, a cold edge stays cold.
    Inside the frame, the frames themselves (chosen by measuring, ``experiments/damage_depth.py``). With
    ``mirrored`` the curvature at the edge is continued mirrored (odd reflection about the edge value,
    ``2 g_e - g_(e-s)``): the other plausible continuation, whose difference bounds the edges' part of an
    error. With ``curved`` the tail is a Gaussian's instead of a line: ``ln`` of the means fitted by a
    parabola (its curvature kept <= 0) over their last :data:`_CURVED_PIXELS`, weighted by the squared
    means (the logarithm's noise falls as the mean rises), through the edge's own mean: a hot spot's
    convex tail beyond the frame as the heat equation makes it, a spot off the frame rising, then falling.
    With ``noise`` (the frames' white-noise sd, K, ``(B,)`` for ``(B, ..., H, W)``), an edge whose
    mean stands less than half of it above the body temperature (3.5 times the noise of that mean) is
    continued by 0: a cold edge's noise, continued and kept above 0, would put heat where there is none.
    Shape: ``(..., H, W)`` -> ``(..., H + 2 m, W + 2 m)``."""
    left, right, top, bottom = _strips(rise, margin, mirrored, noise, curved)
    return torch.cat([top, torch.cat([left, rise, right], -1), bottom], -2)


def widened_modes(
    rise: Tensor,
    margin: int,
    rows: Tensor,
    cols: Tensor,
    *,
    mirrored: bool = False,
    noise: Tensor | None = None,
    curved: bool = False,
) -> Tensor:
    """``rows @ widen(rise, margin, ...) @ cols^T`` without the widened frames: the frame and the four
    strips beyond its edges each through their own columns of ``rows`` ``(P, H + 2 m)`` and ``cols``
    ``(Q, W + 2 m)`` (a widened video's low cosine modes at a fraction of the memory and time).

    Shape: ``(..., H, W)`` -> ``(..., P, Q)``."""
    h, w = rise.shape[-2:]
    m = margin
    left, right, top, bottom = _strips(rise, m, mirrored, noise, curved)
    middle = rise @ cols[:, m : m + w].T + left @ cols[:, :m].T + right @ cols[:, m + w :].T
    out = rows[:, m : m + h] @ middle
    return out + rows[:, :m] @ (top @ cols.T) + rows[:, m + h :] @ (bottom @ cols.T)


def _strips(
    rise: Tensor, margin: int, mirrored: bool, noise: Tensor | None, curved: bool
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """What :func:`widen` puts beyond the frame: the left and right strips ``(..., H, m)``, then the top and
    bottom ones ``(..., m, W + 2 m)`` (the columns of the frames' means continued by the first two)."""
    shape = rise.shape
    h, w = shape[-2:]
    flat = rise.reshape(-1, 1, h, w)
    means = F.avg_pool2d(F.pad(flat, (2, 2, 2, 2), mode="replicate"), 5, 1).reshape(shape)
    top = rise.amax((-2, -1), keepdim=True).unsqueeze(-1)
    floor = None if noise is None else 0.5 * noise.reshape(-1, *[1] * (rise.ndim - 1)).unsqueeze(-1)

    need = max(_FIT_PIXELS, _CURVED_PIXELS, margin + 1)  # the most pixels any continuation reads

    def sides(x: Tensor) -> tuple[Tensor, Tensor]:
        before = _continue(x[..., :need].flip(-1), margin, top, mirrored, curved).flip(-1)
        after = _continue(x[..., -need:], margin, top, mirrored, curved)
        if floor is not None:
            cold = floor.squeeze(-1)
            before = torch.where(x[..., :1] > cold, before, torch.zeros_like(before))
            after = torch.where(x[..., -1:] > cold, after, torch.zeros_like(after))
        return before, after

    left, right = sides(means)
    # the columns need only their ends: as many rows of the row-continued means as any continuation reads
    n = min(h, need)
    ends = torch.cat([left, means, right], -1)
    upper, _ = sides(ends[..., :n, :].transpose(-1, -2))
    _, lower = sides(ends[..., h - n :, :].transpose(-1, -2))
    return left, right, upper.transpose(-1, -2), lower.transpose(-1, -2)


def _continue(x: Tensor, margin: int, top: Tensor, mirrored: bool, curved: bool = False) -> Tensor:
    """``margin`` values beyond the last of ``x`` ``(..., N)`` on its fitted line (or odd reflection, or
    Gaussian tail), in ``[0, top]``."""
    ahead = torch.arange(1, margin + 1, dtype=x.dtype, device=x.device)
    if curved and not mirrored:
        values = _gaussian_tail(x, ahead)
    elif mirrored:
        reach = min(margin, x.shape[-1] - 1)
        values = 2 * x[..., -1:] - x[..., -1 - reach : -1].flip(-1)
        values = torch.cat([values, values[..., -1:].expand(*values.shape[:-1], margin - reach)], -1)
    else:
        n = min(_FIT_PIXELS, x.shape[-1])
        s = torch.arange(1 - n, 1, dtype=x.dtype, device=x.device)  # the last pixels' offsets, the edge at 0
        centred = s - s.mean()
        tail = x[..., -n:]
        slope = (tail * centred).sum(-1, keepdim=True) / (centred**2).sum().clamp_min(1e-12)
        values = tail.mean(-1, keepdim=True) - slope * s.mean() + slope * ahead
    return torch.minimum(values.clamp_min(0.0), top.squeeze(-1))


def _gaussian_tail(x: Tensor, ahead: Tensor) -> Tensor:
    """``x``'s tail ``(..., N)`` continued to the offsets ``ahead`` ``(A,)`` (px) by the parabola fitted to
    the logarithm of its last :data:`_CURVED_PIXELS` values (weights: the squared values; curvature <= 0),
    through its last value: ``(..., A)``."""
    n = min(_CURVED_PIXELS, x.shape[-1])
    s = torch.arange(1 - n, 1, dtype=x.dtype, device=x.device)
    tail = x[..., -n:]
    tiny = 1e-9 * float(tail.detach().abs().max().clamp_min(1e-30))
    weight = tail.clamp_min(0.0) ** 2
    m = weight @ torch.stack([s**p for p in range(5)], -1)  # (..., 5): sum w s^p
    r = (weight * torch.log(tail.clamp_min(tiny))) @ torch.stack([s**p for p in range(3)], -1)
    m0, m1, m2, m3, m4 = m.unbind(-1)
    r0, r1, r2 = r.unbind(-1)
    # the normal equations [[m0 m1 m2] [m1 m2 m3] [m2 m3 m4]] c = r by Cramer's rule: the curvature c2
    det = m0 * (m2 * m4 - m3 * m3) - m1 * (m1 * m4 - m2 * m3) + m2 * (m1 * m3 - m2 * m2)
    top = m0 * (m2 * r2 - m3 * r1) - m1 * (m1 * r2 - m2 * r1) + r0 * (m1 * m3 - m2 * m2)
    scale = (m0 * m2 * m4).abs().clamp_min(tiny)
    curvature = torch.where(det.abs() > 1e-12 * scale, top / det.where(det != 0, 1.0), 0.0).clamp_max(0.0)
    # the curvature kept, the level and slope fitted again: [[m0 m1] [m1 m2]] (c0, c1) = r - c2 (m2, m3)
    q0, q1 = r0 - curvature * m2, r1 - curvature * m3
    det2 = m0 * m2 - m1 * m1
    slope = torch.where(
        det2.abs() > 1e-12 * (m0 * m2).abs().clamp_min(tiny),
        (m0 * q1 - m1 * q0) / det2.where(det2 != 0, 1.0),
        0.0,
    )
    exponent = slope.unsqueeze(-1) * ahead + curvature.unsqueeze(-1) * ahead * ahead
    # bounded: a cold edge's tail (0 times a huge growth) must stay 0, never NaN; the caller caps it anyway
    return tail[..., -1:].clamp_min(0.0) * torch.exp(exponent.clamp_max(80.0))


@dataclass(frozen=True)
class Window:
    """How :func:`window_temperatures` maps the low modes of a widened frame to the frame's pixels.

    ``count``: how many of the problem's modes (the first) are the widened frame's ``p x q`` low modes;
    ``rows`` ``(p, H)``, ``cols`` ``(q, W)``: their cosines at the frame's pixels."""

    count: int
    rows: Tensor
    cols: Tensor


def window_problem(
    rise: Tensor,
    dt: Tensor,
    dx: Tensor,
    rates: tuple[Tensor, Tensor],
    grid: tuple[tuple, int],
    continued: Beyond,
) -> tuple[ModalProblem, Window]:
    """The frame as a window, at the cost of the frame: the surface ``rise`` ``(B, T, H, W)`` split in two
    exactly (the PDE is linear): the low modes (``|k| <=`` :data:`LOW_WAVENUMBER`) of the frames widened as
    ``continued`` says (:class:`Beyond`), whose walls lie beyond
    the heat's reach, and what is left at the frame's pixels in the frame's own cosine modes; one
    :class:`~anra_torch.tissue.depth_solver.ModalProblem` of both (``a``, ``b`` in ``rates``; ``grid``:
    the nodes and how many are reported)."""
    margin = continued.margin
    h, w = rise.shape[-2:]
    step = float(dx.detach().max())
    hh, ww = h + 2 * margin, w + 2 * margin
    p = min(hh, math.ceil(LOW_WAVENUMBER * hh * step / math.pi) + 1)
    q = min(ww, math.ceil(LOW_WAVENUMBER * ww * step / math.pi) + 1)
    ch, cw = dct_matrix(hh).to(rise)[:p], dct_matrix(ww).to(rise)[:q]
    low = widened_modes(rise, margin, ch, cw, curved=continued.curved, noise=continued.noise)  # (B, T, p, q)
    rows, cols = ch[:, margin : margin + h], cw[:, margin : margin + w]
    fh, fw = dct_matrices(rise)
    detail = fh @ (rise - rows.T @ low @ cols) @ fw.T
    ky = (math.pi / hh) * torch.arange(p, device=rise.device, dtype=rise.dtype)[None, :] / dx[:, None]
    kx = (math.pi / ww) * torch.arange(q, device=rise.device, dtype=rise.dtype)[None, :] / dx[:, None]
    k2 = torch.cat([(ky[:, :, None] ** 2 + kx[:, None, :] ** 2).flatten(1), wavenumbers(h, w, dx)], 1)
    spectrum = torch.cat([low.flatten(2), detail.flatten(2)], -1)
    problem = modal_problem(spectrum, k2, dt, *rates, *grid)
    return replace(problem, step=step), Window(p * q, rows, cols)


def window_temperatures(
    rise: Tensor, problem: ModalProblem, window: Window, start: int, states: Tensor
) -> Tensor:
    """Rise (K) at the reported nodes, surface first, under the frame's pixels of a block of states of
    :func:`window_problem`'s modes: ``(B, L, Z, H, W)``."""
    n = window.count
    out = node_temperatures(rise, problem, start, states[..., n:, :])
    low = torch.matmul(problem.operator["to_nodes"], states[..., :n, :].transpose(-1, -2))
    grid = low.view(*low.shape[:3], len(window.rows), len(window.cols))
    out[:, :, 1:] += window.rows.T @ grid @ window.cols
    return out


@dataclass(frozen=True)
class Beyond:
    """How the frames are continued beyond the window (:func:`widen`): by ``margin`` px, by a Gaussian tail
    (``curved``) or a line; an edge colder than half the frames' noise sd ``noise`` (K, ``(B,)``) by 0."""

    margin: int
    curved: bool = False
    noise: Tensor | None = None


def pooled_window(continued: Beyond | None, coarse: int, copies: int) -> Beyond | None:
    """:func:`window_problem`'s ``continued`` for a base and ``copies`` copies stacked (video-major by copy)
    on ``coarse x coarse`` px means: the margin in their pixels, the noise's sd of their means."""
    if continued is None:
        return None
    noise = continued.noise
    if noise is not None:
        noise = (noise / coarse).repeat(copies + 1)
    return replace(continued, margin=continued.margin // coarse, noise=noise)
