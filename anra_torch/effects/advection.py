"""``advection``: ``- (vx dT/dx + vy dT/dy)``, a flow carrying heat (central differences).

Parameters: ``vx``, ``vy`` in mm/s. Diagnosis: regressors ``T_x``, ``T_y`` of the balance bank. Random
draw: displacement ``|v| duration`` 2-10 px in any direction.
"""

from __future__ import annotations

import math

import numpy as np
from torch import Tensor

from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Rates, Term, signed
from anra_torch.simulation import Continuum

__all__ = ["SPEC"]


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


def _advection_params(c: dict[str, float], ctx: Context) -> dict[str, float]:
    return {"vx": -c["T_x"], "vy": -c["T_y"]}


def _equation(p: dict[str, float]) -> str:
    return f"- ({p['vx']:.2f} dT/dx {signed(p['vy'], '.2f')} dT/dy)"


def _continuum(p: dict[str, float], m: Continuum, grid: Grid) -> None:
    m.velocity = (p["vx"], p["vy"])


SPEC = EffectSpec(
    name="advection",
    params={"vx": "mm/s", "vy": "mm/s"},
    build=_advection_build,
    sample=_advection_sample,
    help="- (vx dT/dx + vy dT/dy): a flow carrying heat",
    rates=lambda p, r: Rates(speed=abs(p["vx"]) + abs(p["vy"])),
    regressors=("T_x", "T_y"),
    from_coefficients=_advection_params,
    equation=_equation,
    continuum=_continuum,
)
