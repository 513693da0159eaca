"""Does each named effect earn its place? Its own forecast inside the fit frames, with and without it.

:func:`anra_torch.selection.diagnose_terms` names the effects that balance the PDE significantly and are
material (a share of ``dT/dt``, a physical size). Significance is not use: at a low noise every small
departure of the camera from the model's operators is significant, and two effects that explain the same
signal (a small loss, a small temperature-dependent diffusivity) are told apart by the order they are
tested in. :func:`earned_diagnosis` asks each effect what it does for a forecast:

- **Inner splits.** The fit frames are split again at :data:`EARN_SPLITS` of their length (the phases'
  several-split average: one split's validation frames are few and a model can win it by chance). On each,
  the extended model and the model without each of its effects are fitted to the frames before the split
  (:func:`anra_torch.selection.fit_effects`: the same smoothing and noise model, no test) and forecast the
  frames after it, as :func:`~anra_torch.forecast.assess_gain` forecasts held-out frames (the assimilated
  state, the evaluation scale, the noise floor of :mod:`~anra_torch.forecast.core`).
- **The cost of removing an effect** is how much worse the model without it forecasts, in noise floors,
  averaged over the splits. Backward elimination: while the cheapest effect to remove costs at most
  :data:`EARN_MARGIN` floors, it goes (the smallest model whose forecast is within the noise of the best).
  When two effects each cost that little, they explain the same signal: the one whose own model forecasts
  better stays (rule ``"same_signal"``); an effect alone that does not help the forecast goes by rule
  ``"forecast"``. Each removal is listed in the diagnosis' ``negligible`` with its rule and cost. A split
  on which the model itself cannot be fitted or forecast (a plate's depth from 5 frames) judges none of its
  effects; when no split is left, the model stays as the selection named it, its costs unknown (None).
- **Layered plates.** Where the layered forecast is asked for (:mod:`~anra_torch.forecast.layered`), an
  inner refit is forecast as the layers run it (:func:`~anra_torch.forecast.layered.within_layered`): a
  tensor that is not positive definite or an isotropic ``a`` that is not positive at the defect map's, a
  negative loss rate as none. The balance's refits on fewer frames land there (plate 3 of
  experiments.flash_defect_map: the models without one of its effects refused on all or 2 of 3 splits, no
  removal judged, the loss the truth lacks kept with a held-out gain of -0.26; plate 11's depth term alone,
  without the delamination, refused on every split). The surviving model is refitted as before: an
  anisotropy refitted there not positive definite leaves it (rule ``"unphysical"``).
- **Offset steps.** Where the artefact search found global offset steps, the frames are forecast with the
  found steps taken out and scored frame by frame about their mean (the balance's per-frame fixed effects):
  a recalibration the camera made is forecast by no model and decides nothing. Where it found a static
  fixed pattern, each model is forecast with its own per-pixel fixed effects, measured on its fit frames,
  as a stationary heat input (:mod:`~anra_torch.forecast.pattern`): the pattern, which a model alone
  smooths away and the camera keeps, would otherwise make most of every model's error and judge the
  effects by how they smooth it (a true disc of lower diffusivity cost -0.9 floors with a pattern of 3
  noise sds). Scoring each pixel's errors about their mean instead also took out most of a wrong model's
  error (a true anisotropy of 35 % of ``dT/dt`` cost 0.04 floors).

Every model, the inner ones and the surviving one, is fitted with the diagnosis' hints (candidate shapes
from outside the balance: a flash map's defects) and its nuisance terms beside it
(:attr:`~anra_torch.selection.Diagnosis.nuisance`: significant effects too small to name, which stay in
the fit so that the named ones are not biased by their absence); an effect removed by a forecast rule leaves
the fit, as the inner forecasts that removed it were fitted. The surviving model is refitted on the whole
fit frames (:func:`~anra_torch.selection.fit_effects`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import Tensor

from anra_torch.balance import Artefacts, find_artefacts
from anra_torch.checks import mostly_finite
from anra_torch.effects import EFFECTS
from anra_torch.forecast.core import (
    INNER_SPLITS,
    TIME_WINDOW,
    at_scale,
    evaluation_scale,
    extended_effects,
    forecast_errors,
    forecast_floor,
    interior,
    split_index,
)
from anra_torch.forecast.gain import _Forecasts
from anra_torch.forecast.layered import within_layered
from anra_torch.forecast.pattern import pixel_forcing
from anra_torch.selection import Diagnosis, diagnose_terms, fit_effects

__all__ = [
    "EARN_MARGIN",
    "EARN_SPLITS",
    "WEAK_SIGNAL",
    "earned_diagnosis",
    "signal_to_noise",
    "without_offsets",
]

EARN_SPLITS = tuple(0.6 + extra for extra in INNER_SPLITS)
"""Inner splits of the fit frames (fractions of their length) over which an effect's forecast is averaged: a
recording's fit fraction plus :data:`~anra_torch.forecast.INNER_SPLITS`, as the phases compare their
candidates."""

EARN_MARGIN = 0.1
"""Noise floors by which removing an effect must worsen the inner forecasts for the effect to stay."""

WEAK_SIGNAL = 5.0
"""Noise sds of change (:func:`signal_to_noise`) below which a recording's signal is weak: a few noise
levels, where only the smallest model whose forecast is within the noise of the best can be told."""

_F64 = torch.float64


def signal_to_noise(frames: Tensor, diagnosis: Diagnosis) -> float:
    """How much the frames change, in noise sds: the 99th percentile over the interior of the change between
    the first and the last frame at the diagnosis' scale (its Gaussian smoothing), over the sensor noise's sd.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    ends = at_scale(torch.as_tensor(frames).detach().to(_F64)[[0, -1]], float(diagnosis.smoothing))
    change = interior(ends[1] - ends[0], diagnosis.margin).abs().flatten()
    if change.numel() == 0 or diagnosis.noise_sd <= 0:
        return math.inf
    return float(torch.quantile(change, 0.99)) / float(diagnosis.noise_sd)


def earned_diagnosis(
    frames: Tensor,
    dt: float,
    dx: float,
    diagnosis: Diagnosis | None = None,
    *,
    time_window: int | None = None,
    assimilate: int | None = None,
) -> Diagnosis:
    """The diagnosis of ``frames`` with only the effects that earn their place by their own forecast.

    Args:
        frames: the fit frames of one video (all of it, or a recording's fit part).
        dt: frame period in s.
        dx: pixel size in mm.
        diagnosis: :func:`~anra_torch.selection.diagnose_terms` of exactly these frames; default made here.
        time_window: frames of the moving average in time at the evaluation scale; default
            :data:`~anra_torch.forecast.TIME_WINDOW`, at most half of each split's validation frames.
        assimilate: frames assimilated into each forecast's starting state (default: all before the split).

    Returns:
        The :class:`~anra_torch.selection.Diagnosis` of the earned model: ``diagnosis`` itself when every
        effect earns its place, else the earned model refitted, with each removed effect in ``negligible``
        (``{"name", "params", "share", "rule", "cost", "margin"}``, ``"kept"`` for ``"same_signal"``);
        each named effect has its ``"forecast_cost"`` (noise floors; None when no inner split could judge it).

    Raises:
        ValueError: as :func:`~anra_torch.selection.diagnose_terms`.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    video = mostly_finite(torch.as_tensor(frames).detach().to(_F64))
    if diagnosis is None:
        diagnosis = diagnose_terms(video, dt, dx)
    names = list(diagnosis.names)
    splits = _splits(video.shape[0])
    if not names or not splits:
        return diagnosis
    repaired = without_offsets(*find_artefacts(video))
    kept, cost, removed = _eliminate(repaired, dt, dx, diagnosis, splits, time_window, assimilate)
    final, unphysical = (diagnosis, []) if not removed else _refit(video, dt, dx, diagnosis, kept)
    ranked = sorted(final.effects, key=lambda e: -e["score"])
    return replace(
        final,
        effects=[{**e, "forecast_cost": cost[e["name"]]} for e in ranked],
        scores=dict(diagnosis.scores),
        thresholds=dict(diagnosis.thresholds),
        negligible=[
            *(n for n in final.negligible if n.get("rule") == "share"),  # the nuisance terms, as refitted
            *(n for n in diagnosis.negligible if n.get("rule") != "share"),
            *removed,
            *unphysical,
        ],
    )


def _refit(
    video: Tensor, dt: float, dx: float, diagnosis: Diagnosis, kept: list[str]
) -> tuple[Diagnosis, list]:
    """The kept model fitted on the whole fit frames with the diagnosis' nuisance terms and hints, and the
    ``negligible`` entries (rule ``"unphysical"``) of its effects dropped because their refitted parameters
    are not physical (the survivors fitted again without them): the inner fits that kept an effect were
    each fitted on fewer frames, and a shape refitted on all of them can land where the model cannot be
    simulated (a plate's delamination of strength -1.7, and with it no effect at all in the held-out
    forecast)."""
    unphysical: list[dict] = []
    while True:
        (final,) = fit_effects(
            video, dt, dx, [kept], smoothing=diagnosis.smoothing, noise_sd=diagnosis.noise,
            nuisance=diagnosis.nuisance, physical=True, hints=diagnosis.hints,
        )  # fmt: skip
        dropped = [n for n in final.negligible if n.get("rule") == "unphysical"]
        unphysical.extend(n for n in dropped if n not in unphysical)
        if not any(n["name"] in kept for n in dropped):
            return final, unphysical
        kept = final.names


def without_offsets(frames: Tensor, artefacts: Artefacts) -> Tensor:
    """``frames`` with the global offset steps the artefact search found taken out: each frame after a
    step lowered by the step (a camera's recalibrations are no heat; a drift between them stays).

    Shape:
        ``frames`` ``(T, H, W)``; output the same.
    """
    if not artefacts.steps:
        return frames
    offsets = torch.zeros(frames.shape[0], dtype=frames.dtype, device=frames.device)
    for step, size in zip(artefacts.steps, artefacts.step_sizes, strict=True):
        offsets[step:] += size
    return frames - offsets[:, None, None]


def _eliminate(
    video: Tensor,
    dt: float,
    dx: float,
    diagnosis: Diagnosis,
    splits: list[int],
    time_window: int | None,
    assimilate: int | None,
) -> tuple[list[str], dict[str, float | None], list[dict]]:
    """Backward elimination by the inner forecasts: the effects kept, each one's cost of removal (noise
    floors, averaged over the splits that judge the kept model; None where none does) in the kept model,
    and the removed ones' ``negligible`` entries."""
    named = {e["name"]: {"name": e["name"], "params": dict(e["params"]), "share": e.get("share")}
             for e in diagnosis.effects}  # fmt: skip
    scores: dict[frozenset[str], list[float]] = {}
    removed: list[dict] = []
    kept = list(diagnosis.names)
    cost: dict[str, float | None] = {}
    while kept:
        models = [kept, *(_without(kept, name) for name in kept), []]
        # each distinct model once (one effect kept: the model without it is the plain model)
        missing = list({frozenset(m): m for m in models if frozenset(m) not in scores}.values())
        if missing:
            scores.update(_inner_scores(video, dt, dx, diagnosis, missing, splits, time_window, assimilate))
        full = scores[frozenset(kept)]
        # A split where the model itself cannot be fitted or forecast judges none of its effects; with no
        # split left, the model stays as it is (its effects' costs unknown).
        judged = [k for k, ratio in enumerate(full) if math.isfinite(ratio)]
        if not judged:
            cost = {name: None for name in kept}
            break
        judged_cost = {
            name: sum(scores[frozenset(_without(kept, name))][k] - full[k] for k in judged) / len(judged)
            for name in kept
        }
        cost = dict(judged_cost)
        cheap = sorted((c, name) for name, c in judged_cost.items() if c <= EARN_MARGIN)
        if not cheap:
            break
        value, name = cheap[0]
        # Others that could go as cheaply explain the same signal: the one that forecasts better alone stays.
        rivals = [other for _, other in cheap[1:]]
        removed.append(
            {**named[name], "rule": "forecast", "cost": value, "margin": EARN_MARGIN, "_with": rivals}
        )
        kept = _without(kept, name)
    for entry in removed:
        rivals = [other for other in entry.pop("_with") if other in kept]
        if rivals:
            entry.update(rule="same_signal", kept=rivals[0])
    return kept, cost, removed


def _without(model: Sequence[str], name: str) -> list[str]:
    """``model`` without ``name`` and without the effects that require it."""
    gone = {name} | {e for e in model if name in EFFECTS[e].requires}
    return [e for e in model if e not in gone]


def _splits(n_frames: int) -> list[int]:
    """The distinct inner split indices of :data:`EARN_SPLITS` that leave a diagnosis its frames and at
    least 2 frames to validate."""
    out: list[int] = []
    for fraction in EARN_SPLITS:
        try:
            split = split_index(n_frames, fraction)
        except ValueError:
            continue
        if split not in out:
            out.append(split)
    return out


def _inner_scores(
    video: Tensor,
    dt: float,
    dx: float,
    diagnosis: Diagnosis,
    models: list[list[str]],
    splits: list[int],
    time_window: int | None,
    assimilate: int | None,
) -> dict[frozenset[str], list[float]]:
    """Each model's validation RMSE in noise floors on each inner split (infinity where the model cannot be
    fitted or simulated)."""
    totals: dict[frozenset[str], list[float]] = {frozenset(m): [] for m in models}
    for split in splits:
        prefix = video[: split + 1]
        fitted: list[Diagnosis | None]
        try:
            fitted = list(
                fit_effects(
                    prefix,
                    dt,
                    dx,
                    models,
                    smoothing=diagnosis.smoothing,
                    noise_sd=diagnosis.noise,
                    nuisance=diagnosis.nuisance,
                    hints=diagnosis.hints,
                )  # fmt: skip
            )
        except ValueError:
            fitted = [None] * len(models)
        found = diagnosis.artefacts
        within = (found is not None and found.global_offsets, found is not None and found.fixed_pattern)
        for model, inner in zip(models, fitted, strict=True):
            ratio = math.inf if inner is None else _validation(video, dt, dx, inner, split, time_window,
                                                                assimilate, within)  # fmt: skip
            totals[frozenset(model)].append(ratio)
    return totals


def _validation(
    video: Tensor,
    dt: float,
    dx: float,
    inner: Diagnosis,
    split: int,
    time_window: int | None,
    assimilate: int | None,
    within: tuple[bool, bool],
) -> float:
    """RMSE over the noise floor of ``inner`` (fitted on frames ``0 .. split``) forecasting the rest.

    ``within``: (offset steps found: scored frame by frame about the mean; fixed pattern found: forecast
    with the model's own per-pixel fixed effects, :func:`~anra_torch.forecast.pattern.pixel_forcing`)."""
    inner = within_layered(inner)  # a layered plate's refit bounded where the layers need it bounded
    horizon = video.shape[0] - split
    window = max(1, min(TIME_WINDOW if time_window is None else time_window, (horizon - 1) // 2))
    n_assimilated = split + 1 if assimilate is None else min(assimilate, split + 1)
    scale = evaluation_scale(inner, None)
    fit_duration = split * dt
    offsets, pattern = within
    try:
        effects = extended_effects(
            inner, fit_duration=fit_duration, start=fit_duration, duration=(horizon - 1) * dt
        )
        forcing = pixel_forcing(video[: split + 1], inner, dt, dx) if pattern else None
        run = _Forecasts(video, inner, split, dt, dx, effects, scale, window, n_assimilated, forcing=forcing)
        predicted = run.evaluate(run.forecast(effects))
    except ValueError:
        return math.inf
    measured = run.evaluate(video[split + 1 :])
    rmse = forecast_errors(predicted, measured, inner.margin, within_frames=offsets)[1]
    floor = forecast_floor(
        inner, scale, dt=dt, dx=dx, held_out=horizon - 1, window=window, assimilated=n_assimilated
    )
    return rmse / floor if floor > 0 else (0.0 if rmse == 0 else math.inf)
