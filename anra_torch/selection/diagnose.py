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
``depth_conduction``     ``Z = r(t) (T - T_ref)``: fitted      ``- strength Z``
                         heating time and plate depth time
``delamination``         ``Y = disc (r_plate - r_layer)``      ``+ strength Y``
                         ``(T - T_ref)``, after depth
``delamination_2``       ``Y2``: ``Y`` over another region     ``+ strength Y2``
                         of a defect map, after ``Y``
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
look-elsewhere penalty (``EffectSpec.look_elsewhere``) for their fitted shape, measured on pure heat videos.
Among the significant candidates, the one that lowers the residual above its expected noise part most enters,
a fitted shape's drop discounted by the share of its statistic that its look-elsewhere penalty stands for
(Wald statistics of non-nested models measure significance, not fit: a disc of higher diffusivity around a
hot spot is as "significant" as ``a`` growing with ``T``, but only the true model fits down to the noise).
The shapes of ``S`` and ``H`` are fitted by the same errors-in-variables least squares: plain least squares
prefers a disc that keeps the noisy ``L`` where its signal is strong (there it is biased least towards
zero) over the disc that explains ``U``, which named a slow disc under a hot spot as loss + advection +
source.

A significant effect is named only if it is material: its term makes at least :data:`MIN_SHARE` of ``dT/dt``
(the RMS of its coefficients times its regressors over the RMS of ``U``, noise parts removed: what it does to
the frames, whatever its parameters), and it reaches its physical size where it states one
(``EffectSpec.min_size``). At a low noise the balance also sees a camera's departures from the model's
operators; they make well under 1 % of ``dT/dt``. An effect under the share is not named but stays in the fit
as a nuisance term: a real small effect left out biases the named ones that share its signal (an intact flash
plate's loss, 0.94 % of ``dT/dt``: without it the anisotropy's ``a_y`` read 1.83 mm^2/s for a true 1.1). One
below its physical size leaves the model, as before. Whether an effect earns its place by its own forecast
is asked one layer up (:func:`anra_torch.forecast.earned_diagnosis`), on models :func:`fit_effects` fits.

Measured by ``python -m experiments.diagnosis_benchmark`` (README): the top effect, parameter errors and
false positives over 20 random cases per effect and 20 pure videos.

Limits: white noise is assumed (the standard errors and thresholds come from it); the noise parts of
``N`` and ``H`` in the Gram matrix are first-order approximations; a heterogeneity is a disc with a
one-pixel edge, a source a Gaussian moving on a straight line.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import torch
from torch import Tensor

from anra_torch.balance import Artefacts, BalanceSystem, Fit, NoiseModel, find_artefacts, measure_noise
from anra_torch.checks import as_video, mostly_finite, positive
from anra_torch.effects import EFFECTS, Shape
from anra_torch.layers import GaussianSmoothing, TimeDerivative
from anra_torch.selection.stepwise import Selection, checked_hints, tried

__all__ = ["ALPHA", "SMOOTHING", "Diagnosis", "diagnose_terms", "fit_effects", "minimum_frame_size"]

ALPHA = 1e-3
"""Family-wise false-positive rate of the model selection on pure heat-transfer video."""

SMOOTHING: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0)
"""Spatial smoothing candidates (px); the one giving the smallest standard error of ``a`` is used."""

_MIN_VALID_PX = 16  # a smoothing candidate must leave at least this many pixels per side
_MIN_SIGNIFICANCE = 3.0  # |a| / std_error below this (and no effect): no thermal activity
_F64 = torch.float64


# ------------------------------------------------------------------------------------------ result
@dataclass(frozen=True)
class Diagnosis:
    """Output of :func:`diagnose_terms`.

    Attributes:
        base: diffusivity ``a`` (mm^2/s) of the selected model: the coefficient of ``Lap T`` (for
            anisotropy the mean ``(a_x + a_y) / 2``, for nonlinear diffusion ``a`` at the mean
            temperature, for heterogeneity ``a_outside``).
        base_std_error: its standard error (mm^2/s).
        effects: the effects found, ``{"name", "params", "score", "share"}`` ranked by score (``score`` is
            ``-log10`` of the effect's p-value given the rest of the model, ``share`` its share of ``dT/dt``:
            :meth:`~anra_torch.selection.stepwise.Selection.share`); empty for pure heat transfer.
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
        noise: the noise model measured from the video (level, correlation in time and space) that the
            standard errors, the errors-in-variables corrections and the tests come from.
        artefacts: the camera artefacts found and what was done (:mod:`anra_torch.balance.artefacts`).
        negligible: effects that were significant but not material, not named: ``{"name", "params",
            "share", "min_share", "rule"}`` each, ``rule`` ``"share"`` (under
            :data:`~anra_torch.selection.MIN_SHARE` of ``dT/dt``: a nuisance term, still in the fit,
            :attr:`nuisance`) or ``"size"`` (under its physical size, out of the fit,
            :attr:`~anra_torch.effects.EffectSpec.min_size`: then also ``"size"``, ``"min_size"``; both are
            there for every effect that states a size).
        hints: the candidate shapes it was given (:func:`diagnose_terms`), for later :func:`fit_effects`.
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
    noise: NoiseModel | None = None
    artefacts: Artefacts | None = None
    negligible: list[dict] = field(default_factory=list)
    hints: dict[str, tuple[dict[str, float], ...]] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        """Names of the effects found, best first."""
        return [e["name"] for e in self.effects]

    @property
    def nuisance(self) -> list[str]:
        """The effects fitted beside the named ones but too small to name (``negligible``, rule
        ``"share"``): their terms are in the fit and in :attr:`coefficients`, not in :attr:`effects`."""
        return [e["name"] for e in self.negligible if e.get("rule") == "share"]


# --------------------------------------------------------------------------------------------- API
def _as_frames(frames: object) -> Tensor:
    video, batched = as_video(frames, name="frames")
    if batched:
        raise ValueError(
            f"frames must have shape (T, H, W), got {tuple(video.shape)}; diagnose one video per call"
        )
    return mostly_finite(video[0].detach().to(_F64))


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


def diagnose_terms(
    frames: Tensor,
    dt: float,
    dx: float,
    *,
    alpha: float = ALPHA,
    smoothing: float | Sequence[float] | None = None,
    noise_sd: float | NoiseModel | None = None,
    effects: Sequence[str] | None = None,
    time_family: str = "smooth",
    hints: Mapping[str, Sequence[Mapping[str, float]]] | None = None,
) -> Diagnosis:
    """Identify the hidden effects of a thermal video by balancing candidate PDE terms on its frames.

    Args:
        frames: temperatures of one video, ``(T, H, W)`` (computed in float64).
        dt: frame period in s.
        dx: pixel size in mm.
        alpha: family-wise false-positive rate on pure heat-transfer video.
        smoothing: Gaussian sigma (px) or candidates; default :data:`SMOOTHING`, taking the one with
            the smallest standard error of ``a``.
        noise_sd: the noise when it is known: a white-noise sd (data units), or a whole
            :class:`~anra_torch.balance.NoiseModel` (e.g. the one a camera's noise was planted with);
            default measured from the video (:func:`~anra_torch.balance.measure_noise`).
        effects: names in :data:`anra_torch.effects.EFFECTS` to look for; default those searched by
            default (every effect but ``periodic_source``); those the ``hints`` let it try (``tried``).
        time_family: Holoborodko time family of ``dT/dt`` (:data:`anra_torch.layers.stencils.TIME_FAMILIES`).
        hints: candidate shapes ``{"x", "y", "radius"}`` (mm) by effect: :meth:`Selection.in_hint`.

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
    video, dt, dx = _as_frames(frames), positive(dt, "dt", "s"), positive(dx, "dx", "mm")
    if not (0 < alpha < 1):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    names = _known([n for n, spec in EFFECTS.items() if spec.searched] if effects is None else effects)
    video, artefacts, system, plain = _balance(video, dt, dx, smoothing, noise_sd, time_family, hints)
    selection = Selection(system, alpha, tried(names, system.hints), _background(video[0]))
    selection.forward()
    selection.backward()
    # Localised shapes are refitted to the final model (without themselves).
    for name in [n for n in selection.shapes if n in selection.selected]:
        selection.refit(name)
    selection.drop_unphysical()
    return _result(system, selection, plain, artefacts)


def fit_effects(
    frames: Tensor,
    dt: float,
    dx: float,
    models: Sequence[Sequence[str]],
    *,
    smoothing: float,
    noise_sd: float | NoiseModel | None = None,
    time_family: str = "smooth",
    nuisance: Sequence[str] = (),
    physical: bool = False,
    hints: Mapping[str, Sequence[Mapping[str, float]]] | None = None,
) -> list[Diagnosis]:
    """Fit given models on a video as they are: no test, no size rule, nothing added (dropped: ``physical``).

    What :func:`diagnose_terms` does to the model it selected, for models chosen elsewhere (each effect
    the model holds, in order: one that requires another comes after it): one balance at ``smoothing``
    for every model, a localised effect's shape fitted to what the model's other effects leave.

    Args:
        frames: temperatures of one video, ``(T, H, W)`` (computed in float64).
        dt: frame period in s.
        dx: pixel size in mm.
        models: each a sequence of names in :data:`anra_torch.effects.EFFECTS` (empty: the plain model).
        smoothing: the Gaussian sigma (px) of the balance.
        noise_sd: as :func:`diagnose_terms` (e.g. the noise model a diagnosis of the whole video measured).
        time_family: as :func:`diagnose_terms`.
        nuisance: effects fitted beside every model but not named (a diagnosis'
            :attr:`Diagnosis.nuisance`; listed in ``negligible``, rule ``"share"``); one whose required
            effect a model lacks is left out of that model.
        physical: drop the effects fitted unphysical (:meth:`Selection.drop_unphysical_given`).
        hints: as :func:`diagnose_terms` (e.g. the diagnosis' :attr:`Diagnosis.hints`).

    Returns:
        One :class:`Diagnosis` per model, its ``effects`` in the model's order.

    Raises:
        ValueError: as :func:`diagnose_terms`, and an unknown or repeated effect in a model.

    Shape:
        ``frames`` ``(T, H, W)`` as :func:`diagnose_terms`.
    """
    video, dt, dx = _as_frames(frames), positive(dt, "dt", "s"), positive(dx, "dx", "mm")
    for model in [*models, nuisance]:
        if len(set(_known(model))) != len(model):
            raise ValueError(f"a model names each effect once, got {list(model)}")
    video, artefacts, system, plain = _balance(video, dt, dx, float(smoothing), noise_sd, time_family, hints)
    out, shared = [], dict[tuple, Shape]()  # the shapes fitted alike in several models, fitted once
    for model in models:
        selection = Selection(system, ALPHA, _with_nuisance(model, nuisance), _background(video[0]), shared)
        selection.take(selection.names)
        if physical:
            selection.drop_unphysical_given()
        out.append(_result(system, selection, plain, artefacts, given=model))
    return out


def _known(names: Sequence[str]) -> list[str]:
    """``names`` as a list, each checked to be in :data:`~anra_torch.effects.EFFECTS`."""
    for name in names:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; expected one of: {', '.join(EFFECTS)}")
    return list(names)


def _with_nuisance(model: Sequence[str], nuisance: Sequence[str]) -> list[str]:
    """``model`` and the nuisance terms whose required effects it holds, a required effect's first."""
    extra = [n for n in nuisance if n not in model]
    fitted = [*model, *(n for n in extra if all(r in model or r in extra for r in EFFECTS[n].requires))]
    return sorted(fitted, key=lambda n: bool(EFFECTS[n].requires))  # stable: the model's order otherwise


def minimum_frame_size(smoothing: float | Sequence[float] | None = None) -> int:
    """The smallest frame side (px) :func:`diagnose_terms` accepts with ``smoothing`` (default its
    candidates): the smallest candidate's filter reach on both sides plus the least valid interior."""
    sigmas = (
        SMOOTHING if smoothing is None else (smoothing,) if isinstance(smoothing, int | float) else smoothing
    )
    return min(2 * (GaussianSmoothing(float(s)).radius + 1) for s in sigmas) + _MIN_VALID_PX


def _usable_smoothing(video: Tensor, smoothing: float | Sequence[float] | None) -> tuple[float, ...]:
    """The smoothing candidates (px) that leave enough pixels and frames for the filters.

    Raises:
        ValueError: too few frames for the time derivative, or frames too small for every candidate.
    """
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
    usable = tuple(s for s in sigmas if side >= minimum_frame_size(s))
    if not usable:
        need = minimum_frame_size(sigmas)
        raise ValueError(
            f"frames must be at least {need} x {need} px for this smoothing, "
            f"got {video.shape[1]} x {video.shape[2]}"
        )
    return usable


def _balance(
    video: Tensor,
    dt: float,
    dx: float,
    smoothing: float | Sequence[float] | None,
    noise_sd: float | NoiseModel | None,
    time_family: str,
    hints: Mapping[str, Sequence[Mapping[str, float]]] | None = None,
) -> tuple[Tensor, Artefacts, BalanceSystem, Fit]:
    """The repaired video, its artefacts, and the balance at the least noisy usable smoothing with its plain
    fit (:func:`diagnose_terms`' set-up: the noise measured unless given)."""
    sigmas = _usable_smoothing(video, smoothing)
    video, artefacts = find_artefacts(video)
    if float(video.amax() - video.amin()) == 0.0:
        raise ValueError("frames are constant: no thermal activity to diagnose")
    if noise_sd is None:
        noise = measure_noise(video, static_pattern=artefacts.fixed_pattern)
    elif isinstance(noise_sd, NoiseModel):
        noise = noise_sd
    else:
        noise = NoiseModel(positive(noise_sd, "noise_sd", "data units"))
    options = {"time_family": time_family, "noise": noise, "within": artefacts.within}
    system, plain = _least_noisy(video, dt, dx, sigmas, float(noise.sd), options)
    system.hints = checked_hints(hints)
    return video, artefacts, system, plain


def _least_noisy(
    video: Tensor, dt: float, dx: float, sigmas: Sequence[float], sd: float, options: dict
) -> tuple[BalanceSystem, Fit]:
    """The balance at the smoothing whose plain-model ``a`` has the smallest standard error, and that fit."""
    best: tuple[float, BalanceSystem, Fit] | None = None
    for sigma in sigmas:
        system = BalanceSystem(video, dt, dx, sigma, sd, **options)
        plain = system.fit(["L"])
        se = float(plain.cov[0, 0].clamp_min(0).sqrt())
        if best is None or se < best[0]:
            best = (se, system, plain)
    assert best is not None
    return best[1], best[2]


def _result(
    system: BalanceSystem,
    selection: Selection,
    plain: Fit,
    artefacts: Artefacts,
    *,
    given: Sequence[str] | None = None,
) -> Diagnosis:
    """The :class:`Diagnosis` of the selected model (refitted), named effects ranked by score, the selected
    effects under :data:`MIN_SHARE` of ``dT/dt`` kept in the fit as nuisance terms (listed in
    ``negligible``, rule ``"share"``). ``given``: the effects of a model fitted as given (named in its
    order, whatever their share; the other selected effects are its nuisance terms), and no thermal
    activity is no error.

    Raises:
        ValueError: no effect and a plain ``a`` within 3 standard errors of 0 (no thermal activity).
    """
    final = selection.fit(selection.selected)
    coefficients = final.coefficients()
    found, nuisance = selection.named(final, given)
    expected = system.expected_rss(final)  # 0 for noiseless (e.g. quantised, noise-free) frames
    fit_ratio = final.rss / expected if expected > 0 else (math.inf if final.rss > 0 else 1.0)
    a_plain = float(plain.beta[0])
    a_se = float(plain.cov[0, 0].clamp_min(0).sqrt())
    if given is None and not found and not nuisance and abs(a_plain) < _MIN_SIGNIFICANCE * a_se:
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
        noise_sd=float(system.noise.sd),
        smoothing=system.sigma,
        mean=system.mean,
        fit_ratio=fit_ratio,
        residual_map=system.residual(final).mean(0),
        margin=system.margin,
        noise=system.measured_noise,
        artefacts=artefacts,
        negligible=[*nuisance, *(v for k, v in selection.negligible.items() if k not in selection.selected)],
        hints=dict(system.hints),
    )
