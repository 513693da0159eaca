"""What an effect is: the contract every effect module fills in, and the types they share.

An effect is one module in :mod:`anra_torch.effects` holding one :class:`EffectSpec`: its forward term for
the simulator, how to draw detectable random parameters, its regressors for the diagnosis (built-in terms of
the balance bank, or a fitted shape), how coefficients become physical parameters, and how to write,
re-time and draw it. Nothing outside its module branches on its name.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import check_choice, number
from anra_torch.simulation import BOUNDARIES, Continuum

if TYPE_CHECKING:
    from anra_torch.balance import BalanceSystem, Fit, NoiseSpec

__all__ = [
    "Context",
    "EffectSpec",
    "Geometry",
    "Grid",
    "Rates",
    "Shape",
    "Term",
    "require",
    "same_bounds",
    "signed",
]

Term = Callable[[Tensor, Tensor], Tensor]
"""``(t in s, T (..., H, W)) -> dT/dt contribution (..., H, W)``, built once per simulation."""


# ------------------------------------------------------------------------------------ geometry
@dataclass(frozen=True)
class Grid:
    """The pixel grid an effect acts on.

    Attributes:
        shape: frame size ``(H, W)`` in px.
        dx: pixel size in mm.
        duration: time of the last frame in s (the source's path ends there; 0 keeps it at its start).
        boundary: a key of :data:`anra_torch.simulation.BOUNDARIES`.
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
        return (torch.arange(self.shape[1], dtype=torch.float64, device="cpu") + 0.5) * self.dx

    @property
    def y(self) -> Tensor:
        """Row centres in mm."""
        return (torch.arange(self.shape[0], dtype=torch.float64, device="cpu") + 0.5) * self.dx

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
class Rates:
    """What an effect does to the step size: an effective diffusivity for the 5-point bound
    ``|lambda| <= 8 a / dx^2`` (None: does not touch diffusion), a speed (mm/s, the sum |vx| + |vy|
    bounding central-difference advection by ``speed / dx``) and a decay rate (1/s)."""

    diffusivity: float | None = None
    speed: float = 0.0
    decay: float = 0.0


def same_bounds(p: dict[str, float], low: float, high: float, duration: float) -> tuple[float, float]:
    """The effect creates no new extremes (diffusion, advection)."""
    return low, high


# ------------------------------------------------------------------------------------ diagnosis
@dataclass(frozen=True)
class Context:
    """What turning fitted coefficients into physical parameters needs besides them.

    Attributes:
        mean: ``Tbar``, the temperature the terms were centred on.
        background: median temperature of the first frame's border (the scene's background).
        shape: fitted shape parameters of localised effects, by effect name.
    """

    mean: float
    background: float
    shape: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Shape:
    """A localised effect's fitted term on the output grid, its noise, shape parameters (mm) and the
    unconstrained shape vector they come from."""

    term: Tensor
    noise: NoiseSpec | None
    params: dict[str, float]
    theta: Tensor


ShapeFit = Callable[["BalanceSystem", "Fit", Tensor | None], Shape]
"""``(system, current fit, start) -> Shape``: the effect's term fitted to what the current model leaves
unexplained (from ``start`` when given)."""


# ------------------------------------------------------------------------------------- the spec
@dataclass(frozen=True)
class EffectSpec:
    """One effect: everything the simulator, the diagnosis, the forecast and the reports need of it.

    Attributes:
        name: the effect's name in every record.
        params: parameter name -> unit, in the canonical order.
        build: ``(params, grid) -> term``: the ``dT/dt`` contribution as a function ``(t, T)`` (t in s),
            or, when ``replaces_diffusion``, the operator used instead of ``a Lap T``.
        sample: ``(rng, geometry) -> params``: random parameters that are clearly visible in a video of
            that geometry yet keep it physical.
        help: one line.
        replaces_diffusion: whether the term replaces ``a Lap T`` (at most one such effect per model).
        check: raises ``ValueError`` on parameters outside the model's domain (finite numbers are checked
            for every effect).
        rates: ``(params, (T_low, T_high)) -> Rates`` for the stable step; may raise when the model is
            ill-posed over that temperature range.
        bounds: ``(params, T_low, T_high, duration) -> (T_low, T_high)``: a range the temperatures stay in.
        derived: ``params -> {name: value}`` quantities recorded with the truth (e.g. ``angle_deg``).
        derived_units: units of ``derived``.
        reference_a: ``params -> a`` the diffusivity an isotropic, homogeneous fit should be compared with.
        diffusivity_map: ``(params, grid) -> (H, W)`` diffusivity field, when the effect has one.
        positions: ``(x_key, y_key)`` pairs of coordinates in mm (shifted when a video is cropped).
        regressors: terms added to ``L`` in the diagnosis: names of the balance bank
            (:data:`anra_torch.balance.filters.TERMS`) or, with ``shape``, the name of its fitted term.
        from_coefficients: ``(coefficients by regressor, Context) -> params`` (with derived values).
        valid: whether fitted parameters are physical; an effect whose fit is not cannot enter a model.
        shape: the shape fit of a localised effect (:data:`ShapeFit`), None for a global one.
        look_elsewhere: extra ``-log10 p`` a fitted shape must beat (the search over shapes inflates the
            statistic of the best one).
        searched: whether the diagnosis looks for it by default.
        equation: ``params -> str``: its term in ``dT/dt = ...`` (for a diffusion-replacing effect, the
            diffusion term itself), e.g. ``"- 0.12 (T - 30.0)"``.
        retime: ``(params, fit_duration, start, duration) -> params`` for a model simulated over another
            time span than it was fitted on (a moving source's path); None when time does not enter.
        positive: parameters that must stay positive (refined in log space).
        draw: ``(axes, params) -> caption`` drawing its shape on a map in mm, or None.
        requires: effects that must already be in the model before this one is tried (a local change
            of a global effect).
        size: ``(params, (T_low, T_high)) -> float``: how much the effect changes the model over the
            temperatures the video reaches, dimensionless (e.g. the relative change of the diffusivity);
            None when the effect states no physical size.
        min_size: the smallest ``size`` that materially changes the model: below it a significant effect is
            reported as negligible (with its size), not named.
        heat_input: whether the effect puts heat in (a source): a phase that names one also tries the
            measured source maps (:mod:`anra_torch.recording.phase_diagnosis`).
        continuum: ``(params, continuum, grid) -> None``: fills in the effect's part of the continuous PDE
            that the independent simulator solves (:class:`~anra_torch.simulation.Continuum`:
            coefficients, fields and heat inputs, none of this module's operators); None when the
            independent simulator has no model of it.
        tried: ``hints -> bool``: whether the diagnosis looks for it given the balance's candidate shapes
            by effect (:func:`~anra_torch.selection.checked_hints`; ``{}`` without any), e.g. a second
            delamination only where a defect map gives two regions or more; by default always.
        footprint: ``(params, balance) -> float`` in ``(0, 1]``: the share of the balance's points a localised
            effect held at a candidate region acts on (its share of ``dT/dt`` is then measured there, not
            diluted by the rest of the frame); None: every point.
    """

    name: str
    params: dict[str, str]
    build: Callable[[dict[str, float], Grid], Term]
    sample: Callable[[np.random.Generator, Geometry], dict[str, float]]
    help: str
    replaces_diffusion: bool = False
    check: Callable[[dict[str, float]], None] | None = None
    rates: Callable[[dict[str, float], tuple[float, float]], Rates] = lambda p, span: Rates()
    bounds: Callable[[dict[str, float], float, float, float], tuple[float, float]] = same_bounds
    derived: Callable[[dict[str, float]], dict[str, float]] | None = None
    derived_units: dict[str, str] = field(default_factory=dict)
    reference_a: Callable[[dict[str, float]], float] | None = None
    diffusivity_map: Callable[[dict[str, float], Grid], Tensor] | None = None
    positions: tuple[tuple[str, str], ...] = ()
    regressors: tuple[str, ...] = ()
    from_coefficients: Callable[[dict[str, float], Context], dict[str, float]] | None = None
    valid: Callable[[dict[str, float]], bool] = lambda p: True
    shape: ShapeFit | None = None
    look_elsewhere: float = 0.0
    searched: bool = True
    equation: Callable[[dict[str, float]], str] = lambda p: ""
    retime: Callable[[dict[str, float], float, float, float | None], dict[str, float]] | None = None
    positive: frozenset[str] = frozenset()
    draw: Callable[[Any, dict[str, float]], str] | None = None
    requires: tuple[str, ...] = ()
    size: Callable[[dict[str, float], tuple[float, float]], float] | None = None
    min_size: float = 0.0
    heat_input: bool = False
    continuum: Callable[[dict[str, float], Continuum, Grid], None] | None = None
    tried: Callable[[Mapping[str, tuple[dict[str, float], ...]]], bool] = lambda hints: True
    footprint: Callable[[dict[str, float], BalanceSystem], float] | None = None


def require(condition: bool, name: str, key: str, need: str, params: dict[str, float]) -> None:
    if not condition:
        raise ValueError(f"{name}.{key} must be {need}, got {params[key]!r}")


def signed(value: float, spec: str) -> str:
    """``+ 0.20`` or ``- 0.20``: a term joined to the previous one in an equation's text."""
    return f"{'-' if value < 0 else '+'} {abs(value):{spec}}"
