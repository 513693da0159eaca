"""What every forecast of held-out frames shares: the split, the assimilation, the evaluation scale, the
errors, the noise floor and the diagnosed model as effects.

:func:`anra_torch.forecast.assess_gain` forecasts the plain and the extended model,
:func:`anra_torch.forecast.source_map_gain` the source map and :func:`anra_torch.forecast.refine_model`
compares a simulation with the frames it was fitted to; all three go through the functions here, so that
their numbers compare like with like.

**Split.** The diagnosis uses frames ``0 .. s`` (``s + 1 = round(fit_fraction T)`` frames,
:func:`split_index`); every forecast starts at frame ``s`` (the split index) and predicts frames
``s + 1 .. T - 1``.

**Assimilation.** A forecast starts from the state its model makes of the fit part
(:func:`assimilated_state`): the running mean, frame by frame over the fit part's last ``assimilate`` frames
(default all of them), of the model's one-frame forecast of the running state and the measured frame,
``x_k = k / (k + 1) M(x_{k-1}) + y_k / (k + 1)``. For a linear model ``M`` this is exactly the mean of the
forecasts started from each of those frames, ``mean_j M^j y_{s-j}``: the measured frames' noise is averaged
(the split frame alone carried most of the noise floor into a forecast of 1-2 s), while a model that
describes the fit part follows the field without lag. A model that does not describe it carries its
error into the state, which is its forecast error too. (A least-squares line in time through the last 15
frames also averaged noise, but lagged wherever the field curves in time: fast sources and advection
were forecast worse.) ``assimilate=1`` starts the forecast from the measured split frame.

**Boundary.** A camera's frame edge is not insulated: heat crosses it, and only the measured frames say
how much. Every forecast's outermost pixel ring follows the measured frames (linearly in time between
them), a measured Dirichlet boundary for the pixels inside; the plain and the extended model share it.
(Zero-flux edges kept heat in that left a flash plate's 20 mm frame within seconds: effects acting near
the edges got own gains at or below zero.)

**Evaluation scale.** Errors are taken on the interior (``diagnosis.margin`` px from each edge are left out:
there the measured ring's noise and the filters' reach dominate, :func:`forecast_errors`) and at the
evaluation scale: the spatial Gaussian the diagnosis identified the model at (``diagnosis.smoothing`` px, or
``scale_px``, :func:`at_scale`), then a moving average of :data:`TIME_WINDOW` frames in time
(:func:`time_average`), applied in the same way to the forecasts and to the held-out frames. The forecasts
are simulated at full resolution and smoothed afterwards: a heterogeneous, nonlinear or forced model does
not commute with the smoothing, so smoothing the initial state instead would make even the true model miss.
Smoothing both sides leaves the model error (slow in time, smooth in space) while it removes most of the
white sensor noise, which no model can forecast.

**Noise floor.** The RMSE a perfect model would reach at that scale (:func:`forecast_floor`): the smoothed,
averaged noise of the held-out frames plus the noise of the assimilated state carried forward by the plain
model's heat kernel. Against the raw frames (the same forecasts unsmoothed) the floor is the sensor sd, and
the noise caps the gain: a model error ``e`` against noise ``sd`` gives at most ``1 - sd / sqrt(sd^2 + e^2)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from anra_torch.effects import EFFECTS, Effect, simulate_effects
from anra_torch.layers import GaussianSmoothing, TimeDerivative, gaussian_taps
from anra_torch.selection import Diagnosis

__all__ = [
    "AT_FLOOR",
    "DIAGNOSED_FRAMES",
    "INNER_SPLITS",
    "TIME_WINDOW",
    "assimilated_state",
    "at_scale",
    "check_diagnosis_frames",
    "check_scale",
    "evaluation_scale",
    "extended_effects",
    "forecast_errors",
    "forecast_floor",
    "gain_above_floor",
    "interior",
    "simulate_model",
    "split_index",
    "time_average",
]

_F64 = torch.float64

DIAGNOSED_FRAMES = TimeDerivative("smooth").length
"""The fewest frames a diagnosis needs: the length of its time filter."""

INNER_SPLITS = (0.0, 0.1, 0.2)
"""Inner fit fractions of a comparison inside the fit frames, added to the first (a phase's fit fraction, or
the frames a diagnosis needs): one split's validation frames are few and a model can win it by chance (a
sparse cooling chose a map at +0.02 held out where the average over three splits chose one at +0.49)."""

TIME_WINDOW = 9
"""Frames of the moving average in time at the evaluation scale (at most the held-out frames)."""

AT_FLOOR = 1.1
"""A plain forecast whose RMSE is below ``AT_FLOOR`` times the noise floor has no measurable model error:
on the 20 pure heat-transfer videos of ``experiments/diagnosis_benchmark.py`` the ratio is 0.96-1.10, median
1.01 (``base_over_floor`` in its ``results.json``; assimilated starting state, 9-frame average in time,
measured-edge forecasts)."""


def split_index(n_frames: int, fit_fraction: float) -> int:
    """Index of the fit part's last frame (``round(fit_fraction T) - 1``), validated.

    Raises:
        ValueError: ``fit_fraction`` outside (0, 1), or a fit part shorter than the diagnosis needs or
            fewer than 2 held-out frames.

    Shape:
        No tensors.
    """
    if not (isinstance(fit_fraction, int | float) and 0 < fit_fraction < 1):
        raise ValueError(f"fit_fraction must be a number in (0, 1), got {fit_fraction!r}")
    n_fit = round(fit_fraction * n_frames)
    if n_fit < DIAGNOSED_FRAMES or n_frames - n_fit < 2:
        raise ValueError(
            f"video too short to split at fit_fraction={fit_fraction:g}: {n_frames} frames give {n_fit} to "
            f"diagnose (need >= {DIAGNOSED_FRAMES}) and {n_frames - n_fit} held out (need >= 2); use a "
            "longer video or another fit_fraction"
        )
    return n_fit - 1


def check_diagnosis_frames(diagnosis: Diagnosis, height: int, width: int) -> None:
    """Raise a one-line ``ValueError`` unless ``diagnosis`` was made on ``height`` x ``width`` px frames.

    Shape:
        No tensors (``diagnosis.residual_map`` is ``(height - 2 margin, width - 2 margin)``).
    """
    m = diagnosis.margin
    if tuple(diagnosis.residual_map.shape) != (height - 2 * m, width - 2 * m):
        raise ValueError(
            "diagnosis was made on frames of another size: residual map "
            f"{tuple(diagnosis.residual_map.shape)} with margin {m} px, frames {height} x {width} px"
        )


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
            raise _unphysical(f"diagnosed effect {name!r} cannot be simulated: {err}") from err
    return tuple(effects)


def _unphysical(reason: str) -> ValueError:
    """The error for a diagnosed model that cannot be simulated: it is about the input, not the code."""
    return ValueError(
        f"the frames do not behave like physical heat transfer: {reason}; check the input (frames in "
        "reverse time order, an unmodelled source, corrupt samples, wrong dt or dx)"
    )


def simulate_model(
    initial: Tensor,
    diagnosis: Diagnosis,
    *,
    dt: float,
    dx: float,
    n_frames: int,
    effects: tuple[Effect, ...] | None = None,
    edges: Tensor | None = None,
    forcing: Tensor | None = None,
) -> Tensor:
    """Forecast ``n_frames`` frames from ``initial`` with the diagnosis' model, bounded by measured edges.

    Args:
        initial: the measured first frame.
        diagnosis: gives ``a`` (``base``, or ``a_plain`` when ``effects`` is empty; a negative ``a``,
            which the plain fit gives when a source dominates, is simulated as 0).
        dt: frame period in s.
        dx: pixel size in mm.
        n_frames: frames to return, ``initial`` included.
        effects: the effects to include (already re-timed); None: all of :func:`extended_effects`.
        edges: the measured frames of the forecast's span; their outermost pixel ring is the forecast's
            boundary (:func:`anra_torch.effects.simulate_effects`). None: zero-flux edges.
        forcing: a stationary heat input ``(H, W)`` in data units per s added to the model (None: none).

    Returns:
        The forecast in float64.

    Shape:
        ``initial`` ``(H, W)``; ``edges`` ``(n_frames, H, W)``; output ``(n_frames, H, W)``.

    Raises:
        ValueError: a model that cannot be simulated (e.g. a fitted ``a(T)`` negative over the video's
            temperatures), worded as what it says about the frames.
    """
    chosen = extended_effects(diagnosis) if effects is None else tuple(effects)
    a = diagnosis.base if chosen else diagnosis.a_plain
    try:
        return simulate_effects(
            initial.to(_F64),
            a=max(a, 0.0),
            dx=dx,
            dt=dt,
            n_frames=n_frames,
            effects=chosen,
            edges=edges,
            forcing=forcing,
        )
    except ValueError as err:  # e.g. a fitted a(T) that turns negative over the video's temperatures
        raise _unphysical(f"the diagnosed model cannot be simulated: {err}") from err


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


def check_scale(scale_px: object) -> float:
    """``scale_px`` as a float, checked: a Gaussian sigma >= 0 in px (0: raw frames).

    Raises:
        ValueError: not a finite number >= 0.

    Shape:
        No tensors.
    """
    number = isinstance(scale_px, int | float) and not isinstance(scale_px, bool)
    if not (number and math.isfinite(scale_px) and scale_px >= 0):
        raise ValueError(f"scale_px must be a Gaussian sigma >= 0 in px, got {scale_px!r}")
    return float(scale_px)


def evaluation_scale(diagnosis: Diagnosis, scale_px: float | None) -> float:
    """The evaluation scale in px: ``scale_px``, or the diagnosis' smoothing when None.

    Raises:
        ValueError: a ``scale_px`` that is not a finite number >= 0.

    Shape:
        No tensors.
    """
    return check_scale(float(diagnosis.smoothing) if scale_px is None else scale_px)


def at_scale(frames: Tensor, scale_px: float) -> Tensor:
    """Frames smoothed by a Gaussian of ``scale_px`` (reflecting edges); the frames themselves at 0.

    Shape:
        ``frames`` ``(K, H, W)``; output the same.
    """
    return frames if scale_px == 0 else GaussianSmoothing(scale_px, border="reflect")(frames)


def time_average(frames: Tensor, window: int) -> Tensor:
    """Moving average of ``window`` frames (only full windows); the frames themselves at 1.

    Shape:
        ``(K, H, W)`` -> ``(K - window + 1, H, W)``.
    """
    if window == 1:
        return frames
    return frames.unfold(0, window, 1).mean(-1)


def interior(video: Tensor, margin: int) -> Tensor:
    """The frames without ``margin`` px at each edge (the forecasts' boundary ring and the filters' reach).

    Shape:
        ``(..., H, W)`` -> ``(..., H - 2 margin, W - 2 margin)``.
    """
    return video[..., margin : video.shape[-2] - margin, margin : video.shape[-1] - margin]


def forecast_errors(
    predicted: Tensor,
    measured: Tensor,
    margin: int,
    scored: Tensor | None = None,
    *,
    within_frames: bool = False,
    within_pixels: bool = False,
) -> tuple[Tensor, float, float]:
    """Per-frame RMSE ``(K,)``, overall RMSE and sum of squared errors on the interior (:func:`interior`).

    Args:
        predicted: a forecast, in data units.
        measured: the frames it forecasts, in the same units and at the same scale.
        margin: pixels left out at each edge.
        scored: which frames count in the overall RMSE and sum (the measured samples of a recording
            resampled from irregular times, not the frames interpolated between them); None: all.
        within_frames: score each frame's errors about their mean (per-frame fixed effects: a global
            offset of the camera, which no model forecasts, left out).
        within_pixels: score each pixel's errors about their mean over the frames (per-pixel fixed effects:
            a camera's static pattern, which no model forecasts, left out).

    Returns:
        RMSE per frame (data units, every frame), RMSE over the scored frames (data units), sum of squared
        errors over them (data units^2).

    Raises:
        ValueError: ``scored`` of another length than the frames, or scoring no frame.

    Shape:
        ``predicted``, ``measured`` ``(K, H, W)``; ``scored`` ``(K,)`` bool.
    """
    diff = interior(predicted, margin) - interior(measured, margin)
    if within_pixels:
        diff = diff - diff.mean(0, keepdim=True)
    if within_frames:
        diff = diff - diff.mean((-2, -1), keepdim=True)
    squared = diff.pow(2)
    per_frame = squared.mean((-2, -1)).sqrt()
    if scored is not None:
        scored = torch.as_tensor(scored, dtype=torch.bool, device=per_frame.device)
        if scored.shape != per_frame.shape or not bool(scored.any()):
            raise ValueError(
                f"scored must mark at least one of the {per_frame.numel()} forecast frames, got "
                f"{int(scored.sum())} of {scored.numel()}: no measured sample among the held-out frames"
            )
        squared = squared[scored]
    return per_frame, float(squared.mean().sqrt()), float(squared.sum())


def _white_gain(sigma_px: float) -> float:
    """Variance factor of white noise through a 2-D Gaussian of ``sigma_px`` (sum of squared weights)."""
    return float(gaussian_taps(sigma_px).pow(2).sum()) ** 2


def forecast_floor(
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

    Args:
        diagnosis: gives the noise sd (data units) and the plain diffusivity ``a_plain`` (mm^2/s).
        scale_px: the evaluation scale, a Gaussian sigma in px (0: raw frames).
        dt: frame period in s.
        dx: pixel size in mm.
        held_out: frames forecast.
        window: frames of the moving average in time.
        assimilated: frames assimilated into the starting state.

    Returns:
        The floor in data units.

    Shape:
        No tensors.
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


def gain_above_floor(base_rmse: float, extended_rmse: float, floor: float) -> float:
    """The fraction of the plain forecast's error above the noise floor that the extension removes.

    ``1 - e_extended / e_base`` with ``e = sqrt(max(rmse^2 - floor^2, 0))``; 0 when ``base_rmse`` is below
    :data:`AT_FLOOR` times the floor (nothing measurable to gain). All three in the same data units.

    Shape:
        No tensors.
    """
    if base_rmse < AT_FLOOR * floor:
        return 0.0
    excess_base = math.sqrt(base_rmse**2 - floor**2)
    excess_ext = math.sqrt(max(extended_rmse**2 - floor**2, 0.0))
    return 1.0 - excess_ext / excess_base
