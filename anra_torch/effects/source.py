"""``source``: ``+ rate exp(-|r - c(t)|^2 / (2 width^2))``, a Gaussian heat input moving on a straight line.

Parameters: ``x0``, ``y0``, ``x1``, ``y1``, ``width`` (mm), ``rate`` (K/s). The centre ``c(t)`` moves linearly
from ``(x0, y0)`` at t = 0 to ``(x1, y1)`` at the video's last frame. Diagnosis: a fitted shape ``S`` (the
unit-rate Gaussian on its path, through the balance's filters), its path and width fitted by the
errors-in-variables profile loss starting from the structure left in the residual. Random draw: ``rate
duration`` in [0.2, 1.0] rise; width 2-5 px; path 0-20 px in any direction, both ends at least ``3 width + 2``
px inside the frame.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.balance import BalanceSystem, Fit
from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Shape, Term, require
from anra_torch.effects.shapes import finish_outer, optimise, peak, pixel_grid
from anra_torch.simulation import Continuum, gaussian_cells

__all__ = ["SPEC", "source_term"]

_F64 = torch.float64
_MIN_WIDTH_PX = 0.5


def _source_build(p: dict[str, float], grid: Grid) -> Term:
    x, y = grid.x, grid.y
    speed = 1.0 / grid.duration if grid.duration > 0 else 0.0
    inv = 1.0 / (2.0 * p["width"] ** 2)

    def term(t: Tensor, u: Tensor) -> Tensor:
        s = t.to(torch.float64) * speed  # fraction of the path travelled
        cx = p["x0"] + (p["x1"] - p["x0"]) * s
        cy = p["y0"] + (p["y1"] - p["y0"]) * s
        gx = torch.exp(-((x - cx) ** 2) * inv)
        gy = torch.exp(-((y - cy) ** 2) * inv)
        return (p["rate"] * gy[:, None] * gx[None, :]).to(u).expand_as(u)

    return term


def _source_sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    height, width = g.shape
    width_px = rng.uniform(2.0, 5.0)
    rate = rng.uniform(0.2, 1.0) * g.rise / g.duration  # adds 20-100 % of the rise at a static peak
    length = rng.uniform(0.0, 20.0)  # px travelled over the video
    angle = rng.uniform(0.0, 2.0 * math.pi)
    margin = min(3.0 * width_px + 2.0, min(height, width) / 4.0)
    length = min(length, max(min(height, width) - 2.0 * margin, 0.0))
    ex, ey = 0.5 * length * math.cos(angle), 0.5 * length * math.sin(angle)
    # Midpoint drawn so that both ends stay at least `margin` inside the frame.
    mx = rng.uniform(margin + abs(ex), width - margin - abs(ex))
    my = rng.uniform(margin + abs(ey), height - margin - abs(ey))
    return {
        "x0": (mx - ex) * g.dx,
        "y0": (my - ey) * g.dx,
        "x1": (mx + ex) * g.dx,
        "y1": (my + ey) * g.dx,
        "rate": rate,
        "width": width_px * g.dx,
    }


def _source_bounds(p: dict[str, float], lo: float, hi: float, duration: float) -> tuple[float, float]:
    added = p["rate"] * duration
    return (lo, hi + added) if added >= 0 else (lo + added, hi)


def _source_check(p: dict[str, float]) -> None:
    require(p["width"] > 0, "source", "width", "positive in mm", p)


def _source_params(c: dict[str, float], ctx: Context) -> dict[str, float]:
    return {**ctx.shape["source"], "rate": c["S"]}


def source_term(system: BalanceSystem, theta: Tensor) -> Tensor:
    """``S`` for ``theta = (x0, y0, x1, y1, log width)`` (px): unit-rate Gaussian moving linearly."""
    n_frames = system.shape[0]
    x, y = pixel_grid(system)
    dx = system.dx
    s = torch.arange(n_frames, dtype=_F64, device=theta.device) / max(n_frames - 1, 1)  # fraction of the path
    cx = (theta[0] + (theta[2] - theta[0]) * s) * dx
    cy = (theta[1] + (theta[3] - theta[1]) * s) * dx
    inv = 0.5 / ((_MIN_WIDTH_PX + torch.exp(theta[4])) * dx) ** 2
    gx = torch.exp(-((x[None, :] - cx[:, None]) ** 2) * inv)  # (T, W)
    gy = torch.exp(-((y[None, :] - cy[:, None]) ** 2) * inv)  # (T, H)
    return finish_outer(system, gy, gx)  # each frame gy (x) gx: filtered as two profiles


def _fit_source(system: BalanceSystem, fit: Fit, start: Tensor | None) -> Shape:
    """Fit the source's path and width to the residual of ``fit`` (or refine ``start``)."""
    residual = system.residual(fit)
    m = system.margin
    k = residual.shape[0]
    third = max(k // 3, 1)
    radius = 4 * int(math.ceil(system.sigma)) + 6
    early = peak(residual[:third].mean(0), radius)
    late = peak(residual[-third:].mean(0), radius)
    centre = system.filters.time.centre
    t_early = (0.5 * (third - 1) + centre) / (system.shape[0] - 1)
    t_late = (k - 0.5 * (third + 1) + centre) / (system.shape[0] - 1)
    span = max(t_late - t_early, 1e-6)
    vx, vy = (late[0] - early[0]) / span, (late[1] - early[1]) / span
    # output pixel j is full-frame pixel j + m, whose centre is at j + m + 0.5 px
    x0, y0 = early[0] - vx * t_early + m + 0.5, early[1] - vy * t_early + m + 0.5
    x1, y1 = x0 + vx, y0 + vy
    columns = list(fit.columns)
    scale = fit.rss

    def loss(theta: Tensor) -> Tensor:
        return system.profile_loss(columns, source_term(system, theta)) / scale

    device = system.frames.device
    starts = [
        torch.tensor([x0, y0, x1, y1, math.log(w - _MIN_WIDTH_PX)], dtype=_F64, device=device)
        for w in (2.0, 4.0)
    ]
    theta = optimise(loss, starts if start is None else [*starts, start], iterations=40, runs=1)
    dx = system.dx
    shape = {
        "x0": float(theta[0]) * dx,
        "y0": float(theta[1]) * dx,
        "x1": float(theta[2]) * dx,
        "y1": float(theta[3]) * dx,
        "width": float(_MIN_WIDTH_PX + torch.exp(theta[4])) * dx,
    }
    return Shape(source_term(system, theta).detach(), None, shape, theta)


def _retime_source(
    params: dict[str, float], fit_duration: float, start: float, duration: float | None
) -> dict[str, float]:
    """Path ends at ``start`` and ``start + duration`` of the linear motion fitted over ``fit_duration``."""
    length = fit_duration if duration is None else duration
    out = dict(params)
    for s_key, e_key in (("x0", "x1"), ("y0", "y1")):
        p0, velocity = params[s_key], (params[e_key] - params[s_key]) / fit_duration
        out[s_key] = p0 + velocity * start
        out[e_key] = p0 + velocity * (start + length)
    return out


def _equation(p: dict[str, float]) -> str:
    return (
        f"+ {p['rate']:.2f} G(width {p['width']:.2f} mm, ({p['x0']:.2f}, {p['y0']:.2f}) -> "
        f"({p['x1']:.2f}, {p['y1']:.2f}) mm)"
    )


def _draw(ax: Any, p: dict[str, float]) -> str:
    ax.annotate(
        "",
        xy=(p["x1"], p["y1"]),
        xytext=(p["x0"], p["y0"]),
        arrowprops={"arrowstyle": "->", "color": "k", "lw": 2},
    )
    ax.plot([p["x0"]], [p["y0"]], "ko", ms=4)
    return f"source path ({p['x0']:.2f}, {p['y0']:.2f}) -> ({p['x1']:.2f}, {p['y1']:.2f}) mm"


def _continuum(p: dict[str, float], m: Continuum, grid: Grid) -> None:
    """The Gaussian on its straight path, averaged over each cell exactly."""
    speed = 1.0 / grid.duration if grid.duration > 0 else 0.0

    def q(t: float, xe: np.ndarray, ye: np.ndarray) -> np.ndarray:
        s = t * speed  # fraction of the straight path travelled
        cx, cy = p["x0"] + (p["x1"] - p["x0"]) * s, p["y0"] + (p["y1"] - p["y0"]) * s
        return p["rate"] * np.outer(gaussian_cells(ye, cy, p["width"]), gaussian_cells(xe, cx, p["width"]))

    m.forcings.append(q)


SPEC = EffectSpec(
    name="source",
    params={"x0": "mm", "y0": "mm", "x1": "mm", "y1": "mm", "rate": "K/s", "width": "mm"},
    build=_source_build,
    sample=_source_sample,
    help="+ rate exp(-|r - c(t)|^2 / (2 width^2)), centre moving linearly (x0, y0) -> (x1, y1)",
    check=_source_check,
    bounds=_source_bounds,
    positions=(("x0", "y0"), ("x1", "y1")),
    regressors=("S",),
    from_coefficients=_source_params,
    valid=lambda p: p["rate"] > 0,
    shape=_fit_source,
    look_elsewhere=4.0,
    equation=_equation,
    retime=_retime_source,
    positive=frozenset({"width"}),
    draw=_draw,
    heat_input=True,
    continuum=_continuum,
)
