"""The diffusivity and perfusion of the depth model, fitted where the recording cools: no source acts there.

The surface alone cannot tell ``a`` in one dimension (the surface flux of a half-space scales with
``sqrt(a)`` whatever the history), and the plain ANRA balance reads the heat that leaves downwards as
lateral spreading. The depth model itself gives a consistent estimate. Once the source is off (a laser
switched off, a probe lifted, a tip gone), the only heat crossing the surface is what it loses to the air:
the heat that entered through it, :func:`anra_torch.tissue.surface_heat_input` of the measured surface
under ``a`` and ``b``, must fall by just ``a beta int theta_s dt`` (``beta = h / k``, 1/mm). With the wrong
``a`` the same surface implies heat still flowing in or out, in a way that differs between the frame's
lateral modes (``a |k|^2`` sets how fast each one empties sideways) and, through ``b``, over time.
:func:`fit_depth_parameters` finds ``(a, b, beta)`` by Gauss-Newton on that residual:

    r(n, k) = (Q_k(t_n) - Q_k(t_0) + a beta int_{t_0}^{t_n} g_k dt) / sqrt(sum_k Q_k(t_0)^2),

for the frames ``n`` after the switch-off at ``t_0`` and the cosine modes ``k`` whose energy stands well
above the noise (scale-free in ``a``: no noise bias towards small ``a``). Without ``beta`` the loss to the
air would be read as perfusion. The switch-off is the last frame at which the hottest point (3 x 3 px
means) is within 5 % of its largest rise; the fit starts two frames later (the interval across the switch
is not linear).

Standard errors: the measured white noise pushed through the same residual (seeded replicate videos, to
first order) and the jackknife over groups of lateral modes at the solution (one linearised step per
group: modes that disagree about ``a`` show the model's own error); the larger of the two per parameter.

Volumetric heating (a near-infrared laser deposits its heat below the surface) breaks the model: heat
keeps rising from below after the switch-off and no ``(a, b)`` keeps the surface's heat input flat.
:attr:`DepthParameters.misfit` is the residual's share at the fit (0 for a perfect model);
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
    dct_matrices,
    depth_nodes,
    heat_input,
    modal_problem,
    solver_nodes,
    surface_rise,
    wavenumbers,
)

__all__ = [
    "DIFFUSIVITY_RANGE",
    "LOSS_RANGE",
    "MAX_MODES",
    "MIN_COOLING_FRAMES",
    "VOLUMETRIC_MISFIT",
    "DepthParameters",
    "cooling_start",
    "fit_depth_parameters",
]

MAX_MODES = 96
"""Most lateral cosine modes fitted (the most energetic ones)."""
SIGNAL_TO_NOISE = 10.0
"""A mode is fitted when its change over the record has at least this many times the noise's amplitude."""
MIN_COOLING_FRAMES = 4
"""Fewest frames after the switch-off (the fit's first frame included) for a fit."""
DIFFUSIVITY_RANGE = (0.01, 2.0)
"""mm^2/s: the fit stays inside."""
LOSS_RANGE = (0.0, 0.1)
"""1/s: the fit's perfusion stays inside."""
SURFACE_LOSS_RANGE = (0.0, 1.0)
"""1/mm: the fit's loss through the surface (``h / k``: air, radiation) stays inside."""
VOLUMETRIC_MISFIT = 0.02
"""Largest residual share (:attr:`DepthParameters.misfit`) of a surface-heated recording; above it the heat
looks deposited below the surface (or another effect the depth model lacks acts) and the video is flagged."""
_SWITCH_SHARE = (
    0.05  # the switch-off: last frame within this share of the rise from the heated area's maximum
)
_FIT_GROWTH = 1.1  # the fit's depth grid (the heat content needs less resolution than the damage front)
_GROUPS = 8  # jackknife groups of lateral modes
_REPLICATES = 8  # seeded noise videos for the noise part of the standard errors
_STEP = (0.02, 5e-4)  # finite-difference steps in (ln a, b); the residual is linear in beta
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
        misfit: residual share at the fit, ``(B,)``: ``sum r^2`` (0: the heat input stays exactly flat).
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
        "the heat input through the surface stays flat after the switch-off but for a surface loss: 3-D "
        "depth model, Gauss-Newton over (a, b, h/k)"
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
class _Modes:
    """What the fit sees of a batch: the most energetic cosine modes of the surface rise and where the
    residual counts.

    ``spectrum`` ``(B, T, K)`` (K), ``k2`` ``(B, K)`` (1/mm^2), ``weight`` ``(B, T, K)`` (1 where a mode above
    the noise and a frame after the switch-off meet, else 0), ``group`` ``(B, K)`` (jackknife group),
    ``start`` ``(B,)`` (first frame of the fit), ``dt`` ``(B,)``, ``exposure`` ``(B, T, K)`` (K s: the
    surface rise integrated over time since the fit's first frame, the trapezoid rule)."""

    spectrum: Tensor
    k2: Tensor
    weight: Tensor
    group: Tensor
    start: Tensor
    dt: Tensor
    exposure: Tensor

    def repeat(self, c: int) -> _Modes:
        """Each video ``c`` times (video-major), for ``c`` candidate parameters per video."""
        return _Modes(*(x.repeat_interleave(c, 0) for x in self.__dict__.values()))


def _modes(rise: Tensor, dx: Tensor, dt: Tensor, noise: Tensor, start: Tensor) -> _Modes:
    """Select the modes: the :data:`MAX_MODES` whose change over the record is largest, kept where it is at
    least :data:`SIGNAL_TO_NOISE` times the noise's (white noise of sd ``s`` has ``T s^2`` per mode)."""
    ch, cw = dct_matrices(rise)
    spectrum = (ch @ rise @ cw.T).flatten(2)  # (B, T, H W)
    energy = ((spectrum - spectrum[:, :1]) ** 2).sum(1)  # (B, H W)
    count = min(MAX_MODES, energy.shape[1])
    order = torch.argsort(energy, 1, descending=True)[:, :count]
    floor = SIGNAL_TO_NOISE**2 * rise.shape[1] * noise.view(-1, 1) ** 2
    above = energy.gather(1, order) > floor
    frames = torch.arange(rise.shape[1], device=rise.device)
    after = frames.view(1, -1) >= start.view(-1, 1)
    weight = (after.unsqueeze(-1) & above.unsqueeze(1)).to(rise.dtype)
    group = torch.arange(count, device=rise.device).expand_as(order) % _GROUPS
    k2 = wavenumbers(*rise.shape[-2:], dx).gather(1, order)
    picked = spectrum.gather(2, order.unsqueeze(1).expand(-1, rise.shape[1], -1))
    return _Modes(picked, k2, weight, group, start, dt, _exposure(picked, dt, start))


def _exposure(spectrum: Tensor, dt: Tensor, start: Tensor) -> Tensor:
    """``int_{t_0}^{t_n} g dt`` of every mode ``(N, T, K)`` (trapezoid rule; negative before ``t_0``)."""
    steps = 0.5 * (spectrum[:, 1:] + spectrum[:, :-1]) * dt.view(-1, 1, 1)
    total = torch.cat([torch.zeros_like(spectrum[:, :1]), steps.cumsum(1)], 1)
    return total - total.gather(1, start.view(-1, 1, 1).expand(-1, 1, total.shape[2]))


def _heat(modes: _Modes, a: Tensor, b: Tensor, spectrum: Tensor | None = None) -> Tensor:
    """Cumulative heat input (K mm) of the modes under ``a``, ``b`` ``(N,)``, ``(N, T, K)``; of
    ``spectrum`` instead of the surface's when given (the noise replicates)."""
    duration = float(modes.dt.max()) * (modes.spectrum.shape[1] - 1)
    reach = 7.0 * math.sqrt(float(a.detach().max()) * duration) + 0.1
    reported = depth_nodes(reach, growth=_FIT_GROWTH)
    nodes = solver_nodes(reported, bottom_depth(None, float(reported[-1]), a, duration))
    source = modes.spectrum if spectrum is None else spectrum
    return heat_input(modal_problem(source, modes.k2, modes.dt, a, b, nodes, 2))


def _change(q: Tensor, modes: _Modes) -> tuple[Tensor, Tensor]:
    """The heat input's change since each video's first fitted frame where it counts ``(N, T, K)``, and
    ``sqrt(sum_k Q_k(t_0)^2)`` over the modes used ``(N,)``."""
    at_start = q.gather(1, modes.start.view(-1, 1, 1).expand(-1, 1, q.shape[2]))
    norm = ((at_start[:, 0] ** 2) * modes.weight.amax(1)).sum(1).sqrt().clamp_min(1e-300)
    return (q - at_start) * modes.weight, norm


def _residual(modes: _Modes, theta: Tensor) -> tuple[Tensor, Tensor]:
    """Residual ``(B, C, T, K)`` of ``C`` candidates ``theta`` ``(B, C, 3)`` = ``(ln a, b, beta)`` per video:
    the heat input's change since the fit's first frame plus what the surface lost to the air
    (``a beta int g dt``) over ``sqrt(sum_k Q_k(t_0)^2)``, so that its size does not scale with ``a``; and
    its derivative with respect to ``beta`` (the residual is linear in it)."""
    b, c = theta.shape[:2]
    many = modes.repeat(c)
    a = theta[..., 0].exp().flatten()
    change, norm = _change(_heat(many, a, theta[..., 1].flatten()), many)
    d_beta = (a / norm).view(-1, 1, 1) * many.exposure * many.weight
    r = change / norm.view(-1, 1, 1) + theta[..., 2].reshape(-1, 1, 1) * d_beta
    return r.view(b, c, *r.shape[1:]), d_beta.view(b, c, *r.shape[1:])


def _clamp(theta: Tensor) -> Tensor:
    low = theta.new_tensor([math.log(DIFFUSIVITY_RANGE[0]), LOSS_RANGE[0], SURFACE_LOSS_RANGE[0]])
    high = theta.new_tensor([math.log(DIFFUSIVITY_RANGE[1]), LOSS_RANGE[1], SURFACE_LOSS_RANGE[1]])
    return torch.maximum(torch.minimum(theta, high), low)


def _jacobian(modes: _Modes, theta: Tensor) -> tuple[Tensor, Tensor]:
    """Residual ``(B, T, K)`` and its Jacobian ``(B, T, K, 3)`` at ``theta`` ``(B, 3)``: forward differences
    in ``ln a`` and ``b`` (three candidates per video in one batch), exact in ``beta``."""
    step = theta.new_tensor(_STEP)
    shifts = torch.zeros(3, 3, dtype=theta.dtype, device=theta.device)
    shifts[1, 0], shifts[2, 1] = step[0], step[1]
    r, d_beta = _residual(modes, theta.unsqueeze(1) + shifts)
    jac = torch.stack([(r[:, 1] - r[:, 0]) / step[0], (r[:, 2] - r[:, 0]) / step[1], d_beta[:, 0]], -1)
    return r[:, 0], jac


def _start(modes: _Modes, b0: float) -> Tensor:
    """The best of a coarse grid of ``ln a`` (0.03-0.8 mm^2/s) at ``b = b0``, ``beta = 0``: ``(B, 3)``."""
    grid = torch.linspace(
        math.log(0.03), math.log(0.8), 9, dtype=modes.spectrum.dtype, device=modes.spectrum.device
    )
    theta = torch.stack([grid, torch.full_like(grid, b0), torch.zeros_like(grid)], -1)
    theta = theta.expand(modes.start.shape[0], -1, -1)
    cost = (_residual(modes, theta)[0] ** 2).sum((2, 3))
    return theta.gather(1, cost.argmin(1).view(-1, 1, 1).expand(-1, 1, 3))[:, 0]


def _step(r: Tensor, jac: Tensor, damping: Tensor) -> Tensor:
    """Levenberg-Marquardt step ``(B, P)``: ``(J^T J + damping diag(J^T J)) d = -J^T r``."""
    jj = torch.einsum("btki,btkj->bij", jac, jac)
    jr = torch.einsum("btki,btk->bi", jac, r)
    lhs = jj + damping.view(-1, 1, 1) * torch.diag_embed(jj.diagonal(dim1=1, dim2=2).clamp_min(1e-30))
    return -torch.linalg.solve(lhs, jr)


def _gauss_newton(modes: _Modes, theta: Tensor, iterations: int = 12) -> tuple[Tensor, Tensor, Tensor]:
    """Minimise ``sum r^2`` from ``theta`` ``(B, 3)``: the solution, its residual and Jacobian there."""
    r, jac = _jacobian(modes, theta)
    cost = (r**2).sum((1, 2))
    damping = torch.full_like(cost, 1e-3)
    for _ in range(iterations):
        trial = _clamp(theta + _step(r, jac, damping))
        r_t, jac_t = _jacobian(modes, trial)
        cost_t = (r_t**2).sum((1, 2))
        better = cost_t < cost
        moved = (trial - theta).abs() / theta.new_tensor([*_STEP, 1e-3])
        keep = better.view(-1, 1)
        theta = torch.where(keep, trial, theta)
        r = torch.where(better.view(-1, 1, 1), r_t, r)
        jac = torch.where(better.view(-1, 1, 1, 1), jac_t, jac)
        cost = torch.where(better, cost_t, cost)
        damping = torch.where(better, damping / 3.0, damping * 4.0)
        if bool(((moved.amax(1) < 0.05) & better).all()):
            break
    return theta, r, jac


def _errors(modes: _Modes, theta: Tensor, r: Tensor, jac: Tensor, noise: Tensor) -> Tensor:
    """Standard errors of ``(ln a, b, beta)`` ``(B, 3)``: the larger of the noise's (seeded white replicates
    of the measured sd through the residual, first order) and the jackknife's over groups of modes (one
    linearised step per group without it)."""
    batch, (t, k) = theta.shape[0], modes.spectrum.shape[1:]
    jj = torch.einsum("btki,btkj->bij", jac, jac)
    inverse = torch.linalg.pinv(jj)
    generator = torch.Generator().manual_seed(0)
    white = torch.randn((batch * _REPLICATES, t, k), generator=generator, dtype=_F64, device="cpu")
    white = white.to(modes.spectrum) * noise.repeat_interleave(_REPLICATES).view(-1, 1, 1)
    many = modes.repeat(_REPLICATES)
    a, b = (theta[:, i].repeat_interleave(_REPLICATES) for i in (0, 1))
    _, norm = _change(_heat(modes, theta[:, 0].exp(), theta[:, 1]), modes)
    change, _ = _change(_heat(many, a.exp(), b, white), many)
    beta = theta[:, 2].repeat_interleave(_REPLICATES).view(-1, 1, 1)
    change = change + a.exp().view(-1, 1, 1) * beta * _exposure(white, many.dt, many.start) * many.weight
    change = change.view(batch, _REPLICATES, t, k) / norm.view(-1, 1, 1, 1)
    shift = torch.einsum("bij,brj->bri", inverse, torch.einsum("btki,brtk->bri", jac, change))
    noise_var = (shift**2).mean(1)
    one_hot = torch.nn.functional.one_hot(modes.group, _GROUPS).to(jac.dtype)  # (B, K, G)
    jj_g = torch.einsum("btki,btkj,bkg->bgij", jac, jac, one_hot)
    jr_g = torch.einsum("btki,btk,bkg->bgi", jac, r, one_hot)
    left = torch.linalg.pinv(jj.unsqueeze(1) - jj_g)
    deleted = -torch.einsum("bgij,bgj->bgi", left, jr_g.sum(1, keepdim=True) - jr_g)
    jack_var = (_GROUPS - 1) / _GROUPS * ((deleted - deleted.mean(1, keepdim=True)) ** 2).sum(1)
    return torch.maximum(noise_var, jack_var).sqrt()


def fit_depth_parameters(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    *,
    units: str = "C",
    body_temperature: float | Tensor | None = None,
    noise_sd: float | Tensor | None = None,
) -> DepthParameters:
    """Fit ``a`` and ``b`` of the depth model to a recording's cooling (see the module docstring).

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
        start = cooling_start(rise).clamp_max(t - 1)
        modes = _modes(rise, dx_, dt_, noise, start)
        cooling = t - start
        used = modes.weight.amax(1).sum(1)
        valid = (cooling >= MIN_COOLING_FRAMES) & (used >= 3)
        theta, r, jac = _gauss_newton(modes, _start(modes, 0.003))
        se = _errors(modes, theta, r, jac, noise)
        misfit = (r**2).sum((1, 2))
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
            f"heat keeps entering after the switch-off (misfit {misfit:.3g} > {VOLUMETRIC_MISFIT:g}): looks "
            "volumetrically heated (e.g. a near-infrared laser) or another effect the depth model lacks; "
            "depth maps not reliable"
        )
    return ""
