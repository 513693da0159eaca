"""Hidden effects: forward models of heat transfer beyond ``dT/dt = a (d_xx + d_yy) T``.

The ground truth that diagnosis is tested against. A model is

    dT/dt = D[T] + sum of effect terms,

where ``D[T]`` is ``a Lap T`` (5-point Laplacian) unless one effect replaces it. The effects, by the names
used in every JSON record of the truth (:data:`EFFECTS`, parameters in brackets):

- ``linear_loss`` (``b`` 1/s, ``T_ref``): ``- b (T - T_ref)``, e.g. perfusion or convective cooling.
- ``source`` (``x0``, ``y0``, ``x1``, ``y1``, ``width`` mm; ``rate`` K/s): ``+ rate exp(-|r - c(t)|^2 /
  (2 width^2))`` with ``c(t) = c0 + (c1 - c0) t / duration`` moving linearly from ``(x0, y0)`` at t = 0 to
  ``(x1, y1)`` at the last frame.
- ``advection`` (``vx``, ``vy`` mm/s): ``- (vx dT/dx + vy dT/dy)``, central differences.
- ``anisotropy`` (``a_x``, ``a_y``, ``a_xy`` mm^2/s; derived ``angle_deg``, ``ratio``): replaces ``D`` by
  ``a_x d_xx T + a_y d_yy T + 2 a_xy d_xy T`` (conservative flux form, tensor positive definite).
- ``heterogeneity`` (``x``, ``y``, ``radius`` mm; ``a_inside``, ``a_outside`` mm^2/s): replaces ``D`` by
  ``div(a grad T)`` with ``a`` = ``a_outside`` plus ``(a_inside - a_outside)`` times a disc with a tanh
  edge about one pixel wide.
- ``nonlinear_diffusion`` (``a0`` mm^2/s, ``beta`` 1/K, ``T_ref``): replaces ``D`` by
  ``div(a0 (1 + beta (T - T_ref)) grad T)``.

At most one effect per model may replace the diffusion term. Coordinates as in :mod:`anra_torch.simulate`:
x along columns, y along rows, pixel centres at ``(j + 0.5) dx``; mm, s, mm^2/s; temperatures in the
data's unit (K for the rates).

- :class:`Effect`: a validated (name, parameters) pair; :data:`EFFECTS` the registry of
  :class:`EffectSpec` (parameters and units, the term, random detectable parameters).
- :class:`ExtendedHeatRHS` and :func:`simulate_effects`: method of lines on ``torchdiffeq`` (fixed-step RK4,
  stable substeps).
- :func:`hidden_effect_video`: a random scene with the effects and their true parameters.

Random parameters (:attr:`EffectSpec.sample`, uniform draws; ``rise`` is the peak initial rise over the
background, ``duration`` the video's length, ``a`` the base diffusivity):

- ``linear_loss``: ``exp(-b duration)`` in [0.3, 0.8]; ``T_ref`` = background - [0, 0.2] rise.
- ``source``: ``rate duration`` in [0.2, 1.0] rise; ``width`` 2-5 px; path length 0-20 px in any direction,
  both ends at least ``3 width + 2`` px inside the frame.
- ``advection``: displacement ``|v| duration`` 2-10 px in any direction.
- ``anisotropy``: eigenvalue ratio 1.5-4 at any angle, geometric mean of the eigenvalues = ``a``.
- ``heterogeneity``: radius 8-20 px (at most 4 hot-spot sigmas); ``a_inside / a_outside`` in [0.3, 0.6]
  or [1.7, 3.0] (even odds), ``a_outside = a``; centre within half a radius of the first hot spot and the
  disc's edge within 2 sigmas of that spot's centre, so heat crosses it during the video.
- ``nonlinear_diffusion``: ``a0 = a``, ``T_ref`` = background, ``beta rise`` in [0.3, 1.0] (``a`` grows
  30-100 % from the background to the peak).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from torchdiffeq import odeint

from anra_torch.checks import as_fields, check_choice, check_int, number
from anra_torch.simulate import (
    _SAFETY,
    BOUNDARIES,
    FIXED_STEP_METHODS,
    HeatRHS,
    gaussian_blobs,
)
from anra_torch.video import save_npz

__all__ = [
    "DIFFUSION_EFFECTS",
    "EFFECTS",
    "Effect",
    "EffectSpec",
    "ExtendedHeatRHS",
    "Geometry",
    "Grid",
    "HiddenEffectVideo",
    "effects_from_json",
    "effects_to_json",
    "hidden_effect_video",
    "simulate_effects",
]

Term = Callable[[Tensor, Tensor], Tensor]
"""``(t in s, T (..., H, W)) -> dT/dt contribution (..., H, W)``, built once per simulation."""

_RK4_RADIUS = 2.6155
"""Radius of the largest left half-disc inside RK4's stability region (the boundary comes closest to
0 at about 123 degrees, |z| = 2.6156; it crosses the real axis at 2.785 and the imaginary at 2.828)."""

_ZERO_FLUX = frozenset({"neumann"})
"""Boundaries whose flux through the frame edge is set to zero explicitly (anisotropy's mixed term
would otherwise leak heat through a mirrored ghost pixel)."""


# ------------------------------------------------------------------------------------ geometry
@dataclass(frozen=True)
class Grid:
    """The pixel grid an effect acts on.

    Attributes:
        shape: frame size ``(H, W)`` in px.
        dx: pixel size in mm.
        duration: time of the last frame in s (the source's path ends there; 0 keeps it at its start).
        boundary: a key of :data:`anra_torch.simulate.BOUNDARIES`.
        boundary_value: ghost temperature for ``"dirichlet"``.

    Shape:
        :attr:`x` ``(W,)``, :attr:`y` ``(H,)``: pixel-centre coordinates in mm (float64).
    """

    shape: tuple[int, int]
    dx: float
    duration: float = 0.0
    boundary: str = "neumann"
    boundary_value: float = 0.0

    def __post_init__(self) -> None:
        shape = self.shape
        if (
            not isinstance(shape, Sequence)
            or len(shape) != 2
            or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in shape)
        ):
            raise ValueError(f"shape must be (H, W) with positive integers, got {shape!r}")
        object.__setattr__(self, "shape", (int(shape[0]), int(shape[1])))
        object.__setattr__(self, "dx", number(self.dx, "dx", "mm", positive=True))
        object.__setattr__(self, "duration", number(self.duration, "duration", "s", minimum=0.0))
        check_choice(self.boundary, "boundary", list(BOUNDARIES))
        value = number(self.boundary_value, "boundary_value", "units of T")
        if value != 0.0 and not BOUNDARIES[self.boundary].uses_value:
            raise ValueError(
                f"boundary_value applies to boundary='dirichlet' only, got boundary={self.boundary!r}"
            )
        object.__setattr__(self, "boundary_value", value)

    @property
    def x(self) -> Tensor:
        """Column centres in mm."""
        return (torch.arange(self.shape[1], dtype=torch.float64) + 0.5) * self.dx

    @property
    def y(self) -> Tensor:
        """Row centres in mm."""
        return (torch.arange(self.shape[0], dtype=torch.float64) + 0.5) * self.dx

    def pad(self, u: Tensor) -> Tensor:
        """``u`` with one ghost pixel around the frame from the boundary condition."""
        return BOUNDARIES[self.boundary].field(u, self.boundary_value)


@dataclass(frozen=True)
class Geometry:
    """What :attr:`EffectSpec.sample` needs to draw detectable, physical parameters for a scene.

    Attributes:
        shape: frame size ``(H, W)`` in px.
        dx: pixel size in mm.
        duration: video length in s (> 0).
        a: base diffusivity in mm^2/s.
        rise: peak initial temperature rise above ``background`` (> 0).
        background: temperature of the warm background.
        hotspots: ``(x, y, sigma)`` in mm of the initial hot spots (may be empty).
    """

    shape: tuple[int, int]
    dx: float
    duration: float
    a: float
    rise: float
    background: float = 0.0
    hotspots: tuple[tuple[float, float, float], ...] = ()

    @property
    def width_mm(self) -> float:
        """Frame width (along x) in mm."""
        return self.shape[1] * self.dx

    @property
    def height_mm(self) -> float:
        """Frame height (along y) in mm."""
        return self.shape[0] * self.dx


@dataclass(frozen=True)
class _Rates:
    """What an effect does to the step size: an effective diffusivity for the 5-point bound
    ``|lambda| <= 8 a / dx^2`` (None: does not touch diffusion), a speed (mm/s, the sum |vx| + |vy|
    bounding central-difference advection by ``speed / dx``) and a decay rate (1/s)."""

    diffusivity: float | None = None
    speed: float = 0.0
    decay: float = 0.0


# ------------------------------------------------------------------------------------- registry
def _same_bounds(p: dict[str, float], low: float, high: float, duration: float) -> tuple[float, float]:
    """The effect creates no new extremes (diffusion, advection)."""
    return low, high


@dataclass(frozen=True)
class EffectSpec:
    """One entry of :data:`EFFECTS`: parameters, the operator, and how to draw it at random.

    Attributes:
        params: parameter name -> unit, in the canonical order.
        build: ``(params, grid) -> term``: the ``dT/dt`` contribution as a function ``(t, T)`` (t in s),
            or, when ``replaces_diffusion``, the operator used instead of ``a Lap T``.
        sample: ``(rng, geometry) -> params``: random parameters that are clearly visible in a video of that
            geometry yet keep it physical.
        help: one line.
        replaces_diffusion: whether the term replaces ``a Lap T`` (at most one such effect per model).
        check: raises ``ValueError`` on parameters outside the model's domain (finite numbers are checked
            for every effect).
        rates: ``(params, (T_low, T_high)) -> _Rates`` for the stable step; may raise when the model is
            ill-posed over that temperature range.
        bounds: ``(params, T_low, T_high, duration) -> (T_low, T_high)``: a range the temperatures stay in.
        derived: ``params -> {name: value}`` quantities recorded with the truth (e.g. ``angle_deg``).
        derived_units: units of ``derived``.
        reference_a: ``params -> a`` the diffusivity an isotropic, homogeneous fit should be compared with.
        diffusivity_map: ``(params, grid) -> (H, W)`` diffusivity field, when the effect has one.
        positions: ``(x_key, y_key)`` pairs of coordinates in mm (shifted when a video is cropped).
    """

    params: dict[str, str]
    build: Callable[[dict[str, float], Grid], Term]
    sample: Callable[[np.random.Generator, Geometry], dict[str, float]]
    help: str
    replaces_diffusion: bool = False
    check: Callable[[dict[str, float]], None] | None = None
    rates: Callable[[dict[str, float], tuple[float, float]], _Rates] = lambda p, span: _Rates()
    bounds: Callable[[dict[str, float], float, float, float], tuple[float, float]] = _same_bounds
    derived: Callable[[dict[str, float]], dict[str, float]] | None = None
    derived_units: dict[str, str] = field(default_factory=dict)
    reference_a: Callable[[dict[str, float]], float] | None = None
    diffusivity_map: Callable[[dict[str, float], Grid], Tensor] | None = None
    positions: tuple[tuple[str, str], ...] = ()


def _require(condition: bool, name: str, key: str, need: str, params: dict[str, float]) -> None:
    if not condition:
        raise ValueError(f"{name}.{key} must be {need}, got {params[key]!r}")


# ----- linear_loss
def _loss_build(p: dict[str, float], grid: Grid) -> Term:
    b, t_ref = p["b"], p["T_ref"]
    return lambda t, u: -b * (u - t_ref)


def _loss_sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    survival = rng.uniform(0.3, 0.8)  # exp(-b duration): 20-70 % of the excess lost over the video
    ambient = g.background - g.rise * rng.uniform(0.0, 0.2)  # at or a little below the background
    return {"b": -math.log(survival) / g.duration, "T_ref": ambient}


def _loss_bounds(p: dict[str, float], lo: float, hi: float, duration: float) -> tuple[float, float]:
    return min(lo, p["T_ref"]), max(hi, p["T_ref"])


def _loss_check(p: dict[str, float]) -> None:
    _require(p["b"] >= 0, "linear_loss", "b", "non-negative in 1/s (a loss)", p)


# ----- source
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
    _require(p["width"] > 0, "source", "width", "positive in mm", p)


# ----- advection
def _advection_build(p: dict[str, float], grid: Grid) -> Term:
    vx, vy, h = p["vx"], p["vy"], 2.0 * grid.dx

    def term(t: Tensor, u: Tensor) -> Tensor:
        q = grid.pad(u)
        ddx = (q[..., 1:-1, 2:] - q[..., 1:-1, :-2]) / h
        ddy = (q[..., 2:, 1:-1] - q[..., :-2, 1:-1]) / h
        return -(vx * ddx + vy * ddy)

    return term


def _advection_sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    shift = rng.uniform(2.0, 10.0) * g.dx  # mm travelled over the video
    angle = rng.uniform(0.0, 2.0 * math.pi)
    speed = shift / g.duration
    return {"vx": speed * math.cos(angle), "vy": speed * math.sin(angle)}


# ----- anisotropy
def _eigen(p: dict[str, float]) -> tuple[float, float]:
    mean = 0.5 * (p["a_x"] + p["a_y"])
    half = math.hypot(0.5 * (p["a_x"] - p["a_y"]), p["a_xy"])
    return mean + half, mean - half


def _anisotropy_derived(p: dict[str, float]) -> dict[str, float]:
    large, small = _eigen(p)
    angle = 0.5 * math.degrees(math.atan2(2.0 * p["a_xy"], p["a_x"] - p["a_y"]))
    return {"angle_deg": angle, "ratio": large / small}


def _anisotropy_check(p: dict[str, float]) -> None:
    large, small = _eigen(p)
    if not (p["a_x"] > 0 and p["a_y"] > 0 and p["a_x"] * p["a_y"] - p["a_xy"] ** 2 > 0 and small > 0):
        raise ValueError(
            f"anisotropy tensor [[a_x, a_xy], [a_xy, a_y]] must be positive definite "
            f"(a_x > 0, a_y > 0, a_x a_y > a_xy^2), got a_x={p['a_x']:g}, a_y={p['a_y']:g}, "
            f"a_xy={p['a_xy']:g} (eigenvalues {large:.4g}, {small:.4g}) mm^2/s"
        )


def _anisotropy_build(p: dict[str, float], grid: Grid) -> Term:
    a_x, a_y, a_xy = p["a_x"], p["a_y"], p["a_xy"]
    zero_flux = grid.boundary in _ZERO_FLUX
    scale = 1.0 / grid.dx**2

    def term(t: Tensor, u: Tensor) -> Tensor:
        q = grid.pad(u)
        # Fluxes (times dx) on the faces between columns, (..., H, W + 1), and between rows, (..., H + 1, W):
        # the normal derivative from the two pixels, the tangential one averaged over the four around.
        fx = a_x * (q[..., 1:-1, 1:] - q[..., 1:-1, :-1]) + 0.25 * a_xy * (
            q[..., 2:, 1:] + q[..., 2:, :-1] - q[..., :-2, 1:] - q[..., :-2, :-1]
        )
        fy = a_y * (q[..., 1:, 1:-1] - q[..., :-1, 1:-1]) + 0.25 * a_xy * (
            q[..., 1:, 2:] + q[..., :-1, 2:] - q[..., 1:, :-2] - q[..., :-1, :-2]
        )
        if zero_flux:  # the conormal flux n . A grad T vanishes on the frame edge: heat is conserved
            fx = torch.cat([torch.zeros_like(fx[..., :1]), fx[..., 1:-1], torch.zeros_like(fx[..., :1])], -1)
            fy = torch.cat(
                [torch.zeros_like(fy[..., :1, :]), fy[..., 1:-1, :], torch.zeros_like(fy[..., :1, :])], -2
            )
        return ((fx[..., 1:] - fx[..., :-1]) + (fy[..., 1:, :] - fy[..., :-1, :])) * scale

    return term


def _anisotropy_sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    ratio = rng.uniform(1.5, 4.0)
    angle = math.radians(rng.uniform(-90.0, 90.0))
    large, small = g.a * math.sqrt(ratio), g.a / math.sqrt(ratio)  # geometric mean = a
    c, s = math.cos(angle), math.sin(angle)
    return {
        "a_x": large * c * c + small * s * s,
        "a_y": large * s * s + small * c * c,
        "a_xy": (large - small) * c * s,
    }


def _anisotropy_rates(p: dict[str, float], r: tuple[float, float]) -> _Rates:
    # |symbol| = (4 a_x sin^2 + 4 a_y sin^2 + 2 a_xy sin sin) / dx^2 <= (4 a_x + 4 a_y + 2 |a_xy|) / dx^2.
    return _Rates(diffusivity=(4.0 * p["a_x"] + 4.0 * p["a_y"] + 2.0 * abs(p["a_xy"])) / 8.0)


# ----- heterogeneity
def _disc_map(p: dict[str, float], grid: Grid) -> Tensor:
    r = torch.sqrt((grid.x[None, :] - p["x"]) ** 2 + (grid.y[:, None] - p["y"]) ** 2)
    disc = 0.5 * (1.0 + torch.tanh((p["radius"] - r) / grid.dx))  # 1 inside, 0 outside, ~1 px edge
    return p["a_outside"] + (p["a_inside"] - p["a_outside"]) * disc


def _heterogeneity_build(p: dict[str, float], grid: Grid) -> Term:
    rhs = HeatRHS(_disc_map(p, grid), dx=grid.dx, boundary=grid.boundary, boundary_value=grid.boundary_value)
    return lambda t, u: rhs(t, u).reshape(u.shape)  # HeatRHS returns (1, H, W) for (H, W)


def _heterogeneity_check(p: dict[str, float]) -> None:
    _require(p["radius"] > 0, "heterogeneity", "radius", "positive in mm", p)
    _require(p["a_inside"] >= 0, "heterogeneity", "a_inside", "non-negative in mm^2/s", p)
    _require(p["a_outside"] >= 0, "heterogeneity", "a_outside", "non-negative in mm^2/s", p)


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


# ----- nonlinear_diffusion
def _nonlinear_build(p: dict[str, float], grid: Grid) -> Term:
    a0, beta, t_ref = p["a0"], p["beta"], p["T_ref"]

    def kirchhoff(u: Tensor | float) -> Tensor | float:
        # Phi' = a(T): grad Phi = a(T) grad T. As a(T) is linear in T, Phi(T_j) - Phi(T_i) equals
        # (a_i + a_j) / 2 (T_j - T_i): the flux form with the arithmetic-mean face diffusivity, exactly.
        return a0 * ((u - t_ref) + 0.5 * beta * (u - t_ref) ** 2)

    laplacian = HeatRHS(
        1.0, dx=grid.dx, boundary=grid.boundary, boundary_value=float(kirchhoff(grid.boundary_value))
    )
    return lambda t, u: laplacian(t, kirchhoff(u)).reshape(u.shape)


def _nonlinear_check(p: dict[str, float]) -> None:
    _require(p["a0"] > 0, "nonlinear_diffusion", "a0", "positive in mm^2/s", p)


def _nonlinear_rates(p: dict[str, float], r: tuple[float, float]) -> _Rates:
    low, high = (p["a0"] * (1.0 + p["beta"] * (temp - p["T_ref"])) for temp in r)
    if min(low, high) <= 0:
        raise ValueError(
            f"nonlinear_diffusion: a0 (1 + beta (T - T_ref)) must stay positive over the temperatures "
            f"[{r[0]:.4g}, {r[1]:.4g}] this video can reach, got {min(low, high):.4g} mm^2/s; "
            f"reduce |beta|={abs(p['beta']):g} 1/K or move T_ref"
        )
    return _Rates(diffusivity=max(low, high))


def _nonlinear_sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    spread = rng.uniform(0.3, 1.0)  # a grows by 30-100 % from the background to the peak
    return {"a0": g.a, "beta": spread / g.rise, "T_ref": g.background}


EFFECTS: dict[str, EffectSpec] = {
    "linear_loss": EffectSpec(
        params={"b": "1/s", "T_ref": "data units"},
        build=_loss_build,
        sample=_loss_sample,
        help="- b (T - T_ref): loss to an ambient temperature (perfusion, convection)",
        check=_loss_check,
        rates=lambda p, r: _Rates(decay=p["b"]),
        bounds=_loss_bounds,
    ),
    "source": EffectSpec(
        params={"x0": "mm", "y0": "mm", "x1": "mm", "y1": "mm", "rate": "K/s", "width": "mm"},
        build=_source_build,
        sample=_source_sample,
        help="+ rate exp(-|r - c(t)|^2 / (2 width^2)), centre moving linearly (x0, y0) -> (x1, y1)",
        check=_source_check,
        bounds=_source_bounds,
        positions=(("x0", "y0"), ("x1", "y1")),
    ),
    "advection": EffectSpec(
        params={"vx": "mm/s", "vy": "mm/s"},
        build=_advection_build,
        sample=_advection_sample,
        help="- (vx dT/dx + vy dT/dy): a flow carrying heat",
        rates=lambda p, r: _Rates(speed=abs(p["vx"]) + abs(p["vy"])),
    ),
    "anisotropy": EffectSpec(
        params={"a_x": "mm^2/s", "a_y": "mm^2/s", "a_xy": "mm^2/s"},
        build=_anisotropy_build,
        sample=_anisotropy_sample,
        help="a_x d_xx T + a_y d_yy T + 2 a_xy d_xy T instead of a Lap T (positive definite tensor)",
        replaces_diffusion=True,
        check=_anisotropy_check,
        rates=_anisotropy_rates,
        derived=_anisotropy_derived,
        derived_units={"angle_deg": "deg", "ratio": "1"},
        reference_a=lambda p: math.sqrt(p["a_x"] * p["a_y"] - p["a_xy"] ** 2),
    ),
    "heterogeneity": EffectSpec(
        params={"x": "mm", "y": "mm", "radius": "mm", "a_inside": "mm^2/s", "a_outside": "mm^2/s"},
        build=_heterogeneity_build,
        sample=_heterogeneity_sample,
        help="div(a grad T), a = a_inside in a disc (tanh edge ~1 px), a_outside elsewhere",
        replaces_diffusion=True,
        check=_heterogeneity_check,
        rates=lambda p, r: _Rates(diffusivity=max(p["a_inside"], p["a_outside"])),
        reference_a=lambda p: p["a_outside"],
        diffusivity_map=_disc_map,
        positions=(("x", "y"),),
    ),
    "nonlinear_diffusion": EffectSpec(
        params={"a0": "mm^2/s", "beta": "1/K", "T_ref": "data units"},
        build=_nonlinear_build,
        sample=_nonlinear_sample,
        help="div(a0 (1 + beta (T - T_ref)) grad T): temperature-dependent diffusivity",
        replaces_diffusion=True,
        check=_nonlinear_check,
        rates=_nonlinear_rates,
        reference_a=lambda p: p["a0"],
    ),
}
"""The hidden effects by name (the names and parameter names of every truth record)."""

DIFFUSION_EFFECTS: tuple[str, ...] = tuple(name for name, spec in EFFECTS.items() if spec.replaces_diffusion)


# --------------------------------------------------------------------------------------- effect
def _unknown(name: object) -> ValueError:
    return ValueError(f"unknown effect {name!r}; expected one of: {', '.join(EFFECTS)}")


@dataclass(frozen=True)
class Effect:
    """One hidden effect with its parameters, checked against :data:`EFFECTS`.

    Attributes:
        name: a key of :data:`EFFECTS`.
        params: every parameter of that effect (finite numbers in the units of :attr:`EffectSpec.params`).

    Raises:
        ValueError: unknown name, missing or unknown parameters, non-finite or out-of-domain values.

    Example:
        >>> Effect("advection", {"vx": 0.5, "vy": 0.0}).to_dict()["units"]
        {'vx': 'mm/s', 'vy': 'mm/s'}
    """

    name: str
    params: dict[str, float]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or self.name not in EFFECTS:
            raise _unknown(self.name)
        spec = EFFECTS[self.name]
        if not isinstance(self.params, Mapping):
            raise TypeError(f"{self.name} params must be a mapping name -> number, got {self.params!r}")
        unknown = [k for k in self.params if k not in spec.params]
        if unknown:
            hint = " (derived, set from the others)" if unknown[0] in spec.derived_units else ""
            raise ValueError(
                f"effect {self.name!r} has no parameter {unknown[0]!r}{hint}; "
                f"expected: {', '.join(spec.params)}"
            )
        missing = [k for k in spec.params if k not in self.params]
        if missing:
            raise ValueError(
                f"effect {self.name!r} is missing {', '.join(missing)}; expected: "
                + ", ".join(f"{k} ({u})" for k, u in spec.params.items())
            )
        params = {k: number(self.params[k], f"{self.name}.{k}", unit) for k, unit in spec.params.items()}
        if spec.check is not None:
            spec.check(params)
        object.__setattr__(self, "params", params)

    def __hash__(self) -> int:
        return hash((self.name, tuple(self.params.items())))

    @property
    def spec(self) -> EffectSpec:
        """The registry entry."""
        return EFFECTS[self.name]

    @property
    def replaces_diffusion(self) -> bool:
        """Whether this effect replaces ``a Lap T``."""
        return self.spec.replaces_diffusion

    def derived(self) -> dict[str, float]:
        """Quantities derived from the parameters (``angle_deg`` and ``ratio`` for anisotropy)."""
        return self.spec.derived(self.params) if self.spec.derived is not None else {}

    def term(self, T: Tensor, t: float | Tensor, grid: Grid) -> Tensor:
        """The ``dT/dt`` contribution (or the replaced diffusion operator) at time ``t`` in s.

        Shape:
            ``T`` ``(H, W)`` or ``(B, H, W)`` on ``grid``; output like ``T``.
        """
        time = t if isinstance(t, Tensor) else torch.as_tensor(float(t), dtype=torch.float64)
        return self.spec.build(self.params, grid)(time, T)

    def to_dict(self) -> dict[str, Any]:
        """``{"name", "params" (with derived values), "units"}``, JSON-ready."""
        units = {**self.spec.params, **self.spec.derived_units}
        return {"name": self.name, "params": {**self.params, **self.derived()}, "units": units}

    @classmethod
    def from_dict(cls, record: Mapping[str, Any]) -> Effect:
        """Inverse of :meth:`to_dict` (derived values are checked, not stored; ``units`` is ignored).

        Raises:
            ValueError: not a record, or derived values that disagree with the parameters.
        """
        if not isinstance(record, Mapping) or "name" not in record or "params" not in record:
            raise ValueError(f"an effect record needs 'name' and 'params', got {record!r}")
        name, params = record["name"], dict(record["params"])
        if not isinstance(name, str) or name not in EFFECTS:
            raise _unknown(name)
        given = {k: params.pop(k) for k in EFFECTS[name].derived_units if k in params}
        effect = cls(name, params)
        for key, value in given.items():
            if not math.isclose(float(value), effect.derived()[key], rel_tol=1e-9, abs_tol=1e-12):
                raise ValueError(
                    f"{name}.{key}={value!r} disagrees with the parameters ({effect.derived()[key]!r})"
                )
        return effect


def effects_to_json(effects: Sequence[Effect]) -> str:
    """The truth as a JSON list of :meth:`Effect.to_dict` records (one line)."""
    return json.dumps([_as_effect(e).to_dict() for e in effects], allow_nan=False)


def effects_from_json(text: str) -> tuple[Effect, ...]:
    """Parse :func:`effects_to_json` output back into effects.

    Raises:
        ValueError: not JSON, not a list of effect records, or invalid effects.
    """
    try:
        records = json.loads(text)
    except (TypeError, json.JSONDecodeError) as err:
        raise ValueError(f"effects must be a JSON list of effect records, got {str(text)[:60]!r}") from err
    if not isinstance(records, list):
        raise ValueError(f"effects must be a JSON list of effect records, got {type(records).__name__}")
    return tuple(Effect.from_dict(r) for r in records)


def _as_effect(effect: object) -> Effect:
    if not isinstance(effect, Effect):
        raise TypeError(f"effects must be Effect instances, got {type(effect).__name__}")
    return effect


def _check_effects(effects: object) -> tuple[Effect, ...]:
    """A tuple of distinct effects with at most one that replaces the diffusion term."""
    if isinstance(effects, Effect):
        effects = (effects,)
    if not isinstance(effects, Sequence) or isinstance(effects, str):
        raise TypeError(f"effects must be a sequence of Effect, got {type(effects).__name__}")
    checked = tuple(_as_effect(e) for e in effects)
    names = [e.name for e in checked]
    for name in names:
        if names.count(name) > 1:
            raise ValueError(f"effect {name!r} is given {names.count(name)} times; give each effect once")
    diffusion = [e.name for e in checked if e.replaces_diffusion]
    if len(diffusion) > 1:
        raise ValueError(
            f"effects {' and '.join(diffusion)} both replace the diffusion term; a model may hold at most "
            f"one of {', '.join(DIFFUSION_EFFECTS)}"
        )
    return checked


# ---------------------------------------------------------------------------------- right-hand side
def effect_rhs(
    a: float | Tensor,
    parts: Sequence[tuple[EffectSpec, Mapping[str, float | Tensor]]],
    grid: Grid,
    time_scale: float,
) -> Callable[[Tensor, Tensor], Tensor]:
    """``f(t, T) = (D[T] + sum of effect terms) * time_scale`` from ``(spec, params)`` pairs, unchecked.

    The one assembly of a model's right-hand side: :class:`ExtendedHeatRHS` calls it after validating its
    effects; :func:`anra_torch.refine.refine_model` calls it with tensor parameters so that autograd
    reaches them. ``D`` is ``a`` times the 5-point Laplacian unless a part replaces the diffusion term;
    ``t`` is in units of ``time_scale`` seconds.
    """
    diffusion = None
    terms = []
    for spec, params in parts:
        term = spec.build(params, grid)
        if spec.replaces_diffusion:
            diffusion = term
        else:
            terms.append(term)
    if diffusion is None:
        heat = HeatRHS(a, dx=grid.dx, boundary=grid.boundary, boundary_value=grid.boundary_value)
        diffusion = lambda t, u: heat(t, u).reshape(u.shape)  # noqa: E731

    def rhs(t: Tensor, u: Tensor) -> Tensor:
        seconds = t * time_scale
        out = diffusion(seconds, u)
        for term in terms:
            out = out + term(seconds, u)
        return out * time_scale

    return rhs


class ExtendedHeatRHS(nn.Module):
    """Right-hand side ``dT/dt = D[T] + sum of effect terms`` on the pixel grid, for ``torchdiffeq``.

    ``D[T]`` is ``a`` times the 5-point Laplacian (:class:`anra_torch.simulate.HeatRHS`) unless an effect
    replaces it. Gradients are central differences; the ghost pixel around the frame comes from
    ``grid.boundary`` (zero flux by default). The solver's time ``t`` is in units of ``time_scale`` seconds
    (the output is multiplied by it), so a fixed step of 1 can be one substep exactly.

    Args:
        a: base diffusivity in mm^2/s (>= 0); unused when an effect replaces the diffusion term.
        grid: the pixel grid (shape, dx, duration of the source paths, boundary).
        effects: distinct :class:`Effect` s, at most one replacing the diffusion term.
        time_scale: seconds per unit of solver time.

    Shape:
        ``forward(t, T)``: ``T`` ``(H, W)`` or ``(B, H, W)`` (one model for every video); output like ``T``.

    Raises:
        ValueError: negative ``a``, bad effects (see :func:`simulate_effects`), non-positive ``time_scale``.
    """

    def __init__(
        self, a: float, *, grid: Grid, effects: Sequence[Effect] = (), time_scale: float = 1.0
    ) -> None:
        super().__init__()
        if not isinstance(grid, Grid):
            raise TypeError(f"grid must be a Grid, got {type(grid).__name__}")
        self.a = number(a, "a", "mm^2/s", minimum=0.0)
        self.grid = grid
        self.effects = _check_effects(effects)
        self.time_scale = number(time_scale, "time_scale", "s", positive=True)
        self._rhs = effect_rhs(self.a, [(e.spec, e.params) for e in self.effects], grid, self.time_scale)

    def forward(self, t: Tensor, u: Tensor) -> Tensor:
        return self._rhs(t, u)

    def extra_repr(self) -> str:
        names = ", ".join(e.name for e in self.effects) or "none"
        return f"a={self.a:g}, shape={self.grid.shape}, boundary={self.grid.boundary!r}, effects=({names})"


# --------------------------------------------------------------------------------------- simulate
def _step_rates(
    a: float, effects: tuple[Effect, ...], low: float, high: float, duration: float
) -> tuple[float, float, float]:
    """Largest effective diffusivity, speed and decay rate for the step size."""
    for effect in effects:  # a range the temperatures cannot leave
        low, high = effect.spec.bounds(effect.params, low, high, duration)
    margin = 0.1 * (high - low)  # central-difference advection can overshoot a little
    span = (low - margin, high + margin)
    rates = [e.spec.rates(e.params, span) for e in effects]
    diffusivity = [r.diffusivity for r in rates if r.diffusivity is not None]
    a_max = diffusivity[0] if diffusivity else a
    return a_max, sum(r.speed for r in rates), sum(r.decay for r in rates)


def _substeps(dt: float, dx: float, a_max: float, speed: float, decay: float) -> tuple[int, int]:
    """(automatic, minimum stable) RK4 substeps per frame.

    The spectrum lies in ``[-8 a / dx^2 - b, 0] x i [-speed / dx, speed / dx]``. Stable: inside RK4's
    region (its real-axis limit for a real spectrum, else the largest half-disc). Automatic: also the
    monotone limit ``a ds / dx^2 <= 0.9 * 0.25`` of :func:`anra_torch.simulate.simulate_heat`, so that
    without effects both take the same steps.
    """
    limit = FIXED_STEP_METHODS["rk4"]
    real, imag = 8.0 * a_max / dx**2 + decay, speed / dx
    radius = 8.0 * limit.stable if imag == 0 else _RK4_RADIUS
    size = math.hypot(real, imag) * dt
    needed = max(1, math.ceil(size / radius))
    auto = max(
        needed,
        math.ceil(size / (_SAFETY * radius)),
        math.ceil(a_max * dt / dx**2 / (_SAFETY * limit.monotone)),
    )
    return auto, needed


def simulate_effects(
    initial: Tensor,
    *,
    a: float,
    dx: float,
    dt: float,
    n_frames: int,
    effects: Sequence[Effect] = (),
    boundary: str = "neumann",
    boundary_value: float = 0.0,
    substeps: int | None = None,
    forcing: Tensor | None = None,
) -> Tensor:
    """Simulate a thermal video of ``dT/dt = D[T] + sum of effect terms (+ forcing)`` (method of lines, RK4).

    Fixed-step RK4 (``torchdiffeq``) with an integer number of substeps per frame, by default the fewest
    that are stable for the whole spectrum (diffusion up to the largest diffusivity the model can reach,
    the advection CFL ``|v| ds / dx``, the loss rate ``b``) and monotone for the diffusion part. Frame 0 is
    ``initial``; the source moves over ``duration = (n_frames - 1) dt``.

    Args:
        initial: first frame (temperatures).
        a: base diffusivity in mm^2/s (>= 0); ignored when an effect replaces the diffusion term.
        dx: pixel size in mm.
        dt: frame period in s.
        n_frames: number of frames T (>= 1).
        effects: distinct :class:`Effect` s, at most one of ``anisotropy``, ``heterogeneity``,
            ``nonlinear_diffusion``.
        boundary: a key of :data:`anra_torch.simulate.BOUNDARIES` (default zero flux).
        boundary_value: ghost temperature for ``"dirichlet"``.
        substeps: RK4 steps per frame; default automatic (see above).
        forcing: a stationary heat-input map in data units per s, added to the right-hand side at every
            pixel (e.g. a measured source map, :mod:`anra_torch.source_map`); it does not change stability.

    Returns:
        The video in the dtype of ``initial``.

    Shape:
        ``initial`` ``(H, W)`` or ``(B, H, W)``; ``forcing`` ``(H, W)``; output ``(T, H, W)`` or
        ``(B, T, H, W)``.

    Raises:
        TypeError: ``initial`` not real numbers, effects not :class:`Effect`.
        ValueError: bad shapes or spacings, unknown boundary, duplicate effects, two effects replacing the
            diffusion term, an ill-posed model (a negative nonlinear diffusivity over the temperature
            range), or ``substeps`` below the stability limit.

    Example:
        >>> u0 = torch.full((8, 8), 40.0, dtype=torch.float64)
        >>> loss = Effect("linear_loss", {"b": 0.5, "T_ref": 30.0})
        >>> video = simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=11, effects=[loss])
        >>> round(video[-1, 0, 0].item(), 6), round(30 + 10 * math.exp(-0.5), 6)
        (36.065307, 36.065307)
    """
    u0, batched = as_fields(initial)
    height, width = u0.shape[-2:]
    a = number(a, "a", "mm^2/s", minimum=0.0)
    dx = number(dx, "dx", "mm", positive=True)
    dt = number(dt, "dt", "s", positive=True)
    n_frames = check_int(n_frames, "n_frames", 1)
    checked = _check_effects(effects)
    grid = Grid((height, width), dx, (n_frames - 1) * dt, boundary, boundary_value)
    if substeps is not None:
        substeps = check_int(substeps, "substeps", 1)
    if forcing is not None:
        forcing = torch.as_tensor(forcing)
        need = f"forcing must be a finite map of the frame's shape ({height}, {width}) in data units per s"
        if forcing.shape != (height, width):
            raise ValueError(f"{need}, got shape {tuple(forcing.shape)}")
        if not bool(torch.isfinite(forcing).all()):
            raise ValueError(f"{need}, got non-finite values")
        forcing = forcing.to(u0.dtype)
    duration = grid.duration
    low, high = float(u0.min()), float(u0.max())
    if BOUNDARIES[boundary].uses_value:
        low, high = min(low, grid.boundary_value), max(high, grid.boundary_value)
    a_max, speed, decay = _step_rates(a, checked, low, high, duration)
    auto, needed = _substeps(dt, dx, a_max, speed, decay)
    if substeps is None:
        substeps = auto
    elif substeps < needed:
        raise ValueError(
            f"substeps={substeps} is unstable for RK4 here (a_max={a_max:.4g} mm^2/s, speed={speed:.4g} "
            f"mm/s, decay={decay:.4g} 1/s); need at least {needed} (or leave substeps=None)"
        )
    if n_frames == 1:
        out = u0.unsqueeze(1)
        return out if batched else out[0]
    rhs = ExtendedHeatRHS(a, grid=grid, effects=checked, time_scale=dt / substeps)
    if forcing is not None:
        heat, step_input = rhs, forcing * (dt / substeps)
        rhs = lambda t, u: heat(t, u) + step_input  # noqa: E731
    t = torch.arange(n_frames, dtype=u0.dtype) * substeps
    out = odeint(rhs, u0, t, method="rk4", options={"step_size": 1.0}).movedim(0, 1)
    return out if batched else out[0]


# ----------------------------------------------------------------------------------- hidden video
@dataclass(frozen=True)
class HiddenEffectVideo:
    """A synthetic thermal video with hidden effects and their true parameters.

    Attributes:
        frames: noisy temperatures.
        clean: the noise-free simulation.
        dt: frame period in s.
        dx: pixel size in mm.
        a: the reference diffusivity in mm^2/s: the base ``a``, or the effect's own when one replaces
            the diffusion term (``a_outside``, ``a0``, or ``sqrt(det A)`` for anisotropy).
        times: frame times ``k dt`` in s.
        effects: the effects with their true parameters.
        noise_sd: standard deviation of the added white noise (data units).
        seed: the seed everything was drawn from.
        a_map: the diffusivity field ``(H, W)`` in mm^2/s for ``heterogeneity``, else None.

    Shape:
        ``frames``, ``clean`` ``(T, H, W)``; ``times`` ``(T,)``; ``a_map`` ``(H, W)``.
    """

    frames: Tensor
    clean: Tensor
    dt: float
    dx: float
    a: float
    times: Tensor
    effects: tuple[Effect, ...]
    noise_sd: float
    seed: int
    a_map: Tensor | None = None

    @property
    def truth_json(self) -> str:
        """The true effects as JSON (:func:`effects_to_json`)."""
        return effects_to_json(self.effects)

    def crop(self, top: int, left: int, height: int, width: int) -> HiddenEffectVideo:
        """The window ``[top:top + height, left:left + width]`` with positions in the truth shifted to it.

        Heat then crosses the window's edges (the simulation ran on the full frame).

        Raises:
            ValueError: a window outside the frame.
        """
        rows, cols = self.frames.shape[-2:]
        if not (0 <= top and 0 <= left and 1 <= height and 1 <= width and top + height <= rows
                and left + width <= cols):  # fmt: skip
            raise ValueError(
                f"crop window (top={top}, left={left}, height={height}, width={width}) must lie inside the "
                f"{rows} x {cols} px frame"
            )
        window = (..., slice(top, top + height), slice(left, left + width))
        shift = {"x": left * self.dx, "y": top * self.dx}
        effects = []
        for effect in self.effects:
            params = dict(effect.params)
            for kx, ky in effect.spec.positions:
                params[kx] -= shift["x"]
                params[ky] -= shift["y"]
            effects.append(Effect(effect.name, params))
        return replace(
            self,
            frames=self.frames[window].contiguous(),
            clean=self.clean[window].contiguous(),
            effects=tuple(effects),
            a_map=None if self.a_map is None else self.a_map[window].contiguous(),
        )

    def to_npz(self, path: str | os.PathLike[str], **extra: Any) -> Path:
        """Save as ``.npz`` readable by ``anra estimate``.

        Keys: ``frames``, ``dt``, ``dx``, ``t``, ``a_true``, ``noise_sd``, ``seed``, ``effects`` (the JSON
        truth, a string) and ``a_map`` when there is one.

        Args:
            path: output file (``.npz`` appended when missing).
            **extra: more scalars or arrays to store.

        Returns:
            The path written.
        """
        if self.a_map is not None:
            extra = {"a_map": self.a_map, **extra}
        return save_npz(
            path,
            self.frames,
            dt=self.dt,
            dx=self.dx,
            t=self.times,
            a_true=np.float64(self.a),
            noise_sd=np.float64(self.noise_sd),
            seed=np.int64(self.seed),
            effects=self.truth_json,
            **extra,
        )


def hidden_effect_video(
    effect_names: Sequence[str] | str = (),
    *,
    seed: int,
    size: int = 96,
    dx: float = 0.5,
    fps: float = 30.0,
    duration: float = 3.0,
    a: float = 0.15,
    noise_frac: float = 0.01,
    noise_sd: float | None = None,
    params: Mapping[str, Mapping[str, float]] | None = None,
    background: float = 30.0,
    dtype: torch.dtype = torch.float64,
) -> HiddenEffectVideo:
    """A random scene with the named hidden effects, simulated by :func:`simulate_effects`, plus noise.

    From ``numpy.random.default_rng(seed)``, in this order: one or two Gaussian hot spots on the uniform
    ``background`` (rise 5-20, sigma 3-8 px, centres at least ``2.5 sigma + 10`` px inside the frame), then
    each effect's parameters from its :attr:`EffectSpec.sample` in the order given (ranges in the
    module's docs and the registry). ``params`` overrides drawn values after the draw, so the other
    parameters do not depend on which were overridden. The noise is white, sd ``noise_sd`` or else
    ``noise_frac`` times the peak initial rise, from ``torch.Generator().manual_seed(seed)``. The scene
    is simulated in float64 with zero-flux edges and cast to ``dtype``.

    Args:
        effect_names: keys of :data:`EFFECTS` (distinct); ``()`` gives pure heat transfer.
        seed: seed of the scene, the effect parameters and the noise (>= 0).
        size: frame side in px (>= 16).
        dx: pixel size in mm.
        fps: frame rate in Hz.
        duration: length in s: ``round(duration * fps) + 1`` frames.
        a: base diffusivity in mm^2/s.
        noise_frac: noise sd as a fraction of the peak initial rise (>= 0).
        noise_sd: absolute noise sd (data units); overrides ``noise_frac``.
        params: ``{effect: {parameter: value}}`` fixed instead of drawn.
        background: temperature of the background.
        dtype: float32 or float64.

    Returns:
        A :class:`HiddenEffectVideo` holding the true effects.

    Shape:
        ``frames`` ``(T, size, size)``.

    Raises:
        ValueError: unknown or repeated effects, two diffusion-replacing effects, ``params`` for an effect
            not named, bad sizes or rates.

    Example:
        >>> video = hidden_effect_video(["advection"], seed=1, size=32, duration=0.5)
        >>> tuple(video.frames.shape), [e.name for e in video.effects]
        ((16, 32, 32), ['advection'])
    """
    names = (effect_names,) if isinstance(effect_names, str) else effect_names
    if not isinstance(names, Sequence) or not all(isinstance(n, str) for n in names):
        raise TypeError(f"effect_names must be a sequence of effect names, got {effect_names!r}")
    for name in names:
        if name not in EFFECTS:
            raise _unknown(name)
    seed = check_int(seed, "seed", 0)
    size = check_int(size, "size", 16)
    dx = number(dx, "dx", "mm", positive=True)
    fps = number(fps, "fps", "Hz", positive=True)
    duration = number(duration, "duration", "s", positive=True)
    a = number(a, "a", "mm^2/s", minimum=0.0)
    noise_frac = number(noise_frac, "noise_frac", "fraction of the rise", minimum=0.0)
    if noise_sd is not None:
        noise_sd = number(noise_sd, "noise_sd", "data units", minimum=0.0)
    background = number(background, "background", "data units")
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    overrides = {} if params is None else dict(params)
    for name in overrides:
        if name not in names:
            raise ValueError(
                f"params given for effect {name!r}, which is not among the effects "
                f"({', '.join(names) or 'none'}); add it to effect_names"
            )
    n_frames = round(duration * fps) + 1
    if n_frames < 2:
        raise ValueError(f"duration * fps must give at least 2 frames, got duration={duration} s at {fps} Hz")
    length = (n_frames - 1) / fps

    rng = np.random.default_rng(seed)
    n_spots = int(rng.integers(1, 3))
    spots = []
    for _ in range(n_spots):
        rise, sigma = rng.uniform(5.0, 20.0), rng.uniform(3.0, 8.0)
        margin = min(2.5 * sigma + 10.0, size / 2.0)
        spots.append((rise, sigma, rng.uniform(margin, size - margin), rng.uniform(margin, size - margin)))
    initial = gaussian_blobs(
        [0.0],
        shape=(size, size),
        dx=dx,
        a=0.0,
        peaks=[s[0] for s in spots],
        sigmas=[s[1] * dx for s in spots],
        centres=[[s[2] * dx, s[3] * dx] for s in spots],
        background=background,
    )[0]
    peak_rise = float(initial.max()) - background
    geometry = Geometry(
        shape=(size, size),
        dx=dx,
        duration=length,
        a=a,
        rise=peak_rise,
        background=background,
        hotspots=tuple((s[2] * dx, s[3] * dx, s[1] * dx) for s in spots),
    )
    effects = []
    for name in names:
        drawn = EFFECTS[name].sample(rng, geometry)
        drawn.update(overrides.get(name, {}))
        effects.append(Effect(name, drawn))
    checked = _check_effects(effects)

    dt = 1.0 / fps
    clean = simulate_effects(initial, a=a, dx=dx, dt=dt, n_frames=n_frames, effects=checked).to(dtype)
    sd = noise_sd if noise_sd is not None else noise_frac * peak_rise
    generator = torch.Generator().manual_seed(seed)
    frames = clean + sd * torch.randn(clean.shape, generator=generator, dtype=dtype)
    reference, a_map = a, None
    grid = Grid((size, size), dx, length)
    for effect in checked:
        if effect.spec.reference_a is not None:
            reference = effect.spec.reference_a(effect.params)
        if effect.spec.diffusivity_map is not None:
            a_map = effect.spec.diffusivity_map(effect.params, grid).to(dtype)
    return HiddenEffectVideo(
        frames=frames,
        clean=clean,
        dt=dt,
        dx=dx,
        a=reference,
        times=torch.arange(n_frames, dtype=dtype) * dt,
        effects=checked,
        noise_sd=sd,
        seed=seed,
        a_map=a_map,
    )
