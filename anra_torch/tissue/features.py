"""Tissue features of a thermal video: per-pixel maps and per-video values for damage classification.

:class:`TissueFeatures` turns a video ``(B, T, H, W)`` into maps ``(B, H, W)`` (names in :data:`MAPS`):

=====================  ===========  =====================================================================
map                    unit         how
=====================  ===========  =====================================================================
``peak_temperature``   C            maximum over time of the denoised history
``time_above_43``      s            :func:`anra_torch.tissue.time_above` (one map per threshold)
``time_above_50``      s
``time_above_60``      s
``cem43_minutes``      min          :func:`anra_torch.tissue.cem43` (Sapareto-Dewey)
``omega``              1            :func:`anra_torch.tissue.arrhenius_omega` (skin constants by default)
``heating_rate``       K/s          largest Holoborodko ``dT/dt`` over time
``cooling_rate``       K/s          largest ``-dT/dt`` over time
``rtc_attention``      1            mean over frames of the RTC attention on ``|dT/dt|``, times ``H W``
                                    (1 is uniform attention)
``diffusivity``        mm^2/s       :class:`ANRAEstimator` windowed field; the video's global estimate
                                    where the window has no signal (``confidence`` 0)
``confidence``         [0, 1]       the estimator's per-window reliability
``loss_rate``          1/s          ``b`` of ``U = a L - b (T - T_0)``, fitted with ``a`` on cooling frames
``source``             K            ``sum_k (U - a L + b (T - T_0)) dt``: heating not explained by
                                    diffusion and loss (a moving source leaves its track here)
=====================  ===========  =====================================================================

The dose maps (:data:`DOSE_MAPS`: doses, peak, times above) need no pixel size and work down to one
pixel, a ``(T,)`` trace included. The rate and ANRA maps need ``dx`` and frames the estimator's filters
fit in; otherwise they are absent, with the reason in :attr:`TissueFeatureMaps.absent`. Non-finite
samples are masked and counted in ``masked``. How each map is computed, the extremes' gates and the
denoised history: ``docs/guides/tissue-damage.md``, section "How the maps are computed".
Everything is computed in float64 without gradient tracking.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor, nn

from anra_torch.balance import MatchedFilters, PreparedBatch, fit_loss_windows
from anra_torch.checks import as_spacing, as_video, join_messages, one_line
from anra_torch.estimation import ANRAEstimator, ANRAResult
from anra_torch.layers import GaussianSmoothing, rtc_attention
from anra_torch.tissue.depth_features import DEPTH_MAPS, DepthFeatures, depth_features
from anra_torch.tissue.dose import RULES, SKIN, UNITS, ArrheniusConstants, dose_maps, to_celsius
from anra_torch.tissue.feature_maps import (
    EXTREMES,
    MAP_UNITS,
    MAPS,
    MAX_LOSS_ERROR,
    MIN_CONFIDENCE,
    TissueFeatureMaps,
    dose_record,
)

__all__ = ["TissueFeatures", "feature_summary"]

_F64 = torch.float64


def _fill(celsius: Tensor) -> tuple[Tensor, Tensor, Tensor | None]:
    """Non-finite samples filled with the pixel's mean of its finite frames (37 C for a pixel never seen):
    ``(filled (B, T, H, W), finite (B, T, H, W), per-pixel fill (B, H, W) or None if all are finite)``."""
    finite = torch.isfinite(celsius)
    if bool(finite.all()):
        return celsius, finite, None
    count = finite.sum(1, keepdim=True)
    fill = torch.where(finite, celsius, 0.0).sum(1, keepdim=True) / count.clamp_min(1)
    fill = torch.where(count > 0, fill, 37.0)  # a pixel never seen: body temperature, counted as masked
    return torch.where(finite, celsius, fill), finite, fill[:, 0]


def _by_frames(fn: Callable[[Tensor], object], video: Tensor, overlap: int = 0) -> list:
    """``fn`` of blocks of frames whose intermediates stay in the cache (2 MiB of float64), consecutive ones
    sharing ``overlap`` frames (a filter's support in time): the blocks' outputs, in order."""
    step = max(1, (1 << 18) // max(video.shape[0] * video.shape[-2] * video.shape[-1], 1))
    return [fn(video[:, k : k + step + overlap]) for k in range(0, max(video.shape[1] - overlap, 1), step)]


def _units(maps: dict[str, Tensor], summary: dict[str, Tensor]) -> dict[str, str]:
    """The unit of every map and summary value."""
    units = {name: MAP_UNITS.get(name, "s") for name in maps}
    units |= {f"{name}_max": unit for name, unit in units.items()}
    units |= {"damaged_fraction": "1", "n_masked": "samples", "diffusivity_global": "mm^2/s"}
    units |= {"confident_fraction": "1", "loss_confident_fraction": "1"}
    return {k: v for k, v in units.items() if k in maps or k in summary}


def _messages(
    result: ANRAResult | None, notes: list[str], masked: Tensor, depth: DepthFeatures | None
) -> tuple[str, ...]:
    """One line per video: the estimator's reason for no diffusivity (its warning on a valid, significantly
    negative ``a`` is the rule on heated scenes, where the source has its own map: not passed on), the
    ``notes``, the masked samples and the depth maps' message."""
    return tuple(
        join_messages(
            [
                "" if result is None or bool(result.valid[i]) else result.messages[i],
                *notes,
                f"{int(n)} non-finite samples masked" if int(n) else "",
                f"depth maps: {depth.messages[i]}" if depth is not None and depth.messages[i] else "",
            ]
        )
        for i, n in enumerate(masked.tolist())
    )


def _max_over(m: Tensor, where: Tensor | None) -> Tensor:
    """Per-video maximum of ``m`` ``(B, H, W)`` over the pixels ``where`` (all when None); NaN if none."""
    if where is None:
        return m.flatten(1).amax(1)
    top = torch.where(where, m, -torch.inf).flatten(1).amax(1)
    return torch.where(where.flatten(1).any(1), top, torch.nan)


class TissueFeatures(nn.Module):
    """Per-pixel tissue features of thermal video: dose, temperature, rates, attention, ANRA maps.

    Args:
        units: temperature unit of the frames, ``"C"`` or ``"K"``.
        thresholds: Celsius thresholds of the ``time_above_<C>`` maps.
        constants: Arrhenius constants (default :data:`anra_torch.tissue.SKIN`).
        rule: how the dose integrates the frame history, one of :data:`anra_torch.tissue.RULES`:
            ``"linear"`` over the recorded span ``(T - 1) dt``, or ``"hold"``, each frame held for ``dt``.
        smoothing: Gaussian sigma in px of the denoised history the doses, peak and times above are taken
            from; 0 takes the raw frames.
        term_smoothing: Gaussian sigma in px before the time derivative and the Laplacian of the rate,
            attention, loss-rate and source maps.
        window: odd side in px of the estimator's diffusivity field and of the loss-rate fit.
        time_length: Holoborodko time window in frames.
        sharpness: RTC attention sharpness on ``|dT/dt| / max``, unit invariant.
        depth: also map the damage in depth with :func:`anra_torch.tissue.depth_features`, giving
            :data:`anra_torch.tissue.DEPTH_MAPS` and :attr:`TissueFeatureMaps.depth`; needs ``dx``.
        thickness: with ``depth``, None for a half-space, else a layer's thickness in mm.

    Shape:
        ``frames`` ``(B, T, H, W)``, ``(T, H, W)`` or a one-pixel trace ``(T,)``, read as ``(T, 1, 1)``;
        ``dt`` in s and ``dx`` in mm floats or ``(B,)``; maps ``(B, H, W)``.

    Example:
        >>> from anra_torch.simulation import gaussian_blob
        >>> t = torch.arange(20) * 0.5
        >>> video = 37.0 + gaussian_blob(t, shape=(32, 32), dx=0.1, a=0.01, peak=30.0, sigma=0.5)
        >>> out = TissueFeatures()(video, dt=0.5, dx=0.1)
        >>> round(float(out.summary["peak_temperature_max"]), 1), out.maps["omega"].shape
        (65.6, torch.Size([32, 32]))
        >>> trace = TissueFeatures()(torch.full((601,), 43.0), dt=1.0)  # 10 min at 43 C, no dx
        >>> round(float(trace.summary["cem43_minutes_max"]), 6), "diffusivity" in trace.absent
        (10.0, True)
    """

    def __init__(
        self,
        *,
        units: str = "C",
        thresholds: Sequence[float] = (43.0, 50.0, 60.0),
        constants: ArrheniusConstants = SKIN,
        rule: str = "linear",
        smoothing: float = 1.0,
        term_smoothing: float = 2.0,
        window: int = 9,
        time_length: int = 5,
        sharpness: float = 4.0,
        depth: bool = False,
        thickness: float | None = None,
    ) -> None:
        super().__init__()
        if units not in UNITS:
            raise ValueError(f"units must be one of {', '.join(map(repr, UNITS))}, got {units!r}")
        if rule not in RULES:
            raise ValueError(f"rule must be one of {', '.join(map(repr, RULES))}, got {rule!r}")
        if not isinstance(constants, ArrheniusConstants):
            raise TypeError(f"constants must be ArrheniusConstants, got {type(constants).__name__}")
        for name, value in (("smoothing", smoothing), ("term_smoothing", term_smoothing)):
            if not (value >= 0):
                raise ValueError(f"{name} must be >= 0 px, got {value!r}")
        if window < 1 or window % 2 == 0:
            raise ValueError(f"window must be an odd number of pixels >= 1, got {window!r}")
        if not (sharpness > 0):
            raise ValueError(f"sharpness must be a positive number, got {sharpness!r}")
        self.units, self.rule, self.constants = units, rule, constants
        self.thresholds = tuple(float(t) for t in thresholds)
        self.sharpness = float(sharpness)
        self.history_smoother = GaussianSmoothing(smoothing, border="reflect")
        # The balance's terms at every pixel (padding borders): the 5-point Laplacian (partner: identity).
        self.filters = MatchedFilters(
            term_smoothing,
            time_length=time_length,
            laplacian_size=3,
            laplacian_family="holoborodko",
            border="replicate",
            smoothing_border="reflect",
        )
        self.time = self.filters.time
        self.estimator = ANRAEstimator(window=window, strict=False)
        self.window = window
        self.depth, self.thickness = bool(depth), thickness

    @property
    def map_names(self) -> tuple[str, ...]:
        """Names of the maps, in order."""
        above = tuple(f"time_above_{t:g}" for t in self.thresholds)
        return ("peak_temperature", *above, *MAPS[4:], *(DEPTH_MAPS if self.depth else ()))

    def history_smoothing(self, height: int, width: int) -> float:
        """The Gaussian sigma in px the doses of ``height x width`` px frames are taken at: ``smoothing``,
        or 0 when the frames are no larger than its radius (a reflected border needs more)."""
        fits = min(height, width) > self.history_smoother.radius
        return self.history_smoother.sigma if fits else 0.0

    @torch.no_grad()
    def forward(
        self,
        frames: Tensor,
        dt: float | Tensor,
        dx: float | Tensor | None = None,
        *,
        measured: PreparedBatch | None = None,
    ) -> TissueFeatureMaps:
        """Compute every map that fits and the per-video summary.

        Args:
            frames: temperatures in ``units``, ``(T, H, W)``, ``(B, T, H, W)`` or a trace ``(T,)``.
            dt: frame period in s.
            dx: pixel size in mm; None computes only the dose maps (:data:`DOSE_MAPS`).
            measured: the frames' :func:`~anra_torch.balance.prepare_batch` made already (the ANRA maps'
                estimator then measures nothing again).

        Returns:
            :class:`TissueFeatureMaps`, unbatched for a single video or trace.

        Raises:
            ValueError: bad shapes or spacings; fewer frames than ``rule`` needs, 2 for ``"linear"``;
                temperatures that do not fit ``units``: below absolute zero, or a range only plausible in
                the other unit. Frames too small or too few for the rate and ANRA maps do not raise:
                those maps are absent, with the reason.
        """
        if getattr(frames, "ndim", None) == 1:
            frames = frames.reshape(-1, 1, 1)  # type: ignore[union-attr]
        video, batched = as_video(frames)
        b, t, h, w = video.shape
        if self.rule == "linear" and t < 2:
            raise ValueError(
                f"rule='linear' integrates between frames and needs at least 2, got {t}; rule='hold' "
                "(--rule hold) holds a single frame for dt"
            )
        celsius = to_celsius(video, self.units)
        dt_ = as_spacing(dt, name="dt", unit="s", batch=b, like=celsius)
        dx_ = None if dx is None else as_spacing(dx, name="dx", unit="mm", batch=b, like=celsius)
        filled, finite, fill = _fill(celsius)
        masked = (~finite).sum(1)
        maps = self._dose_maps(filled, finite, fill, dt_)
        raw_note = self._raw_note(h, w)
        spatial = self._spatial(video, filled, dt_, dx_, measured)
        reason = spatial if isinstance(spatial, str) else ""
        if not reason:
            maps |= spatial["maps"]
        depth, depth_reason = self._depth_maps(filled, dt_, dx_)
        maps |= {} if depth is None else depth.maps
        summary = self._summary(maps, masked, None if reason else spatial, dt_ * (t - 1))
        units = _units(maps, summary)
        result = None if reason else spatial["result"]
        notes = [f"rate and ANRA maps not computed: {reason}" if reason else "", raw_note]
        messages = _messages(result, notes, summary["n_masked"], depth)
        valid = torch.zeros(b, dtype=torch.bool, device=video.device) if result is None else result.valid
        why = {name: depth_reason for name in DEPTH_MAPS}
        absent = {name: why.get(name, reason) for name in self.map_names if name not in maps}
        error, cooling = [None if reason else spatial[k] for k in ("loss_rate_std_error", "cooling")]
        out = TissueFeatureMaps(maps, summary, units, masked, valid, messages, error, absent, depth, cooling)
        return out if batched else out.unbatched()

    def _raw_note(self, height: int, width: int) -> str:
        """Why the doses are the raw frames' (frames too small for the Gaussian), or ``""``."""
        if self.history_smoothing(height, width) == self.history_smoother.sigma:
            return ""
        return (
            f"frames of {height} x {width} px are too small for the {self.history_smoother.sigma:g} px "
            "Gaussian: doses, peak and times above from the raw frames"
        )

    def _depth_maps(self, filled: Tensor, dt: Tensor, dx: Tensor | None) -> tuple[DepthFeatures | None, str]:
        """The depth model's maps (with ``depth=True``) of the filled frames (C), or why they are absent."""
        if not self.depth:
            return None, ""
        if dx is None:
            return None, "no pixel size (pass dx, --dx in mm)"
        try:
            found = depth_features(
                filled, dt, dx, constants=self.constants, rule=self.rule, thickness=self.thickness
            )
        except ValueError as err:
            return None, one_line(err)
        return found, ""

    def _dose_maps(self, filled: Tensor, finite: Tensor, fill: Tensor | None, dt: Tensor) -> dict:
        """Peak, times above, CEM43 and Omega of the denoised history: no spatial filter needed."""
        h, w = filled.shape[-2:]
        smoothed = self.history_smoothing(h, w)  # the Gaussian frame by frame
        history = torch.cat(_by_frames(self.history_smoother, filled), 1) if smoothed else filled
        complete = fill is None  # the common case: no sample masked, no masked copy to make
        peak = (history if complete else history.masked_fill(~finite, -torch.inf)).amax(1)
        maps = {"peak_temperature": peak if fill is None else torch.where(finite.any(1), peak, fill)}
        rules = {"thresholds": self.thresholds, "constants": self.constants, "rule": self.rule}
        return maps | dose_maps(history, dt, finite=None if complete else finite, **rules)

    def _spatial(
        self, video: Tensor, filled: Tensor, dt: Tensor, dx: Tensor | None, measured: PreparedBatch | None
    ) -> dict | str:
        """The rate and ANRA maps, the estimator's result and the loss rate's standard error; or why the
        frames do not allow them (the filters' own one-line requirement)."""
        if dx is None:
            return "no pixel size (pass dx, --dx in mm)"
        b, t, h, w = video.shape
        names = ("U", "L", "T")
        try:
            result = self.estimator(
                video, dt, dx, prepared=measured
            )  # the strictest size and length requirement
            blocks = _by_frames(lambda v: self.filters.terms(v, dt, dx, names), filled, self.time.length - 1)
        except ValueError as err:
            return one_line(err)
        terms = {name: torch.cat([block[name] for block in blocks], 1) for name in names}
        rate = terms["U"]  # (B, K, H, W)
        low, high = torch.aminmax(rate, dim=1)
        maps = {"heating_rate": high.clamp_min(0) + 0.0, "cooling_rate": (-low).clamp_min(0) + 0.0}
        rtc = {"sharpness": self.sharpness, "unit_invariant": True}  # each frame's attention on its pixels
        attention = sum(rtc_attention(block["U"], **rtc).sum(1) for block in blocks)
        maps["rtc_attention"] = attention / rate.shape[1] * (h * w)
        global_a = torch.where(result.valid, result.diffusivity, torch.zeros_like(result.diffusivity))
        field_a = torch.where(result.confidence > 0, result.field, global_a.view(b, 1, 1))
        maps["diffusivity"] = torch.nan_to_num(field_a, nan=0.0)
        maps["confidence"] = result.confidence
        noise_sd = result.noise_sd.reshape(b).to(_F64)  # measured once, by the estimator
        fit = fit_loss_windows(self.filters, terms, maps["diffusivity"], noise_sd, dt, dx, window=self.window)
        maps["loss_rate"], maps["source"] = fit.loss_rate, fit.source
        fitted = {"loss_rate_std_error": fit.std_error, "cooling": fit.diffusivity}
        return {"maps": maps, "result": result, **fitted}

    def _summary(self, maps: dict[str, Tensor], masked: Tensor, spatial: dict | None, span: Tensor) -> dict:
        """Per-video values ``(B,)``: map maxima (the ANRA maps' over confident windows) and the rest."""
        gates: dict[str, Tensor] = {}
        if spatial is not None:
            confident = maps["confidence"] >= MIN_CONFIDENCE
            error = spatial["loss_rate_std_error"]
            measured = confident & (error * span.view(-1, 1, 1) <= MAX_LOSS_ERROR)
            gates = {"diffusivity": confident, "loss_rate": measured, "source": measured}
        summary = {f"{name}_max": _max_over(m, gates.get(name)) for name, m in maps.items()}
        summary["damaged_fraction"] = (maps["omega"] >= 1).flatten(1).to(_F64).mean(1)
        summary["n_masked"] = masked.flatten(1).sum(1)
        if spatial is not None:
            summary["diffusivity_global"] = spatial["result"].diffusivity
            summary["confident_fraction"] = gates["diffusivity"].flatten(1).to(_F64).mean(1)
            summary["loss_confident_fraction"] = gates["loss_rate"].flatten(1).to(_F64).mean(1)
        return summary

    def extra_repr(self) -> str:
        return (
            f"units={self.units!r}, thresholds={self.thresholds}, rule={self.rule!r}, "
            f"smoothing={self.history_smoother.sigma:g}, window={self.estimator.window}"
        )


def feature_summary(
    frames: Tensor,
    dt: float,
    dx: float | None = None,
    *,
    units: str = "C",
    rule: str = "linear",
    constants: ArrheniusConstants = SKIN,
    depth: bool = False,
    thickness: float | None = None,
    measured: PreparedBatch | None = None,
) -> tuple[dict, TissueFeatureMaps]:
    """The ``anra features --json`` object of one video and the maps it was made from.

    The object holds every per-video value of :attr:`TissueFeatureMaps.summary`, the input's size and
    spacing, how the doses and extremes were taken, the absent maps and every value's unit; with
    ``depth``, the depth model's record from :meth:`anra_torch.tissue.DepthFeatures.record`. Every key and
    its unit: ``docs/reference/outputs.md``, section ``anra features --json``. Every temperature is in
    Celsius; non-finite numbers become None.

    Args:
        frames: temperatures in ``units``.
        dt: frame period in s.
        dx: pixel size in mm; None gives only the dose maps.
        units: ``"C"`` or ``"K"``.
        rule: dose integration, ``"linear"`` or ``"hold"``, see :data:`anra_torch.tissue.RULES`.
        constants: Arrhenius constants.
        depth: also the damage-in-depth maps, as :class:`TissueFeatures` ``depth``.
        thickness: with ``depth``, a layer's thickness in mm; None for a half-space.
        measured: the frames' :func:`~anra_torch.balance.prepare_batch` made already (measured once).

    Returns:
        The JSON-ready dict and the :class:`TissueFeatureMaps` it was made from.

    Shape:
        ``frames`` ``(T, H, W)`` or ``(T,)``.

    Raises:
        ValueError: as :meth:`TissueFeatures.forward`.
    """
    extractor = TissueFeatures(units=units, rule=rule, constants=constants, depth=depth, thickness=thickness)
    maps = extractor(frames, dt, dx, measured=measured)
    t, h, w = (*frames.shape, 1, 1)[:3]
    record: dict = {"frames": int(t), "height": int(h), "width": int(w)}
    record |= {"dt": float(dt), "dx": None if dx is None else float(dx), "temperature_unit": units}
    for key, value in maps.summary.items():
        record[key] = float(value) if torch.isfinite(value) else None
    record["n_masked"] = int(maps.summary["n_masked"])
    record["masked_fraction"] = record["n_masked"] / (t * h * w)
    record["valid"] = bool(maps.valid)
    record["message"] = maps.messages[0]
    doses = (extractor.rule, extractor.constants, extractor.thresholds)
    record["dose"] = dose_record(doses, int(t), float(dt), extractor.history_smoothing(h, w))
    record["extremes"] = None if "confidence" in maps.absent else dict(EXTREMES)
    record["absent"] = dict(maps.absent)
    if depth:
        record["depth"] = None if maps.depth is None else maps.depth.record(0)
    record["units"] = {"dt": "s", "dx": "mm", **{k: maps.units[k] for k in maps.summary}}
    return record, maps
