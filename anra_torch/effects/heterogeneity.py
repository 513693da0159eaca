"""``heterogeneity``: ``div(a grad T)`` with ``a = a_inside`` in a disc, ``a_outside`` elsewhere.

Parameters: ``x``, ``y``, ``radius`` in mm, ``a_inside``, ``a_outside`` in mm^2/s. The disc has a tanh
edge about one pixel wide; simulated in conservative flux form.

Diagnosis: a fitted shape ``H = G div(disc grad S_t T)`` (its noise is ``L``'s inside the disc), the disc
fitted by the errors-in-variables profile loss from starts where the windowed diffusivity splits in two
and where heat flows.

Random draw: radius 8-20 px (at most 4 hot-spot sigmas), ``a_inside / a_outside`` in [0.3, 0.6] or
[1.7, 3.0], ``a_outside = a``, the edge where heat crosses it during the video. Size:
``|a_inside / a_outside - 1|``; below 5 % it is negligible.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance import BalanceSystem, Fit, NoiseSpec, accumulate
from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Rates, Shape, Term, require
from anra_torch.effects.shapes import draw_circle, edge_disc, optimise, pixel_grid
from anra_torch.simulation import Continuum, HeatRHS

__all__ = ["SPEC"]

_F64 = torch.float64
_MIN_RADIUS_PX = 2.0  # a smaller disc is below the smoothing scale: not identifiable


def _disc_map(p: dict[str, float], grid: Grid) -> Tensor:
    disc = edge_disc(grid.x, grid.y, p["x"], p["y"], p["radius"], grid.dx)  # 1 inside, 0 outside, ~1 px edge
    return p["a_outside"] + (p["a_inside"] - p["a_outside"]) * disc


def _heterogeneity_build(p: dict[str, float], grid: Grid) -> Term:
    rhs = HeatRHS(_disc_map(p, grid), dx=grid.dx, boundary=grid.boundary, boundary_value=grid.boundary_value)
    return lambda t, u: rhs(t, u).reshape(u.shape)  # HeatRHS returns (1, H, W) for (H, W)


def _heterogeneity_check(p: dict[str, float]) -> None:
    require(p["radius"] > 0, "heterogeneity", "radius", "positive in mm", p)
    require(p["a_inside"] >= 0, "heterogeneity", "a_inside", "non-negative in mm^2/s", p)
    require(p["a_outside"] >= 0, "heterogeneity", "a_outside", "non-negative in mm^2/s", p)


def _heterogeneity_sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    height, width = g.shape
    # The disc's edge must lie where heat flows during the video: within two hot-spot widths (sigma) of
    # the first hot spot's centre. With the centre within half a radius of the spot, the edge is between
    # radius / 2 and radius from it, so the radius is capped at 4 sigma and the offset at least
    # radius - 2 sigma (a far edge left the effect invisible in about 3 of 20 seeds).
    sigma_px = g.hotspots[0][2] / g.dx if g.hotspots else math.inf
    radius_px = rng.uniform(8.0, max(8.0, min(20.0, 4.0 * sigma_px)))
    contrast = rng.uniform(0.3, 0.6) if rng.uniform() < 0.5 else rng.uniform(1.7, 3.0)
    low = min(max(0.0, radius_px - 2.0 * sigma_px), 0.5 * radius_px)
    angle, offset = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(low, 0.5 * radius_px)
    if g.hotspots:  # over the first hot spot, where the heat flows
        cx, cy = g.hotspots[0][0] / g.dx, g.hotspots[0][1] / g.dx
    else:
        cx, cy = rng.uniform(0.25, 0.75) * width, rng.uniform(0.25, 0.75) * height
    cx = min(max(cx + offset * math.cos(angle), 2.0), width - 2.0)
    cy = min(max(cy + offset * math.sin(angle), 2.0), height - 2.0)
    return {
        "x": cx * g.dx,
        "y": cy * g.dx,
        "radius": radius_px * g.dx,
        "a_inside": contrast * g.a,
        "a_outside": g.a,
    }


def _heterogeneity_params(c: dict[str, float], ctx: Context) -> dict[str, float]:
    return {**ctx.shape["heterogeneity"], "a_inside": c["L"] + c["H"], "a_outside": c["L"]}


def _radius(theta: Tensor) -> Tensor:
    """Disc radius in px from the unconstrained ``theta[2]``."""
    return _MIN_RADIUS_PX + torch.exp(theta[2])


def _disc(system: BalanceSystem, theta: Tensor) -> Tensor:
    """Disc map ``(H, W)`` in [0, 1] with a tanh edge one pixel wide; ``theta = (x, y, radius code)`` (px)."""
    x, y = pixel_grid(system)
    dx = system.dx
    return edge_disc(x, y, theta[0] * dx, theta[1] * dx, _radius(theta) * dx, dx)


def _heterogeneity_term(system: BalanceSystem, theta: Tensor, average: Tensor) -> Tensor:
    """``H = G div(disc grad S_t T)`` (flux form) on the output grid."""
    disc = _disc(system, theta)
    flux = HeatRHS(disc, dx=system.dx)(average.new_zeros((), dtype=_F64), average)
    return system.finish(flux)


def _activity_centres(system: BalanceSystem, count: int = 2) -> list[tuple[float, float]]:
    """Local maxima (column, row in px of the full frame) of the heat-flow energy ``sum_t L^2``."""
    energy = system.terms["L"].detach().pow(2).sum(0)
    size = 2 * int(4 * max(system.sigma, 1.0)) + 1
    pooled = F.max_pool2d(energy[None, None], size, stride=1, padding=size // 2)[0, 0]
    peaks = ((energy == pooled) & (energy > 0.2 * energy.max())).nonzero().tolist()
    peaks.sort(key=lambda rc: -float(energy[rc[0], rc[1]]))
    m = system.margin
    return [(c + m + 0.5, r + m + 0.5) for r, c in peaks[:count]]


def _local_diffusivity(system: BalanceSystem, window: int) -> tuple[Tensor, Tensor]:
    """Windowed least-squares ``a`` of the plain model and its signal energy, both ``(h, w)``.

    ``a = sum U L / (sum L^2 - noise)`` over a ``window`` x ``window`` box and all frames.
    """

    def box(m: Tensor) -> Tensor:
        pooled = F.avg_pool2d(
            m.sum(0)[None, None], window, stride=1, padding=window // 2, count_include_pad=False
        )
        return pooled[0, 0]

    names = ("U", "L")
    local = accumulate(system.detached, names, reduce=box, noise=system.term_noise(names))
    energy = local.corrected[..., 1, 1]
    a = local.raw[..., 0, 1] / energy.clamp_min(1e-300)
    return a, energy.clamp_min(0)


def _heterogeneity_starts(system: BalanceSystem) -> list[Tensor]:
    """Discs to start from: the two regions of the windowed ``a`` field (split where the weighted
    between-class variance is largest) and circles about where heat flows."""
    m = system.margin
    a, energy = _local_diffusivity(system, 2 * int(math.ceil(2 * system.sigma)) + 5)
    ok = energy > 0.05 * energy.max()
    starts, device = [], system.frames.device
    if int(ok.sum()) >= 4:
        values, weights = a[ok], energy[ok]
        order = values.argsort()
        v, w = values[order], weights[order]
        cw, cv = w.cumsum(0), (w * v).cumsum(0)
        total_w, total_v = cw[-1], cv[-1]
        mean_low = cv[:-1] / cw[:-1]
        mean_high = (total_v - cv[:-1]) / (total_w - cw[:-1])
        between = cw[:-1] * (total_w - cw[:-1]) * (mean_low - mean_high) ** 2
        split = float(v[int(between.argmax())])
        rows, cols = torch.meshgrid(
            torch.arange(a.shape[0], dtype=_F64, device=a.device),
            torch.arange(a.shape[1], dtype=_F64, device=a.device),
            indexing="ij",
        )
        for region in (ok & (a <= split), ok & (a > split)):
            count = int(region.sum())
            if count == 0:
                continue
            radius = max(math.sqrt(count / math.pi), _MIN_RADIUS_PX + 1.0)
            cx, cy = float(cols[region].mean()) + m + 0.5, float(rows[region].mean()) + m + 0.5
            starts.append(
                torch.tensor([cx, cy, math.log(radius - _MIN_RADIUS_PX)], dtype=_F64, device=device)
            )
    for cx, cy in _activity_centres(system):
        for radius in (6.0, 12.0, 20.0):
            starts.append(
                torch.tensor([cx, cy, math.log(radius - _MIN_RADIUS_PX)], dtype=_F64, device=device)
            )
    return starts


def _fit_heterogeneity(system: BalanceSystem, fit: Fit, start: Tensor | None) -> Shape:
    """Fit a disc of different diffusivity where heat flows (or refine ``start``)."""
    columns = list(fit.columns)
    average = system.average.detach()
    scale = fit.rss
    m = system.margin

    def loss(theta: Tensor) -> Tensor:
        noise = NoiseSpec("L", _disc(system, theta)[m:-m, m:-m])
        return system.profile_loss(columns, _heterogeneity_term(system, theta, average), noise) / scale

    if start is None:
        theta = optimise(loss, _heterogeneity_starts(system), iterations=25, runs=3)
    else:  # the previous fit, and the usual starts in case the model around it changed a lot
        theta = optimise(loss, [start, *_heterogeneity_starts(system)], iterations=25, runs=1)
    disc = _disc(system, theta).detach()[m:-m, m:-m]
    # Built from the frames' graph (H is linear in them) so that its noise enters the standard errors.
    term = _heterogeneity_term(system, theta.detach(), system.average)
    dx = system.dx
    shape = {"x": float(theta[0]) * dx, "y": float(theta[1]) * dx, "radius": float(_radius(theta)) * dx}
    return Shape(term, NoiseSpec("L", disc), shape, theta)


def _equation(p: dict[str, float]) -> str:
    return (
        f"div(a grad T) [a = {p['a_inside']:.3f} in the disc r < {p['radius']:.2f} mm around "
        f"({p['x']:.2f}, {p['y']:.2f}) mm, {p['a_outside']:.3f} outside]"
    )


def _draw(ax: Any, p: dict[str, float]) -> str:
    draw_circle(ax, p["x"], p["y"], p["radius"], "k--")
    return f"heterogeneity disc r = {p['radius']:.2f} mm at ({p['x']:.2f}, {p['y']:.2f}) mm"


def _continuum(p: dict[str, float], m: Continuum, grid: Grid) -> None:
    """A disc of other diffusivity with a tanh edge one camera pixel wide, at any point in mm."""

    def a(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        disc = 0.5 * (1.0 + np.tanh((p["radius"] - np.hypot(x - p["x"], y - p["y"])) / grid.dx))
        return p["a_outside"] + (p["a_inside"] - p["a_outside"]) * disc

    m.diffusivity = a


SPEC = EffectSpec(
    name="heterogeneity",
    params={"x": "mm", "y": "mm", "radius": "mm", "a_inside": "mm^2/s", "a_outside": "mm^2/s"},
    build=_heterogeneity_build,
    sample=_heterogeneity_sample,
    help="div(a grad T), a = a_inside in a disc (tanh edge ~1 px), a_outside elsewhere",
    replaces_diffusion=True,
    check=_heterogeneity_check,
    rates=lambda p, r: Rates(diffusivity=max(p["a_inside"], p["a_outside"])),
    reference_a=lambda p: p["a_outside"],
    diffusivity_map=_disc_map,
    positions=(("x", "y"),),
    regressors=("H",),
    from_coefficients=_heterogeneity_params,
    valid=lambda p: p["a_inside"] > 0 and p["a_outside"] > 0,
    shape=_fit_heterogeneity,
    look_elsewhere=4.0,
    equation=_equation,
    positive=frozenset({"a_inside", "a_outside", "radius"}),
    draw=_draw,
    size=lambda p, span: abs(p["a_inside"] / p["a_outside"] - 1.0),
    min_size=0.05,  # a disc within 5 % of its surroundings' diffusivity: negligible
    continuum=_continuum,
)
