"""``periodic_source``: a Gaussian spot whose heat input oscillates, e.g. a laser modulated sinusoidally.

    + rate exp(-|r - c|^2 / (2 width^2)) (1 + sin(2 pi frequency t + phase)) / 2

Parameters: ``x``, ``y``, ``width`` in mm, ``rate`` (K/s, the peak input), ``frequency`` in Hz, ``phase``
(rad, at t = 0 s of the video). The input swings between 0 and ``rate`` at the spot's centre.

Diagnosis (not searched by default: ask for it, ``effects=[..., "periodic_source"]``): a fitted shape ``P``
(the unit-rate modulated spot through the balance's filters), its place, width, frequency and phase fitted
by the errors-in-variables profile loss, starting from the pixel whose residual swings most and the
strongest frequency of that pixel's residual. Random draw: width 2-5 px, 1.5-4 cycles over the video,
``rate duration / 2`` in [0.2, 1.0] rise, any phase.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Shape, Term, require
from anra_torch.effects.shapes import draw_circle, finish_outer, optimise, pixel_grid
from anra_torch.simulation import Continuum, gaussian_cells

if TYPE_CHECKING:
    from anra_torch.balance import BalanceSystem, Fit

__all__ = ["SPEC", "periodic_term"]

_F64 = torch.float64
_MIN_WIDTH_PX = 0.5


def _modulation(t: Tensor, frequency: float | Tensor, phase: float | Tensor) -> Tensor:
    """``(1 + sin(2 pi f t + phase)) / 2`` in [0, 1]."""
    return 0.5 * (1.0 + torch.sin(2.0 * math.pi * frequency * t + phase))


def _build(p: dict[str, float], grid: Grid) -> Term:
    x, y = grid.x, grid.y
    inv = 1.0 / (2.0 * p["width"] ** 2)
    spot = torch.exp(-((y - p["y"]) ** 2) * inv)[:, None] * torch.exp(-((x - p["x"]) ** 2) * inv)[None, :]

    def term(t: Tensor, u: Tensor) -> Tensor:
        strength = p["rate"] * _modulation(t.to(_F64), p["frequency"], p["phase"])
        return (strength * spot).to(u).expand_as(u)

    return term


def _sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    height, width = g.shape
    width_px = rng.uniform(2.0, 5.0)
    margin = min(3.0 * width_px + 2.0, min(height, width) / 4.0)
    return {
        "x": rng.uniform(margin, width - margin) * g.dx,
        "y": rng.uniform(margin, height - margin) * g.dx,
        "width": width_px * g.dx,
        # the mean input (rate / 2) adds 20-100 % of the rise at the spot over the video
        "rate": 2.0 * rng.uniform(0.2, 1.0) * g.rise / g.duration,
        "frequency": rng.uniform(1.5, 4.0) / g.duration,
        "phase": rng.uniform(0.0, 2.0 * math.pi),
    }


def _bounds(p: dict[str, float], lo: float, hi: float, duration: float) -> tuple[float, float]:
    added = p["rate"] * duration
    return (lo, hi + added) if added >= 0 else (lo + added, hi)


def _check(p: dict[str, float]) -> None:
    require(p["width"] > 0, "periodic_source", "width", "positive in mm", p)
    require(p["frequency"] >= 0, "periodic_source", "frequency", "non-negative in Hz", p)


def _from_coefficients(c: dict[str, float], ctx: Context) -> dict[str, float]:
    return {**ctx.shape["periodic_source"], "rate": c["P"]}


# -------------------------------------------------------------------------------------- shape fit
def _profiles(system: BalanceSystem, x: Tensor, y: Tensor, log_width: Tensor) -> tuple[Tensor, Tensor]:
    """The unit Gaussian spot at ``(x, y)`` px with width ``0.5 + exp(log_width)`` px as its two profiles:
    along the rows ``(H,)`` and along the columns ``(W,)`` (the spot is their outer product)."""
    gx, gy = pixel_grid(system)
    dx = system.dx
    inv = 0.5 / ((_MIN_WIDTH_PX + torch.exp(log_width)) * dx) ** 2
    return torch.exp(-((gy - y * dx) ** 2) * inv), torch.exp(-((gx - x * dx) ** 2) * inv)


def periodic_term(system: BalanceSystem, theta: Tensor) -> Tensor:
    """``P`` for ``theta = (x, y, log width, log frequency, phase)`` (px, Hz, rad) on the output grid."""
    t = torch.arange(system.shape[0], dtype=_F64, device=system.frames.device) * system.dt
    modulation = _modulation(t, torch.exp(theta[3]), theta[4])
    rows, cols = _profiles(system, theta[0], theta[1], theta[2])
    return finish_outer(system, modulation[:, None] * rows, cols.expand(len(t), -1))


def _starts(system: BalanceSystem, fit: Fit) -> list[Tensor]:
    """From the pixel whose residual swings most: its strongest frequencies and their phases."""
    residual = system.residual(fit)  # (K, h, w)
    k, h, w = residual.shape
    row, col = divmod(int(residual.std(0).argmax()), w)
    m = system.margin
    series = residual[:, row, col] - residual[:, row, col].mean()
    spectrum = torch.fft.rfft(series)
    frequencies = torch.fft.rfftfreq(k, d=system.dt)
    order = spectrum.abs()[1:].argsort(descending=True)[:2] + 1
    centre = system.filters.time.centre
    starts = []
    for index in order.tolist():
        f = float(frequencies[index])
        # residual ~ sin(2 pi f t + phase) at t = (j + centre) dt; rfft gives cos(2 pi f j dt + angle)
        phase = float(torch.angle(spectrum[index])) + math.pi / 2 - 2 * math.pi * f * centre * system.dt
        for width in (2.0, 4.0):
            starts.append(
                torch.tensor(
                    [col + m + 0.5, row + m + 0.5, math.log(width - _MIN_WIDTH_PX), math.log(f), phase],
                    dtype=_F64,
                    device=system.frames.device,
                )
            )
    return starts


def _fit(system: BalanceSystem, fit: Fit, start: Tensor | None) -> Shape:
    """Fit the spot, frequency and phase to the residual of ``fit`` (or refine ``start``)."""
    columns, scale = list(fit.columns), fit.rss

    def loss(theta: Tensor) -> Tensor:
        return system.profile_loss(columns, periodic_term(system, theta)) / scale

    starts = _starts(system, fit)
    theta = optimise(loss, starts if start is None else [*starts, start], iterations=40, runs=2)
    dx = system.dx
    shape = {
        "x": float(theta[0]) * dx,
        "y": float(theta[1]) * dx,
        "width": float(_MIN_WIDTH_PX + torch.exp(theta[2])) * dx,
        "frequency": float(torch.exp(theta[3])),
        "phase": float(theta[4]) % (2.0 * math.pi),
    }
    return Shape(periodic_term(system, theta).detach(), None, shape, theta)


# ----------------------------------------------------------------------------------- presentation
def _retime(params: dict[str, float], fit_duration: float, start: float, duration: float | None) -> dict:
    """The same oscillation seen from ``start`` s: the phase advances by ``2 pi f start``."""
    phase = params["phase"] + 2.0 * math.pi * params["frequency"] * start
    return {**params, "phase": phase % (2.0 * math.pi)}


def _equation(p: dict[str, float]) -> str:
    return (
        f"+ {p['rate']:.2f} (1 + sin(2 pi {p['frequency']:.3g} t + {p['phase']:.2f})) / 2 "
        f"G(width {p['width']:.2f} mm, at ({p['x']:.2f}, {p['y']:.2f}) mm)"
    )


def _draw(ax: Any, p: dict[str, float]) -> str:
    draw_circle(ax, p["x"], p["y"], p["width"], "k:")
    return f"periodic source at ({p['x']:.2f}, {p['y']:.2f}) mm, {p['frequency']:.3g} Hz"


def _continuum(p: dict[str, float], m: Continuum, grid: Grid) -> None:
    """The Gaussian spot switched on and off sinusoidally, averaged over each cell exactly."""

    def q(t: float, xe: np.ndarray, ye: np.ndarray) -> np.ndarray:
        level = 0.5 * p["rate"] * (1.0 + math.sin(2.0 * math.pi * p["frequency"] * t + p["phase"]))
        return level * np.outer(
            gaussian_cells(ye, p["y"], p["width"]), gaussian_cells(xe, p["x"], p["width"])
        )

    m.forcings.append(q)


SPEC = EffectSpec(
    name="periodic_source",
    params={"x": "mm", "y": "mm", "width": "mm", "rate": "K/s", "frequency": "Hz", "phase": "rad"},
    build=_build,
    sample=_sample,
    help="+ rate G(r - c) (1 + sin(2 pi frequency t + phase)) / 2: a spot heated periodically",
    check=_check,
    bounds=_bounds,
    positions=(("x", "y"),),
    regressors=("P",),
    from_coefficients=_from_coefficients,
    valid=lambda p: p["rate"] > 0,
    shape=_fit,
    look_elsewhere=6.0,
    searched=False,
    equation=_equation,
    retime=_retime,
    positive=frozenset({"width", "frequency"}),
    draw=_draw,
    heat_input=True,
    continuum=_continuum,
)
