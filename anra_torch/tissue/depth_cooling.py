"""What the fit of :mod:`~anra_torch.tissue.depth_fit` sees of a recording's cooling, and the cooling it
forecasts: the first frame of the fit (:func:`cooling_start`), the frames continued beyond the window and
their low-passed cosine modes (:func:`cooling_data`, :class:`Cooling`), and the free surface's cooling from
the tissue's state at that frame under ``(a, b, beta)`` (:func:`forecast`).

Units: mm, s, mm^2/s, 1/s, K.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.tissue.depth_solver import (
    bottom_depth,
    dct_matrix,
    depth_nodes,
    free_surface_operator,
    modal_problem,
    solver_nodes,
    state_at,
)
from anra_torch.tissue.depth_window import widened_modes

__all__ = [
    "EDGE",
    "MARGIN",
    "MAX_MARGIN",
    "REACH",
    "REACH_DIFFUSIVITY",
    "MAX_FRAMES",
    "SMOOTHING",
    "Cooling",
    "cooling_data",
    "cooling_modes",
    "cooling_start",
    "forecast",
    "margin_mm",
]

SMOOTHING = 0.4
"""mm: the Gaussian width of the residual's low-pass (modes above ``3.7 / SMOOTHING`` 1/mm are left out)."""
MARGIN = 2.4
"""mm: how far the frames are continued beyond each edge, at least (see :data:`REACH`)."""
REACH = 1.2
"""The margin is at least this many diffusion lengths ``sqrt(a_reach * duration)`` of the record (with
``a_reach`` :data:`REACH_DIFFUSIVITY`): the heat of a long exposure reaches that far beyond the frame, and
the cosine modes' walls at the widened frame's edges must not hold it in."""
REACH_DIFFUSIVITY = 0.2
"""mm^2/s: the diffusivity the margin's reach assumes (skin and soft tissue 0.10-0.20, water 0.14)."""
MAX_MARGIN = 6.4
"""mm: the margin's largest value (the cost grows with the widened frame's area)."""
EDGE = 0.5
"""mm: the residual is read this far inside the frame's edges (at least one pixel)."""
SIGNAL_TO_NOISE = 3.0
"""A mode is fitted when its change over the record has at least this many times the noise's amplitude."""
MAX_FRAMES = 48
"""Most cooling frames the residual reads (evenly spread over the cooling)."""
_SWITCH_SHARE = (
    0.05  # the switch-off: last frame within this share of the rise from the heated area's maximum
)
_FIT_GROWTH = 1.1  # the fit's depth grid (the cooling needs less resolution than the damage front)
_F64 = torch.float64


def cooling_start(rise: Tensor) -> Tensor:
    """First frame of the fit per video: two after the switch-off, the last frame at which the hottest
    point (of the frames' 3 x 3 px means, which quiets the noise) is within 5 % of its largest rise.

    Whatever the source: a laser spot's hottest point peaks as it switches off, a moving tip's moves with it
    until it stops, a probe's holds its plateau until it is lifted.

    Args:
        rise: surface minus body temperature (K), ``(B, T, H, W)``.

    Returns:
        Frame indices ``(B,)`` (int64).

    Shape:
        ``(B, T, H, W)`` -> ``(B,)``.
    """
    x = rise.detach()
    b, t = x.shape[:2]
    local = F.avg_pool2d(x.reshape(b * t, 1, *x.shape[2:]), 3, 1, 1, count_include_pad=False)
    hottest = local.reshape(b, t, -1).amax(2)  # (B, T)
    top = hottest.amax(1, keepdim=True)
    near = hottest >= top - _SWITCH_SHARE * (top - hottest[:, :1])
    index = torch.arange(t, device=x.device).expand_as(near)
    return torch.where(near, index, 0).amax(1) + 2


@dataclass(frozen=True)
class Cooling:
    """What the fit sees of a batch (``N`` videos, each maybe repeated for candidate parameters).

    ``spectrum`` ``(N, T, K)``: the widened rise's kept cosine modes (K); ``first`` ``(N, K)``: the first
    frame's modes where they stand above the noise (the state's equilibrium), ``k2`` ``(N, K)`` (1/mm^2),
    ``weight`` ``(N, K)`` (the low-pass weight, 0 for a mode left out), ``start`` ``(N,)``, ``frames``
    ``(N, F)`` (the frames read), ``dt`` ``(N,)``, ``data`` ``(N, F, P)`` (the measured side of the
    residual at the window's pixels), ``basis`` ``(K, P)`` (modes to the window's pixels)."""

    spectrum: Tensor
    first: Tensor
    k2: Tensor
    weight: Tensor
    start: Tensor
    frames: Tensor
    dt: Tensor
    data: Tensor
    basis: Tensor

    def repeat(self, c: int) -> Cooling:
        """Each video ``c`` times (video-major), for ``c`` candidate parameters per video."""
        keep = {"basis": self.basis}
        return Cooling(
            **{k: v.repeat_interleave(c, 0) for k, v in self.__dict__.items() if k not in keep}, **keep
        )


def margin_mm(duration: float) -> float:
    """mm by which the frames of a record of ``duration`` s are continued beyond each edge: :data:`MARGIN`,
    or :data:`REACH` diffusion lengths, at most :data:`MAX_MARGIN`."""
    return min(max(MARGIN, REACH * math.sqrt(REACH_DIFFUSIVITY * duration)), MAX_MARGIN)


def _window_basis(h: int, w: int, margin: int, inner: int, like: Tensor, py: int, px: int) -> Tensor:
    """The widened frame's first ``py x px`` cosine modes at the frame's pixels ``inner`` px or more from
    its edges: ``(py px, P)``."""
    ch = dct_matrix(h + 2 * margin).to(like)[:py, margin + inner : margin + h - inner]
    cw = dct_matrix(w + 2 * margin).to(like)[:px, margin + inner : margin + w - inner]
    return (ch[:, None, :, None] * cw[None, :, None, :]).reshape(py * px, -1)


def _geometry(shape: tuple[int, ...], dx: Tensor, dt: Tensor, like: Tensor) -> tuple:
    """The widened frame of a batch of ``shape`` ``(B, T, H, W)``: ``(margin, inner, py, px, rows, cols,
    k2)``, ``k2`` ``(B, py px)`` (1/mm^2) of the kept low modes."""
    _, t, h, w = shape
    step = float(dx.max())
    margin = max(1, math.ceil(margin_mm(float(dt.max()) * (t - 1)) / step - 1e-9))
    inner = min(max(1, round(EDGE / step)), (min(h, w) - 1) // 2)
    hh, ww = h + 2 * margin, w + 2 * margin
    ky = math.pi * torch.arange(hh, dtype=_F64, device=like.device) / hh
    kx = math.pi * torch.arange(ww, dtype=_F64, device=like.device) / ww
    k2 = (ky[:, None] ** 2 + kx[None, :] ** 2) / dx.view(-1, 1, 1) ** 2  # (B, HH, WW)
    cut = (3.7 / SMOOTHING) ** 2
    py = min(hh, math.ceil(math.sqrt(cut) * hh * step / math.pi) + 1)
    px = min(ww, math.ceil(math.sqrt(cut) * ww * step / math.pi) + 1)
    ch, cw = dct_matrix(hh).to(like)[:py], dct_matrix(ww).to(like)[:px]
    return margin, inner, py, px, ch, cw, k2[:, :py, :px].flatten(1)


def cooling_modes(
    rise: Tensor, dx: Tensor, dt: Tensor, noise: Tensor, *, length: int | None = None, mirrored: bool = False
) -> Tensor:
    """The widened frames' low cosine modes ``(B, T, K)`` (all of them: :func:`cooling_data` keeps those
    above the noise); ``length``: the record's frames when ``rise`` holds only some of them."""
    shape = (rise.shape[0], length or rise.shape[1], *rise.shape[2:])
    margin, _, _, _, ch, cw, _ = _geometry(shape, dx, dt, rise)
    return widened_modes(rise, margin, ch, cw, mirrored=mirrored, noise=noise, curved=True).flatten(2)


def cooling_data(
    rise: Tensor,
    dx: Tensor,
    dt: Tensor,
    noise: Tensor,
    start: Tensor,
    *,
    mirrored: bool = False,
    spectrum: Tensor | None = None,
) -> Cooling:
    """The modes, weights, frames and the measured side of the residual of a batch ``(B, T, H, W)``;
    ``spectrum``: its :func:`cooling_modes` when known."""
    b, t, h, w = rise.shape
    margin, inner, py, px, ch, cw, k2 = _geometry(rise.shape, dx, dt, rise)
    cut = (3.7 / SMOOTHING) ** 2
    if spectrum is None:
        spectrum = widened_modes(rise, margin, ch, cw, mirrored=mirrored, noise=noise, curved=True).flatten(2)
    energy = ((spectrum - spectrum[:, :1]) ** 2).sum(1)
    above = energy > SIGNAL_TO_NOISE**2 * t * noise.view(-1, 1) ** 2
    weight = torch.exp(-0.5 * k2 * SMOOTHING**2) * (k2 <= cut) * above
    kept = torch.nonzero((weight > 0).any(0)).flatten()  # the modes some video fits
    spectrum, k2, weight = spectrum[..., kept], k2[:, kept], weight[:, kept]
    first = torch.zeros_like(spectrum[:, 0])  # the tissue below the first frame at the body temperature
    count = min(MAX_FRAMES, t - 1 - int(start.min()))
    grid = torch.linspace(0.0, 1.0, max(count, 1), dtype=_F64, device=rise.device)
    frames = (start.view(-1, 1) + 1 + grid * (t - 2 - start).view(-1, 1)).round().long().clamp_max(t - 1)
    basis = _window_basis(h, w, margin, inner, rise, py, px)[kept]
    picked = spectrum.gather(1, frames.unsqueeze(-1).expand(-1, -1, spectrum.shape[2]))
    return Cooling(
        spectrum, first, k2, weight, start, frames, dt, (picked * weight.unsqueeze(1)) @ basis, basis
    )


def _nodes(a: Tensor, duration: float) -> tuple[float, ...]:
    reach = 7.0 * math.sqrt(float(a.detach().max()) * duration) + 0.1
    reported = depth_nodes(reach, growth=_FIT_GROWTH)
    return solver_nodes(reported, bottom_depth(None, float(reported[-1]), a, duration))


def forecast(c: Cooling, a: Tensor, b: Tensor, betas: Tensor) -> Tensor:
    """The forecast side of the residual ``(N, S, F, P)`` under ``a``, ``b`` ``(N,)`` for ``S`` surface
    losses ``betas`` ``(N, S)`` (the state at the fit's first frame is shared by them)."""
    duration = float(c.dt.max()) * (c.spectrum.shape[1] - 1)
    nodes = _nodes(a, duration)
    problem = modal_problem(c.spectrum, c.k2, c.dt, a, b, nodes, len(nodes) - 1)
    state = state_at(problem, c.start, start=c.first)  # (N, K, M)
    inner = state @ problem.operator["to_nodes"].T  # (N, K, Z - 2): the interior nodes
    surface = c.spectrum.gather(1, c.start.view(-1, 1, 1).expand(-1, 1, c.spectrum.shape[2]))[:, 0]
    values = torch.cat([surface.unsqueeze(-1), inner], -1)  # (N, K, Z - 1), surface first
    lateral = (a.view(-1, 1) * c.k2 + b.view(-1, 1)).unsqueeze(-1)  # (N, K, 1)
    elapsed = (c.frames - c.start.view(-1, 1)).to(a.dtype) * c.dt.view(-1, 1)  # (N, F)
    out = []
    for s in range(betas.shape[1]):
        parts = []
        for i in range(len(a)):  # candidates share the frames; each has its own beta's eigenbasis
            op = {k: v.to(a) for k, v in free_surface_operator(nodes, float(betas[i, s])).items()}
            coefficients = values[i] @ op["to_modes"].T * op["surface"]  # (K, M)
            rates = a[i] * op["lam"] - lateral[i]  # (K, M)
            decay = torch.exp(rates.unsqueeze(0) * elapsed[i].view(-1, 1, 1))  # (F, K, M)
            parts.append((decay * coefficients).sum(-1))
        out.append(torch.stack(parts))
    predicted = torch.stack(out, 1)  # (N, S, F, K)
    return (predicted * c.weight.view(-1, 1, 1, predicted.shape[-1])) @ c.basis
