"""Does a diagnosed effect predict the future? Forecast held-out frames with and without it.

:func:`anra_torch.selection.diagnose_terms` selects effects from how well the PDE balances on the frames.
This module asks the question a user cares about: simulate forward
(:func:`anra_torch.effects.simulate_effects`, RK4, zero-flux edges) from the measured frames with the plain
heat equation (``a_plain``) and with the extended model (``base`` plus the effects found), and compare
both forecasts with frames the diagnosis never saw. The split: the diagnosis uses frames ``0 .. s``
(``s + 1 = round(fit_fraction T)`` frames); both models start at frame ``s`` (the split index) and
predict frames ``s + 1 .. T - 1``.

Both forecasts start from the state each model makes of the fit part (**assimilation**): the running mean,
frame by frame over the fit part's last ``assimilate`` frames (default all of them), of the model's
one-frame forecast of the running state and the measured frame,
``x_k = k / (k + 1) M(x_{k-1}) + y_k / (k + 1)``. For a linear model ``M`` this is exactly the mean of the
forecasts started from each of those frames, ``mean_j M^j y_{s-j}``: the measured frames' noise is averaged
(the split frame alone carried most of the noise floor into a forecast of 1-2 s), while a model that
describes the fit part follows the field without lag. A model that does not describe it carries its
error into the state, which is its forecast error too. (A least-squares line in time through the last 15
frames also averaged noise, but lagged wherever the field curves in time: fast sources and advection
were forecast worse.) ``assimilate=1`` starts both forecasts from the measured split frame.

Errors are taken on the interior (``diagnosis.margin`` px from each edge are left out: there the zero-flux
boundary is an assumption, not a measurement) and at the **evaluation scale**: the spatial Gaussian the
diagnosis identified the model at (``diagnosis.smoothing`` px, or ``scale_px``), then a moving average of
:data:`TIME_WINDOW` frames in time, applied in the same way to the forecasts and to the held-out frames.
The forecasts are simulated at full resolution and smoothed afterwards: a heterogeneous, nonlinear or
forced model does not commute with the smoothing, so smoothing the initial state instead would make even
the true model miss. Smoothing both sides leaves the model error (slow in time, smooth in space) while it
removes most of the white sensor noise, which no model can forecast. The noise floor is the RMSE a
perfect model would reach at that scale: the smoothed, averaged noise of the held-out frames plus the
noise of the assimilated state carried forward by the plain model's heat kernel.
The same quantities against the raw frames (the same forecasts unsmoothed, noise floor = sensor sd)
are kept as ``*_raw``: there the noise caps the gain: a model error ``e`` against noise ``sd`` gives at most
``1 - sd / sqrt(sd^2 + e^2)``.

Measured with ``python experiments/diagnosis_benchmark.py`` (README): see its table.
About 1-5 s per video on one core.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from anra_torch.effects import EFFECTS, Effect, simulate_effects
from anra_torch.layers.derivatives import GaussianSmoothing, TimeDerivative
from anra_torch.layers.stencils import gaussian_taps
from anra_torch.selection import Diagnosis, diagnose_terms

__all__ = [
    "AT_FLOOR",
    "TIME_WINDOW",
    "GainResult",
    "assess_gain",
    "assimilated_state",
    "extended_effects",
    "simulate_model",
]

_F64 = torch.float64

TIME_WINDOW = 9
"""Frames of the moving average in time at the evaluation scale (at most the held-out frames)."""


def extended_effects(
    diagnosis: Diagnosis,
    *,
    fit_duration: float | None = None,
    start: float = 0.0,
    duration: float | None = None,
) -> tuple[Effect, ...]:
    """The diagnosed effects as :class:`anra_torch.effects.Effect` objects for :func:`simulate_effects`.

    The base diffusivity is not an effect: pass ``diagnosis.base`` as ``a`` (it is ignored by the
    simulator when an effect replaces the diffusion term). Derived values (anisotropy's ``angle_deg``,
    ``ratio``) are dropped; every other parameter already has the simulator's name and unit (positions
    in mm on the same pixel-centre grid, the anisotropy tensor ``a_x, a_y, a_xy``, the heterogeneity
    disc ``x, y, radius`` with the same tanh edge).

    A source moves along its path over the diagnosed video's duration. To simulate another time span,
    give ``fit_duration`` (s, the diagnosed video's ``(T - 1) dt``), ``start`` (s, the simulation's first
    frame, from the diagnosed video's first frame) and ``duration`` (s, the simulation's
    ``(n_frames - 1) dt``): the path is re-timed so that the source is where the diagnosed (linear)
    motion puts it at those times, extrapolated beyond the diagnosed video.

    Args:
        diagnosis: from :func:`anra_torch.selection.diagnose_terms`.
        fit_duration: length of the diagnosed video in s (needed only for re-timing).
        start: time of the simulation's first frame in s.
        duration: length of the simulation in s; None keeps the diagnosed timing.

    Returns:
        The effects in the diagnosis' order (best score first).

    Raises:
        ValueError: an effect name the simulator does not know, parameters that do not map (missing,
            unknown, non-finite or unphysical values), or re-timing without ``fit_duration``.

    Shape:
        No tensors.
    """
    retime = duration is not None or start != 0.0
    if retime and (fit_duration is None or not (math.isfinite(fit_duration) and fit_duration > 0)):
        raise ValueError(
            f"fit_duration must be a positive number of s to re-time the effects to start={start!r} s, "
            f"duration={duration!r} s, got {fit_duration!r}"
        )
    effects = []
    for record in diagnosis.effects:
        name = record["name"]
        if name not in EFFECTS:
            raise ValueError(
                f"diagnosed effect {name!r} has no simulator; expected one of: {', '.join(EFFECTS)}"
            )
        spec = EFFECTS[name]
        params = {k: float(v) for k, v in record["params"].items() if k not in spec.derived_units}
        if retime and spec.retime is not None:
            params = spec.retime(params, fit_duration, start, duration)  # type: ignore[arg-type]
        try:
            effects.append(Effect(name, params))
        except (TypeError, ValueError) as err:
            raise ValueError(f"diagnosed effect {name!r} cannot be simulated: {err}") from err
    return tuple(effects)


def simulate_model(
    initial: Tensor,
    diagnosis: Diagnosis,
    *,
    dt: float,
    dx: float,
    n_frames: int,
    effects: tuple[Effect, ...] | None = None,
) -> Tensor:
    """Forecast ``n_frames`` frames from ``initial`` with the diagnosis' model (zero-flux edges).

    Args:
        initial: the measured first frame.
        diagnosis: gives ``a`` (``base``, or ``a_plain`` when ``effects`` is empty; a negative ``a``,
            which the plain fit gives when a source dominates, is simulated as 0).
        dt: frame period in s.
        dx: pixel size in mm.
        n_frames: frames to return, ``initial`` included.
        effects: the effects to include (already re-timed); None: all of :func:`extended_effects`.

    Returns:
        The forecast in float64.

    Shape:
        ``initial`` ``(H, W)``; output ``(n_frames, H, W)``.
    """
    chosen = extended_effects(diagnosis) if effects is None else tuple(effects)
    a = diagnosis.base if chosen else diagnosis.a_plain
    return simulate_effects(
        initial.to(_F64), a=max(a, 0.0), dx=dx, dt=dt, n_frames=n_frames, effects=chosen, boundary="neumann"
    )


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
        effect_gains: each effect's own gain, ``1 - rmse_with_it_alone / base_rmse`` (evaluation scale),
            in the order of ``effects`` (the whole gain when there is one effect).
        gain_above_floor: the fraction of the plain model's error above the noise floor that the
            extension removes, ``1 - e_extended / e_base`` with ``e = sqrt(max(rmse^2 - floor^2, 0))``
            (evaluation scale); 0 when no effect was found or when the plain forecast is within
            :data:`AT_FLOOR` of the floor (nothing measurable to gain).
        elapsed: seconds spent (diagnosis and both simulations).
        time_window: frames of the moving average in time at the evaluation scale (1: none).
        assimilated: the fit part's last frames assimilated into both forecasts' starting states (1: the
            measured split frame).

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

    @property
    def held_out(self) -> int:
        """Number of held-out frames forecast."""
        return self.measured.shape[0] + self.time_window - 1


def _interior(video: Tensor, margin: int) -> Tensor:
    return video[..., margin : video.shape[-2] - margin, margin : video.shape[-1] - margin]


AT_FLOOR = 1.1
"""A plain forecast whose RMSE is below ``AT_FLOOR`` times the noise floor has no measurable model error:
on the 20 pure heat-transfer videos of ``experiments/diagnosis_benchmark.py`` the ratio is 0.96-1.11, median
1.00 (``base_over_floor`` in its ``results.json``; assimilated starting state, 9-frame average in time)."""


def _gain_above_floor(base_rmse: float, extended_rmse: float, floor: float) -> float:
    """``1 - e_extended / e_base`` with ``e = sqrt(max(rmse^2 - floor^2, 0))``; 0 at the floor."""
    if base_rmse < AT_FLOOR * floor:
        return 0.0
    excess_base = math.sqrt(base_rmse**2 - floor**2)
    excess_ext = math.sqrt(max(extended_rmse**2 - floor**2, 0.0))
    return 1.0 - excess_ext / excess_base


def _white_gain(sigma_px: float) -> float:
    """Variance factor of white noise through a 2-D Gaussian of ``sigma_px`` (sum of squared weights)."""
    return float(gaussian_taps(sigma_px).pow(2).sum()) ** 2


def _forecast_floor(
    diagnosis: Diagnosis,
    scale_px: float,
    *,
    dt: float,
    dx: float,
    held_out: int,
    window: int,
    assimilated: int = 1,
) -> float:
    """RMSE of a perfect model at the evaluation scale over the held-out frames, data units.

    A perfect model is wrong by the held-out frames' noise, smoothed by the Gaussian and averaged over
    ``window`` frames (variance ``sd^2 |g|^2 / window``), plus the noise of its starting state carried
    forward by the plain model, a heat kernel that widens the Gaussian to ``sigma^2 = scale^2 + 2 a t / dx^2``
    px^2 after ``t`` s (variance ``sd^2 |g_t|^2``, ``t`` at each window's centre). The assimilated state
    is the mean of ``assimilated`` forecasts started ``0 .. assimilated - 1`` frames before the split, each
    from a frame with its own noise: variance ``sd^2 / n^2 sum_j |g_(t + j dt)|^2``. The parts are
    independent. ``|g|^2`` is the exact sum of squared weights of the sampled Gaussian. Checked against the
    forecast RMSE of pure heat-transfer videos (tests).
    """
    sd = float(diagnosis.noise_sd)
    spread = 2.0 * max(float(diagnosis.a_plain), 0.0) * dt / dx**2  # px^2 per frame
    centres = [j + 1 + (window - 1) / 2 for j in range(held_out - window + 1)]  # frames after the split
    gains: dict[float, float] = {}  # the ages (frames) repeat across windows and starts

    def carried(age: float) -> float:
        if age not in gains:
            gains[age] = _white_gain(math.sqrt(scale_px**2 + spread * age))
        return gains[age]

    per_window = [sum(carried(k + j) for j in range(assimilated)) / assimilated**2 for k in centres]
    return sd * math.sqrt(_white_gain(scale_px) / window + sum(per_window) / len(per_window))


def _frame_count(value: object, name: str, default: int, available: int, *, cap: bool = True) -> int:
    """``value`` checked against 1 .. ``available``; None: ``default`` (capped at half of ``available``
    when ``cap``)."""
    if value is None:
        return max(1, min(default, available // 2)) if cap else default
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= available:
        raise ValueError(f"{name} must be an integer from 1 to {available} frames, got {value!r}")
    return value


def assimilated_state(fit_frames: Tensor, step: Callable[[int, Tensor], Tensor], frames: int) -> Tensor:
    """A model's state at the last fit frame from the last ``frames`` measured frames (module docs).

    ``x_0 = y_0``, then ``x_k = k / (k + 1) step(x_(k-1)) + y_k / (k + 1)`` over the last ``frames`` frames
    ``y``: for a linear ``step`` the mean of the forecasts started from each of them.

    Args:
        fit_frames: the fit part, frames ``0 .. s``.
        step: ``(index of the frame the state is at, state) -> the state one frame later``.
        frames: how many of the last frames to assimilate (1: the last frame itself).

    Shape:
        ``fit_frames`` ``(s + 1, H, W)``; output ``(H, W)``.
    """
    first = fit_frames.shape[0] - frames
    state = fit_frames[first]
    for k in range(1, frames):  # sequential by nature: each state is the next one's start
        state = step(first + k - 1, state) * (k / (k + 1)) + fit_frames[first + k] / (k + 1)
    return state


def time_average(frames: Tensor, window: int) -> Tensor:
    """Moving average of ``window`` frames (only full windows); the frames themselves at 1.

    Shape:
        ``(K, H, W)`` -> ``(K - window + 1, H, W)``.
    """
    if window == 1:
        return frames
    return frames.unfold(0, window, 1).mean(-1)


def check_diagnosis_frames(diagnosis: Diagnosis, height: int, width: int) -> None:
    """Raise a one-line ``ValueError`` unless ``diagnosis`` was made on ``height`` x ``width`` px frames."""
    m = diagnosis.margin
    if tuple(diagnosis.residual_map.shape) != (height - 2 * m, width - 2 * m):
        raise ValueError(
            "diagnosis was made on frames of another size: residual map "
            f"{tuple(diagnosis.residual_map.shape)} with margin {m} px, frames {height} x {width} px"
        )


def evaluation_scale(diagnosis: Diagnosis, scale_px: float | None) -> float:
    """The evaluation scale in px: ``scale_px``, or the diagnosis' smoothing when None.

    Raises:
        ValueError: a ``scale_px`` that is not a finite number >= 0.
    """
    return check_scale(float(diagnosis.smoothing) if scale_px is None else scale_px)


def check_scale(scale_px: object) -> float:
    """``scale_px`` as a float, checked: a Gaussian sigma >= 0 in px (0: raw frames).

    Raises:
        ValueError: not a finite number >= 0.
    """
    number = isinstance(scale_px, int | float) and not isinstance(scale_px, bool)
    if not (number and math.isfinite(scale_px) and scale_px >= 0):
        raise ValueError(f"scale_px must be a Gaussian sigma >= 0 in px, got {scale_px!r}")
    return float(scale_px)


def at_scale(frames: Tensor, scale_px: float) -> Tensor:
    """Frames smoothed by a Gaussian of ``scale_px`` (reflecting edges); the frames themselves at 0.

    Shape:
        ``frames`` ``(K, H, W)``; output the same.
    """
    return frames if scale_px == 0 else GaussianSmoothing(scale_px, border="reflect")(frames)


def forecast_errors(predicted: Tensor, measured: Tensor, margin: int) -> tuple[Tensor, float, float]:
    """Per-frame RMSE ``(K,)``, overall RMSE and sum of squared errors on the interior.

    Shape:
        ``predicted``, ``measured`` ``(K, H, W)``.
    """
    diff = _interior(predicted, margin) - _interior(measured, margin)
    squared = diff.pow(2)
    per_frame = squared.mean((-2, -1)).sqrt()
    return per_frame, float(squared.mean().sqrt()), float(squared.sum())


def split_index(n_frames: int, fit_fraction: float) -> int:
    """Index of the fit part's last frame (``round(fit_fraction T) - 1``), validated.

    Raises:
        ValueError: ``fit_fraction`` outside (0, 1), or a fit part shorter than the diagnosis needs or
            fewer than 2 held-out frames.
    """
    if not (isinstance(fit_fraction, int | float) and 0 < fit_fraction < 1):
        raise ValueError(f"fit_fraction must be a number in (0, 1), got {fit_fraction!r}")
    need = TimeDerivative("smooth").length
    n_fit = round(fit_fraction * n_frames)
    if n_fit < need or n_frames - n_fit < 2:
        raise ValueError(
            f"video too short to split at fit_fraction={fit_fraction:g}: {n_frames} frames give {n_fit} to "
            f"diagnose (need >= {need}) and {n_frames - n_fit} held out (need >= 2); use a longer video or "
            "another fit_fraction"
        )
    return n_fit - 1


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
        time_window: frames of the moving average in time at the evaluation scale (1: none); default
            :data:`TIME_WINDOW`, at most half the held-out frames. Use 1 for videos whose frames are
            seconds apart, where a few frames already span the dynamics.
        assimilate: the fit part's last frames assimilated into each model's starting state (module docs);
            1 starts from the measured split frame; default all the fit part's frames.

    Returns:
        :class:`GainResult`.

    Raises:
        ValueError: too short a video for the split (see :func:`split_index`), bad frames or spacing,
            or no thermal activity (from :func:`anra_torch.selection.diagnose_terms`); a diagnosis whose
            residual map does not fit the frame size; a negative or non-finite ``scale_px``; a
            ``time_window`` that is not an integer from 1 to the number of held-out frames, or an
            ``assimilate`` that is not one from 1 to the fit part's frames.

    Shape:
        ``frames`` ``(T, H, W)``.

    Example:
        >>> from anra_torch.effects import hidden_effect_video
        >>> video = hidden_effect_video(["advection"], seed=0, size=64, duration=3.0)
        >>> result = assess_gain(video.frames, video.dt, video.dx)
        >>> [e.name for e in result.effects], round(result.gain, 2)
        (['advection'], 0.99)
    """
    import time

    tick = time.perf_counter()
    if not isinstance(frames, Tensor):
        frames = torch.as_tensor(frames)
    if frames.ndim != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {tuple(frames.shape)}")
    video = frames.detach().to(_F64)
    n_frames, h, w = video.shape
    split = split_index(n_frames, fit_fraction)
    if diagnosis is None:
        diagnosis = diagnose_terms(video[: split + 1], dt, dx)
    else:
        check_diagnosis_frames(diagnosis, h, w)
    fit_duration = split * dt
    horizon = n_frames - split
    effects = extended_effects(
        diagnosis, fit_duration=fit_duration, start=fit_duration, duration=(horizon - 1) * dt
    )
    scale = evaluation_scale(diagnosis, scale_px)
    m = diagnosis.margin
    held_out = horizon - 1
    window = _frame_count(time_window, "time_window", TIME_WINDOW, held_out)

    n_assimilated = _frame_count(assimilate, "assimilate", split + 1, split + 1, cap=False)

    def forecast(chosen: tuple[Effect, ...]) -> Tensor:  # from the assimilated state, full resolution
        names = {effect.name for effect in chosen}

        def step(frame: int, state: Tensor) -> Tensor:  # one frame ahead from frame ``frame``
            retimed = extended_effects(diagnosis, fit_duration=fit_duration, start=frame * dt, duration=dt)
            effects_now = tuple(e for e in retimed if e.name in names)
            return simulate_model(state, diagnosis, dt=dt, dx=dx, n_frames=2, effects=effects_now)[1]

        initial = assimilated_state(video[: split + 1], step, n_assimilated)
        return simulate_model(initial, diagnosis, dt=dt, dx=dx, n_frames=horizon, effects=chosen)[1:]

    def evaluate(frames_: Tensor) -> Tensor:
        return time_average(at_scale(frames_, scale), window)

    raw = video[split + 1 :]
    base_full = forecast(())
    extended_full = forecast(effects) if effects else base_full
    measured, base, extended = evaluate(raw), evaluate(base_full), evaluate(extended_full)
    rmse_base, base_rmse, base_sse = forecast_errors(base, measured, m)
    rmse_ext, ext_rmse, ext_sse = forecast_errors(extended, measured, m)
    base_raw = forecast_errors(base_full, raw, m)[1]
    ext_raw = forecast_errors(extended_full, raw, m)[1]
    found = bool(effects)
    gain = 1.0 - ext_rmse / base_rmse if found and base_rmse > 0 else 0.0
    effect_gains = [gain] if len(effects) == 1 else []
    for effect in effects if len(effects) > 1 else ():
        alone = evaluate(forecast((effect,)))
        effect_gains.append(
            1.0 - forecast_errors(alone, measured, m)[1] / base_rmse if base_rmse > 0 else 0.0
        )
    floor = _forecast_floor(
        diagnosis, float(scale), dt=dt, dx=dx, held_out=held_out, window=window, assimilated=n_assimilated
    )
    centres = torch.arange(split + 1, n_frames - window + 1, dtype=_F64) + (window - 1) / 2
    return GainResult(
        diagnosis=diagnosis,
        split=split,
        effects=effects,
        base_a=diagnosis.a_plain,
        extended_a=diagnosis.base,
        times=centres * dt,
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
        scale_px=float(scale),
        base_rmse_raw=base_raw,
        extended_rmse_raw=ext_raw,
        gain_raw=1.0 - ext_raw / base_raw if found and base_raw > 0 else 0.0,
        noise_floor_raw=float(diagnosis.noise_sd),
        gain_above_floor=_gain_above_floor(base_rmse, ext_rmse, floor) if found else 0.0,
        effect_gains=tuple(effect_gains),
        time_window=window,
        assimilated=n_assimilated,
        elapsed=time.perf_counter() - tick,
    )
