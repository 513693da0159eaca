"""A Markdown report with figures for one diffusivity estimate (matplotlib on Agg: ``anra_torch[plot]``).

Figures (PNG, next to ``report.md``):

- ``frames.png``: first, middle and last frame on one colour scale (the data's units);
- ``attention.png``: the RTC attention weights at the middle estimate frame;
- ``field.png``: the windowed diffusivity field a(x, y) and its confidence (when the result has one);
- ``per_frame.png``: a[k] against time with the global estimate, its +-2 standard-error band and the truth.

The numbers in the table are the result's :meth:`~anra_torch.estimation.ANRAResult.to_record`, the
same as ``anra estimate --json`` prints.
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

from anra_torch.balance import MatchedFilters
from anra_torch.checks import write_text
from anra_torch.estimation import ANRAEstimator, ANRAResult
from anra_torch.layers import RTCAttention
from anra_torch.report.figures import colormap, format_pm, import_matplotlib, mm_extent, save_figure
from anra_torch.video import Video

__all__ = ["FIGURES", "attention_map", "write_estimate_report"]

FIGURES = ("frames.png", "attention.png", "field.png", "per_frame.png")
"""File names of the figures a report may hold (``field.png`` only when the result has a field)."""


# ------------------------------------------------------------------------------------------- attention
def _rtc_module(estimator: ANRAEstimator | None) -> tuple[nn.Module, bool]:
    """The RTC attention to draw and whether the estimator weighted its pixels with it."""
    if estimator is not None and isinstance(estimator.attention, RTCAttention):
        return estimator.attention, True
    return RTCAttention(), False


def attention_map(video: Video, result: ANRAResult, estimator: ANRAEstimator | None = None) -> Tensor:
    """RTC attention weights at the middle estimate frame, placed on the input frame grid.

    dT/dt as the estimator balanced it (its matched filters at the smoothing the result chose; without
    ``estimator`` the default filters with the time length ``result`` implies), weighted by the estimator's
    :class:`RTCAttention` when it has one, else by the paper's (``RTCAttention()``). Pixels the filters
    cannot reach (the border, or next to masked pixels) are NaN; the others sum to 1.

    Shape:
        ``video.frames`` ``(T, H, W)``; output ``(H, W)``.
    """
    frames = video.frames.to(torch.float64).unsqueeze(0)  # (1, T, H, W)
    filters = _filters_of(estimator, result, frames.shape[1])
    finite = torch.isfinite(frames)
    if not bool(finite.all()):
        fill = frames[finite].mean() if bool(finite.any()) else torch.tensor(0.0, dtype=frames.dtype)
        frames = torch.where(finite, frames, fill)
    k = result.per_frame.shape[-1] // 2
    window = slice(k, k + filters.time.length)
    # dT/dt through the estimator's own time filter and Gaussian (the weights' input), (1, 1, h, w)
    rate = filters.smoother(filters.time_stage(frames[:, window], video.dt)[0])
    m = filters.smoother.radius
    bad = (~finite[:, window]).to(torch.float64).unsqueeze(1)
    bad = F.max_pool3d(bad, (filters.time.length, 2 * m + 1, 2 * m + 1), stride=1).squeeze(1) > 0
    weights = _rtc_module(estimator)[0](rate, ~bad)[0, 0]
    weights = torch.where(bad[0, 0], torch.full_like(weights, torch.nan), weights)
    return F.pad(weights, (m, m, m, m), value=torch.nan)


def _filters_of(estimator: ANRAEstimator | None, result: ANRAResult, n_frames: int) -> MatchedFilters:
    """The matched filters the estimate was made with (without ``estimator``: the default family with the
    time length ``result`` implies and the smoothing it chose)."""
    sigma = float(result.smoothing)
    if estimator is not None:
        return next(f for f in estimator.filters if f.sigma == sigma)
    return MatchedFilters(sigma, time_length=n_frames - result.per_frame.shape[-1] + 1)


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
        image = ax.imshow(frames[k], extent=mm_extent(h, w, video.dx), vmin=lo, vmax=hi, cmap="inferno")
        ax.set_title(f"frame {k}, t = {times[k]:.3f} s")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    fig.colorbar(image, ax=list(axes), label=f"temperature ({video.unit})", shrink=0.9)
    save_figure(fig, canvas, path)


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
    image = ax.imshow(weights, extent=mm_extent(h, w, video.dx), cmap=colormap("viridis"))
    ax.set_title(f"RTC attention, estimate frame {k} (t = {when:.3f} s)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    fig.colorbar(image, ax=ax, label="attention weight (fraction of the frame's total)")
    save_figure(fig, canvas, path)
    return when


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
    image = ax_a.imshow(field, extent=mm_extent(h, w, video.dx), vmin=lo, vmax=hi, cmap=colormap("viridis"))
    ax_a.set_title("windowed diffusivity a(x, y) (grey: no estimate)")
    bar = fig.colorbar(image, ax=ax_a, label="a (mm^2/s)")
    bar.ax.ticklabel_format(useOffset=False)
    image = ax_c.imshow(confidence, extent=mm_extent(h, w, video.dx), vmin=0.0, vmax=1.0, cmap="magma")
    ax_c.set_title("confidence (signal fraction of the window)")
    fig.colorbar(image, ax=ax_c, label="confidence (1)")
    for ax in (ax_a, ax_c):
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    save_figure(fig, canvas, path)
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
    save_figure(fig, canvas, path)


# ------------------------------------------------------------------------------------------- report
def _report_lines(
    video: Video,
    record: dict[str, Any],
    truth: float | None,
    estimator: ANRAEstimator | None,
    when: float,
    field_stats: Any,
) -> list[str]:
    """The lines of ``report.md``: the table of :func:`_rows`, then each figure with its caption."""
    sigma = record["smoothing_px"]
    return [
        f"# ANRA diffusivity estimate: {video.name}",
        "",
        "Model dT/dt = a (d11 + d22) T, estimated directly from the frames "
        "(ANRA: El-Kebir et al., arXiv 2203.13148).",
        "",
        "| quantity | value |",
        "|---|---|",
        *(f"| {name} | {value} |" for name, value in _rows(video, record, truth, estimator)),
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
        f"{sigma:g} px smoothing. Grey: border the filters cannot reach. {_attention_usage(estimator)}",
        "",
        *_field_section(field_stats, estimator),
        "## Per-frame estimates",
        "",
        "![per-frame diffusivity](per_frame.png)",
        "",
        "a[k] per time window against time (s); the line is the global estimate with its ±2 standard-error "
        "band" + (", dashed: the truth" if truth is not None else "") + ". Single frames scatter far more "
        "than the band: the noise of consecutive time derivatives largely cancels in the global sums.",
        "",
    ]


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
    _check_inputs(video, result)
    mpl = import_matplotlib()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    _frames_figure(video, out / "frames.png", mpl)
    when = _attention_figure(video, result, estimator, out / "attention.png", mpl)
    field_stats = None
    if result.field is not None and result.confidence is not None:
        field_stats = _field_figure(video, result, out / "field.png", mpl)
    _per_frame_figure(result, truth, out / "per_frame.png", mpl)

    record = result.to_record(unit=video.unit)
    lines = _report_lines(video, record, truth, estimator, when, field_stats)
    return write_text(out / "report.md", "\n".join(lines))


def _check_inputs(video: Video, result: ANRAResult) -> None:
    if result.diffusivity.ndim != 0:
        raise ValueError(
            f"result must be for a single video, got a batch of {result.diffusivity.shape[0]}; "
            "index it or use ANRAResult.unbatched()"
        )
    if video.dx is None:
        raise ValueError("video.dx is None; the report needs the pixel size in mm")
    t = video.frames.shape[0]
    if result.per_frame.ndim != 1 or result.per_frame.shape[0] > t:
        raise ValueError(
            f"result has {tuple(result.per_frame.shape)} per-frame estimates, not one per window of "
            f"this {t}-frame video"
        )


def _rows(
    video: Video, record: dict[str, Any], truth: float | None, estimator: ANRAEstimator | None
) -> list[tuple[str, str]]:
    """The table's (quantity, value) rows: the estimate, the truth, the video and the result's record."""
    estimate = math.nan if record["diffusivity"] is None else record["diffusivity"]  # format_pm: n/a
    error = math.nan if record["std_error"] is None else record["std_error"]
    t, h, w = video.frames.shape
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
    sigma = record["smoothing_px"]
    rows += [
        ("spatial smoothing chosen", f"{sigma:g} px ({sigma * video.dx:.4g} mm)"),
        ("noise sd", f"{record['noise_sd']:.4g} {video.unit}"),
        ("reliability (signal fraction)", f"{record['reliability']:.4f}"),
        ("masked non-finite pixels", f"{record['n_masked']}"),
        ("valid", "yes" if record["valid"] else f"no: {record['message']}"),
    ]
    return rows


def _attention_usage(estimator: ANRAEstimator | None) -> str:
    """Whether the drawn attention is what the estimator weighted with."""
    if _rtc_module(estimator)[1]:
        return "The estimator weighted its pixels with these."
    if estimator is not None:
        kind = type(estimator.attention).__name__
        return f"Shown for reference (the paper's form): this estimator weighted pixels with {kind}."
    return "The paper's form, shown for reference (the estimator's own weighting is not known here)."


def _field_section(field_stats: dict[str, float] | None, estimator: ANRAEstimator | None) -> list[str]:
    """The report's lines on the windowed field (or why there is none)."""
    if field_stats is None:
        return ["## Diffusivity field", "", "Not computed: estimate with a window (e.g. `--window 15`).", ""]
    window = f" ({estimator.window} px windows)" if estimator is not None and estimator.window else ""
    summary = (
        f"median {field_stats['median']:.4g} mm^2/s, 2-98 % range [{field_stats['p2']:.4g}, "
        f"{field_stats['p98']:.4g}] mm^2/s, "
        if "median" in field_stats
        else "no window with measurable signal, "
    )
    return [
        "## Diffusivity field",
        "",
        "![windowed diffusivity and confidence](field.png)",
        "",
        f"Windowed estimate a(x, y){window}: {summary}estimated on "
        f"{100 * field_stats['coverage']:.1f} % of the pixels. Confidence is the signal fraction of "
        "each window's regressor energy (1: noiseless).",
        "",
    ]
