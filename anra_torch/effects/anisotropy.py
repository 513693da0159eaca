"""``anisotropy``: ``a_x d_xx T + a_y d_yy T + 2 a_xy d_xy T`` instead of ``a Lap T``.

Parameters: ``a_x``, ``a_y``, ``a_xy`` (mm^2/s; the tensor positive definite); derived ``angle_deg`` (of the
principal axis) and ``ratio`` (of the eigenvalues). Simulated in conservative flux form. Diagnosis:
regressors ``D = T_xx - T_yy`` and ``T_xy`` of the balance bank, beside ``L``. Random draw: eigenvalue
ratio 1.5-4 at any angle, geometric mean of the eigenvalues = ``a``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Rates, Term, signed
from anra_torch.simulation import Continuum

__all__ = ["SPEC"]

_ZERO_FLUX = frozenset({"neumann"})
"""Boundaries whose flux through the frame edge is set to zero explicitly (the mixed term would otherwise
leak heat through a mirrored ghost pixel)."""


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


def _anisotropy_rates(p: dict[str, float], r: tuple[float, float]) -> Rates:
    # |symbol| = (4 a_x sin^2 + 4 a_y sin^2 + 2 a_xy sin sin) / dx^2 <= (4 a_x + 4 a_y + 2 |a_xy|) / dx^2.
    return Rates(diffusivity=(4.0 * p["a_x"] + 4.0 * p["a_y"] + 2.0 * abs(p["a_xy"])) / 8.0)


def _anisotropy_params(c: dict[str, float], ctx: Context) -> dict[str, float]:
    # a_x T_xx + a_y T_yy + 2 a_xy T_xy = (a_x + a_y)/2 L + (a_x - a_y)/2 D + 2 a_xy T_xy
    a_x, a_y, a_xy = c["L"] + c["D"], c["L"] - c["D"], 0.5 * c["T_xy"]
    mean, half = 0.5 * (a_x + a_y), math.hypot(0.5 * (a_x - a_y), a_xy)
    large, small = mean + half, mean - half
    return {
        "a_x": a_x,
        "a_y": a_y,
        "a_xy": a_xy,
        "angle_deg": 0.5 * math.degrees(math.atan2(2.0 * a_xy, a_x - a_y)),
        "ratio": large / small if small > 0 else math.inf,
    }


def _equation(p: dict[str, float]) -> str:
    return f"{p['a_x']:.3f} T_xx + {p['a_y']:.3f} T_yy {signed(2 * p['a_xy'], '.3f')} T_xy"


def _continuum(p: dict[str, float], m: Continuum, grid: Grid) -> None:
    m.tensor = (p["a_x"], p["a_y"], p["a_xy"])


SPEC = EffectSpec(
    name="anisotropy",
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
    regressors=("D", "T_xy"),
    from_coefficients=_anisotropy_params,
    valid=lambda p: math.isfinite(p["ratio"]),
    equation=_equation,
    positive=frozenset({"a_x", "a_y"}),
    continuum=_continuum,
)
