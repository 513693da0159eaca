"""``delamination``: a disc where the heat flowing into depth stops short, above a subsurface defect.

Over a delamination (a crack or an air gap parallel to the surface at depth ``d``) the layer above the
defect is a thinner plate: it evens out through its thickness after ``d^2 / a_z`` instead of ``L^2 / a_z``
and then stays warm. In the disc the depth term of :mod:`anra_torch.effects.depth_conduction` runs with
the thin layer's rate instead of the plate's, which adds

    + strength reflected disc(r) (r_plate(t - t_heat) - r_layer(t - t_heat)) (T - T_ref)

(``r_plate``, ``r_layer`` the depth rates of depth times ``plate_time`` and ``depth_time``; strength 1
for a defect that lets no heat through). ``disc`` has a tanh edge about one pixel wide. ``reflected`` is
the share of the layer's excess the disc keeps while the heat the defect sends back spreads sideways
(:func:`reflected_share`; 1 without a lateral diffusivity): a small deep defect's term is weak, not its
defect.

Parameters: ``x``, ``y``, ``radius`` (mm), ``strength`` (1), ``depth_time`` (s, ``d^2 / a_z`` of the
layer above the defect), ``t_heat`` (s), ``plate_time`` (s, ``L^2 / a_z``), ``T_ref`` (data units): the
last three are the plate's, copied from its ``depth_conduction`` fit; ``reflected`` (1), from the disc,
its layer and a defect map's lateral diffusivity where one is given. Derived: ``depth_fraction``
``d / L = sqrt(depth_time / plate_time)``.

Diagnosis: tried once ``depth_conduction`` is in the model (:attr:`EffectSpec.requires`); a fitted shape
``Y`` (the disc's term through the balance's filters), its centre, radius and depth time fitted by the
errors-in-variables profile loss from the strongest positive structure left in the residual, or, given
candidate regions (:func:`~anra_torch.selection.diagnose_terms`' ``hints``: the defects of a flash defect
map, :func:`anra_torch.flash.defect_map`, where the cooling says the heat stops early), held at one of
them: its radius the region's equal-area radius, its centre within 0.7 of the radius of the region's
centroid, its layer's ``d / L`` within 0.1 of the region's, its layer's time that share of the map's plate
time where the region carries one (with its radius and depth free the disc grew over the frame into a
second depth rate of negative strength); an empty set of regions rules it out. A second defect of the map
is :mod:`~anra_torch.effects.delamination_2`'s (the same term and fit under another name, :data:`REGRESSORS`):
each delamination is held at the regions the others in the model do not cover. Held at a region, its
share of ``dT/dt`` is measured over its disc (:attr:`EffectSpec.footprint`), not over the whole frame.
Validated on the independent 3-D plates of :func:`anra_torch.simulation.flash_plate_video` (the lateral
and the depth problems do not separate over a defect, so the 2-D independent simulator has no model of it).
Random draw: under the first hot spot (radius 1-2 of its sigmas), ``d / L`` in 0.2-0.5, ``strength``
0.7-1.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.balance import NoiseSpec
from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Rates, Shape, Term, require
from anra_torch.effects.depth_conduction import depth_rate, depth_rate_at
from anra_torch.effects.shapes import draw_circle, edge_disc, optimise, peak, pixel_grid

if TYPE_CHECKING:
    from anra_torch.balance import BalanceSystem, Fit

__all__ = ["REGRESSORS", "SPEC", "reflected_share", "spec_fields"]

_F64 = torch.float64
_MIN_RADIUS_PX = 2.0
_STRENGTH = (0.2, 5.0)  # the strength at least, the term (strength reflected) at most: :func:`_inside`
_HELD_SHIFT = 0.7  # a held disc's centre moves at most this share of its radius along each axis
_HELD_DEPTH = 0.1  # ... its layer's d / L at most this far from the region's (a defect map's accuracy)
_HINTS = "delamination"  # every delamination reads the candidate regions given under this name

REGRESSORS = {"delamination": "Y", "delamination_2": "Y2"}
"""Each delamination effect (this module's, :mod:`~anra_torch.effects.delamination_2`'s) by name, its
fitted term's regressor: a model names each once, so a second defect of a defect map needs a second name."""


def _difference(elapsed: Tensor, p: dict[str, float]) -> Tensor:
    return depth_rate_at(elapsed, p["plate_time"]) - depth_rate_at(elapsed, p["depth_time"])


def _build(p: dict[str, float], grid: Grid) -> Term:
    disc = edge_disc(grid.x, grid.y, p["x"], p["y"], p["radius"], grid.dx)

    def term(t: Tensor, u: Tensor) -> Tensor:
        elapsed = (
            torch.as_tensor(t, dtype=_F64, device=u.device) - p["t_heat"]
        )  # > 0: the heating precedes the first frame
        rate = p["strength"] * p["reflected"] * _difference(elapsed, p)
        return (rate * disc).to(u) * (u - p["T_ref"])

    return term


def _sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    """Under the first hot spot (the term acts on ``T - T_ref``: elsewhere there is nothing to see)."""
    height, width = g.shape
    if g.hotspots:
        cx, cy, sigma = g.hotspots[0]
        radius = sigma * rng.uniform(1.0, 2.0)
        cx, cy = cx + rng.uniform(-0.5, 0.5) * sigma, cy + rng.uniform(-0.5, 0.5) * sigma
    else:
        radius = rng.uniform(6.0, 15.0) * g.dx
        cx, cy = rng.uniform(0.3, 0.7) * g.width_mm, rng.uniform(0.3, 0.7) * g.height_mm
    plate_time = rng.uniform(1.0, 10.0) * g.duration
    return {
        "x": cx,
        "y": cy,
        "radius": radius,
        "strength": rng.uniform(0.7, 1.0),
        "depth_time": plate_time * rng.uniform(0.2, 0.5) ** 2,
        "t_heat": -rng.uniform(0.02, 0.2) * g.duration,
        "plate_time": plate_time,
        "T_ref": g.background,
        "reflected": 1.0,
    }


def _check(name: str, p: dict[str, float]) -> None:
    require(p["radius"] > 0, name, "radius", "positive in mm", p)
    require(p["strength"] >= 0, name, "strength", "non-negative (1: no heat crosses the defect)", p)
    require(p["plate_time"] > 0, name, "plate_time", "positive in s (L^2 / a_z)", p)
    require(p["t_heat"] < 0, name, "t_heat", "before the first frame (< 0 s)", p)
    require(0 < p["reflected"] <= 1, name, "reflected", "in (0, 1] (the share of the layer's excess kept)", p)
    require(
        0 < p["depth_time"] <= p["plate_time"],
        name,
        "depth_time",
        "in (0, plate_time] s (d <= L)",
        p,
    )


def _rates(p: dict[str, float], span: tuple[float, float]) -> Rates:
    """The disc's rate is below the plate's own at the simulation's start, ``strength r_plate(-t_heat)``."""
    elapsed = torch.tensor(-p["t_heat"], dtype=_F64, device="cpu")
    return Rates(decay=p["strength"] * p["reflected"] * float(depth_rate(elapsed, p["plate_time"])))


def _bounds(p: dict[str, float], lo: float, hi: float, duration: float) -> tuple[float, float]:
    return min(lo, p["T_ref"]), max(hi, p["T_ref"])


def _from_coefficients(name: str, c: dict[str, float], ctx: Context) -> dict[str, float]:
    shape = ctx.shape[name]
    p = {**shape, "strength": c[REGRESSORS[name]] / shape["reflected"]}
    return {**p, "depth_fraction": math.sqrt(p["depth_time"] / p["plate_time"])}


# -------------------------------------------------------------------------------------- shape fit
def _unpack(theta: Tensor, plate_time: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(x px, y px, log(radius - 2 px), logit of depth_time / plate_time)`` -> centre, radius px, s."""
    radius = _MIN_RADIUS_PX + torch.exp(theta[2])
    return theta[0], theta[1], radius, plate_time * torch.sigmoid(theta[3])


def delamination_term(system: BalanceSystem, theta: Tensor, plate: dict[str, float]) -> tuple[Tensor, Tensor]:
    """``Y`` on the output grid for ``theta`` (see :func:`_unpack`) and its noise weight map, under the
    ``plate`` of a depth_conduction fit (``t_heat``, ``depth_time``, ``T_ref``)."""
    cx, cy, radius, depth_time = _unpack(theta, plate["depth_time"])
    gx, gy = pixel_grid(system)
    dx = system.dx
    disc = edge_disc(gx, gy, cx * dx, cy * dx, radius * dx, dx)
    t = torch.arange(system.shape[0], dtype=_F64, device=system.frames.device) * system.dt - plate["t_heat"]
    rate = depth_rate(t, plate["depth_time"]) - depth_rate(t, depth_time)
    centred = system.frames.detach() - plate["T_ref"]
    field = rate[:, None, None] * disc[None] * centred
    m = system.margin
    weight = system.filters.time.average(rate[:, None, None]) * disc[m:-m, m:-m][None]
    return system.finish(system.filters.time.average(field)), weight


_Region = tuple[float, float, float, float, float, float]


def _regions(system: BalanceSystem, plate_time: float) -> list[_Region]:
    """The candidate regions the balance was given (``system.hints``: a flash defect map's defects,
    centroid and equal-area radius in mm, depth fraction, the map's plate time ``L^2 / a_z`` in s, its
    lateral diffusivity in mm^2/s) as ``(x px, y px, radius px, d / L, the map's plate time over the depth
    term's plate_time, lateral mm^2/s)`` (1 without the map's plate time, 0 without a lateral diffusivity)."""
    regions = []
    for h in system.hints.get(_HINTS, ()):
        fraction = h.get("depth_fraction", 0.5)
        fraction = fraction if math.isfinite(fraction) else 0.5
        scale = h.get("plate_time", math.nan) / plate_time
        scale = scale if math.isfinite(scale) and scale > 0 else 1.0
        radius = max(h["radius"] / system.dx, _MIN_RADIUS_PX + 0.5)
        lateral = max(h.get("lateral", 0.0), 0.0)
        regions.append((h["x"] / system.dx, h["y"] / system.dx, radius, fraction, scale, lateral))
    return regions


def reflected_share(radius: float, depth_time: float, lateral: float) -> float:
    """The share of a layer's excess (the heat a defect of ``radius`` mm sends back to the surface) that the
    centre of its disc keeps at the layer's own time ``depth_time`` s (``d^2 / a_z``) under an isotropic
    lateral diffusivity ``lateral`` mm^2/s: the disc averaged by the Gaussian of variance ``lateral t``
    about its centre (:mod:`anra_torch.flash.spread`'s first-order model at ``t = d^2 / a_z``),
    ``1 - exp(-radius^2 / (2 lateral depth_time))``; 1 without a lateral diffusivity. A small deep defect
    keeps little (a disc of 2.6 mm radius at 2 mm depth of a plate with ``a_z`` 0.45 and a lateral 2.8
    mm^2/s: 0.17), so its fitted strength reads far below its own."""
    if lateral <= 0 or depth_time <= 0:
        return 1.0
    return -math.expm1(-(radius**2) / (2.0 * lateral * depth_time))


def _held(region: _Region, phi: Tensor) -> Tensor:
    """``theta`` (see :func:`_unpack`) of a disc held at a candidate region: its radius the region's, its
    centre within :data:`_HELD_SHIFT` of the radius of the region's centroid along each axis and its
    layer's ``d / L`` within :data:`_HELD_DEPTH` of the region's (``tanh`` of ``phi``, ``(3,)``), its layer's
    time ``d^2 / a_z`` that ``d / L`` of the map's plate time where the region has one: the depth term's
    plate time also takes up what the balance's isotropic lateral term misses on an anisotropic plate
    (45-480 s for the map's 8.9 s on a 2 mm plate), and ``(d / L)^2`` of it put the layer far off."""
    cx, cy, radius, fraction, scale, _ = region
    bounded = torch.tanh(phi)
    depth = (fraction + _HELD_DEPTH * bounded[2]).clamp(0.05, 0.95)
    share = (depth**2 * scale).clamp(1e-6, 0.95**2)
    centre = phi.new_tensor([cx, cy]) + _HELD_SHIFT * radius * bounded[:2]
    size = phi.new_tensor([math.log(radius - _MIN_RADIUS_PX)])
    return torch.cat([centre, size, (share / (1 - share)).log()[None]])


def _uncovered(system: BalanceSystem, fit: Fit, name: str, regions: list[_Region]) -> list[_Region]:
    """``regions`` less, for each other delamination in ``fit``'s model (its regressor among the fit's
    columns, :data:`REGRESSORS`), the one nearest its fitted centre in units of the regions' radii: two
    delaminations are held over two defects of the map, not both over the one that explains most."""
    kept = list(regions)
    for other, regressor in REGRESSORS.items():
        shape = system.shapes.get(other)
        if other == name or regressor not in fit.columns or shape is None or not kept:
            continue
        x, y = shape["x"] / system.dx, shape["y"] / system.dx
        kept.remove(min(kept, key=lambda r: math.hypot(x - r[0], y - r[1]) / r[2]))
    return kept


def _held_fit(
    system: BalanceSystem, loss: Callable[[Tensor], Tensor], start: Tensor | None, regions: list[_Region]
) -> tuple[Tensor, _Region]:
    """With candidate regions (:func:`_regions`, :func:`_uncovered`): the disc held at each in turn
    (:func:`_held`: with its radius and depth free the disc grows over the frame as a second depth rate, its
    strength unphysical), its centre refined from the region's centroid (and from ``start``'s where
    ``start`` lies on the region); the best region's ``theta`` and that region."""
    best: tuple[float, Tensor, _Region] | None = None
    for region in regions:
        phis = [torch.zeros(3, dtype=_F64, device=system.frames.device)]
        if start is not None and abs(float(start[2]) - math.log(region[2] - _MIN_RADIUS_PX)) < 1e-9:
            depth = math.sqrt(float(torch.sigmoid(start[3])) / region[4])  # start's layer, d / L
            offset = [(float(start[0]) - region[0]) / (_HELD_SHIFT * region[2])]
            offset += [(float(start[1]) - region[1]) / (_HELD_SHIFT * region[2])]
            offset += [(depth - region[3]) / _HELD_DEPTH]
            phis.append(torch.atanh(phis[0].new_tensor(offset).clamp(-0.99, 0.99)))

        def held_loss(phi: Tensor, region: _Region = region) -> Tensor:
            return loss(_held(region, phi))

        phi = optimise(held_loss, phis, iterations=25, runs=2)
        theta = _held(region, phi).detach()
        with torch.no_grad():
            value = float(loss(theta))
        if best is None or value < best[0]:
            best = (value, theta, region)
    if best is None:
        raise ValueError("delamination: the held fit needs a candidate region no other delamination covers")
    return best[1], best[2]


def _starts(system: BalanceSystem, fit: Fit) -> list[Tensor]:
    """Around the strongest positive structure of the time-mean residual (where heat stays)."""
    residual = system.residual(fit).mean(0)
    m = system.margin
    cx, cy = peak(residual, 4 * int(math.ceil(system.sigma)) + 6)
    starts = []
    for radius in (5.0, 10.0, 20.0):
        for fraction in (0.05, 0.2):
            starts.append(
                torch.tensor(
                    [
                        cx + m + 0.5,
                        cy + m + 0.5,
                        math.log(radius - _MIN_RADIUS_PX),
                        math.log(fraction / (1 - fraction)),
                    ],
                    dtype=_F64,
                    device=system.frames.device,
                )
            )
    return starts


def _fit(name: str, system: BalanceSystem, fit: Fit, start: Tensor | None) -> Shape:
    """Fit the disc of delamination ``name`` and its layer's depth time to the residual of ``fit`` (or
    refine ``start``): held at the candidate regions no other delamination of the model covers
    (:func:`_uncovered`) where the balance has regions, else from the residual's strongest structure
    (only one delamination: a second is tried with regions alone, :data:`REGRESSORS`)."""
    plate = system.shapes.get("depth_conduction")
    if plate is None:  # only tried after depth_conduction (EffectSpec.requires): its plate is fitted
        raise RuntimeError(f"{name} needs the depth_conduction fit of this balance first")
    columns, scale = list(fit.columns), fit.rss

    def loss(theta: Tensor) -> Tensor:
        term, weight = delamination_term(system, theta, plate)
        return system.profile_loss(columns, term, NoiseSpec("T", weight.detach())) / scale

    others = [o for o, regressor in REGRESSORS.items() if o != name and regressor in columns]
    lateral = 0.0
    if system.hints.get(_HINTS) or others:
        regions = _uncovered(system, fit, name, _regions(system, plate["depth_time"]))
        theta, held = _held_fit(system, loss, start, regions)
        lateral = held[5]
    else:
        starts = _starts(system, fit)
        theta = optimise(loss, starts if start is None else [start, *starts], iterations=25, runs=2)
    cx, cy, radius, depth_time = _unpack(theta, plate["depth_time"])
    dx = system.dx
    shape = {
        "x": float(cx) * dx,
        "y": float(cy) * dx,
        "radius": float(radius) * dx,
        "depth_time": float(depth_time),
        "t_heat": plate["t_heat"],
        "plate_time": plate["depth_time"],
        "T_ref": plate["T_ref"],
        "reflected": reflected_share(float(radius) * dx, float(depth_time), lateral),
    }
    term, weight = delamination_term(system, theta.detach(), plate)
    return Shape(term.detach(), NoiseSpec("T", weight.detach()), shape, theta.detach())


def _footprint(p: dict[str, float], system: BalanceSystem) -> float:
    """Held at a defect map's region (``system.hints``): the mean square of the disc over the balance's
    points, at least one point's share; else 1 (a disc looked for anywhere is measured over every point)."""
    if not system.hints.get(_HINTS):
        return 1.0
    gx, gy = pixel_grid(system)
    m = system.margin
    disc = edge_disc(gx, gy, p["x"], p["y"], p["radius"], system.dx)[m:-m, m:-m]
    return max(float(disc.square().mean()), 1.0 / disc.numel())


# ----------------------------------------------------------------------------------- presentation
def _retime(params: dict[str, float], fit_duration: float, start: float, duration: float | None) -> dict:
    return {**params, "t_heat": params["t_heat"] - start}


def _inside(p: dict[str, float]) -> bool:
    """The defect stops at least :data:`_STRENGTH`'s low share of the heat (its strength, after the
    spread), and its term is at most its high end times the full layer's (``strength reflected``): a deep
    defect outlined over its core only has a disc, and so a reflected share, too small (held-out plate 26
    of experiments.flash_defect_map, a 4.5 mm ellipse at d/L 0.6 outlined over 42 of its 306 px: strength
    9, the term 0.29 of the layer's). Of a term within those bounds with ``reflected`` 1 both hold."""
    term = p["strength"] * p["reflected"]
    return _STRENGTH[0] <= p["strength"] and term <= _STRENGTH[1] and p["depth_time"] < p["plate_time"]


def _equation(p: dict[str, float]) -> str:
    kept = "" if p["reflected"] == 1 else f" x {p['reflected']:.2f}"
    return (
        f"+ {p['strength']:.2f}{kept} disc(r < {p['radius']:.2f} mm at ({p['x']:.2f}, {p['y']:.2f}) mm) "
        f"(r_plate - r_layer(d^2/a_z {p['depth_time']:.3g} s)) (T - {p['T_ref']:.1f})"
    )


def _draw(name: str, ax: Any, p: dict[str, float]) -> str:
    draw_circle(ax, p["x"], p["y"], p["radius"], "w--")
    where = f"({p['x']:.2f}, {p['y']:.2f}) mm"
    return f"{name} r = {p['radius']:.2f} mm at {where}, d/L {p['depth_fraction']:.2f}"


def spec_fields(name: str) -> dict[str, Any]:
    """The :class:`~anra_torch.effects.EffectSpec` fields of delamination ``name`` (a key of
    :data:`REGRESSORS`) but what sets one apart from another: ``requires`` and ``tried``."""
    return {
        "name": name,
        "params": {
            "x": "mm",
            "y": "mm",
            "radius": "mm",
            "strength": "1",
            "depth_time": "s",
            "t_heat": "s",
            "plate_time": "s",
            "T_ref": "data units",
            "reflected": "1",
        },
        "build": _build,
        "sample": _sample,
        "help": "+ strength disc (r_plate - r_layer) (T - T_ref): a disc where heat flowing into depth stops "
        "short (a subsurface defect)",
        "check": partial(_check, name),
        "rates": _rates,
        "bounds": _bounds,
        "derived": lambda p: {"depth_fraction": math.sqrt(p["depth_time"] / p["plate_time"])},
        "derived_units": {"depth_fraction": "1"},
        "positions": (("x", "y"),),
        "regressors": (REGRESSORS[name],),
        "from_coefficients": partial(_from_coefficients, name),
        "valid": _inside,
        "shape": partial(_fit, name),
        "look_elsewhere": 4.0,
        "equation": _equation,
        "retime": _retime,
        "positive": frozenset({"radius", "depth_time", "plate_time"}),
        "draw": partial(_draw, name),
        "footprint": _footprint,
    }


SPEC = EffectSpec(**spec_fields("delamination"), requires=("depth_conduction",))
