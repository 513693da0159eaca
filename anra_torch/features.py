"""Tissue features of a thermal video: per-pixel maps and per-video values for damage classification.

:class:`TissueFeatures` turns a video ``(B, T, H, W)`` into maps ``(B, H, W)`` (names in :data:`MAPS`):

=====================  ===========  =====================================================================
map                    unit         how
=====================  ===========  =====================================================================
``peak_temperature``   C            maximum over time of the denoised history (below)
``time_above_43``      s            :func:`anra_torch.dose.time_above` (one map per threshold)
``time_above_50``      s
``time_above_60``      s
``cem43_minutes``      min          :func:`anra_torch.dose.cem43` (Sapareto-Dewey)
``omega``              1            :func:`anra_torch.dose.arrhenius_omega` (skin constants by default)
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

``U`` and ``L`` are ANRA's balanced terms: the Holoborodko time derivative ``D_t`` and the Laplacian of
its temporal partner average ``S_t`` of the Gaussian-smoothed frames (the same filters on both sides, as
in :mod:`anra_torch.selection`, here window by window); ``T_0`` is the pixel's first averaged value (the
tissue is assumed to start at the temperature the loss pulls towards). ``a`` and ``b`` are fitted
jointly, with the errors-in-variables correction of ``L``, on the frames after each pixel's peak (no
source acts there in a heating-then-cooling history) within a ``window``; the source is what the balance
leaves over the whole video.

Denoised history: the doses, the peak and the times above are taken from frames smoothed in space with
a Gaussian of ``smoothing`` px (reflected border): raw noise would inflate the peak and the doses, which
grow exponentially with temperature. Temperatures are converted to Celsius (``units``; checked by
:func:`anra_torch.dose.to_celsius`).

Non-finite samples are masked: they add nothing to the doses (see :mod:`anra_torch.dose`), are filled
with the pixel's mean over its finite frames for the filters, and are counted in ``masked``.
Everything is computed in float64 without gradient tracking.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from anra_torch.balance.filters import MatchedFilters
from anra_torch.balance.moments import Moments, TermNoise, accumulate
from anra_torch.balance.noise import estimate_noise_sd
from anra_torch.checks import as_spacing, as_video
from anra_torch.dose import (
    RULES,
    SKIN,
    UNITS,
    ArrheniusConstants,
    arrhenius_omega,
    cem43,
    time_above,
    to_celsius,
)
from anra_torch.estimator import ANRAEstimator
from anra_torch.layers.attention import rtc_attention
from anra_torch.layers.derivatives import GaussianSmoothing

__all__ = ["MAPS", "TissueFeatureMaps", "TissueFeatures", "feature_summary", "save_feature_maps"]

_F64 = torch.float64
_MIN_DECORRELATION = 0.05  # 1 - corr(L, T - T_0)^2 below this: a and b cannot be told apart

MAPS: tuple[str, ...] = (
    "peak_temperature",
    "time_above_43",
    "time_above_50",
    "time_above_60",
    "cem43_minutes",
    "omega",
    "heating_rate",
    "cooling_rate",
    "rtc_attention",
    "diffusivity",
    "confidence",
    "loss_rate",
    "source",
)
"""Maps of the default :class:`TissueFeatures` (one ``time_above_<C>`` per threshold)."""

_UNITS = {
    "peak_temperature": "C",
    "cem43_minutes": "min",
    "omega": "1",
    "heating_rate": "K/s",
    "cooling_rate": "K/s",
    "rtc_attention": "1",
    "diffusivity": "mm^2/s",
    "confidence": "1",
    "loss_rate": "1/s",
    "source": "K",
}


@dataclass(frozen=True)
class TissueFeatureMaps:
    """Output of :class:`TissueFeatures` (batched: leading ``B``; a single video drops it).

    Attributes:
        maps: name -> map ``(B, H, W)``, finite everywhere.
        summary: name -> per-video value ``(B,)``: ``<map>_max`` for every map, ``damaged_fraction``
            (pixels with ``omega >= 1``), ``diffusivity_global`` (mm^2/s, NaN only when ``valid`` is
            False), ``n_masked`` (non-finite samples).
        units: name -> unit of every map and summary value.
        masked: non-finite samples per pixel, ``(B, H, W)``.
        valid: whether the estimator measured a diffusivity, ``(B,)``.
        messages: one line per video ("" when all went well).
    """

    maps: dict[str, Tensor]
    summary: dict[str, Tensor]
    units: dict[str, str]
    masked: Tensor
    valid: Tensor
    messages: tuple[str, ...]

    def stack(self, names: Sequence[str] | None = None) -> Tensor:
        """The maps as channels, ``(B, F, H, W)`` (or ``(F, H, W)``), in the order of ``names``."""
        names = list(self.maps) if names is None else list(names)
        unknown = [n for n in names if n not in self.maps]
        if unknown:
            raise ValueError(f"unknown feature map {unknown[0]!r}; expected one of: {', '.join(self.maps)}")
        return torch.stack([self.maps[n] for n in names], dim=-3)

    def unbatched(self) -> TissueFeatureMaps:
        """The same result with the batch dimension of size 1 removed."""
        return replace(
            self,
            maps={k: v[0] for k, v in self.maps.items()},
            summary={k: v[0] for k, v in self.summary.items()},
            masked=self.masked[0],
            valid=self.valid[0],
        )


def _solve(
    s_ll: Tensor, s_lt: Tensor, s_tt: Tensor, s_ul: Tensor, s_ut: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Least squares ``U = a L - b rise`` from its sums: ``(a, b, well_conditioned)``."""
    det = s_lt * s_lt - s_ll * s_tt  # of [s_ll, -s_lt; s_lt, -s_tt]
    ok = (s_ll > 0) & (s_tt > 0) & (det.abs() > _MIN_DECORRELATION * s_ll * s_tt)
    safe = torch.where(ok, det, 1.0)
    a = torch.where(ok, (-s_ul * s_tt + s_lt * s_ut) / safe, 0.0)
    b = torch.where(ok, (s_ll * s_ut - s_lt * s_ul) / safe, 0.0)
    return a, b, ok


class TissueFeatures(nn.Module):
    """Per-pixel tissue features of thermal video: dose, temperature, rates, attention, ANRA maps.

    Args:
        units: temperature unit of the frames, ``"C"`` or ``"K"``.
        thresholds: Celsius thresholds of the ``time_above_<C>`` maps.
        constants: Arrhenius constants (default :data:`anra_torch.dose.SKIN`).
        rule: how the dose integrates the frame history (:data:`anra_torch.dose.RULES`).
        smoothing: Gaussian sigma (px) of the denoised history the doses, peak and times above are taken
            from (0: the raw frames).
        term_smoothing: Gaussian sigma (px) before the time derivative and the Laplacian (rates,
            attention, loss rate, source).
        window: side (px, odd) of the estimator's diffusivity field and of the loss-rate fit.
        time_length: Holoborodko time window (frames).
        sharpness: RTC attention sharpness on ``|dT/dt| / max`` (unit invariant).

    Shape:
        ``frames`` ``(B, T, H, W)`` or ``(T, H, W)`` with ``T >= time_length``; ``dt`` (s) and ``dx`` (mm)
        floats or ``(B,)``; maps ``(B, H, W)``.

    Example:
        >>> from anra_torch.simulation import gaussian_blob
        >>> t = torch.arange(20) * 0.5
        >>> video = 37.0 + gaussian_blob(t, shape=(32, 32), dx=0.1, a=0.01, peak=30.0, sigma=0.5)
        >>> out = TissueFeatures()(video, dt=0.5, dx=0.1)
        >>> round(float(out.summary["peak_temperature_max"]), 1), out.maps["omega"].shape
        (65.6, torch.Size([32, 32]))
    """

    def __init__(
        self,
        *,
        units: str = "C",
        thresholds: Sequence[float] = (43.0, 50.0, 60.0),
        constants: ArrheniusConstants = SKIN,
        rule: str = "hold",
        smoothing: float = 1.0,
        term_smoothing: float = 2.0,
        window: int = 9,
        time_length: int = 5,
        sharpness: float = 4.0,
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

    @property
    def map_names(self) -> tuple[str, ...]:
        """Names of the maps, in order."""
        above = tuple(f"time_above_{t:g}" for t in self.thresholds)
        return ("peak_temperature", *above, *MAPS[4:])

    @torch.no_grad()
    def forward(self, frames: Tensor, dt: float | Tensor, dx: float | Tensor) -> TissueFeatureMaps:
        """Compute every map and the per-video summary.

        Args:
            frames: temperatures in ``units``, ``(T, H, W)`` or ``(B, T, H, W)``.
            dt: frame period in s.
            dx: pixel size in mm.

        Returns:
            :class:`TissueFeatureMaps` (unbatched for a single video).

        Raises:
            ValueError: bad shapes or spacings, too few frames, or temperatures that do not fit
                ``units`` (below absolute zero, or a range only plausible in the other unit).
        """
        video, batched = as_video(frames, min_frames=self.time.length)
        b, _, h, w = video.shape
        celsius = to_celsius(video, self.units)
        dt_ = as_spacing(dt, name="dt", unit="s", batch=b, like=celsius)
        dx_ = as_spacing(dx, name="dx", unit="mm", batch=b, like=celsius)
        finite = torch.isfinite(celsius)
        masked = (~finite).sum(1)
        count = finite.sum(1, keepdim=True)
        fill = torch.where(finite, celsius, 0.0).sum(1, keepdim=True) / count.clamp_min(1)
        fill = torch.where(count > 0, fill, 37.0)  # a pixel never seen: body temperature, counted as masked
        filled = torch.where(finite, celsius, fill)

        maps: dict[str, Tensor] = {}
        history = self.history_smoother(filled)
        history_masked = torch.where(finite, history, torch.nan)
        maps["peak_temperature"] = history.masked_fill(~finite, -torch.inf).amax(1)
        maps["peak_temperature"] = torch.where(count[:, 0] > 0, maps["peak_temperature"], fill[:, 0])
        for t in self.thresholds:
            maps[f"time_above_{t:g}"] = time_above(history_masked, dt_, t, rule=self.rule)
        maps["cem43_minutes"] = cem43(history_masked, dt_, rule=self.rule)
        maps["omega"] = arrhenius_omega(history_masked, dt_, constants=self.constants, rule=self.rule)

        terms = self.filters.terms(filled, dt_, dx_, ("U", "L", "T"))  # each (B, K, H, W)
        rate = terms["U"]
        maps["heating_rate"] = rate.amax(1).clamp_min(0)
        maps["cooling_rate"] = (-rate).amax(1).clamp_min(0)
        attention = rtc_attention(rate, sharpness=self.sharpness, unit_invariant=True)
        maps["rtc_attention"] = attention.mean(1) * (h * w)

        result = self.estimator(video, dt_, dx_)
        global_a = torch.where(result.valid, result.diffusivity, torch.zeros_like(result.diffusivity))
        field = torch.where(result.confidence > 0, result.field, global_a.view(b, 1, 1))
        maps["diffusivity"] = torch.nan_to_num(field, nan=0.0)
        maps["confidence"] = result.confidence
        noise_sd = estimate_noise_sd(filled).reshape(b).to(_F64)
        loss, source = self._effects(terms, maps["diffusivity"], noise_sd, dt_, dx_)
        maps["loss_rate"], maps["source"] = loss, source

        units = {name: _UNITS.get(name, "s") for name in maps}
        summary = {f"{name}_max": m.flatten(1).amax(1) for name, m in maps.items()}
        summary["damaged_fraction"] = (maps["omega"] >= 1).flatten(1).to(_F64).mean(1)
        summary["diffusivity_global"] = result.diffusivity
        summary["n_masked"] = masked.flatten(1).sum(1)
        units |= {f"{name}_max": unit for name, unit in units.items()}
        units |= {"damaged_fraction": "1", "diffusivity_global": "mm^2/s", "n_masked": "samples"}
        # Only the estimator's reasons for no diffusivity are passed on: its warning on a valid, significantly
        # negative a is the rule on heated scenes, where the source has its own map.
        messages = tuple(
            "; ".join(
                part
                for part in (
                    "" if ok else msg,
                    f"{int(n)} non-finite samples masked" if int(n) else "",
                )
                if part
            )
            for msg, ok, n in zip(
                result.messages, result.valid.tolist(), summary["n_masked"].tolist(), strict=True
            )
        )
        out = TissueFeatureMaps(maps, summary, units, masked, result.valid, messages)
        return out if batched else out.unbatched()

    def _effects(
        self, terms: dict[str, Tensor], fallback: Tensor, noise_sd: Tensor, dt: Tensor, dx: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Loss-rate (1/s) and source (K) maps from the balance ``U = a L - b (T - T_0) + q``.

        ``a`` and ``b`` are fitted jointly by least squares on the cooling frames (after each pixel's
        peak) of a ``window`` around each pixel, with the noise energy of ``L`` removed
        (errors-in-variables); where that 2 x 2 system is ill-conditioned ``a`` is ``fallback`` and ``b`` 0.
        """
        rate, lap, average = terms["U"], terms["L"], terms["T"]
        rise = average - average[:, :1]
        k = torch.arange(average.shape[1], device=average.device).view(1, -1, 1, 1)
        cooling = (k > average.argmax(1, keepdim=True)).to(_F64)
        # The noise of U and L (rise's is left uncorrected: it enters b only through its own energy).
        covariance = torch.zeros(len(noise_sd), 3, 3, dtype=_F64)
        covariance[:, :2, :2] = self.filters.noise_covariance(("U", "L"), noise_sd**2, dt, dx)
        per_pixel = accumulate(
            {"U": rate, "L": lap, "R": rise},
            ("U", "L", "R"),
            dims=(1,),
            weights=cooling,
            noise=TermNoise(covariance),
        ).map(lambda x: x.movedim((-2, -1), (1, 2)))  # (B, 3, 3, H, W)
        n = self.window

        def box(x: Tensor) -> Tensor:
            flat = x.reshape(-1, 1, *x.shape[-2:])
            pooled = F.avg_pool2d(flat, n, stride=1, padding=n // 2, count_include_pad=False)
            return pooled.reshape(x.shape)

        def sums(moments: Moments) -> tuple[Tensor, ...]:
            c = moments.corrected  # (B, 3, 3, ...): U, L, R
            return c[:, 1, 1], c[:, 1, 2], c[:, 2, 2], c[:, 0, 1], c[:, 0, 2]

        # Whole video first (the fallback), then each window.
        whole = per_pixel.map(lambda x: x.sum((-2, -1), keepdim=True))
        a_video, b_video, ok_video = _solve(*sums(whole))
        a_video = torch.where(ok_video, a_video, fallback.flatten(1).median(1).values.view(-1, 1, 1))
        b_video = torch.where(ok_video, b_video, 0.0)
        s_ll, s_lt, s_tt, s_ul, s_ut = sums(per_pixel.map(box))
        a, b, ok = _solve(s_ll, s_lt, s_tt, s_ul, s_ut)
        # Ill-conditioned window (a single spot cooling: L follows T - T_0): the video's a, local b.
        b_local = torch.where(s_tt > 0, -(s_ut - a_video * s_lt) / torch.where(s_tt > 0, s_tt, 1.0), b_video)
        a = torch.where(ok, a, a_video.expand_as(a))
        b = torch.where(ok, b, b_local)
        residual = rate - a.unsqueeze(1) * lap + b.unsqueeze(1) * rise
        source = residual.sum(1) * dt.view(-1, 1, 1)
        return b, source

    def extra_repr(self) -> str:
        return (
            f"units={self.units!r}, thresholds={self.thresholds}, rule={self.rule!r}, "
            f"smoothing={self.history_smoother.sigma:g}, window={self.estimator.window}"
        )


# ------------------------------------------------------------------------------------ command line
def feature_summary(
    frames: Tensor, dt: float, dx: float, *, units: str = "C"
) -> tuple[dict, TissueFeatureMaps]:
    """The ``anra features --json`` object of one video and the maps it was made from.

    The object holds every per-video value of :attr:`TissueFeatureMaps.summary` (at least
    ``cem43_minutes_max``, ``omega_max``, ``peak_temperature_max``), plus ``frames``, ``height``,
    ``width``, ``dt`` (s), ``dx`` (mm), ``temperature_unit`` (the declared one; every temperature
    reported is Celsius), ``masked_fraction``, ``valid``, ``message`` and ``units`` (key -> unit).
    Non-finite numbers become None.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    maps = TissueFeatures(units=units)(frames, dt, dx)
    n = frames.shape[0] * frames.shape[1] * frames.shape[2]
    record: dict = {
        "frames": int(frames.shape[0]),
        "height": int(frames.shape[1]),
        "width": int(frames.shape[2]),
    }
    record |= {"dt": float(dt), "dx": float(dx), "temperature_unit": units}
    for key, value in maps.summary.items():
        number = float(value)
        record[key] = number if torch.isfinite(value) else None
    record["n_masked"] = int(maps.summary["n_masked"])
    record["masked_fraction"] = record["n_masked"] / n
    record["valid"] = bool(maps.valid)
    record["message"] = maps.messages[0]
    record["units"] = {"dt": "s", "dx": "mm", **{k: maps.units[k] for k in maps.summary}}
    return record, maps


def save_feature_maps(path: str, maps: TissueFeatureMaps, *, dt: float, dx: float) -> str:
    """Write the maps of one video to ``.npz``: one ``(H, W)`` array per map, ``masked``, ``dt``, ``dx``
    and ``units_<name>`` strings. Returns the path written (``.npz`` appended when missing).

    Raises:
        OSError: the file cannot be written.
    """
    import numpy as np

    target = str(path) if str(path).endswith(".npz") else f"{path}.npz"
    arrays = {name: m.detach().cpu().numpy() for name, m in maps.maps.items()}
    arrays["masked"] = maps.masked.cpu().numpy()
    units = {f"units_{name}": np.array(maps.units[name]) for name in maps.maps}
    np.savez_compressed(target, dt=np.array(dt), dx=np.array(dx), **arrays, **units)
    return target
