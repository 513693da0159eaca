"""A Markdown report with figures for one diffusivity estimate (matplotlib on Agg: ``anra_torch[plot]``).

Figures (PNG, next to ``report.md``):

- ``frames.png``: first, middle and last frame on one colour scale (the data's units);
- ``attention.png``: the RTC attention weights at the middle estimate frame;
- ``field.png``: the windowed diffusivity field a(x, y) and its confidence (when the result has one);
- ``per_frame.png``: a[k] against time with the global estimate, its +-2 standard-error band and the truth.

matplotlib is imported only here and drawn through its object API on the Agg canvas, so writing a report
never changes the caller's pyplot backend or state.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from anra_torch.layers.attention import RTCAttention
from anra_torch.layers.derivatives import GaussianSmoothing, TimeDerivative
from anra_torch.layers.estimator import ANRAEstimator, ANRAResult
from anra_torch.video import Video

__all__ = ["FIGURES", "attention_map", "format_pm", "write_estimate_report"]

FIGURES = ("frames.png", "attention.png", "field.png", "per_frame.png")
"""File names of the figures a report may hold (``field.png`` only when the result has a field)."""

_DPI = 110


def format_pm(value: float, error: float | None, unit: str = "") -> str:
    """``value ± error unit`` with the error to two significant digits (``nan`` shown as ``n/a``).

    Example:
        >>> format_pm(0.2000312, 6.13e-5, "mm^2/s")
        '0.200031 ± 0.000061 mm^2/s'
    """
    suffix = f" {unit}" if unit else ""
    if not math.isfinite(value):
        return f"n/a{suffix}"
    if error is None or not math.isfinite(error) or error <= 0:
        return f"{value:.6g}{suffix}"
    decimals = max(0, 1 - math.floor(math.log10(error)))
    if decimals > 12:
        return f"{value:.6g} ± {error:.2g}{suffix}"
    return f"{value:.{decimals}f} ± {error:.{decimals}f}{suffix}"


def _import_matplotlib() -> tuple[Any, Any]:
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as err:
        raise ImportError(
            "writing a report needs matplotlib, which is not installed: pip install anra_torch[plot]"
        ) from err
    return Figure, FigureCanvasAgg


def _extent(h: int, w: int, dx: float) -> tuple[float, float, float, float]:
    """imshow extent in mm, x along columns, y along rows (row 0 at the top)."""
    return (0.0, w * dx, h * dx, 0.0)


def _save(fig: Any, canvas_cls: Any, path: Path) -> None:
    canvas_cls(fig)
    fig.savefig(path, dpi=_DPI)


# ------------------------------------------------------------------------------------------- attention
def _rtc_module(estimator: ANRAEstimator | None) -> tuple[nn.Module, bool]:
    """The RTC attention to draw and whether the estimator weighted its pixels with it."""
    if estimator is not None and isinstance(estimator.attention, RTCAttention):
        return estimator.attention, True
    return RTCAttention(), False


def attention_map(video: Video, result: ANRAResult, estimator: ANRAEstimator | None = None) -> Tensor:
    """RTC attention weights at the middle estimate frame, placed on the input frame grid.

    dT/dt from the estimator's time filter (without ``estimator``: the default filter with the length
    implied by ``result``), smoothed with the sigma the result chose, weighted by the estimator's
    :class:`RTCAttention` when it has one, else by the paper's (``RTCAttention()``). Pixels the filters
    cannot reach (the border, or next to masked pixels) are NaN; the others sum to 1.

    Shape:
        ``video.frames`` ``(T, H, W)``; output ``(H, W)``.
    """
    frames = video.frames.to(torch.float64).unsqueeze(0)  # (1, T, H, W)
    length = frames.shape[1] - result.per_frame.shape[-1] + 1
    time_filter = estimator.time if estimator is not None else TimeDerivative(length=length)
    finite = torch.isfinite(frames)
    if not bool(finite.all()):
        fill = frames[finite].mean() if bool(finite.any()) else torch.tensor(0.0, dtype=frames.dtype)
        frames = torch.where(finite, frames, fill)
    k = result.per_frame.shape[-1] // 2
    window = slice(k, k + time_filter.length)
    smoother = GaussianSmoothing(float(result.smoothing))
    rate = smoother(time_filter(frames[:, window], video.dt))  # (1, 1, H - 2r, W - 2r)
    r = smoother.radius
    bad = (~finite[:, window]).to(torch.float64).unsqueeze(1)
    bad = F.max_pool3d(bad, (time_filter.length, 2 * r + 1, 2 * r + 1), stride=1).squeeze(1) > 0
    weights = _rtc_module(estimator)[0](rate, ~bad)[0, 0]
    weights = torch.where(bad[0, 0], torch.full_like(weights, torch.nan), weights)
    return F.pad(weights, (r, r, r, r), value=torch.nan)


# ------------------------------------------------------------------------------------------- figures
def _frames_figure(video: Video, path: Path, mpl: tuple[Any, Any]) -> None:
    Figure, canvas = mpl
    frames = video.frames.to(torch.float64).numpy()
    n, h, w = frames.shape
    picks = sorted({0, n // 2, n - 1})
    shown = frames[picks]
    finite = shown[np.isfinite(shown)]
    lo, hi = np.percentile(finite, [0.5, 99.5]) if finite.size else (0.0, 1.0)
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    fig = Figure(figsize=(4.0 * len(picks) + 1.0, 4.0), layout="constrained")
    axes = fig.subplots(1, len(picks), squeeze=False)[0]
    times = video.t.numpy() - float(video.t[0]) if video.t is not None else np.arange(n) * video.dt
    for ax, k in zip(axes, picks, strict=True):
        image = ax.imshow(frames[k], extent=_extent(h, w, video.dx), vmin=lo, vmax=hi, cmap="inferno")
        ax.set_title(f"frame {k}, t = {times[k]:.3f} s")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    fig.colorbar(image, ax=list(axes), label=f"temperature ({video.unit})", shrink=0.9)
    _save(fig, canvas, path)


def _attention_figure(
    video: Video, result: ANRAResult, estimator: ANRAEstimator | None, path: Path, mpl: tuple[Any, Any]
) -> float:
    Figure, canvas = mpl
    weights = attention_map(video, result, estimator).numpy()
    h, w = weights.shape
    k = result.per_frame.shape[-1] // 2
    when = float(result.frame_times[k])
    fig = Figure(figsize=(5.6, 4.6), layout="constrained")
    ax = fig.subplots()
    cmap = _cmap("viridis")
    image = ax.imshow(weights, extent=_extent(h, w, video.dx), cmap=cmap)
    ax.set_title(f"RTC attention, estimate frame {k} (t = {when:.3f} s)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    fig.colorbar(image, ax=ax, label="attention weight (fraction of the frame's total)")
    _save(fig, canvas, path)
    return when


def _cmap(name: str) -> Any:
    from matplotlib import colormaps

    return colormaps[name].with_extremes(bad="0.85")  # NaN: pixels the filters cannot reach


def _field_figure(video: Video, result: ANRAResult, path: Path, mpl: tuple[Any, Any]) -> dict[str, float]:
    Figure, canvas = mpl
    field = result.field.to(torch.float64).numpy()
    confidence = result.confidence.to(torch.float64).numpy()
    h, w = field.shape
    finite = np.isfinite(field)
    trusted = field[finite & (confidence >= 0.5)]
    values = trusted if trusted.size else field[finite]
    stats = {"coverage": float(finite.mean())}
    if values.size:
        lo, hi = np.percentile(values, [2, 98])
        stats.update(median=float(np.median(values)), p2=float(lo), p98=float(hi))
    else:
        lo, hi = 0.0, 1.0
    if hi <= lo:
        lo, hi = lo - 0.5 * abs(lo) - 1e-12, hi + 0.5 * abs(hi) + 1e-12
    fig = Figure(figsize=(10.5, 4.6), layout="constrained")
    ax_a, ax_c = fig.subplots(1, 2)
    image = ax_a.imshow(field, extent=_extent(h, w, video.dx), vmin=lo, vmax=hi, cmap=_cmap("viridis"))
    ax_a.set_title("windowed diffusivity a(x, y) (grey: no estimate)")
    bar = fig.colorbar(image, ax=ax_a, label="a (mm^2/s)")
    bar.ax.ticklabel_format(useOffset=False)
    image = ax_c.imshow(confidence, extent=_extent(h, w, video.dx), vmin=0.0, vmax=1.0, cmap="magma")
    ax_c.set_title("confidence (signal fraction of the window)")
    fig.colorbar(image, ax=ax_c, label="confidence (1)")
    for ax in (ax_a, ax_c):
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    _save(fig, canvas, path)
    return stats


def _per_frame_figure(result: ANRAResult, truth: float | None, path: Path, mpl: tuple[Any, Any]) -> None:
    Figure, canvas = mpl
    times = result.frame_times.to(torch.float64).numpy()
    per_frame = result.per_frame.to(torch.float64).numpy()
    estimate, error = float(result.diffusivity), float(result.std_error)
    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    ax = fig.subplots()
    ax.plot(times, per_frame, "o-", ms=4, lw=1, color="C0", label="per frame a[k]")
    anchors = [v for v in per_frame if math.isfinite(v)]
    if math.isfinite(estimate):
        ax.axhline(estimate, color="C1", lw=1.5, label=f"global a = {format_pm(estimate, error)}")
        if math.isfinite(error):
            ax.axhspan(
                estimate - 2 * error, estimate + 2 * error, color="C1", alpha=0.25, label="±2 std. error"
            )
        anchors += [estimate - 2 * error, estimate + 2 * error] if math.isfinite(error) else [estimate]
    if truth is not None:
        ax.axhline(truth, color="k", ls="--", lw=1.2, label=f"truth a = {truth:g}")
        anchors.append(truth)
    finite = per_frame[np.isfinite(per_frame)]
    if finite.size >= 5:
        # Keep the band and the truth readable when a few frames (e.g. ratio mode) are wild.
        lo, hi = np.percentile(finite, [5, 95])
        spread = hi - lo
        keep = [v for v in anchors if lo - 3 * spread <= v <= hi + 3 * spread] or anchors
        low, high = min(keep), max(keep)
        pad = 0.1 * (high - low) or 0.05 * abs(high) or 1.0
        ax.set_ylim(low - pad, high + pad)
    ax.set_xlabel("time since the first frame (s)")
    ax.set_ylabel("diffusivity a (mm^2/s)")
    ax.set_title("per-frame estimates")
    ax.legend(loc="best", fontsize="small")
    _save(fig, canvas, path)


# ------------------------------------------------------------------------------------------- report
def write_estimate_report(
    out_dir: str | os.PathLike[str],
    video: Video,
    result: ANRAResult,
    *,
    truth: float | None = None,
    estimator: ANRAEstimator | None = None,
) -> Path:
    """Write ``report.md`` and its PNG figures for one estimate.

    Args:
        out_dir: directory to write into (created if needed; existing figures are replaced).
        video: the video that was estimated (its ``dt`` in s and ``dx`` in mm label the axes).
        result: the estimator's result for this single video.
        truth: the true diffusivity in mm^2/s, if known (synthetic data).
        estimator: the estimator that produced ``result``, to redo its attention exactly and to record
            its mode and window; without it the defaults are assumed.

    Returns:
        Path of ``report.md``.

    Shape:
        ``video.frames`` ``(T, H, W)``; ``result`` unbatched (``result.per_frame`` ``(K,)``).

    Raises:
        ImportError: matplotlib missing (``pip install anra_torch[plot]``).
        ValueError: a batched result, a video without ``dx``, or a result that does not match the video.
    """
    if result.diffusivity.ndim != 0:
        raise ValueError(
            f"result must be for a single video, got a batch of {result.diffusivity.shape[0]}; "
            "index it or use ANRAResult.unbatched()"
        )
    if video.dx is None:
        raise ValueError("video.dx is None; the report needs the pixel size in mm")
    t, h, w = video.frames.shape
    if result.per_frame.ndim != 1 or result.per_frame.shape[0] > t:
        raise ValueError(
            f"result has {tuple(result.per_frame.shape)} per-frame estimates, not one per window of "
            f"this {t}-frame video"
        )
    mpl = _import_matplotlib()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    _frames_figure(video, out / "frames.png", mpl)
    when = _attention_figure(video, result, estimator, out / "attention.png", mpl)
    field_stats = None
    if result.field is not None and result.confidence is not None:
        field_stats = _field_figure(video, result, out / "field.png", mpl)
    _per_frame_figure(result, truth, out / "per_frame.png", mpl)

    estimate, error = float(result.diffusivity), float(result.std_error)
    sigma = float(result.smoothing)
    used = _rtc_module(estimator)[1]
    if used:
        usage = "The estimator weighted its pixels with these."
    elif estimator is not None:
        kind = type(estimator.attention).__name__
        usage = f"Shown for reference (the paper's form): this estimator weighted pixels with {kind}."
    else:
        usage = "The paper's form, shown for reference (the estimator's own weighting is not known here)."
    rows = [("diffusivity a", f"{format_pm(estimate, error, 'mm^2/s')} (± 1 standard error)")]
    if math.isfinite(estimate) and math.isfinite(error):
        rows.append(
            ("±2 standard errors", f"[{estimate - 2 * error:.6g}, {estimate + 2 * error:.6g}] mm^2/s")
        )
    if truth is not None:
        rel = (
            f" (error {100 * (estimate - truth) / truth:+.3g} %)" if truth and math.isfinite(estimate) else ""
        )
        rows.append(("truth", f"{truth:g} mm^2/s{rel}"))
    rows += [
        ("source", f"`{video.source}`" if video.source is not None else "in memory"),
        ("video", f"{t} frames of {h} x {w} px"),
        ("frame period dt", f"{video.dt:.6g} s ({1 / video.dt:.4g} Hz)"),
        ("pixel size dx", f"{video.dx:.6g} mm (field of view {w * video.dx:.4g} x {h * video.dx:.4g} mm)"),
    ]
    if estimator is not None:
        rows.append(("mode", estimator.mode))
    rows += [
        ("spatial smoothing chosen", f"{sigma:g} px ({sigma * video.dx:.4g} mm)"),
        ("noise sd", f"{float(result.noise_sd):.4g} {video.unit}"),
        ("reliability (signal fraction)", f"{float(result.reliability):.4f}"),
        ("masked non-finite pixels", f"{int(result.n_masked)}"),
        ("valid", "yes" if bool(result.valid) else f"no: {result.messages[0]}"),
    ]
    lines = [
        f"# ANRA diffusivity estimate: {video.name}",
        "",
        "Model dT/dt = a (d11 + d22) T, estimated directly from the frames "
        "(ANRA: El-Kebir et al., arXiv 2203.13148).",
        "",
        "| quantity | value |",
        "|---|---|",
        *(f"| {name} | {value} |" for name, value in rows),
        "",
        "## Frames",
        "",
        "![first, middle and last frame](frames.png)",
        "",
        f"First, middle and last frame on one colour scale ({video.unit}); axes in mm.",
        "",
        "## Attention",
        "",
        "![RTC attention](attention.png)",
        "",
        f"RTC attention weights (fastest temperature change gets most weight) at t = {when:.3f} s, after "
        f"{sigma:g} px smoothing. Grey: border the filters cannot reach. {usage}",
        "",
    ]
    if field_stats is not None:
        window = f" ({estimator.window} px windows)" if estimator is not None and estimator.window else ""
        summary = (
            f"median {field_stats['median']:.4g} mm^2/s, 2-98 % range [{field_stats['p2']:.4g}, "
            f"{field_stats['p98']:.4g}] mm^2/s, "
            if "median" in field_stats
            else "no window with measurable signal, "
        )
        lines += [
            "## Diffusivity field",
            "",
            "![windowed diffusivity and confidence](field.png)",
            "",
            f"Windowed estimate a(x, y){window}: {summary}estimated on "
            f"{100 * field_stats['coverage']:.1f} % of the pixels. Confidence is the signal fraction of "
            "each window's regressor energy (1: noiseless).",
            "",
        ]
    else:
        lines += [
            "## Diffusivity field",
            "",
            "Not computed: estimate with a window (e.g. `--window 15`).",
            "",
        ]
    lines += [
        "## Per-frame estimates",
        "",
        "![per-frame diffusivity](per_frame.png)",
        "",
        "a[k] per time window against time (s); the line is the global estimate with its ±2 standard-error "
        "band" + (", dashed: the truth" if truth is not None else "") + ". Single frames scatter far more "
        "than the band: the noise of consecutive time derivatives largely cancels in the global sums.",
        "",
    ]
    report = out / "report.md"
    report.write_text("\n".join(lines), encoding="utf-8")
    return report


# ------------------------------------------------------------------------------------------ diagnosis
DIAGNOSIS_FIGURES = ("forecast.png", "maps.png", "rmse.png")
"""File names of the figures of :func:`write_diagnosis_report` (plus ``source_map.png`` with a source map)."""


def _forecast_figure(video: Video, gain: Any, path: Path, mpl: tuple[Any, Any]) -> float:
    Figure, canvas = mpl
    measured = gain.measured[-1].to(torch.float64).numpy()
    base = gain.predicted_base[-1].to(torch.float64).numpy()
    extended = gain.predicted_extended[-1].to(torch.float64).numpy()
    h, w = measured.shape
    when = float(gain.times[-1])
    lo, hi = np.percentile(measured, [0.5, 99.5])
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    deviations = (base - measured, extended - measured)
    limit = float(max(np.percentile(np.abs(d), 99.5) for d in deviations)) or 1.0
    fig = Figure(figsize=(17.0, 7.6), layout="constrained")
    axes = fig.subplots(2, 3)
    extent = _extent(h, w, video.dx)
    image = axes[0, 0].imshow(measured, extent=extent, vmin=lo, vmax=hi, cmap="inferno")
    scale = f", {gain.scale_px:g} px Gaussian" if gain.scale_px > 0 else ""
    scale += f", {gain.time_window}-frame mean" if gain.time_window > 1 else ""
    axes[0, 0].set_title(f"measured{scale}, t = {when:.3f} s")
    for ax, field, title in ((axes[0, 1], base, "plain heat equation"), (axes[0, 2], extended, "extended")):
        ax.imshow(field, extent=extent, vmin=lo, vmax=hi, cmap="inferno")
        ax.set_title(f"{title} forecast")
    fig.colorbar(image, ax=list(axes[0]), label=f"temperature ({video.unit})", shrink=0.9)
    axes[1, 0].axis("off")
    for ax, field, title in zip(
        axes[1, 1:], deviations, ("plain - measured", "extended - measured"), strict=True
    ):
        dev = ax.imshow(field, extent=extent, vmin=-limit, vmax=limit, cmap="RdBu_r")
        ax.set_title(f"deviation: {title}")
    fig.colorbar(dev, ax=list(axes[1, 1:]), label=f"deviation ({video.unit})", shrink=0.9)
    for ax in (*axes[0], *axes[1, 1:]):
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    _save(fig, canvas, path)
    return when


def _residual_panel(fig: Any, ax: Any, residual: Tensor, video: Video, margin: int, title: str) -> None:
    h, w = video.frames.shape[-2:]
    values = residual.to(torch.float64).numpy()
    full = np.full((h, w), np.nan)
    full[margin : h - margin, margin : w - margin] = values
    limit = float(np.nanpercentile(np.abs(values), 99.5)) or 1.0
    image = ax.imshow(full, extent=_extent(h, w, video.dx), vmin=-limit, vmax=limit, cmap=_cmap("RdBu_r"))
    ax.set_title(title)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    fig.colorbar(image, ax=ax, label=f"residual ({video.unit}/s)", shrink=0.9)


def _maps_figure(video: Video, diagnosis: Any, gain: Any, path: Path, mpl: tuple[Any, Any]) -> list[str]:
    """Time-mean PDE residual of the plain model and of the selected one, with the effects' shapes."""
    Figure, canvas = mpl
    from anra_torch.diagnosis import diagnose_terms

    h, w = video.frames.shape[-2:]
    try:  # the plain model's residual on the same frames, smoothing and noise level
        plain = diagnose_terms(
            video.frames[: gain.split + 1], video.dt, video.dx, effects=[], smoothing=diagnosis.smoothing,
            noise_sd=diagnosis.noise_sd,
        ).residual_map  # fmt: skip
    except ValueError:
        plain = None
    panels = [(plain, "plain heat equation")] if plain is not None else []
    if diagnosis.effects or plain is None:
        panels.append((diagnosis.residual_map, "selected model"))
    fig = Figure(figsize=(6.2 * len(panels), 5.0), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, (residual, title) in zip(axes, panels, strict=True):
        _residual_panel(fig, ax, residual, video, diagnosis.margin, f"mean PDE residual, {title}")
    drawn = []
    for effect in diagnosis.effects:
        p = effect["params"]
        for ax in axes:
            if effect["name"] == "source":
                ax.annotate(
                    "", xy=(p["x1"], p["y1"]), xytext=(p["x0"], p["y0"]),
                    arrowprops={"arrowstyle": "->", "color": "k", "lw": 2},
                )  # fmt: skip
                ax.plot([p["x0"]], [p["y0"]], "ko", ms=4)
            if effect["name"] == "heterogeneity":
                angle = np.linspace(0.0, 2.0 * np.pi, 200)
                ax.plot(p["x"] + p["radius"] * np.cos(angle), p["y"] + p["radius"] * np.sin(angle), "k--")
            ax.set_xlim(0, w * video.dx)
            ax.set_ylim(h * video.dx, 0)
        if effect["name"] == "source":
            drawn.append(f"source path ({p['x0']:.2f}, {p['y0']:.2f}) -> ({p['x1']:.2f}, {p['y1']:.2f}) mm")
        if effect["name"] == "heterogeneity":
            drawn.append(f"heterogeneity disc r = {p['radius']:.2f} mm at ({p['x']:.2f}, {p['y']:.2f}) mm")
    _save(fig, canvas, path)
    return drawn


def _rmse_figure(video: Video, gain: Any, path: Path, mpl: tuple[Any, Any]) -> None:
    Figure, canvas = mpl
    times = gain.times.to(torch.float64).numpy()
    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    ax = fig.subplots()
    ax.plot(times, gain.rmse_base.numpy(), "-", color="C0", label=f"plain (RMSE {gain.base_rmse:.4g})")
    ax.plot(
        times, gain.rmse_extended.numpy(), "-", color="C1", label=f"extended (RMSE {gain.extended_rmse:.4g})"
    )
    ax.axhline(gain.noise_floor, color="k", ls="--", lw=1.2, label=f"noise floor {gain.noise_floor:.4g}")
    ax.set_ylim(bottom=0)
    ax.set_xlabel("time since the first frame (s)")
    ax.set_ylabel(f"forecast RMSE ({video.unit})")
    ax.set_title(f"forecast error on the held-out frames (interior, {gain.scale_px:g} px scale)")
    ax.legend(loc="best", fontsize="small")
    _save(fig, canvas, path)


def _source_map_figure(video: Video, gain: Any, mapped: Any, path: Path, mpl: tuple[Any, Any]) -> None:
    """The fitted map q(x, y) and the map model's deviation from the last held-out frame."""
    Figure, canvas = mpl
    h, w = video.frames.shape[-2:]
    extent = _extent(h, w, video.dx)
    m = gain.margin
    inside = (slice(m, h - m), slice(m, w - m))
    forcing = np.full((h, w), np.nan)
    forcing[inside] = mapped.model.forcing.to(torch.float64).numpy()[inside]
    deviation = (mapped.predicted[-1] - gain.measured[-1]).to(torch.float64).numpy()
    limit = float(np.percentile(np.abs(deviation[inside]), 99.5)) or 1.0
    fig = Figure(figsize=(12.4, 5.0), layout="constrained")
    left, right = fig.subplots(1, 2)
    image = left.imshow(forcing, extent=extent, cmap=_cmap("inferno"))
    left.set_title(f"source map q(x, y); a = {mapped.model.a:.3g} mm^2/s, b = {mapped.model.b:.3g} 1/s")
    fig.colorbar(image, ax=left, label=f"q ({video.unit}/s)", shrink=0.9)
    dev = right.imshow(deviation, extent=extent, vmin=-limit, vmax=limit, cmap=_cmap("RdBu_r"))
    right.set_title(f"source-map forecast - measured, t = {float(gain.times[-1]):.3f} s")
    fig.colorbar(dev, ax=right, label=f"deviation ({video.unit})", shrink=0.9)
    for ax in (left, right):
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    _save(fig, canvas, path)


def write_diagnosis_report(
    out_dir: str | os.PathLike[str], video: Video, diagnosis: Any, gain: Any, source_map: Any = None
) -> Path:
    """Write ``report.md`` with ``forecast.png``, ``maps.png`` and ``rmse.png`` for a diagnosis.

    Args:
        out_dir: directory to write into (created if needed).
        video: the whole video (``dt`` in s, ``dx`` in mm label the axes).
        diagnosis: :class:`anra_torch.diagnosis.Diagnosis` of its fit part.
        gain: :class:`anra_torch.prediction.GainResult` of the same split.
        source_map: optional :class:`anra_torch.source_map.SourceMapGain` of the same split; adds
            ``source_map.png`` (the map and its forecast's deviation) and its numbers.

    Returns:
        Path of ``report.md``.

    Shape:
        ``video.frames`` ``(T, H, W)``.

    Raises:
        ImportError: matplotlib missing (``pip install anra_torch[plot]``).
        ValueError: a video without ``dx``.
    """
    if video.dx is None:
        raise ValueError("video.dx is None; the report needs the pixel size in mm")
    mpl = _import_matplotlib()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    when = _forecast_figure(video, gain, out / "forecast.png", mpl)
    drawn = _maps_figure(video, diagnosis, gain, out / "maps.png", mpl)
    _rmse_figure(video, gain, out / "rmse.png", mpl)
    t, h, w = video.frames.shape
    rows = [
        ("source", f"`{video.source}`" if video.source is not None else "in memory"),
        ("video", f"{t} frames of {h} x {w} px, dt = {video.dt:.6g} s, dx = {video.dx:.6g} mm"),
        ("diagnosed frames", f"0-{gain.split}; forecast {gain.held_out} held-out frames"),
        ("plain diffusivity a", f"{diagnosis.a_plain:.5g} mm^2/s"),
        ("extended base a", f"{diagnosis.base:.5g} mm^2/s"),
        ("forecast RMSE plain", f"{gain.base_rmse:.4g} {video.unit} (SSE {gain.base_sse:.4g})"),
        ("forecast RMSE extended", f"{gain.extended_rmse:.4g} {video.unit} (SSE {gain.extended_sse:.4g})"),
        (
            "evaluation scale",
            f"frames smoothed by a {gain.scale_px:g} px Gaussian and averaged over {gain.time_window} "
            "frames in time (both forecasts and data)",
        ),
        (
            "forecast start",
            f"each model's state assimilated from the last {gain.assimilated} fit frames"
            if gain.assimilated > 1
            else "the measured split frame",
        ),
        ("gain 1 - RMSE_ext / RMSE_plain", f"{gain.gain:.3f}"),
        ("noise floor (perfect model)", f"{gain.noise_floor:.4g} {video.unit}"),
        ("gain above the noise floor", f"{gain.gain_above_floor:.3f}"),
        (
            "raw frames: RMSE plain / extended, gain",
            f"{gain.base_rmse_raw:.4g} / {gain.extended_rmse_raw:.4g} {video.unit}, {gain.gain_raw:.3f} "
            f"(noise sd {gain.noise_floor_raw:.4g})",
        ),
        ("interior", f"{gain.margin} px left out at each edge"),
    ]
    if source_map is not None:
        _source_map_figure(video, gain, source_map, out / "source_map.png", mpl)
        rows.append(
            (
                "source map dT/dt = a Lap T - b T + q(x, y)",
                f"forecast RMSE {source_map.rmse:.4g} {video.unit}, gain {source_map.gain:.3f}",
            )
        )
    effects = [
        f"- **{e['name']}** (score {e['score']:.1f}): "
        + ", ".join(f"{k} = {v:.4g}" for k, v in e["params"].items())
        for e in diagnosis.effects
    ] or ["- none: pure heat diffusion"]
    lines = [
        f"# Hidden-effect diagnosis: {video.name}",
        "",
        "| quantity | value |",
        "|---|---|",
        *(f"| {name} | {value} |" for name, value in rows),
        "",
        "## Effects found",
        "",
        *effects,
        "",
        "## Forecast at the end of the held-out part",
        "",
        "![measured, forecasts and deviations](forecast.png)",
        "",
        f"Measured frame, the plain and the extended forecasts at t = {when:.3f} s, and their deviations "
        f"from the measurement ({video.unit}); axes in mm.",
        "",
        "## Residual map",
        "",
        "![residual map](maps.png)",
        "",
        f"Time-mean residual of the PDE balance on the diagnosed frames ({video.unit}/s): the plain heat "
        "equation (what it leaves is what the effects must explain) and the selected model. "
        + ("Drawn: " + "; ".join(drawn) + "." if drawn else ""),
        "",
        "## Forecast error against time",
        "",
        "![RMSE against time](rmse.png)",
        "",
        "Per-frame RMSE of both forecasts on the interior; the dashed line is the noise floor, the RMSE of "
        "a perfect model against noisy frames.",
        "",
    ]
    if source_map is not None:
        lines += [
            "## Stationary source map",
            "",
            "![source map and its forecast's deviation](source_map.png)",
            "",
            "The heat input as a map (not a Gaussian spot), fitted on the same frames and scale; its "
            f"forecast RMSE is {source_map.rmse:.4g} {video.unit} against {gain.base_rmse:.4g} for the plain "
            f"model (gain {source_map.gain:.3f}).",
            "",
        ]
    report = out / "report.md"
    report.write_text("\n".join(lines), encoding="utf-8")
    return report
