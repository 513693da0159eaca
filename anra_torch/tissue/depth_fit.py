"""The diffusivity and perfusion of the depth model, fitted where the recording cools: no source acts there.

The surface alone cannot tell ``a`` in one dimension (a half-space's surface cools the same way whatever
``a``, given its own history), and the plain ANRA balance reads the heat that leaves downwards as lateral
spreading. The depth model itself gives a consistent estimate by forecasting the cooling. Up to the frame
``t_0`` two frames after the switch-off, the measured surface drives the tissue below (the depth model of
:mod:`anra_torch.tissue.depth`); from ``t_0`` on no source acts, the surface is free and loses
``a beta theta`` to the air (``beta = h / k``, 1/mm), and the state at ``t_0`` alone fixes how the surface
cools (:func:`anra_torch.tissue.depth_solver.free_surface_operator`, exact in time). The lateral modes cool
at ``a |k|^2 + b`` on top of the depth's own decay: that is what tells ``a`` from ``b``, and ``beta`` from
both. :func:`fit_depth_parameters` finds ``(a, b, beta)`` by Levenberg-Marquardt on

    r(n, p) = S[measured - forecast](t_n, p),   t_n > t_0,  p at least ``EDGE`` mm inside the frame,

where ``S`` keeps the cosine modes (of the frame and a margin) below ``3.7 / SMOOTHING`` 1/mm whose change
stands above the noise, Gaussian-weighted (``exp(-k^2 s^2 / 2)``, the same on both sides).

The frame is a window, not the world: the heat crosses its edges. The frames are continued
``MARGIN`` mm beyond every edge (:func:`anra_torch.tissue.depth_solver.widen`: a straight line through
each edge's last pixels) so that the heat leaves through them as it does in the tissue, the cooling evolves
freely there, and the residual is read only inside the frame, away from its edges.

Standard errors: the larger of the measured white noise's (through the residual's linear operators,
analytic, first order: the measured side and the forecast's state) and the jackknife's over rings of the
window by distance from the edges and halves of the cooling (one linearised step each: parts that
disagree about ``a`` show the model's own error), and in quadrature the edges' part: the change of the fit
when the frames are continued beyond the window with their curvature mirrored instead of straight.

Volumetric heating (a near-infrared laser deposits its heat below the surface) breaks the model: heat
keeps rising from below after the switch-off and no ``(a, b, beta)`` forecasts the cooling.
:attr:`DepthParameters.misfit` is the share of the cooling signal the forecast misses beyond the noise;
above :data:`VOLUMETRIC_MISFIT` the recording is flagged and its depth maps must not be trusted.

Units: mm, s, mm^2/s, 1/s, K.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance import estimate_noise_sd
from anra_torch.tissue.depth_solver import (
    bottom_depth,
    check_rate,
    dct_matrix,
    depth_nodes,
    free_surface_operator,
    modal_problem,
    solver_nodes,
    state_at,
    surface_rise,
    widen,
)

__all__ = [
    "DIFFUSIVITY_RANGE",
    "EDGE",
    "LOSS_RANGE",
    "MARGIN",
    "MIN_COOLING_FRAMES",
    "SMOOTHING",
    "VOLUMETRIC_MISFIT",
    "DepthParameters",
    "cooling_start",
    "fit_depth_parameters",
]

SMOOTHING = 0.4
"""mm: the Gaussian width of the residual's low-pass (modes above ``3.7 / SMOOTHING`` 1/mm are left out)."""
MARGIN = 1.6
"""mm: how far the frames are continued beyond each edge."""
EDGE = 0.5
"""mm: the residual is read this far inside the frame's edges (at least one pixel)."""
SIGNAL_TO_NOISE = 3.0
"""A mode is fitted when its change over the record has at least this many times the noise's amplitude."""
MIN_COOLING_FRAMES = 4
"""Fewest frames after the switch-off (the fit's first frame included) for a fit."""
MAX_FRAMES = 48
"""Most cooling frames the residual reads (evenly spread over the cooling)."""
DIFFUSIVITY_RANGE = (0.01, 2.0)
"""mm^2/s: the fit stays inside."""
LOSS_RANGE = (0.0, 0.1)
"""1/s: the fit's perfusion stays inside."""
SURFACE_LOSS_RANGE = (0.0, 1.0)
"""1/mm: the fit's loss through the surface (``h / k``: air, radiation) stays inside."""
VOLUMETRIC_MISFIT = 0.002
"""Largest share of the cooling signal a surface-heated recording's forecast misses beyond the noise
(:attr:`DepthParameters.misfit`); above it the heat looks deposited below the surface (or another effect
the depth model lacks acts) and the video is flagged."""
_SWITCH_SHARE = (
    0.05  # the switch-off: last frame within this share of the rise from the heated area's maximum
)
_FIT_GROWTH = 1.1  # the fit's depth grid (the cooling needs less resolution than the damage front)
_STEP = (0.02, 5e-4, 2e-3)  # finite-difference steps in (ln a, b, beta)
_F64 = torch.float64


@dataclass(frozen=True)
class DepthParameters:
    """Output of :func:`fit_depth_parameters` (batched: leading ``B``; a single video drops it).

    Attributes:
        diffusivity: ``a`` in mm^2/s, ``(B,)``; ``diffusivity_std`` its standard error.
        loss_rate: ``b`` (perfusion) in 1/s, ``(B,)``; ``loss_rate_std`` its standard error.
        surface_loss: ``beta = h / k`` in 1/mm of the heat the surface loses after the switch-off (air,
            radiation; not part of the depth model: the surface temperature is measured), ``(B,)``;
            ``surface_loss_std`` its standard error.
        noise_sd: the frames' white noise (K), ``(B,)``.
        cooling_start: first frame of the fit (two after the switch-off), ``(B,)``.
        misfit: share of the cooling signal the forecast misses beyond the noise, ``(B,)`` (0: a perfect
            model).
        volumetric: ``misfit > VOLUMETRIC_MISFIT``: the heat looks deposited below the surface, ``(B,)``.
        valid: a fit was possible (enough frames after the switch-off and modes above the noise), ``(B,)``.
        messages: per video, why there is no fit or why it is flagged ("" otherwise).
    """

    diffusivity: Tensor
    diffusivity_std: Tensor
    loss_rate: Tensor
    loss_rate_std: Tensor
    surface_loss: Tensor
    surface_loss_std: Tensor
    noise_sd: Tensor
    cooling_start: Tensor
    misfit: Tensor
    volumetric: Tensor
    valid: Tensor
    messages: tuple[str, ...]

    method = (
        "the cooling after the switch-off forecast from the tissue's state (the measured surface before it) "
        "with a free surface losing heat to the air: 3-D depth model, frames continued beyond the frame, "
        "Levenberg-Marquardt over (a, b, h/k)"
    )

    def unbatched(self) -> DepthParameters:
        """The same result with the batch dimension of size 1 removed."""
        return replace(self, **{k: v[0] for k, v in self.__dict__.items()})


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
class _Cooling:
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

    def repeat(self, c: int) -> _Cooling:
        """Each video ``c`` times (video-major), for ``c`` candidate parameters per video."""
        keep = {"basis": self.basis}
        return _Cooling(
            **{k: v.repeat_interleave(c, 0) for k, v in self.__dict__.items() if k not in keep}, **keep
        )


def _window_basis(h: int, w: int, margin: int, inner: int, like: Tensor, py: int, px: int) -> Tensor:
    """The widened frame's first ``py x px`` cosine modes at the frame's pixels ``inner`` px or more from
    its edges: ``(py px, P)``."""
    ch = dct_matrix(h + 2 * margin).to(like)[:py, margin + inner : margin + h - inner]
    cw = dct_matrix(w + 2 * margin).to(like)[:px, margin + inner : margin + w - inner]
    return (ch[:, None, :, None] * cw[None, :, None, :]).reshape(py * px, -1)


def _cooling(
    rise: Tensor, dx: Tensor, dt: Tensor, noise: Tensor, start: Tensor, *, mirrored: bool = False
) -> _Cooling:
    """The modes, weights, frames and the measured side of the residual of a batch ``(B, T, H, W)``."""
    b, t, h, w = rise.shape
    step = float(dx.max())
    margin = max(1, math.ceil(MARGIN / step - 1e-9))
    inner = min(max(1, round(EDGE / step)), (min(h, w) - 1) // 2)
    wide = widen(rise, margin, mirrored=mirrored, noise=noise)
    hh, ww = wide.shape[-2:]
    ky = math.pi * torch.arange(hh, dtype=_F64, device=rise.device) / hh
    kx = math.pi * torch.arange(ww, dtype=_F64, device=rise.device) / ww
    k2 = (ky[:, None] ** 2 + kx[None, :] ** 2) / dx.view(-1, 1, 1) ** 2  # (B, HH, WW)
    cut = (3.7 / SMOOTHING) ** 2
    py = min(hh, math.ceil(math.sqrt(cut) * hh * step / math.pi) + 1)
    px = min(ww, math.ceil(math.sqrt(cut) * ww * step / math.pi) + 1)
    ch, cw = dct_matrix(hh).to(rise)[:py], dct_matrix(ww).to(rise)[:px]
    spectrum = (ch @ wide @ cw.T).flatten(2)  # (B, T, K)
    k2 = k2[:, :py, :px].flatten(1)
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
    return _Cooling(
        spectrum, first, k2, weight, start, frames, dt, (picked * weight.unsqueeze(1)) @ basis, basis
    )


def _nodes(a: Tensor, duration: float) -> tuple[float, ...]:
    reach = 7.0 * math.sqrt(float(a.detach().max()) * duration) + 0.1
    reported = depth_nodes(reach, growth=_FIT_GROWTH)
    return solver_nodes(reported, bottom_depth(None, float(reported[-1]), a, duration))


def _forecast(c: _Cooling, a: Tensor, b: Tensor, betas: Tensor) -> Tensor:
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


def _residual(c: _Cooling, theta: Tensor, beta_step: float = 0.0) -> Tensor:
    """Residual ``(B, C, S, F, P)`` of ``C`` candidates ``theta`` ``(B, C, 3)`` = ``(ln a, b, beta)`` per
    video; ``S = 2`` with ``beta_step`` (the second with ``beta + beta_step``), else 1."""
    batch, count = theta.shape[:2]
    many = c.repeat(count)
    flat = theta.reshape(-1, 3)
    betas = flat[:, 2:3] if not beta_step else torch.stack([flat[:, 2], flat[:, 2] + beta_step], 1)
    r = many.data.unsqueeze(1) - _forecast(many, flat[:, 0].exp(), flat[:, 1], betas)
    return r.view(batch, count, *r.shape[1:])


def _clamp(theta: Tensor) -> Tensor:
    low = theta.new_tensor([math.log(DIFFUSIVITY_RANGE[0]), LOSS_RANGE[0], SURFACE_LOSS_RANGE[0]])
    high = theta.new_tensor([math.log(DIFFUSIVITY_RANGE[1]), LOSS_RANGE[1], SURFACE_LOSS_RANGE[1]])
    return torch.maximum(torch.minimum(theta, high), low)


def _jacobian(c: _Cooling, theta: Tensor) -> tuple[Tensor, Tensor]:
    """Residual ``(B, F, P)`` and its Jacobian ``(B, F, P, 3)`` at ``theta`` ``(B, 3)``: forward differences
    (``a`` and ``b`` as two more candidates, ``beta`` on the base's state)."""
    step = theta.new_tensor(_STEP)
    shifts = torch.zeros(3, 3, dtype=theta.dtype, device=theta.device)
    shifts[1, 0], shifts[2, 1] = step[0], step[1]
    r = _residual(c, theta.unsqueeze(1) + shifts, _STEP[2])
    base = r[:, 0, 0]
    columns = [(r[:, 1, 0] - base) / step[0], (r[:, 2, 0] - base) / step[1], (r[:, 0, 1] - base) / step[2]]
    return base, torch.stack(columns, -1)


def _start(c: _Cooling) -> Tensor:
    """The best of a coarse grid of ``ln a`` (0.03-0.8 mm^2/s) at ``b = 0.003``, ``beta = 0.02``:
    ``(B, 3)``."""
    grid = torch.linspace(math.log(0.03), math.log(0.8), 9, dtype=_F64, device=c.spectrum.device)
    theta = torch.stack([grid, torch.full_like(grid, 0.003), torch.full_like(grid, 0.02)], -1)
    theta = theta.expand(c.start.shape[0], -1, -1)
    cost = (_residual(c, theta)[:, :, 0] ** 2).sum((2, 3))
    return theta.gather(1, cost.argmin(1).view(-1, 1, 1).expand(-1, 1, 3))[:, 0]


def _step(r: Tensor, jac: Tensor, damping: Tensor) -> Tensor:
    """Levenberg-Marquardt step ``(B, 3)``: ``(J^T J + damping diag(J^T J)) d = -J^T r``."""
    jj = torch.einsum("bfpi,bfpj->bij", jac, jac)
    jr = torch.einsum("bfpi,bfp->bi", jac, r)
    lhs = jj + damping.view(-1, 1, 1) * torch.diag_embed(jj.diagonal(dim1=1, dim2=2).clamp_min(1e-30))
    return -torch.linalg.solve(lhs, jr)


def _levenberg_marquardt(c: _Cooling, theta: Tensor, iterations: int = 15) -> tuple[Tensor, Tensor, Tensor]:
    """Minimise ``sum r^2`` from ``theta`` ``(B, 3)``: the solution, its residual and Jacobian there."""
    r, jac = _jacobian(c, theta)
    cost = (r**2).sum((1, 2))
    damping = torch.full_like(cost, 1e-3)
    for _ in range(iterations):
        trial = _clamp(theta + _step(r, jac, damping))
        r_t, jac_t = _jacobian(c, trial)
        cost_t = (r_t**2).sum((1, 2))
        better = cost_t < cost
        moved = (trial - theta).abs() / theta.new_tensor(_STEP)
        theta = torch.where(better.view(-1, 1), trial, theta)
        r = torch.where(better.view(-1, 1, 1), r_t, r)
        jac = torch.where(better.view(-1, 1, 1, 1), jac_t, jac)
        cost = torch.where(better, cost_t, cost)
        damping = torch.where(better, damping / 3.0, damping * 4.0)
        if bool(((moved.amax(1) < 0.05) & better).all()):
            break
    return theta, r, jac


def _errors(c: _Cooling, theta: Tensor, r: Tensor, jac: Tensor, noise: Tensor) -> Tensor:
    """Standard errors of ``(ln a, b, beta)`` ``(B, 3)``: the larger of the noise's and the jackknife's over
    eight groups (rings of the window by distance from the frame's edges, the cooling's halves; one
    linearised step per group without it).

    The noise's: the frames' white noise through the residual's linear operators, analytic (the measured
    side's frames after ``t_0``, and the forecast's, whose state carries the noise of every frame before:
    the adjoint of the forecast, by automatic differentiation, on the Jacobian's columns)."""
    jj = torch.einsum("bfpi,bfpj->bij", jac, jac)
    inverse = torch.linalg.pinv(jj)
    modes = torch.einsum("kp,bfpi->bfki", c.basis, jac) * c.weight.view(-1, 1, c.weight.shape[1], 1)
    middle = torch.einsum("bfki,bfkj->bij", modes, modes) + _history(c, theta, jac)
    middle = noise.view(-1, 1, 1) ** 2 * middle
    noise_var = (inverse @ middle @ inverse).diagonal(dim1=1, dim2=2)
    groups = _groups(c, r)
    one_hot = F.one_hot(groups, 8).to(jac.dtype)  # (F, P, G)
    jj_g = torch.einsum("bfpi,bfpj,fpg->bgij", jac, jac, one_hot)
    jr_g = torch.einsum("bfpi,bfp,fpg->bgi", jac, r, one_hot)
    left = torch.linalg.pinv(jj.unsqueeze(1) - jj_g)
    deleted = -torch.einsum("bgij,bgj->bgi", left, jr_g.sum(1, keepdim=True) - jr_g)
    jack_var = 7.0 / 8.0 * ((deleted - deleted.mean(1, keepdim=True)) ** 2).sum(1)
    return torch.maximum(noise_var, jack_var).sqrt()


def _history(c: _Cooling, theta: Tensor, jac: Tensor) -> Tensor:
    """``G^T G`` ``(B, 3, 3)``, ``G`` the derivative of ``J^T (forecast)`` with respect to the spectrum of
    every frame (per unit noise in each mode and frame)."""
    with torch.enable_grad():
        spectrum = c.spectrum.detach().clone().requires_grad_(True)
        first = spectrum[:, 0] * (c.first != 0)
        forecast = _forecast(
            replace(c, spectrum=spectrum, first=first), theta[:, 0].exp(), theta[:, 1], theta[:, 2:3]
        )
        gradients = []
        for i in range(3):
            (g,) = torch.autograd.grad(
                (forecast[:, 0] * jac[..., i].detach()).sum(), spectrum, retain_graph=i < 2
            )
            gradients.append(g.flatten(1))
    g = torch.stack(gradients, -1)  # (B, T K, 3)
    return torch.einsum("bni,bnj->bij", g, g)


def _groups(c: _Cooling, r: Tensor) -> Tensor:
    """The jackknife group ``(F, P)`` of every residual: ring of the window by distance from the frame's
    edges (4: the edges' continuation errs most near them) x half of the frames."""
    f, p = r.shape[1:]
    side = round(math.sqrt(p))
    rows = torch.arange(p, device=r.device) // side
    cols = torch.arange(p, device=r.device) % side
    inset = torch.minimum(torch.minimum(rows, side - 1 - rows), torch.minimum(cols, side - 1 - cols))
    ring = (4 * inset // max(1, (side + 1) // 2)).clamp_max(3)
    late = (torch.arange(f, device=r.device) >= f // 2).long()
    return ring.view(1, -1) + 4 * late.view(-1, 1)


def _misfit(c: _Cooling, r: Tensor, noise: Tensor) -> Tensor:
    """Share of the cooling signal the forecast misses beyond the noise's expected part, ``(B,)``."""
    expected = noise**2 * r.shape[1] * ((c.weight**2) * (c.basis**2).sum(1)).sum(1)
    signal = (c.data**2).sum((1, 2)).clamp_min(1e-300)
    return ((r**2).sum((1, 2)) - expected).clamp_min(0.0) / signal


def fit_depth_parameters(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    *,
    units: str = "C",
    body_temperature: float | Tensor | None = None,
    noise_sd: float | Tensor | None = None,
) -> DepthParameters:
    """Fit ``a``, ``b`` and the surface's loss to the air on a recording's cooling (see the module docstring).

    Args:
        frames: surface temperatures in ``units`` (finite), ``(T, H, W)`` or ``(B, T, H, W)``: a heating
            (any surface source) followed by at least :data:`MIN_COOLING_FRAMES` frames of cooling.
        dt: frame period in s; dx: pixel size in mm (numbers or ``(B,)``).
        units: ``"C"`` or ``"K"``.
        body_temperature: C; default the median of each video's first frame.
        noise_sd: white-noise sd of the frames (K); default measured
            (:func:`anra_torch.balance.noise.estimate_noise_sd`).

    Returns:
        :class:`DepthParameters` (computed in float64, without gradients). Where no fit is possible
        ``valid`` is False, the values are NaN and the message says why.

    Raises:
        ValueError: bad shapes, spacings, units or non-finite frames.

    Shape:
        ``frames`` ``(B, T, H, W)`` -> values ``(B,)``.
    """
    with torch.no_grad():
        rise, batched, dt_, dx_, _ = surface_rise(frames, dt, dx, units, body_temperature)
        rise, dt_, dx_ = rise.to(_F64), dt_.to(_F64), dx_.to(_F64)
        batch, t = rise.shape[:2]
        if noise_sd is None:
            noise = estimate_noise_sd(rise).reshape(batch).to(_F64)
        else:
            noise = check_rate(noise_sd, "noise_sd", "K", batch, rise, positive=False)
        noise = noise.clamp_min(1e-3 * float(rise.abs().max().clamp_min(1e-12)))
        start = cooling_start(rise).clamp_max(max(t - 2, 0))
        cooling = t - start
        if t < 3 or int(cooling.max()) < MIN_COOLING_FRAMES:
            return _invalid(rise, noise, start, cooling, batched)
        c = _cooling(rise, dx_, dt_, noise, start)
        used = (c.weight > 0).sum(1)
        valid = (cooling >= MIN_COOLING_FRAMES) & (used >= 3)
        theta, r, jac = _levenberg_marquardt(c, _start(c))
        se = _errors(c, theta, r, jac, noise)
        misfit = _misfit(c, r, noise)
        # The edges' part: the frames continued with their curvature mirrored instead (the other plausible
        # continuation beyond the window) move the fit by about what the continuation can err.
        mirrored = _cooling(rise, dx_, dt_, noise, start, mirrored=True)
        other, _, _ = _levenberg_marquardt(mirrored, theta, iterations=6)
        se = torch.sqrt(se**2 + (other - theta) ** 2)
    return _result(theta, se, noise, start, misfit, valid, cooling, used, batched)


def _result(
    theta: Tensor,
    se: Tensor,
    noise: Tensor,
    start: Tensor,
    misfit: Tensor,
    valid: Tensor,
    cooling: Tensor,
    used: Tensor,
    batched: bool,
) -> DepthParameters:
    a = theta[:, 0].exp()
    messages = tuple(_message(*v) for v in zip(cooling.tolist(), used.tolist(), misfit.tolist(), strict=True))
    nan = torch.full_like(a, torch.nan)
    result = DepthParameters(
        diffusivity=torch.where(valid, a, nan),
        diffusivity_std=torch.where(valid, a * se[:, 0], nan),
        loss_rate=torch.where(valid, theta[:, 1], nan),
        loss_rate_std=torch.where(valid, se[:, 1], nan),
        surface_loss=torch.where(valid, theta[:, 2], nan),
        surface_loss_std=torch.where(valid, se[:, 2], nan),
        noise_sd=noise,
        cooling_start=start,
        misfit=torch.where(valid, misfit, nan),
        volumetric=valid & (misfit > VOLUMETRIC_MISFIT),
        valid=valid,
        messages=messages,
    )
    return result if batched else result.unbatched()


def _invalid(rise: Tensor, noise: Tensor, start: Tensor, cooling: Tensor, batched: bool) -> DepthParameters:
    """The result of a batch none of whose videos records enough cooling."""
    batch = rise.shape[0]
    zeros = torch.zeros(batch, dtype=_F64, device=rise.device)
    theta = torch.stack([zeros, zeros, zeros], 1)
    valid = torch.zeros(batch, dtype=torch.bool, device=rise.device)
    return _result(theta, theta, noise, start, zeros, valid, cooling, zeros.long() + 3, batched)


def _message(cooling: int, used: float, misfit: float) -> str:
    if cooling < MIN_COOLING_FRAMES:
        return (
            f"a and b not fitted: {cooling} frames after the switch-off, need {MIN_COOLING_FRAMES} "
            "(record the cooling)"
        )
    if used < 3:
        return f"a and b not fitted: {int(used)} lateral modes above the noise, need 3"
    if misfit > VOLUMETRIC_MISFIT:
        return (
            f"the cooling is not what surface heating leaves (misfit {misfit:.3g} > {VOLUMETRIC_MISFIT:g}): "
            "looks volumetrically heated (e.g. a near-infrared laser) or another effect the depth model "
            "lacks; depth maps not reliable"
        )
    return ""
