"""A Markdown report with figures for a hidden-effect diagnosis and its forecast test (``anra diagnose
--report``; matplotlib on Agg: ``anra_torch[plot]``).

Figures (PNG, next to ``report.md``): ``forecast.png`` (the measured last held-out frame, both forecasts and
their deviations), ``maps.png`` (time-mean PDE residual of the plain and the selected model, with the
diagnosed source path and heterogeneity disc drawn), ``rmse.png`` (forecast RMSE against time with the noise
floor) and, with a source map, ``source_map.png``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import write_text
from anra_torch.effects import EFFECTS
from anra_torch.report.figures import colormap, import_matplotlib, mm_extent, save_figure
from anra_torch.selection import diagnose_terms
from anra_torch.video import Video

__all__ = ["DIAGNOSIS_FIGURES", "write_diagnosis_report"]

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
    extent = mm_extent(h, w, video.dx)
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
    save_figure(fig, canvas, path)
    return when


def _residual_panel(fig: Any, ax: Any, residual: Tensor, video: Video, margin: int, title: str) -> None:
    h, w = video.frames.shape[-2:]
    values = residual.to(torch.float64).numpy()
    full = np.full((h, w), np.nan)
    full[margin : h - margin, margin : w - margin] = values
    limit = float(np.nanpercentile(np.abs(values), 99.5)) or 1.0
    image = ax.imshow(
        full, extent=mm_extent(h, w, video.dx), vmin=-limit, vmax=limit, cmap=colormap("RdBu_r")
    )
    ax.set_title(title)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    fig.colorbar(image, ax=ax, label=f"residual ({video.unit}/s)", shrink=0.9)


def _maps_figure(video: Video, diagnosis: Any, gain: Any, path: Path, mpl: tuple[Any, Any]) -> list[str]:
    """Time-mean PDE residual of the plain model and of the selected one, with the effects' shapes."""
    Figure, canvas = mpl

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
        draw = EFFECTS[effect["name"]].draw
        for ax in axes:
            caption = draw(ax, effect["params"]) if draw is not None else None
            ax.set_xlim(0, w * video.dx)
            ax.set_ylim(h * video.dx, 0)
        if draw is not None:
            drawn.append(caption)
    save_figure(fig, canvas, path)
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
    save_figure(fig, canvas, path)


def _source_map_figure(video: Video, gain: Any, mapped: Any, path: Path, mpl: tuple[Any, Any]) -> None:
    """The fitted map q(x, y) and the map model's deviation from the last held-out frame."""
    Figure, canvas = mpl
    h, w = video.frames.shape[-2:]
    extent = mm_extent(h, w, video.dx)
    m = gain.margin
    inside = (slice(m, h - m), slice(m, w - m))
    forcing = np.full((h, w), np.nan)
    forcing[inside] = mapped.model.forcing.to(torch.float64).numpy()[inside]
    deviation = (mapped.predicted[-1] - gain.measured[-1]).to(torch.float64).numpy()
    limit = float(np.percentile(np.abs(deviation[inside]), 99.5)) or 1.0
    fig = Figure(figsize=(12.4, 5.0), layout="constrained")
    left, right = fig.subplots(1, 2)
    image = left.imshow(forcing, extent=extent, cmap=colormap("inferno"))
    left.set_title(f"source map q(x, y); a = {mapped.model.a:.3g} mm^2/s, b = {mapped.model.b:.3g} 1/s")
    fig.colorbar(image, ax=left, label=f"q ({video.unit}/s)", shrink=0.9)
    dev = right.imshow(deviation, extent=extent, vmin=-limit, vmax=limit, cmap=colormap("RdBu_r"))
    right.set_title(f"source-map forecast - measured, t = {float(gain.times[-1]):.3f} s")
    fig.colorbar(dev, ax=right, label=f"deviation ({video.unit})", shrink=0.9)
    for ax in (left, right):
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    save_figure(fig, canvas, path)


def write_diagnosis_report(
    out_dir: str | os.PathLike[str], video: Video, diagnosis: Any, gain: Any, source_map: Any = None
) -> Path:
    """Write ``report.md`` with ``forecast.png``, ``maps.png`` and ``rmse.png`` for a diagnosis.

    Args:
        out_dir: directory to write into (created if needed).
        video: the whole video (``dt`` in s, ``dx`` in mm label the axes).
        diagnosis: :class:`anra_torch.selection.Diagnosis` of its fit part.
        gain: :class:`anra_torch.forecast.GainResult` of the same split.
        source_map: optional :class:`anra_torch.forecast.SourceMapGain` of the same split; adds
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
    mpl = import_matplotlib()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    when = _forecast_figure(video, gain, out / "forecast.png", mpl)
    drawn = _maps_figure(video, diagnosis, gain, out / "maps.png", mpl)
    _rmse_figure(video, gain, out / "rmse.png", mpl)
    rows = _rows(video, diagnosis, gain)
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
        *_figure_sections(video, when, drawn),
        *(_source_map_section(video, gain, source_map) if source_map is not None else []),
    ]
    return write_text(out / "report.md", "\n".join(lines))


def _rows(video: Video, diagnosis: Any, gain: Any) -> list[tuple[str, str]]:
    """The table's (quantity, value) rows: the video, the split, both models' forecasts and the gain."""
    t, h, w = video.frames.shape
    return [
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


def _figure_sections(video: Video, when: float, drawn: list[str]) -> list[str]:
    """The report's lines on the forecast, residual-map and RMSE figures."""
    return [
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


def _source_map_section(video: Video, gain: Any, source_map: Any) -> list[str]:
    """The report's lines on the stationary source map."""
    return [
        "## Stationary source map",
        "",
        "![source map and its forecast's deviation](source_map.png)",
        "",
        "The heat input as a map (not a Gaussian spot), fitted on the same frames and scale; its "
        f"forecast RMSE is {source_map.rmse:.4g} {video.unit} against {gain.base_rmse:.4g} for the plain "
        f"model (gain {source_map.gain:.3f}).",
        "",
    ]
