"""A flash recording's defect map in a report a person can read.

:func:`write_flash_report` writes ``flash.md`` with ``flash_maps.png``: the defect score with the mask's
outline, the depth fraction, the through-thickness time constant, and the standard contrasts beside them
(TSR's second derivative at its frame of largest spread, PCT's first component, PPT's phase at the lowest
frequency); then the plate's ``L^2 / a_z`` and a table of the defects
(:meth:`anra_torch.flash.FlashMaps.record`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from anra_torch.checks import write_text
from anra_torch.flash import FlashMaps
from anra_torch.report.figures import colormap, format_pm, import_matplotlib, mm_extent, save_figure

__all__ = ["FLASH_FIGURES", "write_flash_report"]

FLASH_FIGURES = ("flash_maps.png",)
"""The figures :func:`write_flash_report` draws."""


def _panels(maps: FlashMaps) -> list[tuple[np.ndarray, str, str]]:
    arrays = maps.arrays()
    spread = arrays["tsr_d2"].reshape(len(arrays["tsr_d2"]), -1).std(1)
    k = int(np.argmax(spread))
    with np.errstate(divide="ignore"):
        log_time = np.log10(np.where(np.isfinite(arrays["depth_time"]), arrays["depth_time"], np.nan))
    return [
        (arrays["defect_score"], "defect score (outline: defect mask)", "magma"),
        (arrays["depth_fraction"], "depth fraction d / L", "viridis"),
        (log_time, "log10 time constant tau (s)", "cividis"),
        (arrays["tsr_d2"][k], f"TSR d2 at {arrays['tsr_times'][k]:.3g} s", "RdBu_r"),
        (arrays["pct"][0], "PCT component 1", "RdBu_r"),
        (arrays["ppt"][0], f"PPT phase at {arrays['ppt_frequencies'][0]:.3g} Hz (rad)", "RdBu_r"),
    ]


def _figure(path: Path, maps: FlashMaps, dx: float) -> None:
    figure_cls, canvas = import_matplotlib()
    mask = maps.defects.defect_mask.detach().cpu().numpy()
    h, w = mask.shape
    fig = figure_cls(figsize=(12, 7), layout="constrained")
    for ax, (image, title, cmap) in zip(fig.subplots(2, 3).ravel(), _panels(maps), strict=True):
        shown = ax.imshow(image, cmap=colormap(cmap), extent=mm_extent(h, w, dx))
        if mask.any():
            ax.contour(
                mask.astype(float),
                [0.5],
                colors="w",
                linewidths=0.8,
                extent=(0, w * dx, 0, h * dx),
                origin="upper",
            )
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        fig.colorbar(shown, ax=ax, shrink=0.8)
    save_figure(fig, canvas, path)


def write_flash_report(directory: str | Path, maps: FlashMaps, dx: float) -> Path:
    """Write ``flash.md`` and ``flash_maps.png`` into ``directory`` for ``maps`` (pixel size ``dx`` mm);
    returns the Markdown file's path.

    Raises:
        ImportError: matplotlib missing (``anra_torch[plot]``).
        OSError: the directory cannot be written.
    """
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    _figure(out / FLASH_FIGURES[0], maps, dx)
    record = maps.record()
    plate = format_pm(record["plate_time"] or float("nan"), record["plate_time_std_error"], "s")
    reached = "yes" if record["back_wall_reached"] else "no: the plate's time constant is a lower bound"
    a_x, a_y, a_xy = record["lateral_diffusivity"]
    lines = [
        "# Flash: defect map",
        "",
        f"![defect map and contrasts]({FLASH_FIGURES[0]})",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| plate L^2 / a_z (front-face data fix only this ratio) | {plate} |",
        f"| back wall reached in the recording | {reached} |",
        f"| lateral diffusivities a_x, a_y, a_xy taken off | {a_x:.3g}, {a_y:.3g}, {a_xy:.3g} mm^2/s |",
        f"| flash: first frame after it, that frame's time since it | {record['flash_frame']}, "
        f"{record['first_frame_time']:.3g} s |",
        f"| T_ref, noise sd | {record['T_ref']:.4g}, {record['noise_sd']:.2g} |",
        "",
    ]
    if record["defects"]:
        lines += ["| defect | x (mm) | y (mm) | area (mm^2) | depth fraction d / L | runs out of the frame |"]
        lines += ["|---|---|---|---|---|---|"]
        for k, d in enumerate(record["defects"], 1):
            lines.append(
                f"| {k} | {d['x']:.2f} | {d['y']:.2f} | {d['area']:.3g} | {d['depth_fraction']:.2f} | "
                f"{'yes' if d['touches_edge'] else 'no'} |"
            )
    else:
        lines.append("No defect found.")
    return write_text(out / "flash.md", "\n".join(lines) + "\n")
