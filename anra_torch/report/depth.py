"""Damage in depth in a report a person can read: the depth map and a few depth profiles.

:func:`write_depth_report` writes ``depth.md`` with:

- ``depth_map.png``: the damage depth (deepest ``Omega >= 1``, mm), its standard error and the depth of the
  CEM43 threshold, over the frame in mm;
- ``depth_profiles.png``: the peak temperature (with its +-2 standard-error band) and ``Omega`` against
  depth under a few pixels: the deepest burn and pixels whose damage reaches two thirds, one third and
  none of its depth;
- a table of the assumptions and the parameters used (:meth:`anra_torch.tissue.DepthFeatures.record`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from anra_torch.checks import write_text
from anra_torch.report.figures import colormap, format_pm, import_matplotlib, mm_extent, save_figure
from anra_torch.tissue import DepthFeatures

__all__ = ["DEPTH_FIGURES", "profile_pixels", "write_depth_report"]

DEPTH_FIGURES = ("depth_map.png", "depth_profiles.png")
"""The figures :func:`write_depth_report` draws."""


def profile_pixels(damage_depth: np.ndarray) -> list[tuple[int, int]]:
    """Pixels (row, column) whose profiles are drawn: the deepest damage, then the pixels whose damage depth
    is nearest two thirds and one third of it, and the undamaged pixel nearest the deepest (at most four,
    each once).

    Shape:
        ``damage_depth`` ``(H, W)``.
    """
    depth = np.nan_to_num(np.asarray(damage_depth, dtype=float), nan=-1.0)
    deepest = np.unravel_index(int(np.argmax(depth)), depth.shape)
    top = depth[deepest]
    chosen = [tuple(int(i) for i in deepest)]
    if top > 0:
        for share in (2 / 3, 1 / 3):
            chosen.append(
                tuple(
                    int(i) for i in np.unravel_index(int(np.argmin(np.abs(depth - share * top))), depth.shape)
                )
            )
        rows, cols = np.nonzero(depth == 0.0)
        if rows.size:
            k = int(np.argmin((rows - deepest[0]) ** 2 + (cols - deepest[1]) ** 2))
            chosen.append((int(rows[k]), int(cols[k])))
    return list(dict.fromkeys(chosen))


def _map_figure(path: Path, features: DepthFeatures, index: int, dx: float) -> None:
    figure_cls, canvas = import_matplotlib()
    maps = {k: v[index].detach().cpu().numpy() for k, v in features.maps.items()}
    h, w = maps["damage_depth_mm"].shape
    fig = figure_cls(figsize=(12, 3.6), layout="constrained")
    axes = fig.subplots(1, 3)
    threshold = features.profiles.cem43_threshold if features.profiles is not None else float("nan")
    panels = [
        ("damage_depth_mm", "damage depth (Omega >= 1), mm", "magma"),
        ("damage_depth_std_mm", "its standard error, mm", "viridis"),
        ("cem43_depth_mm", f"depth of CEM43 >= {threshold:g} min, mm", "magma"),
    ]
    for ax, (key, title, cmap) in zip(axes, panels, strict=True):
        image = ax.imshow(maps[key], cmap=colormap(cmap), extent=mm_extent(h, w, dx))
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        fig.colorbar(image, ax=ax, shrink=0.8, label="mm")
    save_figure(fig, canvas, path)


def _profile_figure(path: Path, features: DepthFeatures, index: int, dx: float) -> None:
    figure_cls, canvas = import_matplotlib()
    p = features.profiles
    depths = p.depths.cpu().numpy()
    damage = p.damage_depth[index].detach().cpu().numpy()
    fig = figure_cls(figsize=(10, 4), layout="constrained")
    left, right = fig.subplots(1, 2, sharey=True)
    for k, (row, col) in enumerate(profile_pixels(damage)):
        peak = p.peak[index, :, row, col].detach().cpu().numpy()
        band = 2.0 * p.peak_std[index, :, row, col].detach().cpu().numpy()
        label = f"({col * dx:.1f}, {row * dx:.1f}) mm: damage {damage[row, col]:.2f} mm"
        left.plot(peak, depths, color=f"C{k}", label=label)
        left.fill_betweenx(depths, peak - band, peak + band, color=f"C{k}", alpha=0.2)
        omega = p.omega[index, :, row, col].detach().cpu().numpy()
        right.plot(np.log10(np.maximum(omega, 1e-12)), depths, color=f"C{k}")
    right.axvline(0.0, color="k", lw=0.8, ls="--")
    left.set_ylim(float(depths[-1]), 0.0)
    left.set_xlabel("peak temperature (C), +-2 standard errors")
    left.set_ylabel("depth (mm)")
    right.set_xlabel("log10 Omega (damage where >= 0)")
    right.set_xlim(-6, None)
    left.legend(fontsize=7)
    save_figure(fig, canvas, path)


def write_depth_report(
    directory: str | Path, name: str, features: DepthFeatures, dx: float, index: int = 0
) -> Path:
    """Write ``depth.md`` and its figures for video ``index`` of ``features`` (pixel size ``dx`` mm); returns
    the Markdown file's path. Without depth maps for that video the report says why and draws nothing.

    Raises:
        ImportError: matplotlib missing (``anra_torch[plot]``).
        OSError: the directory cannot be written.
    """
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    record = features.record(index)
    lines = [f"# Damage in depth: {name}", ""]
    if not record["maps"]:
        lines += [f"No depth maps: {record['message']}", ""]
    else:
        _map_figure(out / DEPTH_FIGURES[0], features, index, dx)
        _profile_figure(out / DEPTH_FIGURES[1], features, index, dx)
        deepest = float(np.nanmax(features.maps["damage_depth_mm"][index].detach().cpu().numpy()))
        lines += [
            f"Deepest damage (Omega >= 1): {deepest:.3f} mm.",
            "",
            f"![damage depth map]({DEPTH_FIGURES[0]})",
            "",
            f"![depth profiles]({DEPTH_FIGURES[1]})",
            "",
        ]
    a = format_pm(record["diffusivity_mm2_s"] or float("nan"), record["diffusivity_std_mm2_s"], "mm^2/s")
    b = format_pm(record["loss_rate_per_s"] or float("nan"), record["loss_rate_std_per_s"], "1/s")
    lines += [
        "| assumption or parameter | value |",
        "|---|---|",
        f"| diffusivity a | {a} |",
        f"| loss rate b | {b} |",
    ]
    for key in ("parameters_from", "absorption", "geometry", "model", "misfit", "volumetric", "message"):
        lines.append(f"| {key} | {record.get(key)} |")
    return write_text(out / "depth.md", "\n".join(lines) + "\n")
