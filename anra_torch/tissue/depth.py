"""Subsurface temperature and damage in depth from the measured surface: the bioheat forward problem.

Under surface heating (contact burns, electrosurgery, far-infrared and CO2 lasers: the heat is absorbed
at the surface) the temperature below the frame is fixed by the measured surface history and the tissue's
diffusivity ``a`` and loss (perfusion) rate ``b``: with ``theta = T - T_body``::

    d theta / dt = a (d_xx + d_yy + d_zz) theta - b theta,   theta(x, y, 0, t) = measured surface,

in a half-space (or a layer of a given thickness whose bottom stays at ``T_body``), starting in equilibrium
with the first frame. A well-posed forward problem: no inversion.

How it is solved (chosen by measuring, see ``experiments/damage_depth.py``): the lateral terms matter
(under a spot 1-2.5 mm wide heat leaves sideways as well as downwards), so the frame is the boundary of a
3-D problem. With uniform ``a`` and ``b`` it separates exactly:

* laterally, the cosine modes (DCT-II) of the frame, or of the frame continued ``margin`` mm beyond its
  edges (:func:`~anra_torch.tissue.depth_solver.widen`: the frame is a window, and its edges then neither
  hold the heat in nor invent it), each with its own decay ``c = a |k|^2 + b`` (``k = pi (p / H, q / W) /
  dx``, the continuous wavenumbers); a node at depth ``z`` takes the modes with ``|k| z < 9.2`` (the
  others reach it below 1e-4 of their surface amplitude);
* in depth, the second-order finite-difference operator on nodes ``0 = z_0 < z_1 < ...`` whose spacing
  grows geometrically from :data:`FIRST_STEP` (the profiles broaden with depth), down to a bottom so deep
  that no heat reaches it in the record (or a shallower layer's: the grid stops where the heat does,
  whatever the thickness);
* in time, each mode (lateral x depth eigenmode) is integrated EXACTLY between frames for a surface that
  varies linearly between them (an exponential integrator: ``phi_1``, ``phi_2``), so the frame rate sets no
  stability limit and the only errors are the depth grid's and the surface's sampling.

The march steps from frame to frame (a recurrence: each step is one vectorised update of every video's,
pixel's and mode's state), and the physical temperatures of a block of frames are formed at once.
Everything runs on the input's device in its dtype (constants built once in float64 and cached) and is
differentiable with respect to the frames, ``a`` and ``b``.

Damage in depth (:func:`damage_in_depth`): Omega and CEM43 of every depth node's history
(:class:`~anra_torch.tissue.depth_doses.DoseAccumulator`, the rules of :mod:`~anra_torch.tissue.dose`), the
peak-temperature profile, the damage depth (the deepest point with ``Omega >= 1``: ``ln Omega``
interpolated linearly between nodes) and the depth of a CEM43 threshold, each with a standard error
propagated from the standard errors of ``a`` and ``b`` (one extra solve each: the linearised propagation),
from the frames' noise (analytically: :mod:`~anra_torch.tissue.depth_errors`) and from the frames'
sampling in time (the two dose rules' difference). Memory is flat in the number of frames: the march
forms the temperatures a block of frames at a time.

Units: mm, s, C, mm^2/s, 1/s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.checks import number
from anra_torch.tissue.depth_doses import DOSE_FLOOR, OMEGA_FLOOR, DoseAccumulator
from anra_torch.tissue.depth_errors import noise_correlation, perturbed_copies, spread
from anra_torch.tissue.depth_solver import (
    FIRST_STEP,
    GROWTH,
    bottom_depth,
    check_rate,
    dct_matrices,
    depth_nodes,
    frame_problem,
    heat_input,
    march,
    node_temperatures,
    solver_nodes,
    surface_rise,
    widen,
)
from anra_torch.tissue.dose import RULES, SKIN, ArrheniusConstants

__all__ = [
    "CEM43_THRESHOLD",
    "DOSE_FLOOR",
    "OMEGA_FLOOR",
    "DepthMaps",
    "damage_in_depth",
    "subsurface_temperature",
    "surface_heat_input",
    "threshold_depth",
]

CEM43_THRESHOLD = 240.0
"""Default CEM43 threshold (min) of :attr:`DepthMaps.cem43_depth`: thermal necrosis of most tissues."""
_BLOCK_VALUES = 2**22  # temperatures formed per block of frames (32 MiB in float64)
_COARSE_GROWTH = 1.15  # the depth grid of the pass that finds how deep the heat goes
_F64 = torch.float64
_TINY = 1e-300  # a dose floor for logarithms


def _nodes_with(wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The geometric grid down to the deepest ``wanted`` depth with every ``wanted`` depth inserted (grid
    nodes closer than a third of their spacing to one dropped), and where each wanted depth sits."""
    grid = depth_nodes(max(float(wanted.max()), FIRST_STEP))
    spacing = np.diff(grid, append=grid[-1] + (grid[-1] - grid[-2]))
    distance = np.abs(grid[:, None] - wanted[None, :]).min(1)
    nodes = np.unique(np.concatenate([grid[(distance > spacing / 3) | (grid == 0.0)], wanted]))
    return nodes, np.searchsorted(nodes, wanted)


def subsurface_temperature(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    depths: Sequence[float] | Tensor,
    *,
    diffusivity: float | Tensor,
    loss_rate: float | Tensor = 0.0,
    body_temperature: float | Tensor | None = None,
    thickness: float | None = None,
    units: str = "C",
) -> Tensor:
    """Temperature below every pixel at ``depths``, at every frame, from the measured surface.

    Solves ``dT/dt = a Lap T - b (T - T_body)`` under the frame with the frames as the surface temperature
    (surface heating; see the module docstring), starting in equilibrium with the first frame.

    Args:
        frames: surface temperatures in ``units``, ``(T, H, W)`` or ``(B, T, H, W)``, finite.
        dt: frame period in s (number or ``(B,)``).
        dx: pixel size in mm (number or ``(B,)``).
        depths: depths in mm (>= 0; 0 is the surface itself).
        diffusivity: ``a`` in mm^2/s (number or ``(B,)``, positive).
        loss_rate: ``b`` in 1/s (perfusion; number or ``(B,)``, >= 0).
        body_temperature: C (number or ``(B,)``); default the median of each video's first frame.
        thickness: None for a half-space; else a layer's thickness in mm, its bottom held at ``T_body``.
        units: ``"C"`` or ``"K"`` (the output is in Celsius).

    Returns:
        Temperatures in C, ``(B, T, Z, H, W)`` (``(T, Z, H, W)`` for an unbatched input), in the frames'
        dtype and device; differentiable with respect to ``frames``, ``diffusivity`` and ``loss_rate``.

    Raises:
        ValueError: bad shapes, spacings, rates, depths, non-finite frames, or units that do not fit.
        TypeError: rates that are not numbers.

    Shape:
        ``frames`` ``(B, T, H, W)`` -> ``(B, T, Z, H, W)`` with ``Z = len(depths)``.

    Example:
        >>> frames = torch.full((3, 4, 4), 37.0, dtype=torch.float64)
        >>> frames[1:] = 80.0  # the surface steps to 80 C
        >>> t = subsurface_temperature(frames, 0.5, 0.1, [0.0, 0.2], diffusivity=0.14)
        >>> tuple(t.shape), round(float(t[0, 1, 0, 0]), 1)
        ((3, 2, 4, 4), 37.0)
    """
    rise, batched, dt_, dx_, body = surface_rise(frames, dt, dx, units, body_temperature)
    batch, n = rise.shape[:2]
    a = check_rate(diffusivity, "diffusivity", "mm^2/s", batch, rise, positive=True)
    b = check_rate(loss_rate, "loss_rate", "1/s", batch, rise, positive=False)
    wanted = np.asarray(torch.as_tensor(depths, dtype=_F64, device="cpu").reshape(-1))
    if wanted.size == 0 or not np.isfinite(wanted).all() or (wanted < 0).any():
        raise ValueError(f"depths must be finite depths >= 0 mm, got {wanted.tolist()}")
    order = np.argsort(wanted)
    reported, where = _nodes_with(wanted[order])
    duration = float(dt_.detach().max()) * (n - 1)
    nodes = solver_nodes(reported, bottom_depth(thickness, float(reported[-1]), a, duration))
    problem = frame_problem(rise, dt_, dx_, a, b, nodes, len(reported))
    block = max(1, _BLOCK_VALUES // max(1, rise[0, 0].numel() * len(reported) * batch))
    parts = [node_temperatures(rise, problem, start, states) for start, states in march(problem, block)]
    out = torch.cat(parts, 1)[:, :, torch.from_numpy(where[np.argsort(order)]).to(rise.device)]
    out = out + body.view(-1, 1, 1, 1, 1)
    return out if batched else out[0]


# ------------------------------------------------------------------------------------------ damage
@dataclass(frozen=True)
class DepthMaps:
    """Output of :func:`damage_in_depth` (batched: leading ``B``; a single video drops it).

    Attributes:
        depths: node depths in mm, ``(Z,)``; 0 (the surface) first.
        peak: peak temperature (C) at every node, ``(B, Z, H, W)``; ``peak_std`` its standard error (K).
        omega: Arrhenius damage integral at every node, ``(B, Z, H, W)``.
        cem43: CEM43 (min) at every node, ``(B, Z, H, W)``.
        damage_depth: deepest point with ``Omega >= 1`` (mm; 0 where none), ``(B, H, W)``;
            ``damage_depth_std`` its standard error (mm).
        cem43_depth: deepest point with ``CEM43 >= cem43_threshold`` (mm), ``(B, H, W)``;
            ``cem43_depth_std`` its standard error (mm).
        cem43_threshold: the CEM43 threshold (min).
        diffusivity, loss_rate: the ``a`` (mm^2/s) and ``b`` (1/s) used, ``(B,)``; ``diffusivity_std``,
            ``loss_rate_std`` and ``noise_sd`` (K) the standard errors propagated.
        body_temperature: C, ``(B,)``.
        truncated: pixels whose damage reaches the deepest node (their depth is a lower bound),
            ``(B, H, W)``; never the case by construction unless ``max_depth`` was given.
    """

    depths: Tensor
    peak: Tensor
    peak_std: Tensor
    omega: Tensor
    cem43: Tensor
    damage_depth: Tensor
    damage_depth_std: Tensor
    cem43_depth: Tensor
    cem43_depth_std: Tensor
    cem43_threshold: float
    diffusivity: Tensor
    diffusivity_std: Tensor
    loss_rate: Tensor
    loss_rate_std: Tensor
    noise_sd: Tensor
    body_temperature: Tensor
    truncated: Tensor

    def unbatched(self) -> DepthMaps:
        """The same maps with the batch dimension of size 1 removed."""
        keep = ("depths", "cem43_threshold")
        return replace(self, **{k: v[0] for k, v in self.__dict__.items() if k not in keep})

    def cropped(self, margin: int) -> DepthMaps:
        """The maps without ``margin`` pixels on every side (a widened frame's own)."""
        inner = (..., slice(margin, -margin), slice(margin, -margin))
        return replace(
            self, **{k: v[inner] for k, v in self.__dict__.items() if isinstance(v, Tensor) and v.ndim >= 3}
        )


def threshold_depth(values: Tensor, depths: Tensor, threshold: float | Tensor) -> Tensor:
    """Deepest point where ``values >= threshold`` along the depth axis, ``log(values)`` interpolated
    linearly between the nodes around it (0 where no node reaches it). Differentiable in ``values``.

    Args:
        values: a positive dose at every node (Omega, CEM43), ``(..., Z, H, W)``.
        depths: node depths in mm, ``(Z,)``, increasing.
        threshold: the dose (> 0).

    Returns:
        Depth in mm, ``(..., H, W)``.

    Shape:
        ``(..., Z, H, W)`` -> ``(..., H, W)``.

    Example:
        >>> omega = torch.tensor([8.0, 2.0, 0.5]).view(3, 1, 1)  # ln: 2.08, 0.69, -0.69
        >>> round(float(threshold_depth(omega, torch.tensor([0.0, 0.1, 0.2]), 1.0)), 6)
        0.15
    """
    z = depths.to(device=values.device, dtype=values.dtype)
    above = values >= threshold
    n = values.shape[-3]
    index = torch.arange(n, device=values.device).view(-1, 1, 1)
    last = torch.where(above, index, -1).amax(-3, keepdim=True)  # deepest node at or above
    here = last.clamp_min(0)
    below = (here + 1).clamp_max(n - 1)
    log_here = torch.log(values.gather(-3, here).clamp_min(1e-300) / threshold)
    log_below = torch.log(values.gather(-3, below).clamp_min(1e-300) / threshold)
    span = (log_here - log_below).clamp_min(1e-12)
    fraction = torch.where(below > here, (log_here / span).clamp(0.0, 1.0), torch.zeros_like(span))
    depth = z[here] + fraction * (z[below] - z[here])
    return torch.where(last >= 0, depth, torch.zeros_like(depth)).squeeze(-3)


def _threshold_noise(values: Tensor, variance: Tensor, depths: Tensor, threshold: float) -> Tensor:
    """The variance (mm^2) of :func:`threshold_depth` from the dose's noise variance ``variance`` at every
    node: ``Var(ln D)`` interpolated to the crossing, over the squared slope of ``ln D`` there."""
    z = depths.to(device=values.device, dtype=values.dtype)
    n = values.shape[-3]
    index = torch.arange(n, device=values.device).view(-1, 1, 1)
    last = torch.where(values >= threshold, index, -1).amax(-3, keepdim=True)
    here = last.clamp_min(0)
    below = (here + 1).clamp_max(n - 1)
    log_here = torch.log(values.gather(-3, here).clamp_min(1e-300) / threshold)
    log_below = torch.log(values.gather(-3, below).clamp_min(1e-300) / threshold)
    span = (log_here - log_below).clamp_min(1e-12)
    fraction = (log_here / span).clamp(0.0, 1.0)
    relative = variance / values.clamp_min(1e-300) ** 2  # Var(ln D) at every node
    mixed = (1 - fraction) * relative.gather(-3, here) + fraction * relative.gather(-3, below)
    slope = span / (z[below] - z[here]).clamp_min(1e-12)
    out = torch.where((last >= 0) & (below > here), mixed / slope**2, torch.zeros_like(mixed))
    return out.squeeze(-3)


def _reach(
    rise: Tensor, dt: Tensor, dx: Tensor, a: Tensor, b: Tensor, body: Tensor, thickness: object
) -> float:
    """Deepest depth (mm) where any video's peak exceeds :data:`DOSE_FLOOR`, one coarse node deeper: the
    3-D solve on a coarse depth grid (spacings growing :data:`_COARSE_GROWTH`-fold) of the frames averaged
    over blocks of pixels (at most 32 x 32 of them), peak only."""
    floor = DOSE_FLOOR - body  # K, (B,)
    if not bool((rise.detach().flatten(1).amax(1) > floor).any()):
        return 0.0
    duration = float(dt.max()) * (rise.shape[1] - 1)
    reach = 7.0 * math.sqrt(float(a.max()) * duration) + 0.1  # where an erfc tail falls below 1e-6
    if thickness is not None:
        reach = min(reach, float(thickness) * (1.0 - 1e-9))
    reported = _above(depth_nodes(max(reach, 2 * FIRST_STEP), growth=_COARSE_GROWTH), thickness)
    nodes = solver_nodes(reported, bottom_depth(thickness, float(reported[-1]), a, duration))
    factor = max(1, math.ceil(max(rise.shape[-2:]) / 32))
    coarse = rise.detach()
    if factor > 1:  # block means: a spot's peak at depth is smooth across pixels
        b_, t, h, w = coarse.shape
        coarse = torch.nn.functional.avg_pool2d(
            coarse.reshape(b_ * t, 1, h, w), factor, factor, ceil_mode=True
        )
        coarse = coarse.reshape(b_, t, *coarse.shape[-2:])
    problem = frame_problem(coarse, dt, dx * factor, a.detach(), b.detach(), nodes, len(reported))
    peak = torch.full((rise.shape[0], len(reported)), -torch.inf, device=rise.device, dtype=rise.dtype)
    block = max(1, _BLOCK_VALUES // coarse[:, 0].numel() // len(reported))
    for start, states in march(problem, block):
        peak = torch.maximum(peak, node_temperatures(coarse, problem, start, states).amax((1, 3, 4)))
    warm = (peak > floor.view(-1, 1)).any(0)
    deepest = int(torch.nonzero(warm).max()) if bool(warm.any()) else 0
    return float(reported[min(deepest + 1, len(reported) - 1)])


def _above(nodes: np.ndarray, thickness: object) -> np.ndarray:
    """``nodes`` above a layer's bottom (the grid passes its last depth by up to one spacing)."""
    if thickness is None:
        return nodes
    kept = nodes[nodes < number(thickness, "thickness", "mm", positive=True)]
    return kept if len(kept) >= 2 else nodes[:2]


def _parameters(values: dict[str, object], like: Tensor) -> list[Tensor]:
    """``a``, ``b`` and the three standard errors (detached) as ``(B,)``, checked."""
    units = {"diffusivity": "mm^2/s", "loss_rate": "1/s", "diffusivity_std": "mm^2/s", "loss_rate_std": "1/s"}
    out = []
    for name, value in values.items():
        x = check_rate(value, name, units.get(name, "K"), like.shape[0], like, positive=name == "diffusivity")
        out.append(x if name in ("diffusivity", "loss_rate") else x.detach())
    return out


def damage_in_depth(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    *,
    diffusivity: float | Tensor,
    loss_rate: float | Tensor = 0.0,
    diffusivity_std: float | Tensor = 0.0,
    loss_rate_std: float | Tensor = 0.0,
    noise_sd: float | Tensor = 0.0,
    body_temperature: float | Tensor | None = None,
    thickness: float | None = None,
    units: str = "C",
    constants: ArrheniusConstants = SKIN,
    rule: str = "linear",
    cem43_threshold: float = CEM43_THRESHOLD,
    max_depth: float | None = None,
    growth: float = GROWTH,
    lateral: bool = True,
    margin: float = 0.0,
    coarse: int = 1,
) -> DepthMaps:
    """Omega, CEM43 and the peak temperature at every depth node under every pixel, the damage depth and
    the depth of a CEM43 threshold, each with its standard error.

    The standard errors propagate those of ``a`` and ``b`` to first order (one extra solve with ``a +
    diffusivity_std``, one with ``b + loss_rate_std``: the root sum of squares of the changes), the frames'
    white noise of sd ``noise_sd`` analytically (:mod:`anra_torch.tissue.depth_errors`: no noise copies)
    and the frames' sampling in time (half the difference between the depths by the two integration rules
    of :data:`anra_torch.tissue.RULES`), added in quadrature.

    Args:
        frames: surface temperatures in ``units`` (finite), ``(T, H, W)`` or ``(B, T, H, W)``; the solve
            runs in their dtype (float32 is within the error budget: 1e-5 K).
        dt: frame period in s; dx: pixel size in mm (numbers or ``(B,)``).
        diffusivity: ``a`` (mm^2/s); loss_rate: ``b`` (1/s); numbers or ``(B,)``.
        diffusivity_std, loss_rate_std: their standard errors (0: not propagated).
        noise_sd: the frames' white-noise sd in K (0: not propagated).
        body_temperature: C; default the median of each video's first frame.
        thickness: None for a half-space, else a layer's thickness (mm) over tissue at ``T_body`` (a layer
            deeper than the heat reaches in the record is solved as the half-space it is then).
        units: ``"C"`` or ``"K"``.
        constants: Arrhenius constants (default skin).
        rule: how each node's history is integrated (:data:`anra_torch.tissue.RULES`).
        cem43_threshold: CEM43 (min) whose depth is mapped.
        max_depth: deepest node (mm); default one coarse node below the deepest point where the peak
            exceeds :data:`DOSE_FLOOR` (a coarse pass with ``a + 2 diffusivity_std``).
        growth: ratio of consecutive depth spacings (:data:`GROWTH`; from :data:`FIRST_STEP` at the surface).
        lateral: False: each pixel's column on its own (1-D, no heat sideways; too deep under small spots).
        margin: mm by which the frames are continued beyond every edge
            (:func:`anra_torch.tissue.depth_solver.widen`) so that heat crosses the frame's edges as in the
            tissue (0: the frame's edges hold it in); the maps are the frame's.
        coarse: the perturbed solves (``a + se``, ``b + se``) on the frames' ``coarse x coarse`` px means
            (their changes vary smoothly across pixels; 2 halves the work), the base at full resolution.

    Returns:
        :class:`DepthMaps`; differentiable with respect to ``frames``, ``diffusivity`` and ``loss_rate``.

    Raises:
        ValueError: bad shapes, spacings, rates, rule, threshold or non-finite frames.
        TypeError: rates that are not numbers, ``constants`` not :class:`ArrheniusConstants`.

    Shape:
        ``frames`` ``(B, T, H, W)``; maps ``(B, H, W)``; profiles ``(B, Z, H, W)``.
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {', '.join(map(repr, RULES))}, got {rule!r}")
    if not isinstance(constants, ArrheniusConstants):
        raise TypeError(f"constants must be ArrheniusConstants, got {type(constants).__name__}")
    cem43_threshold = number(cem43_threshold, "cem43_threshold", "min", positive=True)
    rise, batched, dt_, dx_, body = surface_rise(frames, dt, dx, units, body_temperature)
    given = {"diffusivity": diffusivity, "loss_rate": loss_rate, "diffusivity_std": diffusivity_std}
    a, b, *errors = _parameters(given | {"loss_rate_std": loss_rate_std, "noise_sd": noise_sd}, rise)
    pixels = math.ceil(number(margin, "margin", "mm", minimum=0.0) / float(dx_.min()) - 1e-9)
    rise = widen(rise, pixels) if pixels else rise
    nodes, reported = _grid(rise, dt_, dx_, (a, b), errors, body, (thickness, max_depth, growth))
    settings = (rule, constants, cem43_threshold, lateral, int(number(coarse, "coarse", "px", minimum=1)))
    maps = _solve(rise, dt_, dx_, body, (a, b), errors, nodes, reported, settings)
    maps = maps.cropped(pixels) if pixels else maps
    return maps if batched else maps.unbatched()


def _grid(
    rise: Tensor, dt: Tensor, dx: Tensor, rates: tuple, errors: list, body: Tensor, settings: tuple
) -> tuple[tuple[float, ...], int]:
    """The solver's depth nodes and how many of them are reported: down to ``max_depth`` (default where the
    peak with ``a + 2 se`` exceeds :data:`DOSE_FLOOR`), then to a bottom no heat reaches in the record."""
    thickness, max_depth, growth = settings
    a, b = rates
    if max_depth is None:
        bounds = (a.detach() + 2 * errors[0], (b.detach() - 2 * errors[1]).clamp_min(0.0))
        max_depth = _reach(rise, dt, dx, *bounds, body, thickness)
    reported = depth_nodes(
        max(number(max_depth, "max_depth", "mm", minimum=0.0), 2 * FIRST_STEP), growth=growth
    )
    reported = _above(reported, thickness) if max_depth < float(thickness or math.inf) else reported
    duration = float(dt.max()) * (rise.shape[1] - 1)
    bottom = bottom_depth(thickness, float(reported[-1]), a + 2 * errors[0], duration)
    return solver_nodes(reported, bottom), len(reported)


def _solve(
    rise: Tensor,
    dt: Tensor,
    dx: Tensor,
    body: Tensor,
    rates: tuple[Tensor, Tensor],
    errors: tuple[Tensor, Tensor, Tensor],
    nodes: tuple,
    reported: int,
    settings: tuple,
) -> DepthMaps:
    """The march of the base problem and its perturbed copies (on ``coarse x coarse`` pixel means), their
    doses and the maps with their spread."""
    rule, constants, cem43_threshold, lateral, coarse = settings
    a, b = rates
    batch, (h, w) = rise.shape[0], rise.shape[-2:]
    span = (nodes, reported)
    depths = torch.tensor(nodes[:reported], dtype=_F64, device="cpu").to(rise.device)
    variance, rho = noise_correlation(depths, a, b, dt, dx, (h, w), errors[2])
    if coarse > 1:  # the base at full resolution, the copies' changes on pixel means
        doses = copies = _march_doses(rise, (dt, dx, body), (a, b), rho, settings, span)
        pooled = F.avg_pool2d(rise.reshape(-1, 1, h, w), coarse, coarse, ceil_mode=True)
        pooled = pooled.reshape(batch, -1, *pooled.shape[-2:])
        stacked, diffusivities, losses, weights = perturbed_copies(pooled, a, b, errors[:2])
        if len(weights):
            per_video = (dt, dx * coarse, body)
            copies = _march_doses(stacked, per_video, (diffusivities, losses), rho[:0], settings, span)
    else:
        stacked, diffusivities, losses, weights = perturbed_copies(rise, a, b, errors[:2])
        doses = copies = _march_doses(stacked, (dt, dx, body), (diffusivities, losses), rho, settings, span)
    node_variance = variance.view(batch, -1, 1, 1)
    maps = {}
    for name, threshold in (("omega", 1.0), ("cem43", cem43_threshold)):
        dose = getattr(doses, name)[:batch]
        value = threshold_depth(dose, depths, threshold)
        if coarse == 1:  # the copies' own depths
            parameters = spread(threshold_depth(getattr(copies, name), depths, threshold), weights)[1] ** 2
        else:  # the copies' change of ln D at every node, interpolated to the pixels, at the base's crossing
            log = torch.log(getattr(copies, name).clamp_min(_TINY))  # (V B, Z, H', W')
            cold = (log <= math.log(_TINY)).reshape(-1, batch, *log.shape[1:]).any(0)  # never hot: no rate
            change = _upsampled(spread(log, weights)[1].masked_fill(cold, 0.0), h, w)
            parameters = _threshold_noise(dose, change.to(dose.dtype) ** 2 * dose**2, depths, threshold)
        sampling = 0.5 * (threshold_depth(doses.other(name), depths, threshold) - value)
        noise = _threshold_noise(dose, doses.variance[name] * node_variance, depths, threshold)
        maps[name] = (value, torch.sqrt(parameters + sampling**2 + noise).to(value.dtype))
    peak_std = spread(copies.peak, weights)[1]
    peak = doses.peak[:batch]
    return DepthMaps(
        depths=depths,
        peak=peak,
        peak_std=torch.sqrt(_upsampled(peak_std, h, w) ** 2 + node_variance.to(peak.dtype)),
        omega=doses.omega[:batch],
        cem43=doses.cem43[:batch],
        damage_depth=maps["omega"][0],
        damage_depth_std=maps["omega"][1],
        cem43_depth=maps["cem43"][0],
        cem43_depth_std=maps["cem43"][1],
        cem43_threshold=cem43_threshold,
        diffusivity=a,
        diffusivity_std=errors[0],
        loss_rate=b,
        loss_rate_std=errors[1],
        noise_sd=errors[2],
        body_temperature=body,
        truncated=doses.omega[:batch, -1] >= 1.0,
    )


def _upsampled(x: Tensor, h: int, w: int) -> Tensor:
    """``(B, Z, H', W')`` values at the centres of blocks of ``ceil(H / H')`` px, interpolated bilinearly to
    the ``(B, Z, H, W)`` pixels (the same tensor when ``H' = H``)."""
    if x.shape[-2:] == (h, w):
        return x
    factor = math.ceil(h / x.shape[-2])
    size = (x.shape[-2] * factor, x.shape[-1] * factor)
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)[..., :h, :w]


def _march_doses(
    stacked: Tensor,
    per_video: tuple[Tensor, Tensor, Tensor],
    rates: tuple[Tensor, Tensor],
    rho: Tensor,
    settings: tuple,
    nodes: tuple[tuple, int],
) -> DoseAccumulator:
    """Peak, Omega and CEM43 at the reported nodes of the stacked ``(V B, T, H, W)`` rises (the base videos
    first), and for the base videos the doses by the other rule and their noise variance.
    ``per_video``: ``dt``, ``dx`` and the body temperature, ``(B,)`` each; ``rho`` ``(B, Z)`` (``(0, Z)``:
    no video gets the other rule nor the noise)."""
    rule, constants, _, lateral, _ = settings
    nodes, reported = nodes
    n, (h, w) = stacked.shape[0], stacked.shape[-2:]
    batch = per_video[0].numel()
    index = (torch.arange(n, device="cpu") % batch).to(stacked.device)
    spacing, size, warm = (x[index] for x in per_video)
    problem = frame_problem(stacked, spacing, size, *rates, nodes, reported, lateral=lateral)
    doses = DoseAccumulator(stacked, (n, reported, h, w), spacing, rule, constants, len(rho), rho)
    offset = warm.view(-1, 1, 1, 1, 1)
    block = max(1, _BLOCK_VALUES // (n * reported * h * w))
    for start, states in march(problem, block):
        doses.add(offset + node_temperatures(stacked, problem, start, states))
    return doses


def surface_heat_input(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    *,
    diffusivity: float | Tensor,
    loss_rate: float | Tensor = 0.0,
    body_temperature: float | Tensor | None = None,
    thickness: float | None = None,
    units: str = "C",
) -> Tensor:
    """Heat that has entered the tissue through the surface under each pixel since the first frame.

    The surface flux the measured surface implies (the solution's ``a d theta / dz`` at ``z = 0``,
    integrated over time; heat per area over ``rho c``, in K mm): where no source acts it stays flat, so it
    is how the depth model is checked against the recording and how ``a`` and ``b`` are fitted
    (:func:`anra_torch.tissue.fit_depth_parameters`). Computed with the depth grid of :func:`depth_nodes`
    down to ``7 sqrt(a t)`` (the heat's reach over the record).

    Args:
        frames: surface temperatures in ``units``, finite, ``(T, H, W)`` or ``(B, T, H, W)``.
        dt, dx: frame period (s) and pixel size (mm).
        diffusivity, loss_rate: ``a`` (mm^2/s) and ``b`` (1/s), numbers or ``(B,)``.
        body_temperature: C; default the median of each video's first frame.
        thickness: None for a half-space, else a layer's (mm).
        units: ``"C"`` or ``"K"``.

    Returns:
        Cumulative heat input in K mm, ``(B, T, H, W)`` (0 at the first frame).

    Raises:
        ValueError: bad shapes, spacings, rates or non-finite frames.

    Shape:
        ``(B, T, H, W)`` -> ``(B, T, H, W)``.
    """
    rise, batched, dt_, dx_, _ = surface_rise(frames, dt, dx, units, body_temperature)
    batch = rise.shape[0]
    a = check_rate(diffusivity, "diffusivity", "mm^2/s", batch, rise, positive=True)
    b = check_rate(loss_rate, "loss_rate", "1/s", batch, rise, positive=False)
    duration = float(dt_.max()) * (rise.shape[1] - 1)
    reach = 7.0 * math.sqrt(float(a.detach().max()) * duration) + 0.1
    if thickness is not None:
        reach = min(reach, float(thickness) * (1.0 - 1e-9))
    reported = depth_nodes(reach)
    nodes = solver_nodes(reported, bottom_depth(thickness, float(reported[-1]), a, duration))
    heat = heat_input(frame_problem(rise, dt_, dx_, a, b, nodes, 2))
    ch, cw = dct_matrices(rise)
    out = ch.T @ heat.reshape(rise.shape) @ cw
    return out if batched else out[0]
