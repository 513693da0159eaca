"""The balance of one video: its term bank, moments and least-squares fits, plus fitted extra terms.

:class:`BalanceSystem` is what model selection works on (:mod:`anra_torch.selection`) and what an effect's
shape fit (a source's path, a disc of other diffusivity: :mod:`anra_torch.effects`) is fitted against. It
holds the video's terms through one set of :class:`~anra_torch.balance.MatchedFilters` (the
5-point operators of a finite-difference heat model after a Gaussian, so simulated effects are fitted
exactly), their :class:`~anra_torch.balance.Moments` with the errors-in-variables noise parts, and
fits by least squares with the sandwich covariance of the coefficients (exact for white noise).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import torch
from torch import Tensor

from anra_torch.balance.filters import TERMS, MatchedFilters
from anra_torch.balance.moments import TermNoise, accumulate, extend, pushback, sandwich, within
from anra_torch.balance.noise_model import NoiseModel

__all__ = ["REGRESSORS", "BalanceSystem", "Fit", "NoiseSpec"]

_F64 = torch.float64
_TRIAL = "_trial"  # a trial shape's term while its shape is fitted

REGRESSORS: tuple[str, ...] = ("L", "T", "1", "T_x", "T_y", "D", "T_xy", "N")
"""The bank's right-side terms of a :class:`BalanceSystem` (``L`` is always in a model)."""


@dataclass(frozen=True)
class NoiseSpec:
    """Noise of an extra term: ``weight`` times the sensor noise through ``kernel``'s filters (linearised).

    Attributes:
        kernel: the bank term whose impulse response carries this noise (None: the term is noiseless).
        weight: a map broadcastable to the terms (None: 1).
    """

    kernel: str | None
    weight: Tensor | None = None


@dataclass(frozen=True)
class Fit:
    """A least-squares fit of ``U`` on ``columns``.

    Attributes:
        columns: the regressors' names.
        beta: their coefficients, ``(k,)``.
        cov: the coefficients' covariance (sandwich form), ``(k, k)``.
        rss: residual sum of squares.
    """

    columns: tuple[str, ...]
    beta: Tensor
    cov: Tensor
    rss: float

    def coefficients(self) -> dict[str, float]:
        """Coefficients by regressor name."""
        return {c: float(b) for c, b in zip(self.columns, self.beta, strict=True)}

    def std_errors(self) -> dict[str, float]:
        """Standard errors by regressor name."""
        variances = self.cov.diagonal().clamp_min(0)
        return {c: float(v.sqrt()) for c, v in zip(self.columns, variances, strict=True)}


class BalanceSystem:
    """The terms of one video at one smoothing, their noise model and least-squares fits.

    The term bank, its moments (with their errors-in-variables noise parts) and the sandwich covariance
    all come from :mod:`anra_torch.balance`; this class keeps the fitted shapes' extra terms beside them.

    Args:
        frames: one video, ``(T, H, W)`` float64.
        dt: frame period in s.
        dx: pixel size in mm.
        sigma: Gaussian sigma in px.
        noise_sd: white sensor-noise sd in data units.
        time_family: Holoborodko time family of the derivative (window of 5 frames).

    Shape:
        Every term ``(T - 4, H - 2 margin, W - 2 margin)``.
    """

    def __init__(
        self,
        frames: Tensor,
        dt: float,
        dx: float,
        sigma: float,
        noise_sd: float,
        *,
        time_family: str = "smooth",
        noise: NoiseModel | None = None,
        within: Sequence[str] = (),
    ) -> None:
        self.filters = MatchedFilters(
            sigma, time_family=time_family, time_length=5, laplacian_size=3, laplacian_family="holoborodko"
        )  # the 5-point stencil (its partner: a 1-px crop) and the operators of a finite-difference model
        self.dt, self.dx, self.sigma, self.noise_sd = dt, dx, sigma, noise_sd
        self.within = tuple(within)
        self.measured_noise = NoiseModel(noise_sd) if noise is None else noise
        # Per-pixel fixed effects take a static pattern out exactly: the balance sees the rest.
        pixel = "pixel" in self.within
        self.noise = self.measured_noise.without_static() if pixel else self.measured_noise
        self.mean = float(frames.mean())
        self.frames = frames.detach().clone().requires_grad_(True)
        self.shape = tuple(frames.shape)
        centred = self.frames - self.mean
        stage = self.filters.time_stage(centred, dt)
        self.average = stage[1]  # S_t (T - Tbar) before smoothing, for H
        names = ("U", *REGRESSORS)
        raw = self.filters.terms(centred, dt, dx, names, time_stage=stage)
        self.weights: dict[str, Tensor] = {n: raw[TERMS[n].noise_weight].detach() for n in names
                                           if TERMS[n].noise_weight}  # fmt: skip
        self.terms: dict[str, Tensor] = {k: self.fixed_effects(v) for k, v in raw.items()}
        self.detached = {k: v.detach() for k, v in self.terms.items()}
        kernels = sorted({TERMS[n].noise_kernel for n in names} - {None})
        k, h, w = raw["U"].shape
        unit = self.filters.noise_covariance(
            kernels, 1.0, dt, dx, noise=self.noise, within=self.within, extent=(k, h * w)
        ).to(self.frames.device)
        self._unit = {(a, b): unit[i, j] for i, a in enumerate(kernels) for j, b in enumerate(kernels)}
        self.kernels: dict[str, str | None] = {n: TERMS[n].noise_kernel for n in names}
        self.n = self.terms["U"].numel()
        self._base = accumulate(self.detached, names, noise=self.term_noise(names))
        self.moments = self._base
        # Fitted shape parameters by effect, as the selection last fitted them: an effect that refines
        # another (EffectSpec.requires) builds on its entry.
        self.shapes: dict[str, dict[str, float]] = {}
        # Candidate shapes by effect from outside the balance (a flash defect map's defects for a
        # delamination, mm): the effect's shape fit starts from them, its fit must lie in one, and an empty
        # tuple rules the effect out (the map looked and found none).
        self.hints: dict[str, tuple[dict[str, float], ...]] = {}

    @cached_property
    def smoothed(self) -> Tensor:
        """The centred frames smoothed and cropped like ``U``, before time averaging: ``(T, h, w)``
        (a term that weights whole frames, e.g. by a rate in time, is this weighted then time-averaged)."""
        return self.finish(self.frames.detach() - self.mean)

    @property
    def u(self) -> Tensor:
        return self.terms["U"]

    @property
    def margin(self) -> int:
        """Pixels lost on each side."""
        return self.filters.margin

    def fixed_effects(self, term: Tensor) -> Tensor:
        """``term`` with the fixed effects of :attr:`within` removed (unchanged without them; see
        :func:`anra_torch.balance.moments.within`).

        Shape:
            ``(K, h, w)`` -> the same.
        """
        return within(term, pixel="pixel" in self.within, frame="frame" in self.within)

    def finish(self, field: Tensor) -> Tensor:
        """Smooth and crop a full-frame, time-averaged term like ``U``: ``(K, H, W) -> (K, h, w)``."""
        return self.filters.laplacian.partner(self.filters.smoother(field))

    def term_noise(self, names: Sequence[str], extra: NoiseSpec | None = None) -> TermNoise:
        """The noise of ``names`` (and of one more, trial term ``extra`` last) per output point."""
        kernels = [self.kernels[n] for n in names] + ([] if extra is None else [extra.kernel])
        zero = torch.zeros((), dtype=_F64, device=self.frames.device)
        covariance = torch.stack(
            [
                torch.stack([self._unit.get((a, b), zero) if a and b else zero for b in kernels])
                for a in kernels
            ]
        )
        weights = dict(self.weights)
        if extra is not None and extra.weight is not None:
            weights[_TRIAL] = extra.weight
        return TermNoise(self.noise.variance * covariance, weights)

    def add(self, name: str, term: Tensor, noise: NoiseSpec | None) -> None:
        """Register (or replace) an extra term (source, heterogeneity) on the output grid."""
        self.add_terms({name: (term, noise)})

    def add_terms(self, terms: Mapping[str, tuple[Tensor, NoiseSpec | None]]) -> None:
        """Register (or replace) several extra terms at once: their moments are computed in one pass."""
        for name, (term, noise) in terms.items():
            term = self.fixed_effects(term)
            self.terms[name] = term
            self.detached[name] = term.detach()
            self.kernels[name] = None if noise is None else noise.kernel
            self.weights.pop(name, None)
            if noise is not None and noise.weight is not None:
                self.weights[name] = noise.weight
        extras = [n for n in self.detached if n not in self._base.names]
        names = (*self._base.names, *extras)
        self.moments = extend(self._base, self.detached, extras, noise=self.term_noise(names))

    def normal_equations(self, columns: Sequence[str]) -> tuple[Tensor, Tensor]:
        """``(X^T X, X^T U)`` minus their expected noise parts (errors-in-variables)."""
        return self.moments.normal_equations(columns)

    def fit(self, columns: Sequence[str]) -> Fit:
        """Least squares of U on ``columns`` and the white-noise covariance of the coefficients.

        The residual map ``frames -> U - sum beta_j X_j`` (linearised) is pushed back through the
        transposed filters with each regressor as the lever (the sandwich form, exact for white noise).
        """
        columns = tuple(columns)
        gram, cross = self.normal_equations(columns)
        # Equilibrated: a column far smaller than L (a term that nearly vanishes) must not be cut by the
        # pseudo-inverse's relative cutoff, which would give it a zero coefficient with a zero variance.
        scale = gram.diagonal().abs().clamp_min(1e-300).rsqrt()
        inverse = scale[:, None] * torch.linalg.pinv(scale[:, None] * gram * scale, hermitian=True) * scale
        beta = inverse @ cross
        residual = self.u - sum(float(beta[i]) * self.terms[c] for i, c in enumerate(columns))
        backs = pushback(
            residual, self.frames, [self.detached[c] for c in columns], reach=self._reach(columns)
        )
        cov = sandwich(inverse, backs, self.noise) + self.correction_covariance(columns, inverse, beta)
        rss = float(residual.detach().pow(2).sum())
        return Fit(columns, beta, cov, rss)

    def _reach(self, columns: Sequence[str]) -> int | None:
        """The frames one output frame of the residual is made from (the time filter's length), where the
        map from the frames to the residual is local in time: None with per-pixel fixed effects (a mean over
        every frame) or a column whose term is built from the frames by something else than the filters."""
        if "pixel" in self.within or any(self.terms[c].requires_grad for c in columns if c not in REGRESSORS):
            return None
        return self.shape[0] - self.u.shape[0] + 1

    def correction_covariance(self, columns: Sequence[str], inverse: Tensor, beta: Tensor) -> Tensor:
        """The coefficients' covariance from the error of the errors-in-variables correction, ``(k, k)``.

        A measured noise model's variance is known to a relative error ``e``
        (:attr:`~anra_torch.balance.NoiseModel.variance_error`; 0 for white noise), shared by every
        noise part: the correction ``N`` of the normal equations is off by ``e N``, which moves the
        coefficients by ``e G^-1 (N_XX beta - N_XU)`` (rank one). Where noise dominates a regressor's energy
        (little smoothing, strongly correlated noise) this is the larger error, and the smoothing and the
        tests must see it. A regressor whose corrected energy is not at least twice the correction's error
        is unresolved at this smoothing (its variance is infinite): the first-order shift would be
        meaningless there, the corrected energy being as likely near zero as where it came out.
        """
        error = float(self.noise.variance_error)
        if error == 0.0:
            return torch.zeros_like(inverse)
        noise = self.moments.noise
        rows = self.moments.index(columns)
        shift = noise[rows][:, rows] @ beta.detach() - noise[rows][:, self.moments.index(["U"])[0]]
        lever = error * (inverse @ shift)
        out = lever[:, None] * lever[None, :]
        energy, noise_energy = self.moments.corrected.diagonal()[rows], noise.diagonal()[rows]
        unresolved = energy <= 2 * error * noise_energy.abs()
        return out + torch.diag(torch.where(unresolved, torch.inf, 0.0).to(out.dtype))

    def expected_rss(self, fit: Fit) -> float:
        """Expected residual sum of squares of ``fit`` if the data were its model plus white noise."""
        names = ("U", *fit.columns)
        weights = torch.cat([fit.beta.new_ones(1, dtype=_F64), -fit.beta.to(_F64)])
        return float(weights @ self.moments.subset(names).noise @ weights)

    def residual(self, fit: Fit) -> Tensor:
        """``U - X beta`` of a fit, detached, ``(K, h, w)``."""
        return (
            self.u - sum(float(b) * self.terms[c] for b, c in zip(fit.beta, fit.columns, strict=True))
        ).detach()

    def profile_loss(self, columns: Sequence[str], extra: Tensor, noise: NoiseSpec | None = None) -> Tensor:
        """Residual sum of squares above the noise of U on ``columns`` plus ``extra`` (differentiable in
        ``extra`` and in ``noise``'s weight, the extra term's noise model).

        The errors-in-variables fit of :meth:`fit`: the products lose their expected noise parts and the
        loss is ``rss - expected_rss`` at the corrected coefficients. Plain least squares would prefer
        shapes that keep a noisy regressor where its signal is strong (there it is biased least towards
        zero), not the shape that explains ``U``. Written by blocks: the base columns' excess minus
        ``r^2 / q``, with ``r`` the extra term's corrected covariance with the base residual and ``q`` its
        corrected energy beyond the base columns. ``q`` is kept at least a tenth of its raw value: a shape
        whose own noise is over 90 % of that energy sits where there is no signal, and a vanishing ``q``
        would otherwise make the loss arbitrarily negative; an example: ``docs/results/hidden-effects.md``.
        """
        names = ("U", *columns)
        p = len(columns)
        trial = extend(
            self.moments.subset(names),
            {**self.detached, _TRIAL: self.fixed_effects(extra)},
            [_TRIAL],
            noise=self.term_noise(names, noise if noise is not None else NoiseSpec(None)),
        )
        raw, cor = trial.raw, trial.corrected
        base, x = slice(1, p + 1), p + 1
        raw_base, gram_base, cross_base = raw[base, base], cor[base, base], cor[base, 0]
        # A tiny ridge keeps the solves defined when a trial shape leaves the frame or copies a column.
        ridge = 1e-10 * raw_base.diagonal().abs().max() * torch.eye(p, dtype=_F64, device=raw.device)
        beta_base = torch.linalg.solve(gram_base + ridge, cross_base)
        raw_extra, cross_extra = raw[base, x], cor[base, x]
        q_raw = raw[x, x] - raw_extra @ torch.linalg.solve(raw_base + ridge, raw_extra)
        q = cor[x, x] - cross_extra @ torch.linalg.solve(gram_base + ridge, cross_extra)
        r = cor[0, x] - cross_extra @ beta_base
        base_excess = cor[0, 0] - cross_base @ beta_base
        return base_excess - r * r / torch.maximum(q, 0.1 * q_raw).clamp_min(1e-300)
