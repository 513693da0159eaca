"""Damage in depth under every pixel from the measured surface: the doses of the solve of
:mod:`~anra_torch.tissue.depth`.

:func:`damage_in_depth` gives Omega, CEM43 and the peak temperature at every depth node, the damage
depth, which is the deepest point with ``Omega >= 1``, and the depth of a CEM43 threshold. Each comes with
a standard error from those of ``a`` and ``b``, from the frames' noise and from their sampling in time.
Memory does not grow with the number of frames. How the errors are propagated: ``docs/architecture.md``,
"The depth model".

Units: mm, s, C, mm^2/s, 1/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.checks import number
from anra_torch.tissue.depth_cooling import cooling_start, margin_mm
from anra_torch.tissue.depth_doses import DOSE_FLOOR, OMEGA_FLOOR, DoseAccumulator
from anra_torch.tissue.depth_errors import (
    noise_correlation,
    perturbed_copies,
    spread,
    threshold_depth,
    threshold_variance,
)
from anra_torch.tissue.depth_solver import (
    BLOCK_VALUES,
    FIRST_STEP,
    GROWTH,
    bottom_depth,
    check_rate,
    depth_nodes,
    frame_problem,
    march,
    node_temperatures,
    solver_nodes,
    surface_rise,
)
from anra_torch.tissue.depth_window import Beyond, pooled_window, widen, window_problem, window_temperatures
from anra_torch.tissue.dose import RULES, SKIN, ArrheniusConstants

__all__ = [
    "CEM43_THRESHOLD",
    "DOSE_FLOOR",
    "OMEGA_FLOOR",
    "DepthMaps",
    "DepthSettings",
    "StandardErrors",
    "damage_in_depth",
    "threshold_depth",
]

CEM43_THRESHOLD = 240.0
"""Default CEM43 threshold (min) of :attr:`DepthMaps.cem43_depth`: thermal necrosis of most tissues."""
_COARSE_GROWTH = 1.15  # the depth grid of the pass that finds how deep the heat goes
_F64 = torch.float64
_TINY = 1e-300  # a dose floor for logarithms


@dataclass(frozen=True)
class DepthMaps:
    """Output of :func:`damage_in_depth`: batched maps lead with ``B``, a single video's drop it.

    Attributes:
        depths: node depths in mm, the surface 0 first, ``(Z,)``.
        peak: peak temperature in C at every node, ``(B, Z, H, W)``; ``peak_std`` its standard error in K.
        omega: Arrhenius damage integral at every node, ``(B, Z, H, W)``.
        cem43: CEM43 in min at every node, ``(B, Z, H, W)``.
        damage_depth: deepest point with ``Omega >= 1`` in mm, 0 where none, ``(B, H, W)``;
            ``damage_depth_std`` its standard error in mm.
        cem43_depth: deepest point with ``CEM43 >= cem43_threshold`` in mm, ``(B, H, W)``;
            ``cem43_depth_std`` its standard error in mm.
        cem43_threshold: the CEM43 threshold in min.
        diffusivity, loss_rate: the ``a`` in mm^2/s and ``b`` in 1/s used, ``(B,)``; ``diffusivity_std``,
            ``loss_rate_std`` and ``noise_sd`` in K: the standard errors propagated.
        body_temperature: in C, ``(B,)``.
        truncated: pixels whose damage reaches the deepest node, so that their depth is a lower bound,
            ``(B, H, W)``; possible only when ``max_depth`` is set.
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


def _reach(
    rise: Tensor, spacing: tuple, rates: tuple, body: Tensor, thickness: object, continued: Beyond | None
) -> float:
    """Deepest depth in mm where any video's peak exceeds :data:`DOSE_FLOOR`, one coarse node deeper: a
    peak-only 3-D solve on a depth grid growing :data:`_COARSE_GROWTH`-fold, of the frames' means over at
    most 32 x 32 blocks of pixels, continued beyond the frame as ``continued`` says.
    ``spacing``: ``dt``, ``dx``; ``rates``: ``a``, ``b``, each ``(B,)``."""
    (dt, dx), (a, b) = spacing, rates
    floor = DOSE_FLOOR - body  # K, (B,)
    if not bool((rise.detach().flatten(1).amax(1) > floor).any()):
        return 0.0
    duration = float(dt.max()) * (rise.shape[1] - 1)
    reach = 7.0 * math.sqrt(float(a.max()) * duration) + 0.1  # where an erfc tail falls below 1e-6
    if thickness is not None:
        reach = min(reach, float(thickness) * (1.0 - 1e-9))
    reported = _above(depth_nodes(max(reach, 2 * FIRST_STEP), growth=_COARSE_GROWTH), thickness)
    nodes = solver_nodes(reported, bottom_depth(thickness, float(reported[-1]), a, duration))
    margin = 0 if continued is None else continued.margin
    factor = max(1, math.ceil((max(rise.shape[-2:]) + 2 * margin) / 32))
    coarse = rise.detach()
    if factor > 1:  # block means: a spot's peak at depth is smooth across pixels
        b_, t, h, w = coarse.shape
        coarse = F.avg_pool2d(coarse.reshape(b_ * t, 1, h, w), factor, factor, ceil_mode=True)
        coarse = coarse.reshape(b_, t, *coarse.shape[-2:])
    if continued is not None and margin:
        noise = None if continued.noise is None else continued.noise / factor
        coarse = widen(coarse, math.ceil(margin / factor), curved=continued.curved, noise=noise)
    problem = frame_problem(coarse, dt, dx * factor, a.detach(), b.detach(), nodes, len(reported))
    peak = torch.full((rise.shape[0], len(reported)), -torch.inf, device=rise.device, dtype=rise.dtype)
    block = max(1, BLOCK_VALUES // coarse[:, 0].numel() // len(reported))
    for start, states in march(problem, block):
        peak = torch.maximum(peak, node_temperatures(coarse, problem, start, states).amax((1, 3, 4)))
    warm = (peak > floor.view(-1, 1)).any(0)
    deepest = int(torch.nonzero(warm).max()) if bool(warm.any()) else 0
    return float(reported[min(deepest + 1, len(reported) - 1)])


def _above(nodes: np.ndarray, thickness: object) -> np.ndarray:
    """``nodes`` above a layer's bottom, which the grid passes by up to one spacing."""
    if thickness is None:
        return nodes
    kept = nodes[nodes < number(thickness, "thickness", "mm", positive=True)]
    return kept if len(kept) >= 2 else nodes[:2]


@dataclass(frozen=True)
class StandardErrors:
    """The standard errors :func:`damage_in_depth` propagates; 0 propagates nothing.

    Attributes:
        diffusivity: of ``a`` in mm^2/s, a number or ``(B,)``.
        loss_rate: of ``b`` in 1/s, a number or ``(B,)``.
        noise_sd: the frames' white-noise sd in K, a number or ``(B,)``.
    """

    diffusivity: float | Tensor = 0.0
    loss_rate: float | Tensor = 0.0
    noise_sd: float | Tensor = 0.0


@dataclass(frozen=True)
class DepthSettings:
    """How :func:`damage_in_depth` integrates the doses and lays out its grid.

    Attributes:
        constants: Arrhenius constants, default skin.
        rule: how each node's history is integrated, one of :data:`anra_torch.tissue.RULES`.
        cem43_threshold: CEM43 in min whose depth is mapped.
        max_depth: deepest node in mm; default one coarse node below the deepest point where the peak
            with ``a`` raised and ``b`` lowered by 2 standard errors exceeds :data:`DOSE_FLOOR`.
        growth: ratio of consecutive depth spacings, from
            :data:`~anra_torch.tissue.depth_solver.FIRST_STEP` at the surface.
        lateral: False solves each pixel's column on its own in 1-D, with no heat sideways.
        margin: mm by which the frames are continued beyond every edge by
            :func:`anra_torch.tissue.depth_window.widen`; 0 lets the frame's edges hold the heat in; None
            continues them as far as the heat reaches over the record,
            :func:`anra_torch.tissue.depth_cooling.margin_mm`. The maps cover the frame's pixels only.
        curved: continue the frames by a Gaussian tail, ``widen``'s ``curved``, instead of a line.
        between: add a copy with the surface between the frames as high as they allow, for the frames'
            sampling in time: :func:`anra_torch.tissue.depth_errors.perturbed_copies`.
        coarse: solve the perturbed copies on the frames' ``coarse x coarse`` px means, the base at full
            resolution.
    """

    constants: ArrheniusConstants = SKIN
    rule: str = "linear"
    cem43_threshold: float = CEM43_THRESHOLD
    max_depth: float | None = None
    growth: float = GROWTH
    lateral: bool = True
    margin: float | None = 0.0
    coarse: int = 1
    curved: bool = False
    between: bool = False


def _parameters(values: dict[str, object], like: Tensor) -> list[Tensor]:
    """``a``, ``b`` and the three standard errors as ``(B,)``, checked; the errors detached."""
    units = {"diffusivity": "mm^2/s", "loss_rate": "1/s", "diffusivity_std": "mm^2/s", "loss_rate_std": "1/s"}
    out = []
    for name, value in values.items():
        x = check_rate(value, name, units.get(name, "K"), like.shape[0], like, positive=name == "diffusivity")
        out.append(x if name in ("diffusivity", "loss_rate") else x.detach())
    return out


def _checked(settings: DepthSettings) -> DepthSettings:
    """``settings`` with its rule, constants, threshold and coarse factor checked."""
    if not isinstance(settings, DepthSettings):
        raise TypeError(f"settings must be DepthSettings, got {type(settings).__name__}")
    if settings.rule not in RULES:
        raise ValueError(f"rule must be one of {', '.join(map(repr, RULES))}, got {settings.rule!r}")
    if not isinstance(settings.constants, ArrheniusConstants):
        raise TypeError(f"constants must be ArrheniusConstants, got {type(settings.constants).__name__}")
    threshold = number(settings.cem43_threshold, "cem43_threshold", "min", positive=True)
    return replace(
        settings, cem43_threshold=threshold, coarse=int(number(settings.coarse, "coarse", "px", minimum=1))
    )


def damage_in_depth(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    *,
    diffusivity: float | Tensor,
    loss_rate: float | Tensor = 0.0,
    errors: StandardErrors = StandardErrors(),
    body_temperature: float | Tensor | None = None,
    thickness: float | None = None,
    units: str = "C",
    settings: DepthSettings = DepthSettings(),
) -> DepthMaps:
    """Omega, CEM43 and the peak temperature at every depth node under every pixel, the damage depth and
    the depth of a CEM43 threshold, each with its standard error.

    The standard error adds in quadrature the parts from the errors of ``a`` and ``b``, to first order,
    from the frames' white noise and from the frames' sampling in time.

    Args:
        frames: finite surface temperatures in ``units``; the solve runs in their dtype.
        dt: frame period in s; dx: pixel size in mm; numbers or ``(B,)``.
        diffusivity: ``a`` in mm^2/s; loss_rate: ``b`` in 1/s; numbers or ``(B,)``.
        errors: the standard errors to propagate, :class:`StandardErrors`.
        body_temperature: in C; default the median of each video's first frame.
        thickness: None for a half-space, else a layer's thickness in mm over tissue at ``T_body``.
        units: ``"C"`` or ``"K"``.
        settings: the doses' rule and constants and the grid, :class:`DepthSettings`.

    Returns:
        :class:`DepthMaps`; differentiable with respect to ``frames``, ``diffusivity`` and ``loss_rate``.

    Raises:
        ValueError: bad shapes, spacings, rates, rule, threshold, margin, depths or thickness, fewer than 2
            frames, non-finite frames, or units that do not fit the values.
        TypeError: frames not a real tensor or array, values that are not numbers, ``settings`` not
            :class:`DepthSettings` or ``constants`` not :class:`ArrheniusConstants`.

    Shape:
        ``frames`` ``(B, T, H, W)``; maps ``(B, H, W)``; profiles ``(B, Z, H, W)``. A single video
        ``(T, H, W)`` gives them without ``B``.
    """
    settings = _checked(settings)
    rise, batched, dt_, dx_, body = surface_rise(frames, dt, dx, units, body_temperature)
    given = {"diffusivity": diffusivity, "loss_rate": loss_rate, "diffusivity_std": errors.diffusivity}
    a, b, *stds = _parameters(given | {"loss_rate_std": errors.loss_rate, "noise_sd": errors.noise_sd}, rise)
    pixels = _margin_pixels(settings, dt_, dx_, rise.shape[1])
    noise = stds[2] if bool((stds[2] > 0).all()) else None
    continued = Beyond(pixels, settings.curved, noise) if pixels else None
    grid = (thickness, settings.max_depth, settings.growth)
    nodes, reported = _grid(rise, dt_, dx_, (a, b), stds, body, grid, continued)
    maps = _solve(rise, (dt_, dx_, body), (a, b), stds, (nodes, reported), settings, continued)
    return maps if batched else maps.unbatched()


def _margin_pixels(settings: DepthSettings, dt: Tensor, dx: Tensor, frames: int) -> int:
    """The margin in whole pixels, a multiple of ``coarse`` so that the copies' pixel means tile the frame;
    None: as far as the heat reaches over the record, :func:`anra_torch.tissue.depth_cooling.margin_mm`."""
    if settings.margin is None:
        margin = margin_mm(float(dt.max()) * (frames - 1))
    else:
        margin = number(settings.margin, "margin", "mm", minimum=0.0)
    pixels = math.ceil(margin / float(dx.min()) - 1e-9)
    return settings.coarse * math.ceil(pixels / settings.coarse)


def _grid(
    rise: Tensor,
    dt: Tensor,
    dx: Tensor,
    rates: tuple,
    errors: list,
    body: Tensor,
    settings: tuple,
    continued: Beyond | None,
) -> tuple[tuple[float, ...], int]:
    """The solver's depth nodes and how many of them are reported: down to ``max_depth``, by default where
    the peak with ``a + 2 se``, ``b - 2 se`` exceeds :data:`DOSE_FLOOR`, then to a bottom no heat reaches."""
    thickness, max_depth, growth = settings
    a, b = rates
    if max_depth is None:
        bounds = (a.detach() + 2 * errors[0], (b.detach() - 2 * errors[1]).clamp_min(0.0))
        max_depth = _reach(rise, (dt, dx), bounds, body, thickness, continued)
    reported = depth_nodes(
        max(number(max_depth, "max_depth", "mm", minimum=0.0), 2 * FIRST_STEP), growth=growth
    )
    reported = _above(reported, thickness) if max_depth < float(thickness or math.inf) else reported
    duration = float(dt.max()) * (rise.shape[1] - 1)
    bottom = bottom_depth(thickness, float(reported[-1]), a + 2 * errors[0], duration)
    return solver_nodes(reported, bottom), len(reported)


def _solve(
    rise: Tensor,
    per_video: tuple[Tensor, Tensor, Tensor],
    rates: tuple[Tensor, Tensor],
    errors: list[Tensor],
    grid: tuple[tuple, int],
    settings: DepthSettings,
    continued: Beyond | None,
) -> DepthMaps:
    """The march of the base problem and of its perturbed copies on ``coarse x coarse`` pixel means, their
    doses and the maps with their spread. ``per_video``: ``dt``, ``dx``, the body temperature;
    ``continued``: how the frames are continued beyond the window, :func:`window_problem`, or None."""
    dt, dx, body = per_video
    a, b = rates
    coarse, batch, (h, w) = settings.coarse, rise.shape[0], rise.shape[-2:]
    depths = torch.tensor(grid[0][: grid[1]], dtype=_F64, device="cpu").to(rise.device)
    variance, rho = noise_correlation(depths, a, b, dt, dx, (h, w), errors[2])
    switch = cooling_start(rise) - 2 if settings.between else None  # the last frame before the switch-off
    if coarse > 1:  # the base at full resolution, the copies' changes on pixel means
        doses = copies = _march_doses(rise, per_video, (a, b), rho, settings, (*grid, continued))
        pooled = F.avg_pool2d(rise.reshape(-1, 1, h, w), coarse, coarse, ceil_mode=True)
        pooled = pooled.reshape(batch, -1, *pooled.shape[-2:])
        stacked, diffusivities, losses, weights = perturbed_copies(pooled, a, b, errors[:2], switch=switch)
        if len(weights):
            coarser, within = (dt, dx * coarse, body), (*grid, pooled_window(continued, coarse, len(weights)))
            copies = _march_doses(stacked, coarser, (diffusivities, losses), rho[:0], settings, within)
    else:
        stacked, diffusivities, losses, weights = perturbed_copies(rise, a, b, errors[:2], switch=switch)
        within = (*grid, pooled_window(continued, 1, len(weights)))
        doses = copies = _march_doses(stacked, per_video, (diffusivities, losses), rho, settings, within)
    node_variance = variance.view(batch, -1, 1, 1)
    maps = {
        name: _depth_map(name, (doses, copies, weights), depths, node_variance, (threshold, coarse))
        for name, threshold in (("omega", 1.0), ("cem43", settings.cem43_threshold))
    }
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
        cem43_threshold=settings.cem43_threshold,
        diffusivity=a,
        diffusivity_std=errors[0],
        loss_rate=b,
        loss_rate_std=errors[1],
        noise_sd=errors[2],
        body_temperature=body,
        truncated=doses.omega[:batch, -1] >= 1.0,
    )


def _depth_map(
    name: str, marched: tuple, depths: Tensor, node_variance: Tensor, levels: tuple[float, int]
) -> tuple[Tensor, Tensor]:
    """The depth where dose ``name`` reaches its threshold and its standard error: the copies' spread for
    the parameters, the frames' sampling in time and their noise, in quadrature."""
    doses, copies, weights = marched
    threshold, coarse = levels
    batch, (h, w) = node_variance.shape[0], doses.peak.shape[-2:]
    dose = getattr(doses, name)[:batch]
    value = threshold_depth(dose, depths, threshold)
    if coarse == 1:  # the copies' own depths
        parameters = spread(threshold_depth(getattr(copies, name), depths, threshold), weights)[1] ** 2
    else:  # the copies' change of ln D at every node, interpolated to the pixels, at the base's crossing
        log = torch.log(getattr(copies, name).clamp_min(_TINY))  # (V B, Z, H', W')
        cold = (log <= math.log(_TINY)).reshape(-1, batch, *log.shape[1:]).any(0)  # never hot: no rate
        change = _upsampled(spread(log, weights)[1].masked_fill(cold, 0.0), h, w)
        parameters = threshold_variance(dose, change.to(dose.dtype) ** 2 * dose**2, depths, threshold)
    sampling = 0.5 * (threshold_depth(doses.other(name), depths, threshold) - value)
    noise = threshold_variance(dose, doses.variance[name] * node_variance, depths, threshold)
    return value, torch.sqrt(parameters + sampling**2 + noise).to(value.dtype)


def _upsampled(x: Tensor, h: int, w: int) -> Tensor:
    """``(B, Z, H', W')`` values at the centres of blocks of ``ceil(H / H')`` px, interpolated bilinearly to
    the ``(B, Z, H, W)`` pixels; the same tensor when ``H' = H``."""
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
    settings: DepthSettings,
    grid: tuple[tuple, int, Beyond | None],
) -> DoseAccumulator:
    """Peak, Omega and CEM43 at the reported nodes of the stacked rises ``(V B, T, H, W)``, base videos
    first; for the base videos also the doses by the other rule and their noise variance.
    ``per_video``: ``dt``, ``dx`` and the body temperature, ``(B,)`` each; ``rho`` ``(B, Z)``, and
    ``(0, Z)`` gives no video the other rule nor the noise; ``grid``: the nodes, how many are reported and
    how the frames are continued beyond the window, :func:`window_problem`, or None for cosine modes."""
    nodes, reported, continued = grid
    n, (h, w) = stacked.shape[0], stacked.shape[-2:]
    batch = per_video[0].numel()
    index = (torch.arange(n, device="cpu") % batch).to(stacked.device)
    spacing, size, warm = (x[index] for x in per_video)
    if continued and settings.lateral:
        problem, window = window_problem(stacked, spacing, size, rates, (nodes, reported), continued)
    else:
        problem = frame_problem(stacked, spacing, size, *rates, nodes, reported, lateral=settings.lateral)
    doses = DoseAccumulator(
        stacked, (n, reported, h, w), spacing, settings.rule, settings.constants, len(rho), rho
    )
    offset = warm.view(-1, 1, 1, 1, 1)
    block = max(1, BLOCK_VALUES // (n * reported * h * w))
    for start, states in march(problem, block):
        if continued and settings.lateral:
            doses.add(offset + window_temperatures(stacked, problem, window, start, states))
        else:
            doses.add(offset + node_temperatures(stacked, problem, start, states))
    return doses
