"""``depth_conduction``: heat flowing from the imaged surface into the body below it.

A body heated at its surface (a flash, a laser switched off, skin after exposure) cools at the surface
mostly by conduction into depth, not by loss to the air. For a plate of thickness ``L`` and
through-thickness diffusivity ``a_z``, heated at its surface at ``t_heat`` and insulated on both faces, the
surface temperature above ``T_ref`` is the lateral diffusion times the depth factor
``theta((t - t_heat) / tau) = 1 + 2 sum_n exp(-n^2 (t - t_heat) / tau)``, ``tau = L^2 / (pi^2 a_z)``, for any
lateral pattern and any lateral (anisotropic) diffusivity. Differentiating its logarithm gives a term that
is local in space:

    - strength r(t - t_heat) (T - T_ref),   r(s) = - d ln theta(s / tau) / ds

``r(s) = 1 / (2 s)`` while heat is still moving through the half-space (``s << L^2 / a_z``: the surface
falls like ``1 / sqrt(t)``, not exponentially), and falls to 0 once the plate has evened out through its
thickness. ``strength`` is 1 for a homogeneous body heated at its surface; other values absorb a
surface layer or a heating that lasted a while.

Parameters: ``strength`` (1), ``t_heat`` (s, the heating's time relative to the video's first frame, < 0;
the fit looks up to the fitted video's length before it), ``depth_time`` (s, ``L^2 / a_z``, the
time heat needs to cross the body; a half-space is ``depth_time`` >> the video), ``T_ref`` (data units, the
temperature before heating).

Diagnosis: a fitted term ``Z`` (``r (T - T_ref)`` through the balance's filters), with ``t_heat``,
``depth_time`` and ``T_ref`` fitted by the errors-in-variables profile loss; valid with ``strength`` in
0.2-5 (far from 1 the term is a transient fitted to a few frames, not a body below the surface). Because
``r`` multiplies each frame as a whole and the Gaussian smoothing acts on each frame alone, ``Z`` is the
smoothed, cropped frames weighted frame by frame, then averaged in time: one smoothing pass per video.
Random draw: ``t_heat`` 2-20 % of the video before its first frame, ``depth_time`` 1-10 videos,
``strength`` 0.7-1, ``T_ref`` at the background.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from anra_torch.balance import NoiseSpec
from anra_torch.effects.base import Context, EffectSpec, Geometry, Grid, Rates, Shape, Term, require, signed
from anra_torch.effects.shapes import optimise
from anra_torch.simulation import Continuum

if TYPE_CHECKING:
    from anra_torch.balance import BalanceSystem, Fit

__all__ = ["SPEC", "depth_rate", "depth_rate_at"]

_F64 = torch.float64
_STRENGTH = (0.2, 5.0)  # a fit outside is not conduction into depth (1 for a homogeneous body)
_SERIES = 8  # terms of either theta series (each converges like exp(-n^2 pi^2 / 2) where it is used)


def depth_rate(elapsed: Tensor, depth_time: float | Tensor) -> Tensor:
    """``r = - d ln theta / dt`` (1/s) of a plate heated at its surface ``elapsed`` s ago.

    ``theta(s) = 1 + 2 sum_n exp(-n^2 s)``, ``s = elapsed pi^2 / depth_time``. Small ``s`` use the
    Poisson-summed form ``sqrt(pi / s) (1 + 2 sum_m exp(-pi^2 m^2 / s))``, where ``r = 1 / (2 elapsed)``
    plus an exponentially small correction; large ``s`` the direct series. Differentiable in both.

    Args:
        elapsed: time since the heating in s, > 0 (any shape).
        depth_time: ``L^2 / a_z`` in s, > 0.

    Returns:
        ``r`` in 1/s, the shape of ``elapsed``.
    """
    elapsed = elapsed.to(_F64)
    tau = torch.as_tensor(depth_time, dtype=_F64, device=elapsed.device) / math.pi**2
    s = elapsed / tau
    n = torch.arange(1, _SERIES + 1, dtype=_F64, device=elapsed.device)
    small = s < 1.0
    # direct series, used where s >= 1
    s_big = torch.where(small, torch.ones_like(s), s)[..., None]
    decay = torch.exp(-(n**2) * s_big)
    direct = (2.0 * (n**2 * decay).sum(-1)) / (1.0 + 2.0 * decay.sum(-1))
    # Poisson-summed series, used where s < 1
    s_small = torch.where(small, s, torch.ones_like(s))[..., None]
    k = math.pi**2 * n**2
    dual_decay = torch.exp(-k / s_small)
    dual = 0.5 / s_small[..., 0] - (2.0 * (k / s_small**2 * dual_decay).sum(-1)) / (
        1.0 + 2.0 * dual_decay.sum(-1)
    )
    return torch.where(small, dual, direct) / tau


@functools.lru_cache(maxsize=1 << 15)
def _rate_at(elapsed: float, depth_time: float) -> float:
    return float(depth_rate(torch.tensor(elapsed, dtype=_F64, device="cpu"), depth_time))


def depth_rate_at(elapsed: Tensor, depth_time: float | Tensor) -> Tensor:
    """:func:`depth_rate` at one time, as a simulation's term asks for it: the same values, looked up.

    A simulation asks at the same solver times again and again (every stage of every forecast of one
    video), so a time that is a CPU scalar without gradient, with a numeric ``depth_time``, is computed
    once per process; any other input goes to :func:`depth_rate`.

    Args:
        elapsed: time since the heating in s, > 0, a 0-d float64 tensor.
        depth_time: ``L^2 / a_z`` in s, > 0.

    Returns:
        ``r`` in 1/s, 0-d float64 on ``elapsed``'s device.
    """
    if (
        elapsed.ndim == 0
        and elapsed.device.type == "cpu"
        and not elapsed.requires_grad
        and isinstance(depth_time, (int, float))
    ):
        return torch.tensor(_rate_at(float(elapsed), float(depth_time)), dtype=_F64, device="cpu")
    return depth_rate(elapsed, depth_time)


def _build(p: dict[str, float], grid: Grid) -> Term:
    strength, t_heat, depth_time, t_ref = p["strength"], p["t_heat"], p["depth_time"], p["T_ref"]

    def term(t: Tensor, u: Tensor) -> Tensor:
        elapsed = (
            torch.as_tensor(t, dtype=_F64, device=u.device) - t_heat
        )  # > 0: the heating precedes the first frame
        return (-strength * depth_rate_at(elapsed, depth_time)).to(u) * (u - t_ref)

    return term


def _sample(rng: np.random.Generator, g: Geometry) -> dict[str, float]:
    return {
        "strength": rng.uniform(0.7, 1.0),
        "t_heat": -rng.uniform(0.02, 0.2) * g.duration,
        "depth_time": rng.uniform(1.0, 10.0) * g.duration,
        "T_ref": g.background,
    }


def _check(p: dict[str, float]) -> None:
    require(p["strength"] >= 0, "depth_conduction", "strength", "non-negative (1 for a homogeneous body)", p)
    require(p["depth_time"] > 0, "depth_conduction", "depth_time", "positive in s (L^2 / a_z)", p)
    require(p["t_heat"] < 0, "depth_conduction", "t_heat", "before the first frame (< 0 s)", p)


def _rates(p: dict[str, float], span: tuple[float, float]) -> Rates:
    """The fastest decay is at the simulation's start (t = 0 s), ``strength r(-t_heat)``."""
    return Rates(
        decay=p["strength"] * float(depth_rate(torch.tensor(-p["t_heat"], device="cpu"), p["depth_time"]))
    )


def _bounds(p: dict[str, float], lo: float, hi: float, duration: float) -> tuple[float, float]:
    return min(lo, p["T_ref"]), max(hi, p["T_ref"])


def _from_coefficients(c: dict[str, float], ctx: Context) -> dict[str, float]:
    return {"strength": -c["Z"], **ctx.shape["depth_conduction"]}


# -------------------------------------------------------------------------------------- shape fit
def _unpack(system: BalanceSystem, theta: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``theta = (logit of the elapsed time at the first frame, log of the depth time's excess, T_ref
    offset)`` -> ``(elapsed s, depth_time s, T_ref - Tbar)``.

    The elapsed time stays in ``(dt / 4, duration)`` and the depth time above a third of the video: a
    plate that evens out sooner would confine the term to the first frames, where a degenerate fit (a
    term that vanishes almost everywhere, with a coefficient to match) could explain a few noisy values.
    """
    length = system.shape[0] * system.dt
    low = 0.25 * system.dt
    elapsed = low + (length - low) * torch.sigmoid(theta[0])
    return elapsed, length / 3.0 + torch.exp(theta[1]), theta[2] * _spread(system)


def _spread(system: BalanceSystem) -> float:
    return float(system.frames.detach().std()) or 1.0


def depth_term(system: BalanceSystem, theta: Tensor) -> tuple[Tensor, Tensor]:
    """``Z`` on the output grid for ``theta`` (see :func:`_unpack`) and ``r`` at the output frames."""
    return _term(system, *_unpack(system, theta))


def _term(
    system: BalanceSystem, elapsed: Tensor, depth_time: Tensor, offset: Tensor
) -> tuple[Tensor, Tensor]:
    t = torch.arange(system.shape[0], dtype=_F64, device=system.frames.device) * system.dt
    rate = depth_rate(t + elapsed, depth_time)
    field = rate[:, None, None] * (system.smoothed - offset)
    return system.filters.time.average(field), system.filters.time.average(rate[:, None, None])


def _starts(system: BalanceSystem) -> list[Tensor]:
    length = system.shape[0] * system.dt
    low = 0.25 * system.dt
    frames = system.frames.detach()
    spread = _spread(system)
    offsets = {float(frames[0].min()) - system.mean, float(frames.min()) - system.mean}
    starts = []
    for elapsed in (system.dt, 0.05 * length, 0.3 * length):
        fraction = min(max((elapsed - low) / (length - low), 1e-3), 1 - 1e-3)
        for depth_time in (0.5 * length, 3.0 * length, 100.0 * length):
            for offset in offsets:
                starts.append(
                    torch.tensor(
                        [
                            math.log(fraction / (1 - fraction)),
                            math.log(depth_time - length / 3),
                            offset / spread,
                        ],
                        dtype=_F64,
                        device=system.frames.device,
                    )
                )
    return starts


def _held(system: BalanceSystem) -> Shape | None:
    """The term held at the plate the balance was given (``system.hints["depth_conduction"]``: a flash
    defect map's ``T_ref``, plate time ``L^2 / a_z`` and ``t_heat`` before the first frame), None without.

    Fitted to the balance's isotropic lateral term, the plate is degenerate: the first frames after a
    flash, where ``r = 1 / (2 s)`` changes faster than the time stencil resolves, and the anisotropy the
    isotropic term misses are explained by a ``T_ref`` near the final temperature and a half-space's plate
    time (21.6 C and 480 s for the map's 20.04 C and 9.28 s on a 2 mm plate), and a delamination measured
    against that plate turns negative. Held at the map's plate the depth term's strength reads 1.0 there.
    """
    held = system.hints.get("depth_conduction")
    if not held:
        return None
    plate, device = held[0], system.frames.device
    shape = {"t_heat": plate["t_heat"], "depth_time": plate["plate_time"], "T_ref": plate["T_ref"]}
    elapsed = torch.tensor(-plate["t_heat"], dtype=_F64, device=device)
    depth_time = torch.tensor(plate["plate_time"], dtype=_F64, device=device)
    offset = torch.tensor(plate["T_ref"] - system.mean, dtype=_F64, device=device)
    term, rate = _term(system, elapsed, depth_time, offset)
    theta = torch.stack([elapsed, depth_time, offset])
    return Shape(term.detach(), NoiseSpec("T", rate.detach()), shape, theta)


def _fit(system: BalanceSystem, fit: Fit, start: Tensor | None) -> Shape:
    """Fit the heating time, depth time and reference temperature to the residual of ``fit``, or hold them
    at a given plate (:func:`_held`)."""
    held = _held(system)
    if held is not None:
        return held
    columns, scale = list(fit.columns), fit.rss

    def loss(theta: Tensor) -> Tensor:
        term, rate = depth_term(system, theta)
        return system.profile_loss(columns, term, NoiseSpec("T", rate.detach())) / scale

    starts = _starts(system)
    theta = optimise(loss, starts if start is None else [*starts, start], iterations=40, runs=2)
    elapsed, depth_time, offset = _unpack(system, theta)
    shape = {
        "t_heat": -float(elapsed),
        "depth_time": float(depth_time),
        "T_ref": system.mean + float(offset),
    }
    term, rate = depth_term(system, theta)
    return Shape(term.detach(), NoiseSpec("T", rate.detach()), shape, theta.detach())


# ----------------------------------------------------------------------------------- presentation
def _retime(params: dict[str, float], fit_duration: float, start: float, duration: float | None) -> dict:
    """The same heating seen from ``start`` s: it lies ``start`` s further back."""
    return {**params, "t_heat": params["t_heat"] - start}


def _equation(p: dict[str, float]) -> str:
    return (
        f"{signed(-p['strength'], '.2f')} r(t {signed(-p['t_heat'], '.3g')} s; L^2/a_z "
        f"{p['depth_time']:.3g} s) (T - {p['T_ref']:.1f})"
    )


def _continuum(p: dict[str, float], m: Continuum, grid: Grid) -> None:
    m.depth = (p["strength"], p["t_heat"], p["depth_time"], p["T_ref"])


SPEC = EffectSpec(
    name="depth_conduction",
    params={"strength": "1", "t_heat": "s", "depth_time": "s", "T_ref": "data units"},
    build=_build,
    sample=_sample,
    help="- strength r(t - t_heat) (T - T_ref): conduction into depth after surface heating "
    "(r = 1/(2 (t - t_heat)) in a thick body)",
    check=_check,
    rates=_rates,
    bounds=_bounds,
    regressors=("Z",),
    from_coefficients=_from_coefficients,
    valid=lambda p: _STRENGTH[0] <= p["strength"] <= _STRENGTH[1],
    shape=_fit,
    look_elsewhere=2.0,
    equation=_equation,
    retime=_retime,
    positive=frozenset({"depth_time"}),
    continuum=_continuum,
)
