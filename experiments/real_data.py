"""The whole pipeline on measured thermography (../shared/data): fit, forecast, what goes wrong, why, gain.

Recordings:

- ``laser_silicone/Nov19`` and ``Nov19_2``: FLIR C3-X radiometric JPEGs (degC from the raw counts and
  Planck constants), 25 frames with EXIF/FFF timestamps stepping 4.1-5.9 s; resampled EXPLICITLY onto a
  uniform grid at the median step (linear interpolation in time, stated in results.json). Pixel size
  unknown: nominal 0.55 mm, interval 0.5-0.6 mm (C3-X field of view at ~10 cm), carried into an interval
  on ``a`` (``a`` scales as ``dx^2``).
- ``flir_csv/*.csv``: FLIR Tools box exports (apparent degC, emissivity 1), calibrated to true degC with
  ``calibration_og.csv``; frame period and pixel size undocumented: 0.1 s and 0.25 mm (the source's
  assumptions) are used and every diffusivity from them is conditional on them.

Per recording, the phases (baseline / heating / cooling) come from the data
(:func:`anra_torch.video.segment_phases`). Per phase:

- Laser silicone (frames 96 x 128 px): the ANRA estimate of ``a`` (plain heat equation), then
  :func:`anra_torch.forecast.assess_gain`: the diagnosis on the first 60 % of the phase names the
  effects, and the plain model forecasts the held-out rest from the measured frame at the split (RMSE on
  the interior, degC, at the diagnosis' scale). The extended model is a loss plus the heat input as a
  measured map (:mod:`anra_torch.forecast.source_map`, ``dT/dt = a Lap T - b T + q(x, y)``, fitted on the same
  frames at the same scale): the beam from a fibre tip is not a Gaussian spot, and the parametric
  extension (a Gaussian spot on a straight path, extrapolated) is reported beside it as
  ``parametric_gain``.
- FLIR CSV boxes (9-15 px wide) are smaller than the project's filters need (20-26 px), so a small-box
  model written here replaces them: the same 11-frame moving average on both sides of the PDE, central
  time differences and the 5-point Laplacian; least squares for the plain model ``dT/dt = a Lap T`` and
  the loss model ``dT/dt = a Lap T - b (T - Tbar) + c`` fitted on the 100 frames before the split (``b``:
  linear loss to the sample and stage, ``c``: net heating by the spot source); forecasts by explicit
  Euler substeps with the MEASURED edge pixels as Dirichlet boundary (the box edges are not insulated).
  Conduction crosses such a box within a frame (the plain ``a`` comes out about 0: not resolved), so
  while the source is on the extended model is the quasi-steady source ``T = harmonic(edges) + S(x, y)``
  (:func:`quasi_steady_forecast`); once it is off, the loss model. The other one's gain is reported too.

Outputs in --out (default results/real_data): table.md, results.json, one Fig.-3-style PNG per recording
and phase (measured, plain prediction and its deviation, extended prediction and its deviation, N s after
the split) and the hot-spot signal with its phases per recording.

    python experiments/real_data.py                      # all recordings (about 15 s)
    python experiments/real_data.py --quick              # one laser run and one CSV file
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from anra_torch.estimator import ANRAEstimator
from anra_torch.forecast import assess_gain, source_map_gain, split_index
from anra_torch.selection import diagnose_terms
from anra_torch.video import Video, load_video
from anra_torch.video.calibration import PixelSize, apply_calibration, load_calibration
from anra_torch.video.phases import Phase, hot_spot_signal, segment_phases

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
LASER_DX = PixelSize(0.55, 0.5, 0.6)  # mm/px, C3-X 41 x 31 deg over 128 x 96 px at about 10 cm
CSV_DT, CSV_DX = 0.1, 0.25  # s, mm: the source's assumptions, not documented facts
PDMS = (0.10, 0.15)  # mm^2/s, literature
BOX_SMOOTH = 11  # frames of the moving average in the small-box model
BOX_HORIZON = 200  # frames forecast at most in a CSV phase (20 s at the assumed 10 frames/s)
BOX_FIT_WINDOW = 100  # frames just before the split that the small-box models are fitted on (of 100,
# 200 and 400 tried, the most local; the gains for the others are stated in the README)

CAUSES = {
    "source": "heat source while it is on (laser / heated spot)",
    "linear_loss": "heat loss into the deep liquid / sample and to the air",
    "advection": "flow or drift of the hot region",
    "anisotropy": "direction-dependent spreading",
    "heterogeneity": "a region that conducts differently",
    "nonlinear_diffusion": "temperature-dependent diffusivity",
}


# ------------------------------------------------------------------------------------- small-box model
def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    kernel = np.ones(n) / n
    c = np.cumsum(np.pad(x, ((1, 0), (0, 0), (0, 0))), axis=0)
    return (c[n:] - c[:-n]) / n if x.shape[0] >= n else x[:0] * kernel[0]


def _lap(u: np.ndarray, dx: float) -> np.ndarray:
    return (
        u[..., 1:-1, 2:] + u[..., 1:-1, :-2] + u[..., 2:, 1:-1] + u[..., :-2, 1:-1] - 4 * u[..., 1:-1, 1:-1]
    ) / dx**2


def box_fit(frames: np.ndarray, dt: float, dx: float, extended: bool) -> dict[str, float]:
    """Least squares on the interior: plain ``dT/dt = a Lap T`` or extended ``+ (-b (T - Tbar) + c)``."""
    u = _moving_average(frames, BOX_SMOOTH)
    dudt = (u[2:] - u[:-2]) / (2 * dt)
    lap = _lap(u[1:-1], dx)
    y = dudt[:, 1:-1, 1:-1].reshape(-1)
    columns = [lap.reshape(-1)]
    tbar = float(u.mean())
    if extended:
        columns += [-(u[1:-1, 1:-1, 1:-1].reshape(-1) - tbar), np.ones_like(y)]
    x = np.stack(columns, axis=1)
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    fit = {"a": float(beta[0]), "b": 0.0, "c": 0.0, "T_ref": tbar}
    if extended:
        fit.update(b=float(beta[1]), c=float(beta[2]))
    return fit


def box_forecast(
    frames: np.ndarray, dt: float, dx: float, fit: dict[str, float], start: int, n: int
) -> np.ndarray:
    """Forecast ``n`` frames after ``frames[start]``; edges follow the measurement (Dirichlet in time)."""
    a = max(fit["a"], 0.0)  # a negative diffusivity is ill-posed forward: treated as no diffusion
    rate = a / dx**2 * 4 + max(fit["b"], 0.0)
    substeps = max(1, math.ceil(dt * rate / 0.4))
    h = dt / substeps
    u = frames[start].astype(np.float64).copy()
    out = np.empty((n, *u.shape))
    for k in range(n):
        for s in range(substeps):
            w = (s + 1) / substeps
            edge = (1 - w) * frames[start + k] + w * frames[start + k + 1]
            du = a * _lap(u, dx) - fit["b"] * (u[1:-1, 1:-1] - fit["T_ref"]) + fit["c"]
            u[1:-1, 1:-1] += h * du
            u[0], u[-1], u[:, 0], u[:, -1] = edge[0], edge[-1], edge[:, 0], edge[:, -1]
        out[k] = u
    return out


@functools.cache
def _laplace_inverse(height: int, width: int) -> np.ndarray:
    """Inverse of the 5-point Laplacian on the interior of a ``height`` x ``width`` box (zero edges)."""
    second = lambda n: np.diag(np.full(n, -2.0)) + np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1)  # noqa: E731
    laplace = np.kron(np.eye(height - 2), second(width - 2)) + np.kron(second(height - 2), np.eye(width - 2))
    return np.linalg.inv(laplace)


def harmonic_interior(frames: np.ndarray) -> np.ndarray:
    """Each frame's steady state for its measured edges: the interior solving the 5-point Laplace equation.

    Shape:
        ``(T, H, W)`` -> ``(T, H - 2, W - 2)``.
    """
    t, h, w = frames.shape
    edges = frames.astype(np.float64).copy()
    edges[:, 1:-1, 1:-1] = 0.0
    rhs = -_lap(edges, 1.0).reshape(t, -1)  # the edges' pull on the interior
    return (rhs @ _laplace_inverse(h, w).T).reshape(t, h - 2, w - 2)


def quasi_steady_forecast(frames: np.ndarray, fit_part: slice, start: int, n: int) -> np.ndarray:
    """Conduction faster than a frame with a stationary source: ``T = harmonic(edges) + S(x, y)``.

    The limit of ``dT/dt = a Lap T + q(x, y)`` for ``a dt / dx^2 >> 1``: the interior is at every frame
    the steady state for its measured edges plus the source's particular solution ``S`` (``Lap S =
    -q / a``, zero on the edges), ``S`` the mean of ``T - harmonic(edges)`` over ``frames[fit_part]``.

    Shape:
        ``(T, H, W)`` -> ``(n, H, W)`` (the frames after ``frames[start]``; edges as measured).
    """
    source = (frames[fit_part, 1:-1, 1:-1] - harmonic_interior(frames[fit_part])).mean(axis=0)
    out = frames[start + 1 : start + 1 + n].astype(np.float64).copy()
    out[:, 1:-1, 1:-1] = harmonic_interior(out) + source
    return out


def edge_explained(frames: np.ndarray) -> float:
    """Fraction of the interior's variance over time that the steady state for its edges explains."""
    inner = frames[:, 1:-1, 1:-1] - frames[:, 1:-1, 1:-1].mean(axis=0)
    harmonic = harmonic_interior(frames)
    harmonic -= harmonic.mean(axis=0)
    return float(1 - ((inner - harmonic) ** 2).sum() / (inner**2).sum())


def box_phase(video: Video, phase: Phase, window: int = BOX_FIT_WINDOW) -> dict[str, Any]:
    """Small-box fits on the ``window`` frames before the split, and their held-out gains.

    The extended model follows the phase: while the source is on (heating), the quasi-steady source
    model; once it is off (cooling), the loss model. The other one's gain is reported beside it.
    """
    frames = video.frames[phase.start : phase.stop].double().numpy()
    split = int(round(0.6 * (frames.shape[0] - 1)))
    horizon = min(frames.shape[0] - 1 - split, BOX_HORIZON)
    fit_slice = slice(max(0, split - window), split + 1)
    fit_part = frames[fit_slice]
    plain = box_fit(fit_part, video.dt, video.dx, extended=False)
    loss = box_fit(fit_part, video.dt, video.dx, extended=True)
    measured = frames[split + 1 : split + 1 + horizon]
    pred_plain = box_forecast(frames, video.dt, video.dx, plain, split, horizon)
    pred_loss = box_forecast(frames, video.dt, video.dx, loss, split, horizon)
    pred_quasi = quasi_steady_forecast(frames, fit_slice, split, horizon)
    inner = (slice(None), slice(1, -1), slice(1, -1))
    rmse = lambda p: float(np.sqrt(np.mean((p[inner] - measured[inner]) ** 2)))  # noqa: E731
    noise = float(np.std(np.diff(frames[: split + 1], axis=0)[inner]) / np.sqrt(2))
    base_rmse = rmse(pred_plain)
    gain = lambda r: 1 - r / base_rmse if base_rmse > 0 else 0.0  # noqa: E731
    heating = phase.name == "heating"
    ext_name, other_name = ("quasi-steady source", "loss") if heating else ("loss", "quasi-steady source")
    pred_ext, pred_other = (pred_quasi, pred_loss) if heating else (pred_loss, pred_quasi)
    ext_rmse, other_rmse = rmse(pred_ext), rmse(pred_other)
    if heating:
        cause = "source"
    else:  # the sign of the loss model's non-diffusive rate at the split (net heating or net loss)
        net = loss["c"] - loss["b"] * (float(frames[split].mean()) - loss["T_ref"])
        cause = "source" if net > 0 else "linear_loss"
    return {
        "model": f"small-box (5-point Laplacian, measured edges); extended: {ext_name}",
        "a_plain": plain["a"],
        "a_extended": loss["a"],
        "loss_b_per_s": loss["b"],
        "source_c_per_s": loss["c"],
        "edge_explained_fit": edge_explained(fit_part),
        "effects": [cause],
        "extended_model": ext_name,
        "base_rmse": base_rmse,
        "extended_rmse": ext_rmse,
        "gain": gain(ext_rmse),
        "other_model": other_name,
        "other_rmse": other_rmse,
        "other_gain": gain(other_rmse),
        "noise_floor": noise,
        "split": split,
        "horizon_frames": horizon,
        "_figure": (measured, pred_plain, pred_ext, horizon * video.dt),
    }


# ------------------------------------------------------------------------------------ project pipeline
def anra_phase(video: Video, phase: Phase, effects: list[str] | None = None) -> dict[str, Any]:
    """ANRA fit and held-out gain of one phase; ``effects`` restricts the diagnosis' candidates."""
    frames = video.frames[phase.start : phase.stop].double()
    est = ANRAEstimator(strict=False)(frames, video.dt, video.dx)
    split = split_index(frames.shape[0], 0.6)
    diagnosis = diagnose_terms(frames[: split + 1], video.dt, video.dx, effects=effects)
    # Frames 5 s apart: no average in time (a few frames already span the dynamics), and forecasts from
    # the measured split frame, as the source map's (source_map_gain compares like with like).
    result = assess_gain(
        frames, video.dt, video.dx, fit_fraction=0.6, diagnosis=diagnosis, time_window=1, assimilate=1
    )
    a = float(est.diffusivity)
    k = result.held_out
    mapped = source_map_gain(frames, video.dt, video.dx, result)
    source_map = mapped.model
    return {
        "model": "ANRA, diagnose_terms, assess_gain; extended: measured source map",
        "a_anra": a,
        "a_anra_interval": list(LASER_DX.diffusivity_interval(a)) if math.isfinite(a) else None,
        "a_anra_valid": bool(est.valid),
        "a_plain": result.base_a,
        "a_extended": result.extended_a,
        "effects": [e["name"] for e in result.diagnosis.effects],
        "effect_params": [{k2: float(v) for k2, v in e["params"].items()} for e in result.diagnosis.effects],
        "source_map": {
            "a": source_map.a,
            "b_per_s": source_map.b,
            "forcing_max_per_s": float(source_map.forcing.max()),
            "forcing_min_per_s": float(source_map.forcing.min()),
            "scale_px": result.scale_px,
        },
        "base_rmse": result.base_rmse,
        "extended_rmse": mapped.rmse,
        "gain": mapped.gain,
        "parametric_rmse": result.extended_rmse,
        "parametric_gain": result.gain,
        "noise_floor": result.noise_floor,
        "split": result.split,
        "horizon_frames": k,
        "_figure": (
            result.measured.numpy(),
            result.predicted_base.numpy(),
            mapped.predicted.numpy(),
            k * video.dt,
        ),
    }


# ---------------------------------------------------------------------------------------------- figures
def fig3(path: Path, title: str, figure: tuple, unit: str) -> None:
    """Measured, predicted (plain, extended) and their deviations at the last held-out frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    measured, plain, ext, after = figure
    m, p, e = measured[-1], plain[-1], ext[-1]
    lo, hi = float(np.nanmin(m)), float(np.nanmax(m))
    dev = max(float(np.nanmax(np.abs(p - m))), float(np.nanmax(np.abs(e - m))), 1e-9)
    fig, axes = plt.subplots(2, 3, figsize=(11, 6.2), constrained_layout=True)
    panels = [
        (m, "measured", "inferno", lo, hi),
        (p, "plain heat equation", "inferno", lo, hi),
        (p - m, "plain - measured", "RdBu_r", -dev, dev),
        (m, "measured", "inferno", lo, hi),
        (e, "extended model", "inferno", lo, hi),
        (e - m, "extended - measured", "RdBu_r", -dev, dev),
    ]
    for ax, (img, name, cmap, vmin, vmax) in zip(axes.flat, panels, strict=True):
        im = ax.imshow(img, cmap=cmap, vmin=vmin, vmax=vmax)
        ax.set_title(name, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, shrink=0.8, label=unit)
    fig.suptitle(f"{title}: {after:.1f} s after the split", fontsize=10)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def signal_figure(path: Path, name: str, video: Video, phases: list[Phase]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    signal, _ = hot_spot_signal(video.frames)
    t = video.t.numpy() if video.t is not None else np.arange(signal.numel()) * video.dt
    fig, ax = plt.subplots(figsize=(6, 3), constrained_layout=True)
    ax.plot(t, signal.numpy(), "k.-", ms=3, lw=0.8)
    colours = {"baseline": "0.85", "heating": "tab:red", "cooling": "tab:blue"}
    for ph in phases:
        ax.axvspan(ph.t_start, ph.t_stop, color=colours[ph.name], alpha=0.2, label=ph.name)
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"hot spot ({video.unit})")
    ax.set_title(name, fontsize=9)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=90)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------ main
def recordings(quick: bool) -> list[tuple[str, Path, dict]]:
    laser = DATA / "laser_silicone"
    runs = [("Nov19", laser / "Nov19", {}), ("Nov19_2", laser / "Nov19_2", {})]
    csvs = sorted((DATA / "flir_csv").glob("* *.csv"))
    runs += [(p.stem, p, {}) for p in csvs]
    return [runs[0], runs[2]] if quick else runs


def load(name: str, path: Path) -> Video:
    if path.is_dir():
        return load_video(path, dx=LASER_DX.value, timestamps="resample")
    video = load_video(path, dt=CSV_DT, dx=CSV_DX)
    return apply_calibration(video, load_calibration(DATA / "flir_csv" / "calibration_og.csv"))


def run(
    out: Path, quick: bool, effects: list[str] | None = None, window: int = BOX_FIT_WINDOW
) -> dict[str, Any]:
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = {"pixel_size_laser_mm": vars(LASER_DX), "csv_dt_s": CSV_DT, "csv_dx_mm": CSV_DX}
    rows = []
    for name, path, _ in tqdm(recordings(quick), desc="recordings", file=sys.stderr):
        record: dict[str, Any] = {"path": str(path)}
        results[name] = record
        try:
            video = load(name, path)
        except (ValueError, OSError) as err:  # a bad recording never stops the others
            record["error"] = str(err)
            continue
        record.update(
            frames=int(video.frames.shape[0]),
            shape=list(video.frames.shape[1:]),
            dt_s=video.dt,
            dx_mm=video.dx,
            resampled=video.meta.get("resampled"),
            calibration=video.meta.get("calibration"),
        )
        times = video.t if video.t is not None else torch.arange(video.frames.shape[0]) * video.dt
        video = replace(video, t=times.double())
        phases = segment_phases(video.frames, video.t)
        signal_figure(out / f"{name}_phases.png".replace(" ", "_"), name, video, phases)
        record["phases"] = {}
        for phase in phases:
            if phase.name == "baseline":
                continue
            tick = time.perf_counter()
            try:
                fit = anra_phase(video, phase, effects) if path.is_dir() else box_phase(video, phase, window)
            except (ValueError, RuntimeError) as err:
                record["phases"][phase.name] = {"error": str(err)}
                continue
            figure = fit.pop("_figure")
            png = out / f"{name}_{phase.name}.png".replace(" ", "_")
            fig3(png, f"{name} {phase.name} ({fit['model']})", figure, video.unit)
            fit.update(
                start_frame=phase.start,
                stop_frame=phase.stop,
                t_start=phase.t_start,
                t_stop=phase.t_stop,
                frames=phase.frames,
                seconds=time.perf_counter() - tick,
            )
            fit["cause"] = "; ".join(CAUSES.get(e, e) for e in fit["effects"][:1]) or "none found"
            record["phases"][phase.name] = fit
            rows.append((name, phase.name, fit))
    (out / "results.json").write_text(json.dumps(results, indent=1, default=float))
    (out / "table.md").write_text(table(rows))
    return results


def _f(x: Any, spec: str = ".3g") -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def table(rows: list) -> str:
    lines = [
        "| recording | phase | frames (t) | model | a (mm^2/s) | effects found (named cause first) "
        "| RMSE plain | RMSE extended | gain | gain, other extension | noise |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, phase, f in rows:
        model = "ANRA; source map" if "a_anra" in f else f"small box; {f['extended_model']}"
        other = "Gaussian spot" if "a_anra" in f else f["other_model"]
        if "a_anra" in f:
            lo, hi = f["a_anra_interval"] or (None, None)
            a = f"ANRA {_f(f['a_anra'])} [{_f(lo)}, {_f(hi)}] for dx 0.5-0.6 mm; plain {_f(f['a_plain'])}"
        else:
            a = (
                f"plain {_f(f['a_plain'])}, loss model {_f(f['a_extended'])} (b {_f(f['loss_b_per_s'])}/s); "
                f"edges explain {100 * f['edge_explained_fit']:.0f} %"
            )
        lines.append(
            f"| {name} | {phase} | {f['frames']} ({f['t_start']:.0f}-{f['t_stop']:.0f} s) | "
            f"{model} | {a} | {', '.join(f['effects']) or 'none'} | "
            f"{_f(f['base_rmse'])} | {_f(f['extended_rmse'])} | {_f(f['gain'], '+.2f')} | "
            f"{_f(f.get('parametric_gain', f.get('other_gain')), '+.2f')} ({other}) | "
            f"{_f(f['noise_floor'])} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/real_data", help="output directory")
    parser.add_argument("--quick", action="store_true", help="one laser run and one CSV file")
    parser.add_argument(
        "--effects",
        type=lambda text: [name.strip() for name in text.split(",") if name.strip()],
        default=None,
        metavar="NAME[,NAME...]",
        help="restrict the laser phases' diagnosis to these candidate effects (default all); "
        "the small-box CSV model is unchanged",
    )
    parser.add_argument(
        "--box-window",
        type=int,
        default=BOX_FIT_WINDOW,
        metavar="N",
        help=f"frames before the split the small-box CSV models are fitted on (default {BOX_FIT_WINDOW})",
    )
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        print(f"real_data: {DATA} not found (the measured data live beside the checkout)", file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    run(Path(args.out), args.quick, args.effects, args.box_window)
    print((Path(args.out) / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
