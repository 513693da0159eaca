"""The phases of a recording in a report a person can read: the timeline, and per phase the forecasts.

:func:`write_phase_report` writes ``phases.md`` with:

- ``phases.png``: the hot-spot signal over time with the phases found shaded;
- per analysed phase ``phase_<k>_<kind>.png``: the measured frame, the plain and the extended forecast at
  the last held-out frame, and the deviations (the residual maps) of both, on one colour scale each;
- a table: kind, frames, times, model family, the extension chosen, diffusivity, causes and gains.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from anra_torch.checks import write_text
from anra_torch.report.figures import format_pm, import_matplotlib, save_figure
from anra_torch.video import Video, hot_spot_signal, measured_frames

__all__ = ["forecast_figure", "timeline_figure", "write_phase_report"]

_COLOURS = {"baseline": "0.75", "heating": "tab:red", "cooling": "tab:blue", "steady": "tab:green"}


def timeline_figure(path: Path, title: str, video: Video, phases: list[Any]) -> None:
    """The hot-spot signal (mean of the 3 x 3 px around the pixel that rises most) with ``phases``
    (:class:`~anra_torch.video.Phase`) shaded, against time in s; a video resampled from irregular times
    marks the frames that stand for its measured samples, the rest being interpolated between them."""
    figure_cls, canvas = import_matplotlib()
    signal, _ = hot_spot_signal(video.frames)
    n = signal.numel()
    t = video.t.numpy() if video.t is not None else np.arange(n) * video.dt
    fig = figure_cls(figsize=(6.5, 3.0), layout="constrained")
    ax = fig.add_subplot()
    measured_t = video.meta.get("measured_t")
    if measured_t is None or video.t is None:
        ax.plot(t, signal.numpy(), "k.-", ms=3, lw=0.8)
    else:
        sampled = measured_frames(video.t, measured_t).numpy()
        ax.plot(t, signal.numpy(), "k-", lw=0.8, label="resampled")
        ax.plot(t[sampled], signal.numpy()[sampled], "ko", ms=4, label="measured samples")
    for phase in phases:
        ax.axvspan(
            phase.t_start, phase.t_stop, color=_COLOURS.get(phase.name, "0.5"), alpha=0.2, label=phase.name
        )
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"hot spot ({video.unit})")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    save_figure(fig, canvas, path)


def forecast_figure(
    path: Path, title: str, forecasts: tuple[np.ndarray, np.ndarray, np.ndarray], unit: str
) -> None:
    """Measured, plain and extended forecast and their deviations at the last held-out frame.

    Shape:
        each of ``forecasts`` (measured, plain, extended) ``(K, H, W)``.
    """
    figure_cls, canvas = import_matplotlib()
    measured, plain, extended = (np.asarray(f)[-1] for f in forecasts)
    lo, hi = float(np.nanmin(measured)), float(np.nanmax(measured))
    dev = max(float(np.nanmax(np.abs(plain - measured))), float(np.nanmax(np.abs(extended - measured))), 1e-9)
    fig = figure_cls(figsize=(11, 6.2), layout="constrained")
    axes = fig.subplots(2, 3)
    panels = [
        (measured, "measured", "inferno", lo, hi),
        (plain, "plain heat equation", "inferno", lo, hi),
        (plain - measured, "plain - measured", "RdBu_r", -dev, dev),
        (measured, "measured", "inferno", lo, hi),
        (extended, "extended model", "inferno", lo, hi),
        (extended - measured, "extended - measured (residual)", "RdBu_r", -dev, dev),
    ]
    for ax, (image, name, cmap, vmin, vmax) in zip(axes.flat, panels, strict=True):
        im = ax.imshow(image, cmap=cmap, vmin=vmin, vmax=vmax)
        ax.set_title(name, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, shrink=0.8, label=unit)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, canvas, path)


def _number(x: float | None, spec: str = ".4g") -> str:
    return "n/a" if x is None else format(x, spec)


def write_phase_report(directory: str | Path, video: Video, phases: list[Any]) -> Path:
    """Write ``phases.md`` and its figures for :func:`~anra_torch.forecast.diagnose_recording`'s ``phases``
    (:class:`~anra_torch.forecast.PhaseDiagnosis`) of ``video``; returns the Markdown file's path."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    name = Path(str(video.source)).name
    timeline_figure(
        out / "phases.png", f"{name}: phases found from the data", video, [p.phase for p in phases]
    )
    lines = [
        f"# Phases of {name}",
        "",
        "![hot-spot signal with the phases](phases.png)",
        "",
        "| phase | frames | t (s) | family; extension | a (mm^2/s) | causes | RMSE plain | RMSE extended "
        "| gain |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    figures = []
    for k, found in enumerate(phases):
        p, r = found.phase, found.to_record()
        where = f"| {p.name} | {p.start}-{p.stop - 1} | {p.t_start:.4g}-{p.t_stop:.4g} |"
        if found.reason is not None:
            lines.append(f"{where} not analysed: {found.reason} | | | | | |")
            continue
        base = r["base"]
        if base.get("diffusivity_lower_bound") is not None:
            a = f"unresolved, > {base['diffusivity_lower_bound']:.3g}"
        else:
            a = format_pm(base["diffusivity"], None) + (
                f" ({', '.join(base['flags'])})" if base.get("flags") else ""
            )
        causes = ", ".join(e["name"] for e in r["effects"]) or "none"
        lines.append(
            f"{where} {found.family}; {found.model} | {a} | {causes} | {_number(found.base_rmse)} | "
            f"{_number(found.extended_rmse)} | {_number(found.gain, '+.2f')} |"
        )
        if found.forecasts is not None:
            png = f"phase_{k}_{p.name}.png"
            f = found.forecasts
            after = f["measured"].shape[0] * video.dt
            title = f"{name} {p.name} ({found.family}; {found.model}): {after:.3g} s after the split"
            forecast_figure(
                out / png,
                title,
                tuple(f[key].numpy() for key in ("measured", "plain", "extended")),
                video.unit,
            )
            figures.append(f"![{p.name}: measured, forecasts and residuals]({png})")
    return write_text(out / "phases.md", "\n".join([*lines, "", *figures, ""]))
