"""``linear_loss``: ``- b (T - T_ref)``, loss to an ambient temperature (perfusion, convection).

Parameters: ``b`` (1/s, >= 0), ``T_ref`` in data units. Diagnosis: regressors ``T`` and ``1`` of the
balance bank (``- b (T - Tbar) - b (Tbar - T_ref)``). Random draw: ``exp(-b duration)`` in [0.3, 0.8];
``T_ref`` = background - [0, 0.2] rise.
"""

from __future__ import annotations

import math

import numpy as np

from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Rates, Term, require, signed
from anra_torch.simulation import Continuum

__all__ = ["SPEC"]


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
    require(p["b"] >= 0, "linear_loss", "b", "non-negative in 1/s (a loss)", p)


def _loss_params(c: dict[str, float], ctx: Context) -> dict[str, float]:
    # -b (T - T_ref) = -b (T - Tbar) - b (Tbar - T_ref)
    b = -c["T"]
    return {"b": b, "T_ref": ctx.mean + c["1"] / b if b != 0 else math.nan}


def _equation(p: dict[str, float]) -> str:
    return f"{signed(-p['b'], '.2f')} (T - {p['T_ref']:.1f})"


def _continuum(p: dict[str, float], m: Continuum, grid: Grid) -> None:
    m.loss, m.ambient = p["b"], p["T_ref"]


SPEC = EffectSpec(
    name="linear_loss",
    params={"b": "1/s", "T_ref": "data units"},
    build=_loss_build,
    sample=_loss_sample,
    help="- b (T - T_ref): loss to an ambient temperature (perfusion, convection)",
    check=_loss_check,
    rates=lambda p, r: Rates(decay=p["b"]),
    bounds=_loss_bounds,
    regressors=("T", "1"),
    from_coefficients=_loss_params,
    valid=lambda p: p["b"] > 0,
    equation=_equation,
    continuum=_continuum,
)
