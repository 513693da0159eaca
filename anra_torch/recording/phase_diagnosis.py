"""A recording as it comes: its phases, each diagnosed on its own, the extended model chosen by the data.

:func:`diagnose_recording` splits a recording into phases (:func:`anra_torch.video.recording_phases`:
baseline, heating, cooling, or one phase) and analyses every phase with enough frames on its own:

- **Frames that fit the balance's filters** (:func:`anra_torch.selection.minimum_frame_size`): the
  diagnosis and held-out forecast of :func:`~anra_torch.forecast.assess_gain`. When a source is named
  (or the phase heats, or the diagnosed extension cannot be simulated over the held-out frames: it then
  loses), the parametric source (a Gaussian on a path) and the measured source maps
  (:func:`~anra_torch.forecast.source_map_gain`; stationary, or decaying in time as a source over a thick
  body does: :data:`SOURCE_MAPS`) compete on a split INSIDE the fit frames; the held-out
  frames are scored only after the choice. Frames seconds apart (fewer held-out frames than one time
  window) get no time average and start from the measured split frame.
- **Smaller regions** (down to 3 x 3 px): the small-box models of :mod:`~anra_torch.estimation.small_box`;
  ``loss`` and ``quasi_steady`` compete on the same inner split. When the steady state for the measured
  edges explains most of the interior's change, conduction crosses the region within a frame: the
  diffusivity is reported as unresolved, with the lower bound that implies.

Every phase's :meth:`PhaseDiagnosis.to_record` is the ``"phases"`` element of ``anra diagnose --json``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import torch
from torch import Tensor

from anra_torch.checks import extended_diffusivity_warning
from anra_torch.effects import EFFECTS
from anra_torch.flash import DefectMap
from anra_torch.forecast import (
    DIAGNOSED_FRAMES,
    INNER_SPLITS,
    TIME_WINDOW,
    WEAK_SIGNAL,
    GainResult,
    assess_gain,
    earned_diagnosis,
    signal_to_noise,
    source_map_gain,
    split_index,
)
from anra_torch.layers import TimeDerivative
from anra_torch.recording.box_phase import small_box_phase
from anra_torch.recording.phase_record import PhaseDiagnosis, flag_implausible, implausible
from anra_torch.recording.phases import MIN_PHASE_FRAMES, recording_phases_of, repaired
from anra_torch.selection import diagnose_terms, minimum_frame_size
from anra_torch.video import Phase, measured_frames

__all__ = ["INNER_SPLITS", "PhaseDiagnosis", "diagnose_recording", "flash_hints"]

_F64 = torch.float64
_RESOLVED_FRAMES = TimeDerivative("smooth").length  # frames after a flash that the time stencil spans


def diagnose_recording(
    frames: Tensor,
    dt: float,
    dx: float,
    t: Tensor | None = None,
    *,
    fit_fraction: float = 0.6,
    assimilate: int | None = None,
    phases: list[Phase] | None = None,
    measured_t: Sequence[float] | Tensor | None = None,
    hints: dict[str, Any] | None = None,
) -> list[PhaseDiagnosis]:
    """Diagnose every phase of a recording on its own (see the module text).

    Args:
        frames: temperatures, uniformly sampled at ``dt``.
        dt: frame period in s.
        dx: pixel size in mm.
        t: timestamps in s (default ``dt`` times the frame index); used to time the phases.
        fit_fraction: each phase's fraction diagnosed; the rest is held out.
        assimilate: frames assimilated into the balance forecasts' starting state (default: adapted).
        phases: the phases (default :func:`find_phases`).
        measured_t: for frames resampled from irregular timestamps, the measured samples' times in s
            (``Video.meta["measured_t"]``): no phase keeps a frame blended from another phase's samples.
        hints: candidate shapes by effect for every phase's balance diagnosis
            (:func:`~anra_torch.selection.diagnose_terms`; :func:`flash_hints` of a flash defect map).

    Returns:
        One :class:`PhaseDiagnosis` per phase, in time order.

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.
    """
    video = torch.as_tensor(frames).to(_F64)
    clean_video = repaired(video)  # once: the phases, the small boxes and the source map need finite frames
    times = torch.arange(video.shape[0], dtype=_F64) * dt if t is None else torch.as_tensor(t)
    if phases is None:
        phases = recording_phases_of(clean_video, times, measured_t)
    sampled = None if measured_t is None else measured_frames(times, measured_t)
    out = []
    for phase in phases:
        phase, phase_hints = _after_heating(phase, times, hints)
        if phase.frames < MIN_PHASE_FRAMES:
            reason = f"too short: {phase.frames} frames, need {MIN_PHASE_FRAMES}"
            out.append(PhaseDiagnosis(phase, "none", reason=reason))
            continue
        part, clean = video[phase.start : phase.stop], clean_video[phase.start : phase.stop]
        scored = None if sampled is None else sampled[phase.start : phase.stop]
        scored = None if scored is None or bool(scored.all()) else scored
        try:
            if min(part.shape[1:]) >= minimum_frame_size():  # it repairs and reports the artefacts itself
                fraction = _short_phase_fraction(phase.frames, fit_fraction)
                out.append(
                    _balance_phase(phase, part, clean, dt, dx, fraction, assimilate, scored, phase_hints)
                )
            else:
                out.append(small_box_phase(phase, clean, dt, dx, fit_fraction))
        except ValueError as err:
            out.append(PhaseDiagnosis(phase, "none", reason=str(err)))
    return out


def flash_hints(defects: DefectMap, *, layered: bool = False) -> dict[str, Any]:
    """The diagnosis' hints (:func:`~anra_torch.selection.diagnose_terms`) from a flash recording's defect
    map: the depth term held at the map's plate ``{"T_ref", "plate_time", "t_heat"}`` (the temperature
    before the flash, ``L^2 / a_z`` in s, the flash's time before the first frame in s); a delamination
    looked for at the map's defects only (where the cooling says the heat stops early), each a region
    ``{"x", "y", "radius", "depth_fraction", "plate_time", "lateral"}`` (its centroid and the radius of its
    area's disc in mm, its ``d / L``, the map's ``L^2 / a_z`` in s, the map's lateral diffusivity as one
    isotropic value ``sqrt(a_x a_y - a_xy^2)`` in mm^2/s, 0 where not measured: how far the heat the defect
    sends back spreads, :mod:`~anra_torch.effects.delamination`); a map without a defect rules the
    delamination out. ``layered``: the plate's forecasts resolved through its thickness
    (:mod:`anra_torch.forecast.layered`; the plate's ``"layered"`` 1.0 and the map's lateral diffusivities
    ``"a_x"``, ``"a_y"``, ``"a_xy"`` in mm^2/s)."""
    plate = {"T_ref": defects.t_ref, "plate_time": defects.plate_time, "t_heat": -defects.first_time}
    if layered:
        plate["layered"] = 1.0
        plate.update(zip(("a_x", "a_y", "a_xy"), defects.lateral, strict=True))
    a_x, a_y, a_xy = defects.lateral
    lateral = math.sqrt(max(a_x * a_y - a_xy**2, 0.0))
    regions = tuple(
        {
            "x": d.x,
            "y": d.y,
            "radius": math.sqrt(d.area / math.pi),
            "depth_fraction": d.depth_fraction,
            "plate_time": defects.plate_time,
            "lateral": lateral,
        }
        for d in defects.defects
        if d.area > 0
    )
    hints: dict[str, Any] = {"delamination": regions}
    hints["depth_conduction"] = (plate,)
    return hints


def _after_heating(phase: Phase, times: Tensor, hints: dict[str, Any] | None) -> tuple[Phase, dict | None]:
    """A phase diagnosed with a held depth term (``hints["depth_conduction"]``, its ``t_heat`` from the
    recording's first frame) from its first frame a time stencil after the heating on, and the hints with
    ``t_heat`` from that frame: in the first frames after a flash the depth rate ``1 / (2 s)`` changes
    several times over the stencil, which no term of the balance resolves (on a 2 mm plate its isotropic
    ``a`` went negative and an advection was named; from 3 frames after the flash on, as the map starts,
    the delamination and the anisotropy had negative own gains there). Other phases and hints as they are."""
    held = None if hints is None else hints.get("depth_conduction")
    if hints is None or not held or times.shape[0] < 2:
        return phase, hints
    heating = float(times[0]) + held[0]["t_heat"]
    resolved = heating + _RESOLVED_FRAMES * float(times[1] - times[0])
    start = phase.start
    while start < phase.stop - 1 and float(times[start]) < resolved:
        start += 1
    plate = tuple({**h, "t_heat": heating - float(times[start])} for h in held)
    return replace(phase, start=start, t_start=float(times[start])), {**hints, "depth_conduction": plate}


def _short_phase_fraction(frames: int, fit_fraction: float) -> float:
    """``fit_fraction``, raised for a short phase so that its fit part keeps :data:`_INNER_FRAMES` frames
    (three time samples of dT/dt, and the inner comparison of the source candidates) while 2 are held out."""
    target = min(_INNER_FRAMES, frames - 2)
    return fit_fraction if round(fit_fraction * frames) >= target else target / frames


def _measured_split(fit_fraction: float, scored: Tensor) -> float:
    """``fit_fraction`` moved back so that the fit part ends on a measured sample (``scored``, one bool per
    frame of resampled irregular times): the forecast then starts from a measurement, not from a frame
    interpolated towards the first held-out sample. Unchanged when no earlier sample leaves the diagnosis
    its 5 frames."""
    n = scored.shape[0]
    split = round(fit_fraction * n) - 1
    samples = [int(k) for k in torch.nonzero(scored[: split + 1]).flatten() if k >= DIAGNOSED_FRAMES - 1]
    return (samples[-1] + 1) / n if samples else fit_fraction


def _balance_phase(
    phase: Phase,
    part: Tensor,
    clean: Tensor,
    dt: float,
    dx: float,
    fit_fraction: float,
    assimilate: int | None,
    scored: Tensor | None = None,
    hints: dict[str, Any] | None = None,
) -> PhaseDiagnosis:
    """The balance family: assess_gain; the source map (on ``clean``, the repaired frames: it needs finite
    ones) against the parametric source when a source acts. ``scored``: the phase's frames that are measured
    samples (resampled irregular times): forecasts are scored there only, each frame on its own."""
    options, fit_fraction = _phase_options(part, fit_fraction, assimilate, scored, hints)
    result, effects, unsimulated = _assessed(part, dt, dx, fit_fraction, options)
    names = [e["name"] for e in effects]
    diagnosis = PhaseDiagnosis(
        phase,
        "balance",
        diffusivity=result.diagnosis.a_plain,
        base_rmse=result.base_rmse,
        noise_floor=result.noise_floor,
        effects=effects,
        result=result,
    )
    _flag_balance(diagnosis, result, effects, (part, clean, dt, dx), unsimulated)
    held = {"parametric": (math.inf, -math.inf) if unsimulated else (result.extended_rmse, result.gain)}
    predicted = {"parametric": result.predicted_extended}
    validation: dict[str, float] = {}
    if any(EFFECTS[n].heat_input for n in names) or phase.name == "heating" or unsimulated:
        forecasts = (held, predicted)
        validation = _source_maps(
            clean, dt, dx, result, (fit_fraction, options), forecasts, diagnosis.warnings
        )
    if validation.get("parametric") == math.inf:
        diagnosis.warnings.append("the parametric source fitted inside the fit frames cannot be simulated")
    chosen = min(validation, key=validation.__getitem__) if validation else "parametric"
    if unsimulated and chosen == "parametric":  # no extension could be forecast or chosen: the plain model
        held["plain"], predicted["plain"], chosen = (result.base_rmse, 0.0), result.predicted_base, "plain"
    diagnosis.model = chosen
    diagnosis.extended_rmse, diagnosis.gain = held[chosen]
    diagnosis.forecasts = {
        "measured": result.measured,
        "plain": result.predicted_base,
        "extended": predicted[chosen],
    }
    diagnosis.candidates = {
        name: {"validation_rmse": validation.get(name), "gain": held[name][1]} for name in held
    }
    return diagnosis


def _phase_options(
    part: Tensor, fit_fraction: float, assimilate: int | None, scored: Tensor | None, hints: dict | None
) -> tuple[dict[str, Any], float]:
    """A phase's forecast options (:func:`~anra_torch.forecast.assess_gain`'s keywords, and the diagnosis'
    ``hints`` when given) and its fit fraction, moved back onto a measured sample where ``scored``."""
    held_out = part.shape[0] - 1 - split_index(part.shape[0], fit_fraction)
    sparse = held_out < TIME_WINDOW  # frames seconds apart: a few frames already span the dynamics
    options: dict[str, Any] = (
        {"time_window": 1, "assimilate": assimilate or 1} if sparse else {"assimilate": assimilate}
    )
    if scored is not None:
        options.update(time_window=1, scored=scored)
        fit_fraction = _measured_split(fit_fraction, scored)
    if hints is not None:
        options["hints"] = hints
    return options, fit_fraction


def _flag_balance(
    diagnosis: PhaseDiagnosis,
    result: GainResult,
    effects: list[dict[str, Any]],
    frames: tuple[Tensor, Tensor, float, float],
    unsimulated: str | None,
) -> None:
    """The balance diagnosis' flags and warnings: a negative diffusivity, implausible effects, a weak signal,
    conduction the extension explains, an extension not forecast; ``frames`` is ``(part, clean, dt, dx)``."""
    part, clean, dt, dx = frames
    if result.diagnosis.a_plain < 0:
        diagnosis.flags.append("negative")
    diagnosis.warnings = implausible(effects, part.shape[1] * dx, part.shape[2] * dx)
    diagnosis.signal_to_noise = signal_to_noise(clean[: result.split + 1], result.diagnosis)
    if diagnosis.signal_to_noise < WEAK_SIGNAL:
        diagnosis.warnings.append(
            f"weak signal: the fit frames change by {diagnosis.signal_to_noise:.2g} noise sds (under "
            f"{WEAK_SIGNAL:g}); only effects whose own forecast beats the noise are named, the fewest that do"
        )
    diagnosis.warnings.extend(_extended_conduction(result, effects))
    if unsimulated:
        diagnosis.warnings.append(f"the parametric extension was not forecast: {unsimulated}")
    flag_implausible(diagnosis, dt, dx)


def _source_maps(
    clean: Tensor,
    dt: float,
    dx: float,
    result: GainResult,
    fit: tuple[float, dict[str, Any]],
    forecasts: tuple[dict[str, tuple[float, float]], dict[str, Tensor]],
    warnings: list[str],
) -> dict[str, float]:
    """Each source map's held-out RMSE and gain and its forecast (added to ``forecasts``, the ``held`` and
    ``predicted`` of the candidates), and the validation RMSE of every candidate inside the fit frames
    (``fit``: the fit fraction and the gain's options); ``{}`` and a warning when they cannot be compared."""
    held, predicted = forecasts
    try:
        for name, decay in SOURCE_MAPS.items():
            mapped = source_map_gain(clean, dt, dx, result, decay=decay, t_on=_T_ON * dt)
            held[name] = (mapped.rmse, mapped.gain)
            predicted[name] = mapped.predicted
        if result.split + 1 < _INNER_FRAMES:
            raise ValueError(
                f"its {result.split + 1} fit frames are fewer than the {_INNER_FRAMES} a comparison "
                "inside them needs (5 to diagnose, 2 to validate); the parametric source is kept, the "
                "source map's held-out gain is shown for information only"
            )
        return _inner_balance(clean[: result.split + 1], dt, dx, fit[0], fit[1])
    except ValueError as err:
        warnings.append(f"the source map was not compared: {err}")
        return {}


def _assessed(
    part: Tensor, dt: float, dx: float, fit_fraction: float, options: dict[str, Any], *, earn: bool = True
) -> tuple[GainResult, list[dict[str, Any]], str | None]:
    """:func:`~anra_torch.forecast.assess_gain` of the phase, its named effects ``{"name", "params",
    "share", "forecast_cost", "gain"}`` and None; or, when the diagnosed extension cannot be simulated over
    the held-out frames (a conductivity that turns negative over the temperatures they reach), the plain
    model's assessment, the effects named without a held-out gain (None), and why: the source maps still
    compete. ``earn``: the named effects are those that earn their place by their own forecast inside the
    fit frames (:func:`~anra_torch.forecast.earned_diagnosis`; not for the inner comparisons of the
    source candidates, which keep the stepwise model). ``options["hints"]``: the diagnosis' candidate
    shapes (:func:`~anra_torch.selection.diagnose_terms`), the rest :func:`assess_gain`'s keywords."""
    fit = part[: split_index(part.shape[0], fit_fraction) + 1]
    options = dict(options)
    found = diagnose_terms(fit, dt, dx, hints=options.pop("hints", None))
    if earn:
        window, assimilate = options.get("time_window"), options.get("assimilate")
        found = earned_diagnosis(fit, dt, dx, found, time_window=window, assimilate=assimilate)
    unsimulated = None
    try:
        result = assess_gain(part, dt, dx, fit_fraction=fit_fraction, diagnosis=found, **options)
        gains: list[float | None] = list(result.effect_gains)
    except ValueError as err:
        if not found.effects:
            raise
        plain = replace(found, effects=[])
        result = assess_gain(part, dt, dx, fit_fraction=fit_fraction, diagnosis=plain, **options)
        gains, unsimulated = [None] * len(found.effects), str(err)
    effects = [
        {
            "name": e["name"],
            "params": {k: float(v) for k, v in e["params"].items()},
            "share": e.get("share"),
            "forecast_cost": e.get("forecast_cost"),
            "gain": g,
        }
        for e, g in zip(found.effects, gains, strict=True)
    ]
    return result, effects, unsimulated


def _extended_conduction(result: GainResult, effects: list[dict[str, Any]]) -> list[str]:
    """:func:`~anra_torch.checks.extended_diffusivity_warning` of the phase's extended model."""
    names = [e["name"] for e in effects]
    found = extended_diffusivity_warning(result.diagnosis.base, result.diagnosis.a_plain, names)
    return [found] if found else []


SOURCE_MAPS = {"source_map": 0.0, "source_map_t^-0.5": 0.5, "source_map_t^-1": 1.0, "source_map_t^-1.5": 1.5}
"""The measured source maps that compete with the parametric source, by the power of their input's decay in
time (:func:`~anra_torch.forecast.fit_source_map`): stationary; a flux into a half-space
(``t^(-1/2)``); and faster, as heat also spreads sideways towards a steady state (``t^(-3/2)``)."""

_T_ON = 0.5  # frame periods: a source switches on between a phase's first two frames

_INNER_FRAMES = DIAGNOSED_FRAMES + 2
"""Fit frames the inner comparison of the source candidates needs: 5 to diagnose, 2 to validate."""


def _inner_balance(fit: Tensor, dt: float, dx: float, fit_fraction: float, options: dict) -> dict[str, float]:
    """Each candidate's validation error inside the fit frames: its RMSE over the plain model's on the same
    split, averaged over the distinct splits of :data:`INNER_SPLITS` that leave 2 frames to validate (as the
    small-box models are validated over :data:`~anra_torch.recording.box_phase.INNER_ORIGINS`). An inner
    parametric model that cannot be simulated (a conductivity that turns negative over the reachable
    temperatures) scores infinity instead of cancelling the comparison."""
    n = fit.shape[0]
    if options.get("scored") is not None:
        options = {**options, "scored": options["scored"][:n]}
    first = max(fit_fraction, (DIAGNOSED_FRAMES - 1) / (n - 1))  # frames enough to diagnose
    fractions = {}
    for extra in INNER_SPLITS:
        fraction = min(first + extra, (n - 2) / n)  # at least 2 frames validate
        if options.get("scored") is not None:
            fraction = _measured_split(fraction, options["scored"])
        fractions.setdefault(split_index(n, fraction), fraction)
    ratios: dict[str, list[float]] = {}
    for fraction in fractions.values():
        inner, _, unsimulated = _assessed(fit, dt, dx, fraction, options, earn=False)
        rmse = {"parametric": math.inf if unsimulated else inner.extended_rmse}  # unphysical there: it loses
        for name, decay in SOURCE_MAPS.items():
            rmse[name] = source_map_gain(fit, dt, dx, inner, decay=decay, t_on=_T_ON * dt).rmse
        for name, value in rmse.items():
            ratios.setdefault(name, []).append(value / inner.base_rmse if inner.base_rmse > 0 else value)
    return {name: sum(values) / len(values) for name, values in ratios.items()}
