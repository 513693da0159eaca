"""``nonlinear_diffusion``: ``div(a0 (1 + beta (T - T_ref)) grad T)``, temperature-dependent diffusivity.

Parameters: ``a0`` (mm^2/s, > 0), ``beta`` in 1/K, ``T_ref`` in data units. Simulated exactly in flux form
through the Kirchhoff transform. Diagnosis: regressor ``N = Lap (T - Tbar)^2 / 2`` of the balance bank
(``a(T) = c_L + c_N (T - Tbar)``, reported at ``T_ref`` = the background). Random draw: ``a0 = a``,
``T_ref`` = background, ``beta rise`` in [0.3, 1.0]. Size: ``|beta|`` times the video's temperature span
(the relative change of the diffusivity); below 2 % it is negligible.
"""

from __future__ import annotations

import math

import numpy as np
from torch import Tensor

from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Rates, Term, require
from anra_torch.simulation import Continuum, HeatRHS

__all__ = ["SPEC"]


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
    require(p["a0"] > 0, "nonlinear_diffusion", "a0", "positive in mm^2/s", p)


def _nonlinear_rates(p: dict[str, float], r: tuple[float, float]) -> Rates:
    low, high = (p["a0"] * (1.0 + p["beta"] * (temp - p["T_ref"])) for temp in r)
    if min(low, high) <= 0:
        raise ValueError(
            f"nonlinear_diffusion: a0 (1 + beta (T - T_ref)) must stay positive over the temperatures "
            f"[{r[0]:.4g}, {r[1]:.4g}] this video can reach, got {min(low, high):.4g} mm^2/s; "
            f"reduce |beta|={abs(p['beta']):g} 1/K or move T_ref"
        )
    return Rates(diffusivity=max(low, high))


def _nonlinear_sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    spread = rng.uniform(0.3, 1.0)  # a grows by 30-100 % from the background to the peak
    return {"a0": g.a, "beta": spread / g.rise, "T_ref": g.background}


def _nonlinear_params(c: dict[str, float], ctx: Context) -> dict[str, float]:
    # a(T) = c_L + c_N (T - Tbar); reported at T_ref = the background: a0 = a(T_ref), beta = c_N / a0.
    a0 = c["L"] + c["N"] * (ctx.background - ctx.mean)
    return {"a0": a0, "beta": c["N"] / a0 if a0 != 0 else math.nan, "T_ref": ctx.background}


def _equation(p: dict[str, float]) -> str:
    return f"div({p['a0']:.3f} (1 + {p['beta']:.3g} (T - {p['T_ref']:.1f})) grad T)"


def _continuum(p: dict[str, float], m: Continuum, grid: Grid) -> None:
    m.conductivity = (p["a0"], p["beta"], p["T_ref"])


SPEC = EffectSpec(
    name="nonlinear_diffusion",
    params={"a0": "mm^2/s", "beta": "1/K", "T_ref": "data units"},
    build=_nonlinear_build,
    sample=_nonlinear_sample,
    help="div(a0 (1 + beta (T - T_ref)) grad T): temperature-dependent diffusivity",
    replaces_diffusion=True,
    check=_nonlinear_check,
    rates=_nonlinear_rates,
    reference_a=lambda p: p["a0"],
    regressors=("N",),
    from_coefficients=_nonlinear_params,
    valid=lambda p: p["a0"] > 0,
    equation=_equation,
    positive=frozenset({"a0"}),
    size=lambda p, span: abs(p["beta"]) * (span[1] - span[0]),
    min_size=0.02,  # the diffusivity changes by less than 2 % over the video's temperatures: negligible
    continuum=_continuum,
)
