"""The diffusivity and perfusion of the depth model, fitted where the recording cools and no source acts.

:func:`fit_depth_parameters` fits the diffusivity ``a``, the perfusion ``b`` and the surface's loss to the
air ``beta = h / k`` by forecasting the cooling: from two frames after the switch-off on, the depth
model's state fixes how the free surface cools, and the fit matches the forecast to the measured cooling
inside the frame, with the frames continued beyond its edges. :attr:`DepthParameters.misfit` is the share
of the cooling the forecast misses; above :data:`VOLUMETRIC_MISFIT` the heat looks deposited below the
surface, as a near-infrared laser does, and the depth maps must not be trusted. The method and its
standard errors: ``docs/architecture.md``, "The depth model".

Units: mm, s, mm^2/s, 1/s, K.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance import estimate_noise_sd
from anra_torch.tissue.depth_cooling import Cooling, cooling_data, cooling_modes, cooling_start, forecast
from anra_torch.tissue.depth_errors import BETWEEN_WEIGHT
from anra_torch.tissue.depth_solver import check_rate, surface_rise

__all__ = [
    "DIFFUSIVITY_RANGE",
    "LOSS_RANGE",
    "MIN_COOLING_FRAMES",
    "VOLUMETRIC_MISFIT",
    "DepthParameters",
    "fit_depth_parameters",
    "square_root_drop",
]

MIN_COOLING_FRAMES = 4
"""Fewest frames after the switch-off (the fit's first frame included) for a fit."""
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
_STEP = (0.02, 5e-4, 2e-3)  # finite-difference steps in (ln a, b, beta)
_F64 = torch.float64


@dataclass(frozen=True)
class DepthParameters:
    """Output of :func:`fit_depth_parameters`: batched values lead with ``B``, a single video's drop it.

    Attributes:
        diffusivity: ``a`` in mm^2/s, ``(B,)``; ``diffusivity_std`` its standard error.
        loss_rate: ``b``, the perfusion, in 1/s, ``(B,)``; ``loss_rate_std`` its standard error.
        surface_loss: ``beta = h / k`` in 1/mm, the surface's loss to the air and by radiation after the
            switch-off, ``(B,)``; ``surface_loss_std`` its standard error.
        noise_sd: the frames' white-noise sd in K, ``(B,)``.
        cooling_start: first frame of the fit, two after the switch-off, ``(B,)``.
        misfit: share of the cooling signal the forecast misses beyond the noise, 0 for a perfect model,
            ``(B,)``.
        volumetric: ``misfit > VOLUMETRIC_MISFIT``: the heat looks deposited below the surface, ``(B,)``.
        valid: whether a fit was possible, with enough cooling frames and modes above the noise, ``(B,)``.
        messages: per video, why there is no fit or why it is flagged; "" otherwise.
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


def _residual(c: Cooling, theta: Tensor, beta_step: float = 0.0) -> Tensor:
    """Residual ``(B, C, S, F, P)`` of ``C`` candidates ``theta`` ``(B, C, 3)``, each ``(ln a, b, beta)``;
    ``S = 2`` with ``beta_step``, the second at ``beta + beta_step``, else 1."""
    batch, count = theta.shape[:2]
    many = c.repeat(count)
    flat = theta.reshape(-1, 3)
    betas = flat[:, 2:3] if not beta_step else torch.stack([flat[:, 2], flat[:, 2] + beta_step], 1)
    r = many.data.unsqueeze(1) - forecast(many, flat[:, 0].exp(), flat[:, 1], betas)
    return r.view(batch, count, *r.shape[1:])


def _clamp(theta: Tensor) -> Tensor:
    low = theta.new_tensor([math.log(DIFFUSIVITY_RANGE[0]), LOSS_RANGE[0], SURFACE_LOSS_RANGE[0]])
    high = theta.new_tensor([math.log(DIFFUSIVITY_RANGE[1]), LOSS_RANGE[1], SURFACE_LOSS_RANGE[1]])
    return torch.maximum(torch.minimum(theta, high), low)


def _jacobian(c: Cooling, theta: Tensor) -> tuple[Tensor, Tensor]:
    """Residual ``(B, F, P)`` and its Jacobian ``(B, F, P, 3)`` at ``theta`` ``(B, 3)`` by forward
    differences: ``a`` and ``b`` as two more candidates, ``beta`` on the base's state."""
    step = theta.new_tensor(_STEP)
    shifts = torch.zeros(3, 3, dtype=theta.dtype, device=theta.device)
    shifts[1, 0], shifts[2, 1] = step[0], step[1]
    r = _residual(c, theta.unsqueeze(1) + shifts, _STEP[2])
    base = r[:, 0, 0]
    columns = [(r[:, 1, 0] - base) / step[0], (r[:, 2, 0] - base) / step[1], (r[:, 0, 1] - base) / step[2]]
    return base, torch.stack(columns, -1)


def _start(c: Cooling) -> Tensor:
    """The best ``(B, 3)`` of a coarse grid of ``a`` in 0.03-0.8 mm^2/s at ``b = 0.003``, ``beta = 0.02``."""
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


def _levenberg_marquardt(c: Cooling, theta: Tensor, iterations: int = 15) -> tuple[Tensor, Tensor, Tensor]:
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


def _errors(c: Cooling, theta: Tensor, r: Tensor, jac: Tensor, noise: Tensor) -> Tensor:
    """Standard errors ``(B, 3)`` of ``(ln a, b, beta)``: the larger of the white noise's, propagated
    analytically through the residual, and the jackknife's over the eight groups of :func:`_groups`."""
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


def _history(c: Cooling, theta: Tensor, jac: Tensor) -> Tensor:
    """``G^T G`` ``(B, 3, 3)``, where ``G`` is the derivative of ``J^T forecast`` with respect to the
    spectrum of every frame, per unit noise in each mode and frame."""
    with torch.enable_grad():
        spectrum = c.spectrum.detach().clone().requires_grad_(True)
        first = spectrum[:, 0] * (c.first != 0)
        predicted = forecast(
            replace(c, spectrum=spectrum, first=first), theta[:, 0].exp(), theta[:, 1], theta[:, 2:3]
        )
        gradients = []
        for i in range(3):
            (g,) = torch.autograd.grad(
                (predicted[:, 0] * jac[..., i].detach()).sum(), spectrum, retain_graph=i < 2
            )
            gradients.append(g.flatten(1))
    g = torch.stack(gradients, -1)  # (B, T K, 3)
    return torch.einsum("bni,bnj->bij", g, g)


def _groups(c: Cooling, r: Tensor) -> Tensor:
    """The jackknife group ``(F, P)`` of every residual: one of 4 rings of the window by distance from the
    frame's edges, times one of 2 halves of the frames."""
    f, p = r.shape[1:]
    side = round(math.sqrt(p))
    rows = torch.arange(p, device=r.device) // side
    cols = torch.arange(p, device=r.device) % side
    inset = torch.minimum(torch.minimum(rows, side - 1 - rows), torch.minimum(cols, side - 1 - cols))
    ring = (4 * inset // max(1, (side + 1) // 2)).clamp_max(3)
    late = (torch.arange(f, device=r.device) >= f // 2).long()
    return ring.view(1, -1) + 4 * late.view(-1, 1)


def _shift(other: Cooling, theta: Tensor, r: Tensor, jac: Tensor) -> Tensor:
    """The change of the fit ``(B, 3)`` when the data are ``other``'s instead, by one linearised step on
    the fit's Jacobian: ``-(J^T J)^+ J^T (r' - r)``."""
    moved = _residual(other, theta.unsqueeze(1))[:, 0, 0] - r
    jj = torch.einsum("bfpi,bfpj->bij", jac, jac)
    return -(torch.linalg.pinv(jj) @ torch.einsum("bfpi,bfp->bi", jac, moved).unsqueeze(-1)).squeeze(-1)


def square_root_drop(rise: Tensor, switch: Tensor) -> Tensor:
    """The frames that put into the tissue the heat of a surface falling as the square root of the time
    since a switch-off right at each video's last heated frame ``switch``: the frame after it lowered by
    a sixth of the drop ``D`` to it, per pixel where the surface falls.

    Shape:
        ``rise`` ``(B, T, H, W)``, ``switch`` ``(B,)`` -> ``(B, T, H, W)``.
    """
    at = switch.clamp(0, rise.shape[1] - 2).view(-1, 1, 1, 1).expand(-1, 1, *rise.shape[2:])
    after = rise.gather(1, at + 1)
    drop = (rise.gather(1, at) - after).clamp_min(0.0)
    return rise.scatter(1, at + 1, after - drop / 6.0)


def _dropped(rise: Tensor, dx: Tensor, dt: Tensor, noise: Tensor, start: Tensor, spectrum: Tensor) -> Cooling:
    """What the fit sees of :func:`square_root_drop`'s frames: the modes of the one frame it changes, put
    into the recording's ``spectrum`` ``(B, T, K)`` from :func:`cooling_modes`."""
    b, t, h, w = rise.shape
    switch = (start - 2).clamp(0, t - 2)
    pair = rise.gather(1, torch.stack([switch, switch + 1], 1).view(b, 2, 1, 1).expand(-1, -1, h, w))
    frame = square_root_drop(pair, torch.zeros_like(switch))[:, 1:]
    changed = cooling_modes(frame, dx, dt, noise, length=t)  # (B, 1, K)
    at = (switch + 1).view(b, 1, 1).expand(-1, 1, spectrum.shape[2])
    return cooling_data(rise, dx, dt, noise, start, spectrum=spectrum.scatter(1, at, changed))


def _misfit(c: Cooling, r: Tensor, noise: Tensor) -> Tensor:
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
    """Fit ``a``, ``b`` and the surface's loss to the air on a recording's cooling.

    Args:
        frames: finite surface temperatures in ``units``: a heating by any surface source, then at least
            :data:`MIN_COOLING_FRAMES` frames of cooling.
        dt: frame period in s; dx: pixel size in mm; numbers or ``(B,)``.
        units: ``"C"`` or ``"K"``.
        body_temperature: in C; default the median of each video's first frame.
        noise_sd: white-noise sd of the frames in K; default measured by
            :func:`anra_torch.balance.noise.estimate_noise_sd`.

    Returns:
        :class:`DepthParameters`, computed in float64 without gradients. Where no fit is possible
        ``valid`` is False, the values are NaN and the message says why.

    Raises:
        ValueError: bad shapes, spacings, units, noise sd, fewer than 2 frames or non-finite frames.
        TypeError: frames that are not a real tensor or array, values that are not numbers.

    Shape:
        ``frames`` ``(B, T, H, W)`` -> values ``(B,)``; ``(T, H, W)`` -> single values.
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
        spectrum = cooling_modes(rise, dx_, dt_, noise)
        c = cooling_data(rise, dx_, dt_, noise, start, spectrum=spectrum)
        used = (c.weight > 0).sum(1)
        valid = (cooling >= MIN_COOLING_FRAMES) & (used >= 3)
        theta, r, jac = _levenberg_marquardt(c, _start(c))
        se = _errors(c, theta, r, jac, noise)
        misfit = _misfit(c, r, noise)
        # The edges' part: the frames continued with their curvature mirrored instead (the other plausible
        # continuation beyond the window) move the fit by about what the continuation can err.
        edges = _shift(cooling_data(rise, dx_, dt_, noise, start, mirrored=True), theta, r, jac)
        # The frames' sampling at the switch-off (see :func:`square_root_drop`): weight 1/3, the truth
        # anywhere between none and the copy's change (a switch-off anywhere between two frames).
        sampling = _shift(_dropped(rise, dx_, dt_, noise, start, spectrum), theta, r, jac)
        se = torch.sqrt(se**2 + edges**2 + BETWEEN_WEIGHT * sampling**2)
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
