"""Does a diagnosed effect predict the future? Forecast held-out frames with and without it.

:func:`anra_torch.selection.diagnose_terms` selects effects from how well the PDE balances on the frames.
:func:`assess_gain` asks the question a user cares about: simulate forward
(:func:`anra_torch.effects.simulate_effects`, RK4, bounded by the measured frame edges) from the fit part
with the plain heat equation (``a_plain``) and with the extended model (``base`` plus the effects found),
and compare both forecasts with frames the diagnosis never saw. The split, the assimilated starting states,
the evaluation scale and the noise floor are those of :mod:`anra_torch.forecast.core`; the same quantities
against the raw frames (the same forecasts unsmoothed, noise floor = sensor sd) are kept as ``*_raw``.

Measured with ``python -m experiments.diagnosis_benchmark`` (README): see its table.
About 1-5 s per video on one core.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import torch
from torch import Tensor

from anra_torch.balance import find_artefacts
from anra_torch.checks import diffusivity_warnings, extended_diffusivity_warning, model_failure, mostly_finite
from anra_torch.effects import Effect
from anra_torch.forecast.core import (
    TIME_WINDOW,
    assimilated_state,
    at_scale,
    check_diagnosis_frames,
    evaluation_scale,
    extended_effects,
    forecast_errors,
    forecast_floor,
    gain_above_floor,
    simulate_model,
    split_index,
    time_average,
)
from anra_torch.forecast.layered import layered_forecast, layered_plate
from anra_torch.selection import Diagnosis, diagnose_terms

__all__ = ["GainResult", "assess_gain"]

_F64 = torch.float64


@dataclass(frozen=True)
class GainResult:
    """How much better the extended model forecasts the held-out frames than the plain heat equation.

    Attributes:
        diagnosis: the diagnosis of the fit part.
        split: index of the fit part's last frame, where both forecasts start.
        effects: the extended model's effects, re-timed to the forecast (source path).
        base_a: ``a_plain`` (mm^2/s), the plain model's diffusivity.
        extended_a: ``diagnosis.base`` (mm^2/s), the extended model's base diffusivity.
        times: centre times of the evaluation windows over the held-out frames, s from the first frame.
        rmse_base: per evaluation window RMSE of the plain forecast (data units), interior pixels, at the
            evaluation scale.
        rmse_extended: the same for the extended forecast.
        base_rmse: RMSE of the plain forecast over all held-out frames (interior, evaluation scale).
        extended_rmse: the same for the extended forecast.
        base_sse: the paper's Problem-1 error, sum of squared errors over the held-out interior
            (evaluation scale).
        extended_sse: the same for the extended forecast.
        gain: ``1 - extended_rmse / base_rmse`` (0 when no effect was found).
        noise_floor: the RMSE a perfect model would reach at the evaluation scale (data units).
        predicted_base: the plain forecast on the full frame at the evaluation scale (smoothed in space,
            averaged in time).
        predicted_extended: the same for the extended forecast.
        measured: the held-out measured frames at the evaluation scale.
        margin: pixels left out at each edge.
        scale_px: the evaluation scale in space, a Gaussian sigma in px (0: raw frames).
        base_rmse_raw: RMSE of the plain forecast against the raw held-out frames (interior).
        extended_rmse_raw: the same for the extended forecast.
        gain_raw: ``1 - extended_rmse_raw / base_rmse_raw`` (0 when no effect was found).
        noise_floor_raw: the sensor noise sd, the least RMSE against raw frames.
        effect_gains: each effect's own gain, what the extended model loses without it, ``(rmse_without_it
            - rmse_extended) / base_rmse`` (evaluation scale),
            in the order of ``effects`` (the whole gain when there is one effect).
        gain_above_floor: the fraction of the plain model's error above the noise floor that the
            extension removes, ``1 - e_extended / e_base`` with ``e = sqrt(max(rmse^2 - floor^2, 0))``
            (evaluation scale); 0 when no effect was found or when the plain forecast is within
            :data:`~anra_torch.forecast.AT_FLOOR` of the floor (nothing measurable to gain).
        elapsed: seconds spent (diagnosis and both simulations).
        time_window: frames of the moving average in time at the evaluation scale (1: none).
        assimilated: the fit part's last frames assimilated into both forecasts' starting states (1: the
            measured split frame).
        warnings: lines for the user (:mod:`anra_torch.checks.flags`), empty when all is well: the final
            model's diffusivity (``extended_a`` when effects were found, else ``base_a``) negative or outside
            every known material, and the final model's forecast RMSE above
            :data:`~anra_torch.checks.MODEL_FAILURE_RATIO` noise floors ("the model does not explain the
            data", with the ratio).
        scored: for a recording resampled from irregular times, which held-out frames are measured
            samples: the RMSEs, sums and gains are taken on those only (``rmse_base`` and
            ``rmse_extended`` keep every frame, for figures); None: every held-out frame.

    Shape:
        ``times``, ``rmse_base``, ``rmse_extended`` ``(K,)``; ``predicted_*``, ``measured`` ``(K, H, W)``
        with ``K = held_out - time_window + 1`` evaluation windows.
    """

    diagnosis: Diagnosis
    split: int
    effects: tuple[Effect, ...]
    base_a: float
    extended_a: float
    times: Tensor
    rmse_base: Tensor
    rmse_extended: Tensor
    base_rmse: float
    extended_rmse: float
    base_sse: float
    extended_sse: float
    gain: float
    noise_floor: float
    predicted_base: Tensor
    predicted_extended: Tensor
    measured: Tensor
    margin: int
    scale_px: float = 0.0
    base_rmse_raw: float = math.nan
    extended_rmse_raw: float = math.nan
    gain_raw: float = 0.0
    noise_floor_raw: float = math.nan
    gain_above_floor: float = 0.0
    effect_gains: tuple[float, ...] = ()
    elapsed: float = 0.0
    time_window: int = 1
    assimilated: int = 1
    warnings: tuple[str, ...] = ()
    scored: Tensor | None = None

    @property
    def held_out(self) -> int:
        """Number of held-out frames forecast."""
        return self.measured.shape[0] + self.time_window - 1


def _frame_count(value: object, name: str, default: int, available: int, *, cap: bool = True) -> int:
    """``value`` checked against 1 .. ``available``; None: ``default`` (capped at half of ``available``
    when ``cap``)."""
    if value is None:
        return max(1, min(default, available // 2)) if cap else default
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= available:
        raise ValueError(f"{name} must be an integer from 1 to {available} frames, got {value!r}")
    return value


@dataclass(frozen=True)
class _Forecasts:
    """One video's split and evaluation settings: every forecast of :func:`assess_gain` is made and scored
    alike (float64 ``video`` ``(T, H, W)``; ``effects`` re-timed to the held-out frames)."""

    video: Tensor
    diagnosis: Diagnosis
    split: int
    dt: float
    dx: float
    effects: tuple[Effect, ...]
    scale: float
    window: int
    assimilated: int
    scored: Tensor | None = None  # which held-out frames are measured samples (None: all)
    forcing: Tensor | None = None  # a stationary heat input of every forecast, data units per s (None: none)

    def forecast(self, chosen: tuple[Effect, ...]) -> Tensor:
        """The held-out frames forecast from the assimilated state, full resolution: ``(T - s - 1, H, W)``;
        the frame's outermost pixel ring follows the measured frames (heat crosses a camera's frame edge)."""
        diagnosis, dt, dx = self.diagnosis, self.dt, self.dx
        fit_duration = self.split * dt
        names = {effect.name for effect in chosen}
        plate = layered_plate(diagnosis, names)
        if plate is not None:
            return layered_forecast(
                self.video, self.split, dt, dx, plate, assimilated=self.assimilated, forcing=self.forcing
            )

        def step(frame: int, state: Tensor) -> Tensor:  # one frame ahead from frame ``frame``
            retimed = extended_effects(diagnosis, fit_duration=fit_duration, start=frame * dt, duration=dt)
            effects_now = tuple(e for e in retimed if e.name in names)
            edges = self.video[frame : frame + 2]
            return simulate_model(
                state,
                diagnosis,
                dt=dt,
                dx=dx,
                n_frames=2,
                effects=effects_now,
                edges=edges,
                forcing=self.forcing,
            )[1]

        initial = assimilated_state(self.video[: self.split + 1], step, self.assimilated)
        horizon = self.video.shape[0] - self.split
        edges = self.video[self.split :]
        return simulate_model(
            initial,
            diagnosis,
            dt=dt,
            dx=dx,
            n_frames=horizon,
            effects=chosen,
            edges=edges,
            forcing=self.forcing,
        )[1:]

    def evaluate(self, frames: Tensor) -> Tensor:
        """``frames`` at the evaluation scale: smoothed in space, averaged in time."""
        return time_average(at_scale(frames, self.scale), self.window)


def assess_gain(
    frames: Tensor,
    dt: float,
    dx: float,
    *,
    fit_fraction: float = 0.6,
    diagnosis: Diagnosis | None = None,
    scale_px: float | None = None,
    time_window: int | None = None,
    assimilate: int | None = None,
    scored: Tensor | None = None,
) -> GainResult:
    """Diagnose the first part of a video and forecast the rest with the plain and the extended model.

    Args:
        frames: temperatures of one video.
        dt: frame period in s.
        dx: pixel size in mm.
        fit_fraction: fraction of the frames diagnosed (the rest is held out).
        diagnosis: a diagnosis of exactly ``frames[: round(fit_fraction T)]``; default: made here.
        scale_px: evaluation scale, a Gaussian sigma in px (0 compares raw frames); default the
            diagnosis' smoothing.
        time_window: frames of the moving average in time at the evaluation scale (1: none, for frames
            seconds apart); default :data:`~anra_torch.forecast.TIME_WINDOW`, at most half the held out.
        assimilate: the fit part's last frames assimilated into each model's starting state
            (:mod:`anra_torch.forecast.core`; 1: the measured split frame); default all of them.
        scored: bool per frame of ``frames``: the measured samples of a recording resampled from
            irregular times. The held-out frames are scored only there, each on its own
            (``time_window`` must then be 1, the default); None scores every held-out frame.

    Returns:
        :class:`GainResult`.

    Raises:
        ValueError: too short a video for the split (:func:`~anra_torch.forecast.split_index`), bad frames
            or spacing, no thermal activity (:func:`~anra_torch.selection.diagnose_terms`), a diagnosis of
            another frame size, a bad ``scale_px``, ``time_window`` (1 .. held-out frames) or ``assimilate``.

    Shape:
        ``frames`` ``(T, H, W)``.

    Example:
        >>> from anra_torch.effects import hidden_effect_video
        >>> video = hidden_effect_video(["advection"], seed=0, size=64, duration=3.0)
        >>> result = assess_gain(video.frames, video.dt, video.dx)
        >>> [e.name for e in result.effects], round(result.gain, 2)
        (['advection'], 0.99)
    """
    tick = time.perf_counter()
    video = _checked_video(frames)
    split = split_index(video.shape[0], fit_fraction)
    diagnosis = _fit_diagnosis(video, split, dt, dx, diagnosis)
    run = _forecasts(video, diagnosis, split, dt, dx, scale_px, time_window, assimilate, scored)
    return _scored(run, tick)


def _forecasts(
    video: Tensor,
    diagnosis: Diagnosis,
    split: int,
    dt: float,
    dx: float,
    scale_px: float | None,
    time_window: int | None,
    assimilate: int | None,
    scored: Tensor | None,
) -> _Forecasts:
    """:func:`assess_gain`'s forecasts of frames ``split + 1 ..`` with its options checked."""
    n_frames = video.shape[0]
    horizon = n_frames - split
    effects = extended_effects(
        diagnosis, fit_duration=split * dt, start=split * dt, duration=(horizon - 1) * dt
    )
    scale = evaluation_scale(diagnosis, scale_px)
    window = _frame_count(time_window, "time_window", 1 if scored is not None else TIME_WINDOW, horizon - 1)
    held_scored = _held_out_scored(scored, n_frames, split, window)
    n_assimilated = _frame_count(assimilate, "assimilate", split + 1, split + 1, cap=False)
    # Forecasts start from, and are scored against, frames without camera artefacts (a masked sample, a
    # spike, a dead element): the diagnosis repairs its own fit frames the same way.
    repaired = find_artefacts(video)[0]
    return _Forecasts(repaired, diagnosis, split, dt, dx, effects, scale, window, n_assimilated, held_scored)


def _checked_video(frames: Tensor) -> Tensor:
    """``frames`` as float64 ``(T, H, W)``, mostly finite (counted on the whole video, not only the fit
    part)."""
    if not isinstance(frames, Tensor):
        frames = torch.as_tensor(frames, device="cpu")
    if frames.ndim != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {tuple(frames.shape)}")
    return mostly_finite(frames.detach().to(_F64))


def _fit_diagnosis(video: Tensor, split: int, dt: float, dx: float, diagnosis: Diagnosis | None) -> Diagnosis:
    """``diagnosis`` checked against the frame size, or, when None, the diagnosis of frames ``0 .. split``."""
    if diagnosis is None:
        return diagnose_terms(video[: split + 1], dt, dx)
    check_diagnosis_frames(diagnosis, video.shape[1], video.shape[2])
    return diagnosis


def _held_out_scored(scored: Tensor | None, n_frames: int, split: int, window: int) -> Tensor | None:
    """The held-out part of ``scored`` ``(T,)`` (None stays None), checked against the frames and window."""
    if scored is None:
        return None
    scored = (
        scored.to(torch.bool)
        if isinstance(scored, Tensor)
        else torch.as_tensor(scored, dtype=torch.bool, device="cpu")
    )
    if scored.shape != (n_frames,):
        raise ValueError(f"scored must be one bool per frame ({n_frames},), got shape {tuple(scored.shape)}")
    if window != 1:
        raise ValueError(f"scored frames are scored each on its own: time_window must be 1, got {window}")
    return scored[split + 1 :]


def _scored(run: _Forecasts, tick: float) -> GainResult:
    """Forecast the held-out frames with both models and score them (:func:`assess_gain`'s result)."""
    diagnosis, split, effects, m = run.diagnosis, run.split, run.effects, run.diagnosis.margin
    raw = run.video[split + 1 :]
    base_full = run.forecast(())
    extended_full = run.forecast(effects) if effects else base_full
    measured, base, extended = run.evaluate(raw), run.evaluate(base_full), run.evaluate(extended_full)
    scored = run.scored
    rmse_base, base_rmse, base_sse = forecast_errors(base, measured, m, scored)
    rmse_ext, ext_rmse, ext_sse = forecast_errors(extended, measured, m, scored)
    base_raw = forecast_errors(base_full, raw, m, scored)[1]
    ext_raw = forecast_errors(extended_full, raw, m, scored)[1]
    found = bool(effects)
    gain = 1.0 - ext_rmse / base_rmse if found and base_rmse > 0 else 0.0
    effect_gains = _effect_gains(run, measured, base_rmse, gain)
    floor = forecast_floor(
        diagnosis,
        float(run.scale),
        dt=run.dt,
        dx=run.dx,
        held_out=raw.shape[0],
        window=run.window,
        assimilated=run.assimilated,
    )
    n_frames = run.video.shape[0]
    centres = (
        torch.arange(split + 1, n_frames - run.window + 1, dtype=_F64, device="cpu") + (run.window - 1) / 2
    )
    return GainResult(
        diagnosis=diagnosis,
        split=split,
        effects=effects,
        base_a=diagnosis.a_plain,
        extended_a=diagnosis.base,
        times=centres * run.dt,
        rmse_base=rmse_base,
        rmse_extended=rmse_ext,
        base_rmse=base_rmse,
        extended_rmse=ext_rmse,
        base_sse=base_sse,
        extended_sse=ext_sse,
        gain=gain,
        noise_floor=floor,
        predicted_base=base,
        predicted_extended=extended,
        measured=measured,
        margin=m,
        scale_px=float(run.scale),
        base_rmse_raw=base_raw,
        extended_rmse_raw=ext_raw,
        gain_raw=1.0 - ext_raw / base_raw if found and base_raw > 0 else 0.0,
        noise_floor_raw=float(diagnosis.noise_sd),
        gain_above_floor=gain_above_floor(base_rmse, ext_rmse, floor) if found else 0.0,
        effect_gains=effect_gains,
        time_window=run.window,
        assimilated=run.assimilated,
        elapsed=time.perf_counter() - tick,
        warnings=_warnings(run, ext_rmse, floor),
        scored=scored,
    )


def _warnings(run: _Forecasts, rmse: float, floor: float) -> tuple[str, ...]:
    """The final model's flags: its diffusivity's plausibility; does it explain the held-out frames?"""
    a, plain = run.diagnosis.base, run.diagnosis.a_plain
    names = [e.name for e in run.effects]
    extended = extended_diffusivity_warning(a, plain, names) if run.effects else None
    # A plausible plain a with an implausible extended one is the effects' doing, not a unit mix-up.
    used = a if run.effects else plain
    found = [extended] if extended else diffusivity_warnings(used, dt=run.dt, dx=run.dx)
    failure = model_failure(rmse, floor)
    return tuple(found + ([failure] if failure else []))


def _effect_gains(run: _Forecasts, measured: Tensor, base_rmse: float, gain: float) -> tuple[float, ...]:
    """Each effect's own gain: what the extended model loses without it, ``(rmse_without_it -
    rmse_extended) / base_rmse``; the whole gain for one effect.

    Judged inside the model, not alone: an effect that completes a dominant one (the anisotropy of a plate
    cooling into depth) forecasts worse alone than the plain model, yet the model needs it. Above 1 when
    the model without the effect forecasts worse than the plain one.
    """
    if len(run.effects) <= 1:
        return (gain,) if run.effects else ()
    if base_rmse <= 0:
        return tuple(0.0 for _ in run.effects)
    extended_rmse = (1.0 - gain) * base_rmse
    gains = []
    for effect in run.effects:
        others = tuple(e for e in run.effects if e is not effect)
        without = run.evaluate(run.forecast(others))
        rmse = forecast_errors(without, measured, run.diagnosis.margin, run.scored)[1]
        gains.append((rmse - extended_rmse) / base_rmse)
    return tuple(gains)
