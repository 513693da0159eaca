"""A stationary heat-input map: the extension for sources that are not Gaussian spots, e.g. a real beam.

The effect library's ``source`` is a Gaussian spot moving on a straight line. A measured beam (an
unfocused fibre tip, a heated stage seen through a window) has its own shape and stays put: fitting it with
a Gaussian leaves a dipole error that grows with the forecast, and extrapolating the spot's small fitted
drift moves it further. This module models the heat input by its map instead:

    dT/dt = a Lap T - b T + q(x, y)

``q`` (data units per s) is a per-pixel constant: the source's own map plus ``b T_ref(x, y)``, a loss
towards a reference that may vary in space (heat stored at depth under a spot relaxes the surface towards a
warmer local level). It is found without solving the PDE, by a fixed-effects regression at one spatial
scale:

1. the frames are smoothed by a Gaussian (the same on both sides of the PDE, so the smoothed field obeys
   the same linear equation);
2. ``U = (S[k+1] - S[k-1]) / (2 dt)``, the central time difference, is paired with ``S[k]`` and its
   5-point Laplacian at the same instant ``k`` (time alignment);
3. removing each pixel's time mean from ``U``, ``Lap S`` and ``S`` removes ``q``; least squares on the
   interior then gives ``a >= 0`` and ``b >= 0`` (the best non-negative pair), and ``q`` is the pixel's
   time mean of ``U - a Lap S + b S``.

A source over a thick body heats its surface ever more slowly: under a constant flux into a half-space
the surface rises like ``sqrt(t)``, its rate like ``t^(-1/2)``, and once heat spreads sideways as well the
rate falls faster (towards ``t^(-3/2)`` near a steady state). With ``decay`` = ``p`` the map's input is
``q(x, y) ((t - t_on) / (t_ref - t_on))^(-p)``: the fixed effect of step 3 is then each pixel's projection
on that profile, and ``q`` is the input at ``t_ref``, the fit part's last rate. ``p = 0`` is the stationary
map.

The map has one value per pixel and needs at least two rates (four frames) per pixel; within ``margin`` px
of the edges, where the filters do not reach, it repeats the nearest interior value (a zero there would pull
those pixels towards 0 through ``- b T``). :meth:`SourceMapModel.forecast` simulates it with
:func:`anra_torch.effects.simulate_effects`, bounded by the measured frame edges like every held-out
forecast.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance import MatchedFilters, Moments, accumulate
from anra_torch.checks import as_spacing, own_tensor
from anra_torch.effects import Effect, simulate_effects
from anra_torch.forecast.core import assimilated_state, at_scale, check_scale, forecast_errors, time_average
from anra_torch.forecast.gain import GainResult

__all__ = ["SourceMapGain", "SourceMapModel", "fit_source_map", "source_map_gain"]

_F64 = torch.float64


@dataclass(frozen=True)
class SourceMapModel:
    """``dT/dt = a Lap T - b T + q(x, y)`` fitted to a video at one spatial scale.

    Attributes:
        a: diffusivity in mm^2/s (>= 0).
        b: loss rate in 1/s (>= 0).
        forcing: the map ``q`` in data units per s; within ``margin`` px of the edges the nearest interior
            value.
        scale_px: the Gaussian sigma (px) the frames were smoothed by before the fit.
        margin: pixels left out at each edge.
        n_rates: time differences per pixel the fit used.
        decay: the power ``p`` of the input's decay in time (0: stationary).
        t_on: when the input started, s, on the clock of the fitted frames (frame ``k`` at ``k dt``).
        t_ref: the time at which the input is ``forcing``, s (the fit part's last rate).

    Shape:
        ``forcing`` ``(H, W)``.
    """

    a: float
    b: float
    forcing: Tensor
    scale_px: float
    margin: int
    n_rates: int
    decay: float = 0.0
    t_on: float = 0.0
    t_ref: float = 1.0

    def profile(self, t: float) -> float:
        """The input's time profile at ``t`` (s, the fitted frames' clock): 1 at ``t_ref``."""
        return _profile(t, self.decay, self.t_on, self.t_ref)

    @property
    def equilibrium(self) -> Tensor:
        """The temperature the model relaxes to without diffusion, ``q / b`` (data units; NaN if b = 0).

        Shape:
            ``(H, W)``.
        """
        return self.forcing / self.b if self.b > 0 else torch.full_like(self.forcing, math.nan)

    def forecast(
        self,
        initial: Tensor,
        *,
        dt: float,
        dx: float,
        n_frames: int,
        edges: Tensor | None = None,
        start: float = 0.0,
    ) -> Tensor:
        """Simulate ``n_frames`` frames from ``initial`` (frame 0 included), float64.

        ``edges``: measured frames over the same span whose outermost pixel ring bounds the forecast
        (:func:`anra_torch.effects.simulate_effects`); None: zero-flux edges. ``start``: the time of
        ``initial`` on the fitted frames' clock (s), for a decaying input (held over each frame interval at
        its value mid-interval).

        Shape:
            ``initial`` ``(H, W)``; ``edges`` ``(n_frames, H, W)``; output ``(n_frames, H, W)``.

        Raises:
            ValueError: a decaying input stepped over its switch-on (``start + dt / 2 <= t_on``), where
                ``(t - t_on)^-p`` is unbounded.
        """
        loss = (Effect("linear_loss", {"b": self.b, "T_ref": 0.0}),) if self.b > 0 else ()
        state = own_tensor(initial, _F64)
        if self.decay == 0.0:
            return simulate_effects(
                state,
                a=self.a,
                dx=dx,
                dt=dt,
                n_frames=n_frames,
                effects=loss,
                forcing=self.forcing,
                edges=edges,
            )
        if n_frames > 1 and not start + 0.5 * dt > self.t_on:
            raise ValueError(
                f"start must put the first interval's middle after the input's switch-on at t_on = "
                f"{self.t_on:g} s, got start = {start:g} s with dt = {dt:g} s: (t - t_on)^-{self.decay:g} is "
                "unbounded there"
            )
        frames = [state]
        for j in range(n_frames - 1):  # one interval at a time: the input changes between frames
            forcing = self.forcing * self.profile(start + (j + 0.5) * dt)
            span = None if edges is None else edges[j : j + 2]
            step = simulate_effects(
                frames[-1], a=self.a, dx=dx, dt=dt, n_frames=2, effects=loss, forcing=forcing, edges=span
            )
            frames.append(step[1])
        return torch.stack(frames)


def _nonnegative_pair(moments: Moments) -> tuple[float, float]:
    """Least squares ``U ~ a L - b T`` with ``a, b >= 0`` from the moments (two columns: try every face)."""
    sign = torch.tensor([1.0, -1.0], dtype=_F64, device=moments.raw.device)  # the columns are L and -T
    gram, cross = moments.normal_equations(("L", "T"))
    gram, cross = gram * sign[:, None] * sign[None, :], cross * sign
    total = float(moments.block(["U"], ["U"])[0, 0])
    best = (0.0, 0.0, total)
    for columns in ((0, 1), (0,), (1,)):
        index = list(columns)
        sub_gram, sub_cross = gram[index][:, index], cross[index]
        coef = torch.linalg.pinv(sub_gram) @ sub_cross
        if bool((coef < 0).any()) or not bool(torch.isfinite(coef).all()):
            continue
        sse = total - 2.0 * float(coef @ sub_cross) + float(coef @ sub_gram @ coef)
        if sse < best[2]:
            full = [0.0, 0.0]
            for i, c in zip(columns, coef.tolist(), strict=True):
                full[i] = c
            best = (full[0], full[1], sse)
    return best[0], best[1]


def _checked_frames(frames: Tensor) -> Tensor:
    """``frames`` as float64 ``(T, H, W)`` with at least 4 frames (2 rates)."""
    video = own_tensor(frames)
    if video.ndim != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {tuple(video.shape)}")
    if video.shape[0] < 4:
        raise ValueError(
            f"frames must hold at least 4 frames for a per-pixel source map (2 rates), got {video.shape[0]}"
        )
    return video.to(_F64)


def _terms(video: Tensor, dt: float, dx: float, scale_px: float, margin: int) -> dict[str, Tensor]:
    """``U``, ``L`` and ``T`` at ``scale_px`` (centred time derivative, 3-point Holoborodko Laplacian) on the
    interior ``margin`` px from each edge, ``(T - 2, H - 2 margin, W - 2 margin)`` each."""
    filters = MatchedFilters(
        scale_px,
        time_family="centred",
        time_length=3,
        laplacian_size=3,
        laplacian_family="holoborodko",
        border="replicate",
        smoothing_border="reflect",
    )
    h, w = video.shape[1:]
    inner = (slice(None), slice(margin, h - margin), slice(margin, w - margin))
    return {k: v[inner] for k, v in filters.terms(video, dt, dx, ("U", "L", "T")).items()}


def fit_source_map(
    frames: Tensor,
    dt: float,
    dx: float,
    *,
    scale_px: float = 1.0,
    margin: int = 3,
    decay: float = 0.0,
    t_on: float = 0.0,
) -> SourceMapModel:
    """Fit ``dT/dt = a Lap T - b T + q(x, y) g(t)`` by the fixed-effects regression of the module docstring
    (``g = 1``, or with ``decay`` = ``p > 0`` the profile ``((t - t_on) / (t_ref - t_on))^(-p)``, frame
    ``k`` at ``k dt`` and ``t_on`` before the first rate's frame, ``k = 1``).

    Args:
        frames: temperatures (any linear unit), uniformly sampled in time.
        dt: frame period in s.
        dx: pixel size in mm.
        scale_px: Gaussian sigma (px) applied to every frame first (0: none).
        margin: pixels left out at each edge (at least 1: the Laplacian's reach).
        decay: the power of the input's decay in time (0: a stationary map).
        t_on: when the input started, s (frame 0 at 0), for ``decay > 0``.

    Returns:
        :class:`SourceMapModel`.

    Raises:
        ValueError: not ``(T, H, W)``, fewer than 4 frames, non-finite values, a margin that leaves no
            interior, bad spacings or scale.

    Shape:
        ``frames`` ``(T, H, W)``.

    Example:
        >>> u0 = torch.full((24, 24), 20.0, dtype=torch.float64)
        >>> q = torch.zeros(24, 24, dtype=torch.float64); q[8:16, 8:16] = 1.0
        >>> video = simulate_effects(u0, a=0.1, dx=0.5, dt=0.1, n_frames=30, forcing=q)
        >>> model = fit_source_map(video, 0.1, 0.5, scale_px=0)
        >>> round(model.a, 2), round(float(model.forcing[12, 12]), 2)
        (0.1, 1.0)
    """
    video = _checked_frames(frames)
    n = video.shape[0]
    dt = float(as_spacing(dt, name="dt", unit="s", batch=1, like=video)[0])
    dx = float(as_spacing(dx, name="dx", unit="mm", batch=1, like=video)[0])
    _check_fit(video, dt, margin, decay, t_on)
    scale_px = check_scale(scale_px)
    terms = _terms(video, dt, dx, scale_px, margin)
    # Fixed effects: each pixel's projection on the input's profile (its time mean for a stationary map)
    # removed from every term removes q g(t) exactly.
    t_ref = (n - 2) * dt
    g = torch.tensor(
        [_profile(k * dt, decay, t_on, t_ref) for k in range(1, n - 1)], dtype=_F64, device=video.device
    )
    g = g.view(-1, 1, 1)
    within = {k: v - g * (g * v).sum(0, keepdim=True) / (g * g).sum() for k, v in terms.items()}
    a, b = _nonnegative_pair(accumulate(within, ("U", "L", "T")))
    interior = (g * (terms["U"] - a * terms["L"] + b * terms["T"])).sum(0) / (g * g).sum()
    forcing = F.pad(interior[None, None], (margin,) * 4, mode="replicate")[0, 0]
    return SourceMapModel(a, b, forcing, scale_px, margin, n - 2, decay, t_on, t_ref)


def _profile(t: float, decay: float, t_on: float, t_ref: float) -> float:
    """``((t - t_on) / (t_ref - t_on))^(-decay)``: an input switched on at ``t_on``, 1 at ``t_ref`` (s)."""
    if decay == 0.0:
        return 1.0
    return (max(t - t_on, 1e-9) / (t_ref - t_on)) ** -decay


def _check_fit(video: Tensor, dt: float, margin: object, decay: float, t_on: float) -> None:
    """One-line errors for :func:`fit_source_map`'s margin, frames and input profile."""
    h, w = video.shape[1:]
    if isinstance(margin, bool) or not isinstance(margin, int) or margin < 1 or min(h, w) - 2 * margin < 3:
        raise ValueError(
            f"margin must be an integer >= 1 that leaves at least 3 x 3 px inside {h} x {w} frames, "
            f"got {margin!r}"
        )
    if not bool(torch.isfinite(video).all()):
        raise ValueError(
            "frames must be finite to fit a source map; crop or fill the non-finite pixels first"
        )
    if not (math.isfinite(decay) and decay >= 0) or (decay > 0 and not t_on < dt):
        raise ValueError(f"decay must be >= 0 and t_on before frame 1 ({dt:g} s), got {decay!r} and {t_on!r}")


@dataclass(frozen=True)
class SourceMapGain:
    """The source-map model fitted on a :class:`GainResult`'s fit part and its forecast of the held-out rest.

    Attributes:
        model: the fitted :class:`SourceMapModel`.
        predicted: its forecast of the held-out frames (float64, evaluation scale's initial frame).
        rmse: its RMSE against the same smoothed held-out frames and interior as the plain forecast.
        gain: ``1 - rmse / result.base_rmse`` (0 when the plain forecast is exact).

    Shape:
        ``predicted`` ``(K, H, W)``.
    """

    model: SourceMapModel
    predicted: Tensor
    rmse: float
    gain: float


def source_map_gain(
    frames: Tensor, dt: float, dx: float, result: GainResult, *, decay: float = 0.0, t_on: float = 0.0
) -> SourceMapGain:
    """Fit the source map on ``result``'s fit part and forecast its held-out frames like the plain model
    (``decay``, ``t_on``: a decaying input, see :func:`fit_source_map`).

    Same split, evaluation scale, assimilated frames, interior and measured frames as ``result``
    (:func:`anra_torch.forecast.assess_gain` on the same ``frames``), so ``gain`` compares like with like.

    Raises:
        ValueError: ``frames`` not the video ``result`` was made from (frame count), or a fit part shorter
            than :func:`fit_source_map` needs.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    video = own_tensor(frames, _F64)
    split, held_out = result.split, result.held_out
    if video.ndim != 3 or video.shape[0] != split + 1 + held_out:
        raise ValueError(
            f"frames must be the (T, H, W) video the gain was assessed on ({split + 1 + held_out} frames), "
            f"got shape {tuple(video.shape)}"
        )
    scale, m = result.scale_px, result.margin
    model = fit_source_map(
        video[: split + 1], dt, dx, scale_px=scale, margin=max(m, 1), decay=decay, t_on=t_on
    )
    # The map is fitted at the evaluation scale: its forecast starts from the smoothed fit frames,
    # assimilated like ``result``'s (the split frame itself when ``result.assimilated`` is 1).
    # Bounded by the measured (smoothed) frame edges, like the plain and extended forecasts.
    # A decaying input is not stepped over frame 0's interval: it holds its switch-on, where the input
    # ``(t - t_on)^-p`` is unbounded (SourceMapModel.forecast refuses it).
    n = min(result.assimilated, split) if decay > 0 else result.assimilated
    smoothed = at_scale(video[split + 1 - n :], scale)

    first = split + 1 - n  # the first assimilated frame, on the fitted frames' clock

    def step(frame: int, state: Tensor) -> Tensor:
        edges = smoothed[frame : frame + 2]
        return model.forecast(state, dt=dt, dx=dx, n_frames=2, edges=edges, start=(first + frame) * dt)[1]

    initial = assimilated_state(smoothed[:n], step, n)
    edges = smoothed[n - 1 :]
    forecast = model.forecast(initial, dt=dt, dx=dx, n_frames=held_out + 1, edges=edges, start=split * dt)[1:]
    predicted = time_average(forecast, result.time_window)
    rmse = forecast_errors(predicted, result.measured, m, result.scored)[1]
    gain = 1.0 - rmse / result.base_rmse if result.base_rmse > 0 else 0.0
    return SourceMapGain(model=model, predicted=predicted, rmse=rmse, gain=gain)
