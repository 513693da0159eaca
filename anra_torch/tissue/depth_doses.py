"""The doses of the depth march, block by block: peak, Omega and CEM43 at every node, and what the frames'
noise does to them.

:func:`anra_torch.tissue.damage_in_depth` marches the subsurface temperature in blocks of frames and hands
each block to :class:`DoseAccumulator`: the running peak, Omega and CEM43 (float64) by the integration
rule asked and, for the base videos, by the other rule too (the frames' sampling in time), each dose only
over the nodes some video takes above its floor.

The noise: a white surface noise of sd ``sigma`` reaches a node at depth ``z`` as a temperature noise of
variance ``C_0(z)`` whose correlation from frame to frame is modelled as ``rho(z)^|lag|``
(:func:`anra_torch.tissue.depth_errors.noise_correlation`: the variance and the zero-frequency power of the
depth's transfer function, summed over the lateral modes). A dose ``D = sum_t f(T_t)`` then varies by
``Var(delta D) = C_0 sum_t sum_t' f'(T_t) f'(T_t') rho^|t - t'|``, accumulated in one pass by a recursive
filter per node and pixel (``y_t = rho y_(t-1) + f'_t``, ``V += f'_t (2 y_t - f'_t)``). Units: C, s, min.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from anra_torch.tissue.dose import (
    CEM43_R,
    GAS_CONSTANT,
    RULES,
    ArrheniusConstants,
)

__all__ = ["DOSE_FLOOR", "OMEGA_FLOOR", "DoseAccumulator"]

OMEGA_FLOOR = 45.0
"""C: a node never hotter than this gets no Omega (the skin's rate there is 4.5e-5 1/s: under 0.003 in a
minute, against the threshold of 1)."""
DOSE_FLOOR = 40.0
"""C: a node whose temperature never exceeds this gets no CEM43 (1/64 min per min there), and nodes are
reported down to where the peak falls below it."""
_F64 = torch.float64
_KELVIN = 273.15


class DoseAccumulator:
    """Running peak (C), Omega and CEM43 of every node of a batch ``(N, Z, H, W)``, block by block.

    Args:
        like: a tensor on the device and of the dtype of the temperatures.
        shape: ``(N, Z, H, W)``.
        dt: frame periods ``(N,)`` (s).
        rule: the integration rule of the doses (:data:`anra_torch.tissue.RULES`).
        constants: the Arrhenius constants.
        base: the first ``base`` videos also get the doses by the other rule and their noise variance.
        rho: the noise's frame-to-frame correlation at every node of the base videos, ``(base, Z)``.
    """

    def __init__(
        self,
        like: Tensor,
        shape: tuple[int, ...],
        dt: Tensor,
        rule: str,
        constants: ArrheniusConstants,
        base: int,
        rho: Tensor,
    ):
        self.peak = torch.full(shape, -torch.inf, device=like.device, dtype=like.dtype)
        zeros = {"device": like.device, "dtype": _F64}
        self.doses = {
            (name, r): torch.zeros(shape if r == rule else (base, *shape[1:]), **zeros)
            for name in ("omega", "cem43")
            for r in RULES
        }
        self.variance = {name: torch.zeros((base, *shape[1:]), **zeros) for name in ("omega", "cem43")}
        self.filtered = {name: torch.zeros((base, *shape[1:]), **zeros) for name in ("omega", "cem43")}
        self.rho = rho.to(device=like.device, dtype=_F64).reshape(base, shape[1], 1, 1)
        self.dt, self.rule, self.constants, self.base = dt, rule, constants, base
        self._theta = constants.activation_energy / GAS_CONSTANT  # K
        self._log_a = math.log(constants.frequency)
        self.previous: Tensor | None = None

    @property
    def omega(self) -> Tensor:
        return self.doses["omega", self.rule]

    @property
    def cem43(self) -> Tensor:
        return self.doses["cem43", self.rule]

    def other(self, name: str) -> Tensor:
        """The base videos' ``name`` by the other rule."""
        return self.doses[name, next(r for r in RULES if r != self.rule)]

    def add(self, celsius: Tensor) -> None:
        """Add a block ``(N, L, Z, H, W)`` of temperatures (C)."""
        warmest = celsius.amax(1)
        self.peak = torch.maximum(self.peak, warmest)
        previous, self.previous = self.previous, celsius[:, -1:]  # linear segments join consecutive blocks
        if previous is not None:
            warmest = torch.maximum(warmest, previous[:, 0])
        warmest = warmest.detach().amax(0).flatten()  # over the block, the frame before it and the batch
        fresh = 0 if previous is None else 1  # the previous block's last frame leads
        for floor, name in ((DOSE_FLOOR, "cem43"), (OMEGA_FLOOR, "omega")):
            hot = torch.nonzero(warmest > floor).flatten()
            if not hot.numel():
                self.filtered[name] = self.filtered[name] * self.rho ** celsius.shape[1]
                continue
            x = celsius.flatten(2)[:, :, hot]  # (N, L, P), in the temperatures' dtype
            if previous is not None:
                x = torch.cat([previous.flatten(2)[:, :, hot], x], 1)
            exponent, rate = self._rate(name, x)
            dt = self.dt.view(-1, 1).to(_F64) / (60.0 if name == "cem43" else 1.0)  # CEM43 in minutes
            mean = {
                "hold": rate[:, fresh:].sum(1) * dt,
                "linear": _segments(name, x, exponent, rate, (self._log_a, self._theta)).sum(1) * dt
                if x.shape[1] > 1
                else None,
            }
            for rule, dose in mean.items():
                videos = len(x) if rule == self.rule else self.base
                if dose is None or not videos:
                    continue
                total = self.doses[name, rule]
                dose = dose[:videos].to(_F64)
                total = total.reshape(len(total), -1).index_add(1, hot, dose).reshape(total.shape)
                self.doses[name, rule] = total
            if self.base:  # the base videos' noise
                slope = self._slope(name, x[: self.base, fresh:])
                self._noise(name, rate[: self.base, fresh:] * slope * dt[: self.base, None], hot)

    def _rate(self, name: str, x: Tensor) -> tuple[Tensor, Tensor]:
        """The dose rate's exponent and the rate (Omega: 1/s; CEM43: per s, in equivalent s at 43 C)."""
        if name == "omega":
            exponent = self._log_a - self._theta / (x + _KELVIN)
        else:
            exponent = _cem_log_r(x) * (x - 43.0)
        return exponent, torch.exp(exponent)

    def _slope(self, name: str, x: Tensor) -> Tensor:
        """``d ln(rate) / dT`` (1/K)."""
        if name == "omega":
            return self._theta / (x + _KELVIN) ** 2
        return _cem_log_r(x)

    def _noise(self, name: str, slopes: Tensor, hot: Tensor) -> None:
        """Accumulate ``sum f'_t f'_t' rho^|t - t'|`` over the block's ``slopes`` ``(base, L, P)`` of the
        ``hot`` nodes (the others' filters decay)."""
        rho, length = self.rho, slopes.shape[1]
        y, total = self.filtered[name], self.variance[name]
        shape = y.shape
        flat_y, flat_total = y.reshape(self.base, -1), total.reshape(self.base, -1)
        nodes = hot // (shape[2] * shape[3])
        decay = rho.reshape(self.base, -1).gather(1, nodes.expand(self.base, -1))
        state, gained = flat_y.index_select(1, hot), torch.zeros_like(slopes[:, 0])
        for t in range(length):
            slope = slopes[:, t]
            state = torch.addcmul(slope, decay, state)
            gained.addcmul_(slope, state - 0.5 * slope, value=2.0)  # f' (2 y - f')
        self.filtered[name] = (
            (y * rho**length).reshape(self.base, -1).index_copy(1, hot, state).reshape(shape)
        )
        self.variance[name] = flat_total.index_add(1, hot, gained).reshape(shape)


def _cem_log_r(x: Tensor) -> Tensor:
    """``-ln R`` of CEM43: ln 2 at or above 43 C, ln 4 below."""
    high, low = x.new_tensor(-math.log(CEM43_R[0])), x.new_tensor(-math.log(CEM43_R[1]))
    return torch.where(x >= 43.0, high, low)


def _mean_rate(r0: Tensor, x: Tensor) -> Tensor:
    """``int_0^1 r0 e^(s x) ds`` (``expm1(x) / x``: no cancellation; 1 at ``x = 0``)."""
    return r0 * torch.nan_to_num(torch.expm1(x) / x, nan=1.0)


def _bend(r0: Tensor, r1: Tensor, x: Tensor) -> Tensor:
    """``int_0^1 r0 e^(s x) s (s - 1) ds = (r1 (2 - x) - r0 (2 + x)) / x^3`` (``r1 = r0 e^x``; a series
    below ``|x| = 0.05``): the first-order effect of an exponent bent by ``s (s - 1)``."""
    small = x.abs() < 0.05
    safe = torch.where(small, 1.0, x)
    exact = (r1 * (2 - safe) - r0 * (2 + safe)) / safe**3
    return torch.where(small, -r0 * (1 / 6 + x / 12 + x**2 / 40), exact)


def _segments(name: str, x: Tensor, exponent: Tensor, rate: Tensor, constants: tuple[float, float]) -> Tensor:
    """The mean rate over every segment between consecutive frames ``(N, L' - 1, P)`` of the linear
    interpolant.

    CEM43's exponent is linear in T on either side of 43 C: exact (a segment crossing 43 C is cut there).
    Omega's exponent ``-Ea / (R_gas T_K)`` bends: each segment adds its curvature term ``c s (s - 1)``,
    ``c = E'' dT^2 / 2``, to first order, where it matters, in ``n = ceil(sqrt(|c| / 0.002))`` pieces where
    it is large (relative error below 1e-6).
    """
    t0, t1 = x[:, :-1], x[:, 1:]
    e0, e1 = exponent[:, :-1], exponent[:, 1:]
    mean = _mean_rate(rate[:, :-1], e1 - e0)
    if name == "cem43":
        crossing = torch.nonzero(((t0 >= 43.0) != (t1 >= 43.0)).flatten()).flatten()
        if crossing.numel():
            a, b = t0.flatten()[crossing], t1.flatten()[crossing]
            cut = (43.0 - a) / (b - a)  # the share of the segment before 43 C
            ea, eb = e0.flatten()[crossing], e1.flatten()[crossing]
            both = cut * _mean_rate(torch.exp(ea), -ea) + (1 - cut) * _mean_rate(torch.ones_like(eb), eb)
            mean = mean.flatten().index_copy(0, crossing, both).reshape(mean.shape)
        return mean
    log_a, theta = constants
    bend = -theta / (0.5 * (t0 + t1) + _KELVIN) ** 3 * (t1 - t0) ** 2  # E'' dT^2 / 2 (< 0)
    mean = mean + bend * _bend(rate[:, :-1], rate[:, 1:], e1 - e0)
    steep = torch.nonzero((bend < -0.002).flatten()).flatten()  # in pieces
    if not steep.numel():
        return mean
    flat = [v.flatten()[steep] for v in (t0, t1, e0)]
    out = mean.flatten().index_copy(0, steep, _bent_pieces(*flat, -bend.flatten()[steep], log_a, theta))
    return out.reshape(mean.shape)


def _bent_pieces(t0: Tensor, t1: Tensor, e0: Tensor, curvature: Tensor, log_a: float, theta: float) -> Tensor:
    """The mean Arrhenius rate over segments whose exponent bends steeply, each in ``n`` pieces."""
    pieces = torch.ceil(torch.sqrt(curvature / 0.002)).clamp_min(1.0)
    out = torch.zeros_like(t0)
    active, j = torch.arange(t0.numel(), device=t0.device), 0
    while active.numel():
        n = pieces[active]
        step = (t1[active] - t0[active]) / n
        low = t0[active] + j * step
        start = e0[active] if j == 0 else log_a - theta / (low + _KELVIN)
        end = log_a - theta / (low + step + _KELVIN)
        r0, r1 = torch.exp(start), torch.exp(end)
        c = -theta / (low + 0.5 * step + _KELVIN) ** 3 * step**2
        out[active] += (_mean_rate(r0, end - start) + c * _bend(r0, r1, end - start)) / n
        j += 1
        active = active[pieces[active] > j]
    return out
