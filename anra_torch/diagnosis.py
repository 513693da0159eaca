"""Which hidden effect is in a thermal video, found without solving the PDE.

ANRA's principle applied to model selection: the PDE is balanced on the measured frames, term by term.
From the frames we compute, through the SAME Gaussian smoothing ``G`` and the SAME temporal partner
average ``S_t`` of the Holoborodko time derivative ``D_t``, the left side ``U = dT/dt`` and candidate
right-side terms at the same instants, so that every term stays exact for the smoothed field:

=======================  ====================================  ====================================
effect                   regressors besides ``L = Lap T``      the effect's term
=======================  ====================================  ====================================
``linear_loss``          ``T``, ``1``                          ``- b (T - T_ref)``
``advection``            ``T_x``, ``T_y``                      ``- (vx T_x + vy T_y)``
``anisotropy``           ``D = T_xx - T_yy``, ``T_xy``         ``+ (a_x - a_y)/2 D + 2 a_xy T_xy``
``nonlinear_diffusion``  ``N = Lap (T - Tbar)^2 / 2``          ``+ a0 beta N``
``source``               ``S``: a Gaussian moving on a line    ``+ rate S``
``heterogeneity``        ``H = div(disc grad T)``              ``+ (a_inside - a_outside) H``
=======================  ====================================  ====================================

``N`` equals ``(T - Tbar) L + |grad T|^2``; written as the Laplacian of a square it is linear in the
squared field, so smoothing and time averaging commute with it exactly. ``S`` and ``H`` have shape
parameters (path and width; centre and radius) fitted by least squares with the linear coefficients
profiled out, starting from the structure left in the residual (source) or from where heat flows
(heterogeneity). The spatial operators are the size-3 members of :mod:`anra_torch.layers.derivatives`
(5-point Laplacian, central gradient, ``[1, -2, 1]``, 4-point mixed derivative) and the flux form of
:class:`anra_torch.simulation.HeatRHS`: after the Gaussian smoothing they need no more noise suppression,
and they are the operators of a finite-difference heat model, so simulated effects are fitted exactly.

Model selection is stepwise (forward, then backward elimination) with Wald tests. Each effect's
coefficients are tested against their standard errors, propagated exactly from white sensor noise
(its level estimated from the video) through the transposed filters of the residual map (autograd does
the transposing), with the errors-in-variables correction of the Gram matrix. An effect enters when its
p-value beats ``alpha / (effects left)`` (Bonferroni); ``source`` and ``heterogeneity`` pay an extra
look-elsewhere penalty (:data:`LOOK_ELSEWHERE`) for their fitted shape, measured on pure heat videos.
Among the significant candidates, the one that lowers the residual above its expected noise part most enters,
a fitted shape's drop discounted by the share of its statistic that its look-elsewhere penalty stands for
(Wald statistics of non-nested models measure significance, not fit: a disc of higher diffusivity around a
hot spot is as "significant" as ``a`` growing with ``T``, but only the true model fits down to the noise).
The shapes of ``S`` and ``H`` are fitted by the same errors-in-variables least squares: plain least squares
prefers a disc that keeps the noisy ``L`` where its signal is strong (there it is biased least towards
zero) over the disc that explains ``U``, which named a slow disc under a hot spot as loss + advection +
source.

Measured by ``python experiments/diagnosis_benchmark.py`` (README): the top effect, parameter errors and
false positives over 20 random cases per effect and 20 pure videos.

Limits: white noise is assumed (the standard errors and thresholds come from it); the noise parts of
``N`` and ``H`` in the Gram matrix are first-order approximations; a heterogeneity is a disc with a
one-pixel edge, a source a Gaussian moving on a straight line.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from anra_torch.checks import as_video, positive
from anra_torch.layers.derivatives import (
    GaussianSmoothing,
    Gradient,
    Laplacian,
    SecondDerivatives,
    TimeDerivative,
)
from anra_torch.noise import estimate_noise_sd
from anra_torch.simulation import HeatRHS

__all__ = [
    "ALPHA",
    "Diagnosis",
    "EFFECT_GROUPS",
    "EffectGroup",
    "LOOK_ELSEWHERE",
    "REGRESSORS",
    "SMOOTHING",
    "diagnose_terms",
]

REGRESSORS: tuple[str, ...] = ("L", "T", "1", "T_x", "T_y", "D", "T_xy", "N")
"""Global right-side terms computed from the frames (``L`` is always in the model)."""

ALPHA = 1e-3
"""Family-wise false-positive rate of the model selection on pure heat-transfer video."""

LOOK_ELSEWHERE: dict[str, float] = {"source": 4.0, "heterogeneity": 4.0}
"""Extra ``-log10 p`` an effect with a fitted shape must beat: the search over shapes inflates the
statistic of the best shape. On 100 pure videos the source's score reached 2.8 / 3.2 / 5.4 (95 %, 99 %,
max), the heterogeneity's 2.1 / 2.6 / 3.1, against a threshold of 3.8 + 4.0; true effects that are
visible at all score above 8.8 (heterogeneity) and 4000 (source)."""

SMOOTHING: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0)
"""Spatial smoothing candidates (px); the one giving the smallest standard error of ``a`` is used."""

_MIN_VALID_PX = 16  # a smoothing candidate must leave at least this many pixels per side
_MIN_SIGNIFICANCE = 3.0  # |a| / std_error below this (and no effect): no thermal activity
_F64 = torch.float64


# ------------------------------------------------------------------------------------------ terms
class _Terms(nn.Module):
    """``U`` and the candidate regressors at consistent instants, all through the same filters.

    Shape:
        ``frames`` ``(T, H, W)``; every output ``(T - L + 1, H - 2 m, W - 2 m)`` for a time window of
        ``L`` frames, ``m = r + 1`` for a Gaussian of radius ``r``.
    """

    def __init__(self, sigma: float, *, time_length: int = 5) -> None:
        super().__init__()
        self.time = TimeDerivative("smooth", time_length)
        self.smoother = GaussianSmoothing(sigma)
        self.laplacian = Laplacian(3, family="holoborodko")  # the 5-point stencil; partner = 1-px crop
        self.gradient = Gradient(3)
        self.second = SecondDerivatives(3)

    @property
    def margin(self) -> int:
        """Pixels lost on each side."""
        return self.smoother.radius + 1

    def finish(self, field: Tensor) -> Tensor:
        """Smooth and crop a full-frame, time-averaged term like ``U``: ``(K, H, W) -> (K, h, w)``."""
        return self.laplacian.partner(self.smoother(field))

    def forward(self, frames: Tensor, dt: float, dx: float, mean: float) -> dict[str, Tensor]:
        centred = frames - mean
        rate, average = self.time.with_average(centred, dt)
        square = self.time.average(0.5 * centred * centred)
        g_rate, g_avg, g_square = (self.smoother(x) for x in (rate, average, square))
        grad = self.gradient(g_avg, dx)
        second = self.second(g_avg, dx)
        t = self.laplacian.partner(g_avg)
        return {
            "U": self.laplacian.partner(g_rate),
            "L": self.laplacian(g_avg, dx),
            "T": t,
            "1": torch.ones_like(t),
            "T_x": grad[:, 0],
            "T_y": grad[:, 1],
            "D": second[:, 0] - second[:, 1],
            "T_xy": second[:, 2],
            "N": self.laplacian(g_square, dx),
            "_average": average,  # S_t (T - Tbar) before smoothing, for H
        }

    def kernels(self, names: Sequence[str], dt: float, dx: float) -> Tensor:
        """Space-time impulse responses of linear terms at one output point, ``(P, L, S, S)``.

        Their inner products are the noise covariances per output point for unit noise variance.
        """
        side = 2 * self.margin + 1
        probe = torch.zeros(self.time.length, side, side, dtype=_F64, requires_grad=True)
        out = self(probe, dt, dx, 0.0)
        rows = []
        for name in names:
            term = out[name]
            grad = None
            if term.requires_grad:
                (grad,) = torch.autograd.grad(term.sum(), probe, retain_graph=True, allow_unused=True)
            rows.append(torch.zeros_like(probe) if grad is None else grad)
        return torch.stack(rows).detach()


# ------------------------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class _Noise:
    """Noise of a term: ``weight(p)`` times the white noise through ``kernel``'s filters (linearised)."""

    kernel: str  # a name in _System.inner
    weight: Tensor | None = None  # broadcastable to the term; None is 1


@dataclass(frozen=True)
class _Fit:
    columns: tuple[str, ...]
    beta: Tensor
    cov: Tensor
    rss: float

    def coefficients(self) -> dict[str, float]:
        return {c: float(b) for c, b in zip(self.columns, self.beta, strict=True)}

    def std_errors(self) -> dict[str, float]:
        variances = self.cov.diagonal().clamp_min(0)
        return {c: float(v.sqrt()) for c, v in zip(self.columns, variances, strict=True)}

    def score(self, group: Sequence[str]) -> float:
        """``-log10 p`` of the Wald test that the group's coefficients are zero."""
        idx = [self.columns.index(c) for c in group]
        b, cov = self.beta[idx], self.cov[idx][:, idx]
        chi2 = float(b @ torch.linalg.pinv(cov, hermitian=True) @ b)
        if not math.isfinite(chi2):
            return 0.0
        return -_log10_pvalue(chi2, len(idx))


def _log10_pvalue(chi2: float, dof: int) -> float:
    """``log10 P(chi2_dof > chi2)``, accurate far into the tail (no underflow)."""
    s, x = 0.5 * dof, 0.5 * max(chi2, 0.0)
    q = float(torch.special.gammaincc(torch.tensor(s, dtype=_F64), torch.tensor(x, dtype=_F64)))
    if q > 1e-280:
        return math.log10(q)
    # Q(s, x) ~ x^(s-1) e^-x / Gamma(s) (1 + (s-1)/x) for large x.
    return ((s - 1.0) * math.log(x) - x - math.lgamma(s) + math.log1p((s - 1.0) / x)) / math.log(10.0)


def _chi2_of_score(score: float, dof: int) -> float:
    """The chi-square statistic whose ``-log10 p`` at ``dof`` degrees of freedom is ``score`` (bisection)."""
    if score <= 0.0:
        return 0.0
    low, high = 0.0, 1.0
    while -_log10_pvalue(high, dof) < score:
        high *= 2.0
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if -_log10_pvalue(mid, dof) < score else (low, mid)
    return 0.5 * (low + high)


def _search_discount(name: str, score: float) -> float:
    """Share of an effect's statistic left after its :data:`LOOK_ELSEWHERE` penalty (1 without a shape).

    The best of many trial shapes explains some noise too: of a statistic ``chi2(score)``, the part the
    penalty stands for, ``chi2(score) - chi2(score - penalty)``, is not counted as explained signal.
    """
    penalty = LOOK_ELSEWHERE.get(name, 0.0)
    if penalty == 0.0:
        return 1.0
    dof = len(EFFECT_GROUPS[name].regressors)
    full = _chi2_of_score(score, dof)
    return _chi2_of_score(score - penalty, dof) / full if full > 0 else 0.0


class _System:
    """The terms of one video at one smoothing, their noise model and least-squares fits."""

    def __init__(self, frames: Tensor, dt: float, dx: float, sigma: float, noise_sd: float) -> None:
        self.module = _Terms(sigma)
        self.dt, self.dx, self.sigma, self.noise_sd = dt, dx, sigma, noise_sd
        self.mean = float(frames.mean())
        self.frames = frames.detach().clone().requires_grad_(True)
        self.shape = tuple(frames.shape)
        terms = self.module(self.frames, dt, dx, self.mean)
        self.average = terms.pop("_average")
        self.terms: dict[str, Tensor] = terms
        names = ("U", *REGRESSORS)
        k = self.module.kernels(names, dt, dx).flatten(1)
        inner = k @ k.T
        self.inner = {(a, b): float(inner[i, j]) for i, a in enumerate(names) for j, b in enumerate(names)}
        self.noise: dict[str, _Noise | None] = {name: _Noise(name) for name in names}
        self.noise["1"] = None
        # N = Lap G S_t (T - Tbar)^2 / 2: its noise is Lap G S_t ((T - Tbar) n), about (T - Tbar) times L's.
        self.noise["N"] = _Noise("L", terms["T"].detach())
        self.n = terms["U"].numel()
        flat = torch.stack([terms[c].detach().flatten() for c in names], 1)
        self._products = flat.T @ flat  # cached [U, X]^T [U, X] of the global terms
        self._index = {c: i for i, c in enumerate(names)}

    @property
    def u(self) -> Tensor:
        return self.terms["U"]

    def add(self, name: str, term: Tensor, noise: _Noise | None) -> None:
        """Register an extra term (source, heterogeneity) on the output grid."""
        self.terms[name] = term
        self.noise[name] = noise

    def _noise_product(self, a: str, b: str) -> float:
        return float(self._noise_inner(self.noise[a], self.noise[b]))

    def _noise_inner(self, na: _Noise | None, nb: _Noise | None) -> Tensor:
        """Expected product of the noise parts of two terms over all output points (differentiable in
        the weights): ``sd^2 <k_a, k_b> sum(w_a w_b)``."""
        if na is None or nb is None:
            return torch.zeros((), dtype=_F64)
        if na.weight is None and nb.weight is None:
            total = torch.tensor(float(self.n), dtype=_F64)
        else:
            wa = na.weight if na.weight is not None else torch.ones((), dtype=_F64)
            wb = nb.weight if nb.weight is not None else torch.ones((), dtype=_F64)
            product = wa * wb
            total = product.sum() * (self.n / product.numel())
        return self.noise_sd**2 * self.inner[(na.kernel, nb.kernel)] * total

    def _product(self, a: str, b: str) -> Tensor:
        if a in self._index and b in self._index:
            return self._products[self._index[a], self._index[b]]
        return (self.terms[a].detach() * self.terms[b].detach()).sum()

    def normal_equations(self, columns: Sequence[str]) -> tuple[Tensor, Tensor]:
        """``(X^T X, X^T U)`` minus their expected noise parts (errors-in-variables)."""
        p = len(columns)
        gram = torch.empty(p, p, dtype=_F64)
        cross = torch.empty(p, dtype=_F64)
        for i, a in enumerate(columns):
            cross[i] = self._product(a, "U") - self._noise_product(a, "U")
            for j in range(i, p):
                b = columns[j]
                gram[i, j] = gram[j, i] = self._product(a, b) - self._noise_product(a, b)
        return gram, cross

    def fit(self, columns: Sequence[str]) -> _Fit:
        """Least squares of U on ``columns`` and the white-noise covariance of the coefficients.

        The residual map ``frames -> U - sum beta_j X_j`` (linearised) is pushed back through the
        transposed filters with each regressor as the lever: ``Cov = G^-1 M G^-1`` with
        ``M_ij = sd^2 <A^T x_i, A^T x_j>`` (sandwich form, exact for white noise).
        """
        columns = tuple(columns)
        gram, cross = self.normal_equations(columns)
        inverse = torch.linalg.pinv(gram, hermitian=True)
        beta = inverse @ cross
        residual = self.u - sum(float(beta[i]) * self.terms[c] for i, c in enumerate(columns))
        backs = []
        for c in columns:
            lever = self.terms[c].detach().expand_as(residual)
            (back,) = torch.autograd.grad(residual, self.frames, grad_outputs=lever, retain_graph=True)
            backs.append(back.flatten())
        stacked = torch.stack(backs)
        cov = inverse @ (self.noise_sd**2 * (stacked @ stacked.T)) @ inverse
        rss = float(residual.detach().pow(2).sum())
        return _Fit(columns, beta, cov, rss)

    def expected_rss(self, fit: _Fit) -> float:
        """Expected residual sum of squares of ``fit`` if the data were its model plus white noise."""
        weights = {"U": 1.0} | {c: -float(b) for c, b in zip(fit.columns, fit.beta, strict=True)}
        return sum(
            wa * wb * self._noise_product(a, b) for a, wa in weights.items() for b, wb in weights.items()
        )

    def residual(self, fit: _Fit) -> Tensor:
        """``U - X beta`` of a fit, detached, ``(K, h, w)``."""
        return (
            self.u - sum(float(b) * self.terms[c] for b, c in zip(fit.beta, fit.columns, strict=True))
        ).detach()

    def profile_loss(self, columns: Sequence[str], extra: Tensor, noise: _Noise | None = None) -> Tensor:
        """Residual sum of squares above the noise of U on ``columns`` plus ``extra`` (differentiable in
        ``extra`` and in ``noise``'s weight, the extra term's noise model).

        The errors-in-variables fit of :meth:`fit`: the products lose their expected noise parts and the
        loss is ``rss - expected_rss`` at the corrected coefficients. Plain least squares would prefer
        shapes that keep a noisy regressor where its signal is strong (there it is biased least towards
        zero), not the shape that explains ``U``. Written by blocks: the base columns' excess minus
        ``r^2 / q``, with ``r`` the extra term's corrected covariance with the base residual and ``q`` its
        corrected energy beyond the base columns. ``q`` is kept at least a tenth of its raw value: a shape
        whose own noise is over 90 % of that energy sits where there is no signal, and a vanishing ``q``
        would otherwise make the loss arbitrarily negative (in one benchmark case a disc fitted to nothing
        reached -46,000 against +1,000 for the plain model).
        """
        p = len(columns)

        def corrected(a: str, b: str) -> Tensor:
            return self._product(a, b) - self._noise_product(a, b)

        raw_base = torch.stack([torch.stack([self._product(a, b) for b in columns]) for a in columns])
        gram_base = torch.stack([torch.stack([corrected(a, b) for b in columns]) for a in columns])
        cross_base = torch.stack([corrected(a, "U") for a in columns])
        # A tiny ridge keeps the solves defined when a trial shape leaves the frame or copies a column.
        ridge = 1e-10 * raw_base.diagonal().abs().max() * torch.eye(p, dtype=_F64)
        beta_base = torch.linalg.solve(gram_base + ridge, cross_base)
        raw_extra = torch.stack([(self.terms[c].detach() * extra).sum() for c in columns])
        cross_extra = raw_extra - torch.stack([self._noise_inner(self.noise[c], noise) for c in columns])
        energy = (extra * extra).sum()
        q_raw = energy - raw_extra @ torch.linalg.solve(raw_base + ridge, raw_extra)
        q = (
            energy
            - self._noise_inner(noise, noise)
            - cross_extra @ torch.linalg.solve(gram_base + ridge, cross_extra)
        )
        r = (
            (self.u.detach() * extra).sum()
            - self._noise_inner(self.noise["U"], noise)
            - cross_extra @ beta_base
        )
        base_excess = corrected("U", "U") - cross_base @ beta_base
        return base_excess - r * r / torch.maximum(q, 0.1 * q_raw).clamp_min(1e-300)


# ----------------------------------------------------------------------------------- effect groups
@dataclass(frozen=True)
class _Context:
    """What turning coefficients into physical parameters needs besides them."""

    mean: float  # Tbar, the temperature the terms were centred on
    background: float  # median temperature of the first frame's border (the scene's background)
    shape: dict = field(default_factory=dict)  # fitted shape parameters of localised effects


def _loss_params(c: dict[str, float], ctx: _Context) -> dict[str, float]:
    # -b (T - T_ref) = -b (T - Tbar) - b (Tbar - T_ref)
    b = -c["T"]
    return {"b": b, "T_ref": ctx.mean + c["1"] / b if b != 0 else math.nan}


def _advection_params(c: dict[str, float], ctx: _Context) -> dict[str, float]:
    return {"vx": -c["T_x"], "vy": -c["T_y"]}


def _anisotropy_params(c: dict[str, float], ctx: _Context) -> dict[str, float]:
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


def _nonlinear_params(c: dict[str, float], ctx: _Context) -> dict[str, float]:
    # a(T) = c_L + c_N (T - Tbar); reported at T_ref = the background: a0 = a(T_ref), beta = c_N / a0.
    a0 = c["L"] + c["N"] * (ctx.background - ctx.mean)
    return {"a0": a0, "beta": c["N"] / a0 if a0 != 0 else math.nan, "T_ref": ctx.background}


def _source_params(c: dict[str, float], ctx: _Context) -> dict[str, float]:
    return {**ctx.shape["source"], "rate": c["S"]}


def _heterogeneity_params(c: dict[str, float], ctx: _Context) -> dict[str, float]:
    return {**ctx.shape["heterogeneity"], "a_inside": c["L"] + c["H"], "a_outside": c["L"]}


# ------------------------------------------------------------------------------- localised shapes
@dataclass(frozen=True)
class _Shape:
    """A localised effect's fitted term on the output grid, its noise, shape parameters (mm) and
    the unconstrained shape vector they come from."""

    term: Tensor
    noise: _Noise | None
    params: dict[str, float]
    theta: Tensor


def _grid(system: _System) -> tuple[Tensor, Tensor]:
    """Pixel-centre coordinates (mm) of the full frame: x along columns ``(W,)``, y along rows ``(H,)``."""
    _, h, w = system.shape
    return (torch.arange(w, dtype=_F64) + 0.5) * system.dx, (torch.arange(h, dtype=_F64) + 0.5) * system.dx


def _source_term(system: _System, theta: Tensor) -> Tensor:
    """``S`` for ``theta = (x0, y0, x1, y1, log width)`` (px): unit-rate Gaussian moving linearly."""
    n_frames = system.shape[0]
    x, y = _grid(system)
    dx = system.dx
    s = torch.arange(n_frames, dtype=_F64) / max(n_frames - 1, 1)  # fraction of the path
    cx = (theta[0] + (theta[2] - theta[0]) * s) * dx
    cy = (theta[1] + (theta[3] - theta[1]) * s) * dx
    inv = 0.5 / ((_MIN_WIDTH_PX + torch.exp(theta[4])) * dx) ** 2
    gx = torch.exp(-((x[None, :] - cx[:, None]) ** 2) * inv)  # (T, W)
    gy = torch.exp(-((y[None, :] - cy[:, None]) ** 2) * inv)  # (T, H)
    field = gy[:, :, None] * gx[:, None, :]
    return system.module.finish(system.module.time.average(field))


_MIN_RADIUS_PX = 2.0  # a smaller disc is below the smoothing scale: not identifiable
_MIN_WIDTH_PX = 0.5


def _radius(theta: Tensor) -> Tensor:
    """Disc radius in px from the unconstrained ``theta[2]``."""
    return _MIN_RADIUS_PX + torch.exp(theta[2])


def _disc(system: _System, theta: Tensor) -> Tensor:
    """Disc map ``(H, W)`` in [0, 1] with a tanh edge one pixel wide; ``theta = (x, y, radius code)`` (px)."""
    x, y = _grid(system)
    dx = system.dx
    r = torch.sqrt((x[None, :] - theta[0] * dx) ** 2 + (y[:, None] - theta[1] * dx) ** 2 + 1e-12)
    return 0.5 * (1.0 + torch.tanh((_radius(theta) * dx - r) / dx))


def _heterogeneity_term(system: _System, theta: Tensor, average: Tensor) -> Tensor:
    """``H = G div(disc grad S_t T)`` (flux form) on the output grid."""
    disc = _disc(system, theta)
    flux = HeatRHS(disc, dx=system.dx)(torch.zeros((), dtype=_F64), average)
    return system.module.finish(flux)


def _optimise(
    loss: Callable[[Tensor], Tensor], starts: Sequence[Tensor], *, iterations: int, runs: int
) -> Tensor:
    """L-BFGS from the ``runs`` best of ``starts`` (by loss); returns the best parameters seen."""
    with torch.no_grad():
        values = [float(loss(s)) for s in starts]
    order = sorted(range(len(starts)), key=values.__getitem__)
    best = (values[order[0]], starts[order[0]].clone())
    for index in order[:runs]:
        theta = starts[index].clone().requires_grad_(True)
        # The loss is relative to the current model's residual: one unit of chi-square is ~1e-5 of it.
        optimiser = torch.optim.LBFGS(
            [theta], lr=1.0, max_iter=iterations, tolerance_change=1e-8, line_search_fn="strong_wolfe"
        )

        def closure(theta: Tensor = theta, optimiser: torch.optim.LBFGS = optimiser) -> Tensor:
            optimiser.zero_grad()
            value = loss(theta)
            value.backward()
            nonlocal best
            if float(value.detach()) < best[0] and bool(torch.isfinite(theta).all()):
                best = (float(value.detach()), theta.detach().clone())
            return value

        optimiser.step(closure)
    return best[1]


def _peak(image: Tensor, radius: int) -> tuple[float, float]:
    """Centroid (column, row) in px of the positive part of ``image`` around its maximum."""
    h, w = image.shape
    row, col = divmod(int(image.argmax()), w)
    r0, r1, c0, c1 = (
        max(row - radius, 0),
        min(row + radius + 1, h),
        max(col - radius, 0),
        min(col + radius + 1, w),
    )
    patch = image[r0:r1, c0:c1].clamp_min(0)
    total = float(patch.sum())
    if total <= 0:
        return float(col), float(row)
    rows = torch.arange(r0, r1, dtype=_F64)[:, None]
    cols = torch.arange(c0, c1, dtype=_F64)[None, :]
    return float((patch * cols).sum()) / total, float((patch * rows).sum()) / total


def _fit_source(system: _System, fit: _Fit, start: Tensor | None) -> _Shape:
    """Fit the source's path and width to the residual of ``fit`` (or refine ``start``)."""
    residual = system.residual(fit)
    m = system.module.margin
    k = residual.shape[0]
    third = max(k // 3, 1)
    radius = 4 * int(math.ceil(system.sigma)) + 6
    early = _peak(residual[:third].mean(0), radius)
    late = _peak(residual[-third:].mean(0), radius)
    centre = system.module.time.centre
    t_early = (0.5 * (third - 1) + centre) / (system.shape[0] - 1)
    t_late = (k - 0.5 * (third + 1) + centre) / (system.shape[0] - 1)
    span = max(t_late - t_early, 1e-6)
    vx, vy = (late[0] - early[0]) / span, (late[1] - early[1]) / span
    # output pixel j is full-frame pixel j + m, whose centre is at j + m + 0.5 px
    x0, y0 = early[0] - vx * t_early + m + 0.5, early[1] - vy * t_early + m + 0.5
    x1, y1 = x0 + vx, y0 + vy
    columns = list(fit.columns)
    scale = fit.rss

    def loss(theta: Tensor) -> Tensor:
        return system.profile_loss(columns, _source_term(system, theta)) / scale

    starts = [torch.tensor([x0, y0, x1, y1, math.log(w - _MIN_WIDTH_PX)], dtype=_F64) for w in (2.0, 4.0)]
    theta = _optimise(loss, starts if start is None else [*starts, start], iterations=40, runs=1)
    dx = system.dx
    shape = {
        "x0": float(theta[0]) * dx,
        "y0": float(theta[1]) * dx,
        "x1": float(theta[2]) * dx,
        "y1": float(theta[3]) * dx,
        "width": float(_MIN_WIDTH_PX + torch.exp(theta[4])) * dx,
    }
    return _Shape(_source_term(system, theta).detach(), None, shape, theta)


def _activity_centres(system: _System, count: int = 2) -> list[tuple[float, float]]:
    """Local maxima (column, row in px of the full frame) of the heat-flow energy ``sum_t L^2``."""
    energy = system.terms["L"].detach().pow(2).sum(0)
    size = 2 * int(4 * max(system.sigma, 1.0)) + 1
    pooled = F.max_pool2d(energy[None, None], size, stride=1, padding=size // 2)[0, 0]
    peaks = ((energy == pooled) & (energy > 0.2 * energy.max())).nonzero().tolist()
    peaks.sort(key=lambda rc: -float(energy[rc[0], rc[1]]))
    m = system.module.margin
    return [(c + m + 0.5, r + m + 0.5) for r, c in peaks[:count]]


def _local_diffusivity(system: _System, window: int) -> tuple[Tensor, Tensor]:
    """Windowed least-squares ``a`` of the plain model and its signal energy, both ``(h, w)``.

    ``a = sum U L / (sum L^2 - noise)`` over a ``window`` x ``window`` box and all frames.
    """
    u, lap = system.u.detach(), system.terms["L"].detach()

    def box(m: Tensor) -> Tensor:
        return F.avg_pool2d(m[None, None], window, stride=1, padding=window // 2, count_include_pad=False)[
            0, 0
        ]

    noise = system.noise_sd**2 * system.inner[("L", "L")] * u.shape[0]
    energy = box((lap * lap).sum(0)) - noise
    a = box((u * lap).sum(0)) / energy.clamp_min(1e-300)
    return a, energy.clamp_min(0)


def _heterogeneity_starts(system: _System) -> list[Tensor]:
    """Discs to start from: the two regions of the windowed ``a`` field (split where the weighted
    between-class variance is largest) and circles about where heat flows."""
    m = system.module.margin
    a, energy = _local_diffusivity(system, 2 * int(math.ceil(2 * system.sigma)) + 5)
    ok = energy > 0.05 * energy.max()
    starts = []
    if int(ok.sum()) >= 4:
        values, weights = a[ok], energy[ok]
        order = values.argsort()
        v, w = values[order], weights[order]
        cw, cv = w.cumsum(0), (w * v).cumsum(0)
        total_w, total_v = cw[-1], cv[-1]
        mean_low = cv[:-1] / cw[:-1]
        mean_high = (total_v - cv[:-1]) / (total_w - cw[:-1])
        between = cw[:-1] * (total_w - cw[:-1]) * (mean_low - mean_high) ** 2
        split = float(v[int(between.argmax())])
        rows, cols = torch.meshgrid(
            torch.arange(a.shape[0], dtype=_F64), torch.arange(a.shape[1], dtype=_F64), indexing="ij"
        )
        for region in (ok & (a <= split), ok & (a > split)):
            count = int(region.sum())
            if count == 0:
                continue
            radius = max(math.sqrt(count / math.pi), _MIN_RADIUS_PX + 1.0)
            cx, cy = float(cols[region].mean()) + m + 0.5, float(rows[region].mean()) + m + 0.5
            starts.append(torch.tensor([cx, cy, math.log(radius - _MIN_RADIUS_PX)], dtype=_F64))
    for cx, cy in _activity_centres(system):
        for radius in (6.0, 12.0, 20.0):
            starts.append(torch.tensor([cx, cy, math.log(radius - _MIN_RADIUS_PX)], dtype=_F64))
    return starts


def _fit_heterogeneity(system: _System, fit: _Fit, start: Tensor | None) -> _Shape:
    """Fit a disc of different diffusivity where heat flows (or refine ``start``)."""
    columns = list(fit.columns)
    average = system.average.detach()
    scale = fit.rss
    m = system.module.margin

    def loss(theta: Tensor) -> Tensor:
        noise = _Noise("L", _disc(system, theta)[m:-m, m:-m])
        return system.profile_loss(columns, _heterogeneity_term(system, theta, average), noise) / scale

    if start is None:
        theta = _optimise(loss, _heterogeneity_starts(system), iterations=25, runs=3)
    else:  # the previous fit, and the usual starts in case the model around it changed a lot
        theta = _optimise(loss, [start, *_heterogeneity_starts(system)], iterations=25, runs=1)
    disc = _disc(system, theta).detach()[m:-m, m:-m]
    # Built from the frames' graph (H is linear in them) so that its noise enters the standard errors.
    term = _heterogeneity_term(system, theta.detach(), system.average)
    dx = system.dx
    shape = {"x": float(theta[0]) * dx, "y": float(theta[1]) * dx, "radius": float(_radius(theta)) * dx}
    return _Shape(term, _Noise("L", disc), shape, theta)


# ------------------------------------------------------------------------------------ the registry
@dataclass(frozen=True)
class EffectGroup:
    """One entry of :data:`EFFECT_GROUPS`: the regressors that express an effect and its parameters.

    Attributes:
        regressors: names of the terms added to ``L`` when the effect is present.
        params: ``(coefficients, context) -> parameters`` in the units of :data:`anra_torch.effects.EFFECTS`.
        replaces_diffusion: whether the effect changes the diffusion operator (at most one per model).
        valid: whether fitted parameters are physical (e.g. a loss, not a gain); an effect whose
            fit is not cannot enter the model.
        shape: for a localised effect, ``(system, current fit, start) -> _Shape``: its term fitted to
            what the current model leaves unexplained (from ``start`` when given); None for global ones.
    """

    regressors: tuple[str, ...]
    params: Callable[[dict[str, float], _Context], dict[str, float]]
    replaces_diffusion: bool = False
    shape: Callable[[_System, _Fit, Tensor | None], _Shape] | None = None
    valid: Callable[[dict[str, float]], bool] = lambda p: True


EFFECT_GROUPS: dict[str, EffectGroup] = {
    "linear_loss": EffectGroup(("T", "1"), _loss_params, valid=lambda p: p["b"] > 0),
    "advection": EffectGroup(("T_x", "T_y"), _advection_params),
    "anisotropy": EffectGroup(
        ("D", "T_xy"), _anisotropy_params, replaces_diffusion=True, valid=lambda p: math.isfinite(p["ratio"])
    ),
    "nonlinear_diffusion": EffectGroup(
        ("N",), _nonlinear_params, replaces_diffusion=True, valid=lambda p: p["a0"] > 0
    ),
    "source": EffectGroup(("S",), _source_params, shape=_fit_source, valid=lambda p: p["rate"] > 0),
    "heterogeneity": EffectGroup(
        ("H",),
        _heterogeneity_params,
        replaces_diffusion=True,
        shape=_fit_heterogeneity,
        valid=lambda p: p["a_inside"] > 0 and p["a_outside"] > 0,
    ),
}
"""The effects :func:`diagnose_terms` looks for, by the names of :data:`anra_torch.effects.EFFECTS`."""


# ------------------------------------------------------------------------------------------ result
@dataclass(frozen=True)
class Diagnosis:
    """Output of :func:`diagnose_terms`.

    Attributes:
        base: diffusivity ``a`` (mm^2/s) of the selected model: the coefficient of ``Lap T`` (for
            anisotropy the mean ``(a_x + a_y) / 2``, for nonlinear diffusion ``a`` at the mean
            temperature, for heterogeneity ``a_outside``).
        base_std_error: its standard error (mm^2/s).
        effects: the effects found, ``{"name", "params", "score"}`` ranked by score (``score`` is
            ``-log10`` of the effect's p-value given the rest of the model); empty for pure heat transfer.
        a_plain: ``a`` of the plain model ``dT/dt = a Lap T``.
        scores: every effect's score when it was last tested.
        thresholds: the score each effect had to beat when it was last tested.
        coefficients: coefficients of the selected model by regressor name.
        std_errors: their standard errors.
        noise_sd: sensor noise sd used (units of the data).
        smoothing: spatial Gaussian sigma used (px).
        mean: the temperature ``Tbar`` the terms were centred on.
        fit_ratio: residual energy of the selected model over its expected value for white noise of
            ``noise_sd`` alone: about 1 (within +-0.05 on pure 64 px videos) when the model explains the
            video down to the noise, above when something is left unexplained.
        residual_map: time-mean residual ``U - X beta`` of the selected model (units of T per s),
            ``(H - 2 margin, W - 2 margin)``.
        margin: pixels between the frame edge and ``residual_map`` (the filters' reach).
    """

    base: float
    base_std_error: float
    effects: list[dict]
    a_plain: float
    scores: dict[str, float]
    thresholds: dict[str, float]
    coefficients: dict[str, float]
    std_errors: dict[str, float]
    noise_sd: float
    smoothing: float
    mean: float
    fit_ratio: float
    residual_map: Tensor
    margin: int

    @property
    def names(self) -> list[str]:
        """Names of the effects found, best first."""
        return [e["name"] for e in self.effects]


# --------------------------------------------------------------------------------------------- API
def _as_frames(frames: object) -> Tensor:
    video, batched = as_video(frames, name="frames")
    if batched:
        raise ValueError(
            f"frames must have shape (T, H, W), got {tuple(video.shape)}; diagnose one video per call"
        )
    video = video[0].detach().to(_F64)
    bad = int((~torch.isfinite(video)).sum())
    if bad:
        raise ValueError(f"frames must be finite, got {bad} non-finite values; crop or fill them first")
    return video


def _background(frame: Tensor, ring: int = 2) -> float:
    """Median temperature of the frame's outer ring of pixels: the scene's background."""
    edge = torch.cat(
        [
            frame[:ring].flatten(),
            frame[-ring:].flatten(),
            frame[:, :ring].flatten(),
            frame[:, -ring:].flatten(),
        ]
    )
    return float(edge.median())


class _Selection:
    """Stepwise selection state: the effects in the model and the fitted extra terms."""

    def __init__(self, system: _System, alpha: float, names: Sequence[str], background: float) -> None:
        self.system, self.alpha, self.names, self.background = system, alpha, list(names), background
        self.selected: list[str] = []
        self.shapes: dict[str, dict[str, float]] = {}
        self.thetas: dict[str, Tensor] = {}
        self.scores: dict[str, float] = {}
        self.thresholds: dict[str, float] = {}

    def columns(self, effects: Sequence[str]) -> list[str]:
        return ["L"] + [r for e in effects for r in EFFECT_GROUPS[e].regressors]

    def context(self) -> _Context:
        return _Context(mean=self.system.mean, background=self.background, shape=self.shapes)

    def threshold(self, name: str, tested: int) -> float:
        return -math.log10(self.alpha / tested) + LOOK_ELSEWHERE.get(name, 0.0)

    def allowed(self, name: str, effects: Sequence[str]) -> bool:
        group = EFFECT_GROUPS[name]
        return name not in effects and not (
            group.replaces_diffusion and any(EFFECT_GROUPS[e].replaces_diffusion for e in effects)
        )

    def prepare(self, name: str, current: _Fit, *, refine: bool = False) -> None:
        """Fit a localised effect's shape to what the current model leaves unexplained."""
        group = EFFECT_GROUPS[name]
        if group.shape is None:
            return
        fitted = group.shape(self.system, current, self.thetas.get(name) if refine else None)
        self.system.add(group.regressors[0], fitted.term, fitted.noise)
        self.shapes[name] = fitted.params
        self.thetas[name] = fitted.theta

    def forward(self) -> None:
        while True:
            candidates = [n for n in self.names if self.allowed(n, self.selected)]
            if not candidates:
                return
            current = self.system.fit(self.columns(self.selected))
            current_excess = current.rss - self.system.expected_rss(current)
            eligible = {}
            for name in candidates:
                self.prepare(name, current, refine=name in self.thetas)
                fit = self.system.fit(self.columns([*self.selected, name]))
                self.scores[name] = fit.score(EFFECT_GROUPS[name].regressors)
                self.thresholds[name] = self.threshold(name, len(candidates))
                params = EFFECT_GROUPS[name].params(fit.coefficients(), self.context())
                if self.scores[name] > self.thresholds[name] and EFFECT_GROUPS[name].valid(params):
                    explained = current_excess - (fit.rss - self.system.expected_rss(fit))
                    eligible[name] = explained * _search_discount(name, self.scores[name])
            if not eligible:
                return
            # Among the significant effects the one that explains most enters: Wald statistics of
            # different (non-nested) models measure significance, not which model fits better. "Most"
            # is the drop of the residual above its expected noise part (the errors-in-variables fit does
            # not minimise the raw residual, and each model's noise part differs), less the share a
            # fitted shape owes to its search (_search_discount).
            self.selected.append(max(eligible, key=eligible.__getitem__))

    def backward(self) -> _Fit:
        """Drop effects that are no longer significant given the others; return the final fit."""
        while True:
            final = self.system.fit(self.columns(self.selected))
            if not self.selected:
                return final
            tested = len(self.names)
            excess = {}
            for name in self.selected:
                self.scores[name] = final.score(EFFECT_GROUPS[name].regressors)
                self.thresholds[name] = self.threshold(name, tested)
                excess[name] = self.scores[name] - self.thresholds[name]
            worst = min(excess, key=excess.__getitem__)
            if excess[worst] > 0:
                return final
            self.selected.remove(worst)


def diagnose_terms(
    frames: Tensor,
    dt: float,
    dx: float,
    *,
    alpha: float = ALPHA,
    smoothing: float | Sequence[float] | None = None,
    noise_sd: float | None = None,
    effects: Sequence[str] | None = None,
) -> Diagnosis:
    """Identify the hidden effects of a thermal video by balancing candidate PDE terms on its frames.

    Args:
        frames: temperatures of one video, ``(T, H, W)`` (computed in float64).
        dt: frame period in s.
        dx: pixel size in mm.
        alpha: family-wise false-positive rate on pure heat-transfer video.
        smoothing: Gaussian sigma (px) or candidates; default :data:`SMOOTHING`, taking the one with
            the smallest standard error of ``a``.
        noise_sd: known white-noise sd (data units); default estimated from the video.
        effects: names in :data:`EFFECT_GROUPS` to look for; default all.

    Returns:
        :class:`Diagnosis`.

    Raises:
        ValueError: bad shape or spacing, non-finite frames, too few frames or pixels, unknown effects,
            or no thermal activity above the noise.

    Shape:
        ``frames`` ``(T, H, W)`` with ``T >= 5`` and ``H, W >= 2 r + 18`` for the smallest smoothing
        radius ``r`` (px).

    Example:
        >>> from anra_torch.effects import hidden_effect_video
        >>> video = hidden_effect_video(["advection"], seed=1, size=48, duration=1.0)
        >>> d = diagnose_terms(video.frames, video.dt, video.dx)
        >>> d.names, {k: round(v, 2) for k, v in d.effects[0]["params"].items()}
        (['advection'], {'vx': 1.26, 'vy': -2.37})
    """
    video = _as_frames(frames)
    dt, dx = positive(dt, "dt", "s"), positive(dx, "dx", "mm")
    if not (0 < alpha < 1):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    names = list(EFFECT_GROUPS) if effects is None else list(effects)
    for name in names:
        if name not in EFFECT_GROUPS:
            raise ValueError(f"unknown effect {name!r}; expected one of: {', '.join(EFFECT_GROUPS)}")
    length = TimeDerivative("smooth").length
    if video.shape[0] < length:
        raise ValueError(
            f"frames need at least {length} frames for the time derivative, got {video.shape[0]}"
        )
    if isinstance(smoothing, int | float):
        sigmas: tuple[float, ...] = (float(smoothing),)
    else:
        sigmas = SMOOTHING if smoothing is None else tuple(float(s) for s in smoothing)
    side = min(video.shape[1:])
    usable = [s for s in sigmas if side - 2 * (GaussianSmoothing(s).radius + 1) >= _MIN_VALID_PX]
    if not usable:
        need = min(2 * (GaussianSmoothing(s).radius + 1) for s in sigmas) + _MIN_VALID_PX
        raise ValueError(
            f"frames must be at least {need} x {need} px for this smoothing, "
            f"got {video.shape[1]} x {video.shape[2]}"
        )
    if float(video.amax() - video.amin()) == 0.0:
        raise ValueError("frames are constant: no thermal activity to diagnose")
    sd = float(estimate_noise_sd(video)) if noise_sd is None else positive(noise_sd, "noise_sd", "data units")

    # Smoothing: the candidate with the smallest standard error of a in the plain model.
    best: tuple[float, _System, _Fit] | None = None
    for sigma in usable:
        system = _System(video, dt, dx, sigma, sd)
        plain = system.fit(["L"])
        se = float(plain.cov[0, 0].clamp_min(0).sqrt())
        if best is None or se < best[0]:
            best = (se, system, plain)
    _, system, plain = best

    selection = _Selection(system, alpha, names, _background(video[0]))
    selection.forward()
    final = selection.backward()
    # Localised shapes are refitted to the final model (without themselves).
    for name in list(selection.shapes):
        if name in selection.selected:
            others = [e for e in selection.selected if e != name]
            selection.prepare(name, system.fit(selection.columns(others)), refine=True)
    final = system.fit(selection.columns(selection.selected))

    coefficients = final.coefficients()
    context = selection.context()
    found = []
    for name in selection.selected:
        score = final.score(EFFECT_GROUPS[name].regressors)
        found.append(
            {"name": name, "params": EFFECT_GROUPS[name].params(coefficients, context), "score": score}
        )
    found.sort(key=lambda e: -e["score"])
    a_plain = float(plain.beta[0])
    a_se = float(plain.cov[0, 0].clamp_min(0).sqrt())
    if not found and abs(a_plain) < _MIN_SIGNIFICANCE * a_se:
        raise ValueError(
            f"frames show no thermal activity above the noise (a = {a_plain:.3g} +- {a_se:.2g} mm^2/s, "
            "no effect found); nothing to diagnose"
        )
    return Diagnosis(
        base=coefficients["L"],
        base_std_error=final.std_errors()["L"],
        effects=found,
        a_plain=a_plain,
        scores=dict(selection.scores),
        thresholds=dict(selection.thresholds),
        coefficients=coefficients,
        std_errors=final.std_errors(),
        noise_sd=sd,
        smoothing=system.sigma,
        mean=system.mean,
        fit_ratio=final.rss / system.expected_rss(final),
        residual_map=system.residual(final).mean(0),
        margin=system.module.margin,
    )
