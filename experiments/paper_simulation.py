"""Reproduce and beat the simulation of El-Kebir et al. (arXiv 2203.13148): table, KDE figure, sweeps, peers.

The paper's case: a = 0.2 mm^2/s, a Gaussian of peak 3.8 and FWHM 50 px, 224 x 224 px over 10 x 10 mm,
27 Hz for 1 s, white noise sd 0.01. Every ANRA variant and both naive baselines run on the same noisy
videos (one batch per chunk of seeds); the peers (PDE-constrained spectral fit, PySINDy strong and weak
form, a NumPy/SciPy direct estimator) run on the same videos.

    python -m experiments.paper_simulation                      # 200 seeds, ~20 min on 2 cores
    python -m experiments.paper_simulation --seeds 20 --sweep-seeds 8 --peer-seeds 1   # quick look

Writes ``results.json``, ``table.md``, ``kde.png`` and ``sweeps.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from anra_torch import ANRAEstimator
from anra_torch.estimation import BASELINES
from anra_torch.layers import RTCAttention
from anra_torch.simulation import Blobs, blobs_video, paper_video
from experiments.peers import numpy_direct_estimate, pde_find_estimate, spectral_fit, weak_sindy_estimate

A_TRUE = 0.2
CHUNK = 10  # videos per batch through the estimators

Estimator = Callable[[torch.Tensor, float, float], torch.Tensor]


def _anra(**options: object) -> Estimator:
    module = ANRAEstimator(strict=False, **options)

    def run(frames: torch.Tensor, dt: float, dx: float) -> torch.Tensor:
        return module(frames, dt, dx).diffusivity

    return run


METHODS: dict[str, Estimator] = {
    "ANRA default (lsq, EIV-corrected, auto smoothing)": _anra(),
    "ANRA lsq with RTC weights (Stein-corrected)": _anra(attention=RTCAttention(unit_invariant=True)),
    "ANRA lsq, no smoothing, no EIV correction": _anra(
        smoothing=0.0, eiv_correction=False, laplacian_family="holoborodko"
    ),
    "ANRA ratio (paper's estimator, as published)": _anra(mode="ratio"),
    "ANRA ratio + stage-V threshold 0.5": _anra(mode="ratio", attention=RTCAttention(threshold=0.5)),
    # kornia's float64 convolutions are ~8x slower than float32; the baselines fail either way
    "baseline: backward diff + LoG (kornia, float32)": lambda f, dt, dx: BASELINES["backward+LoG"](
        f.float(), dt, dx
    ),
    "baseline: backward diff + LoG + Gaussian blur (kornia, float32)": lambda f, dt, dx: BASELINES[
        "backward+LoG+blur"
    ](f.float(), dt, dx),
}
DEFAULT = "ANRA default (lsq, EIV-corrected, auto smoothing)"
PAPER = "ANRA ratio (paper's estimator, as published)"


def run_methods(
    methods: dict[str, Estimator], n_seeds: int, *, seed0: int = 0, desc: str = "", **video: object
) -> dict[str, dict[str, list[float]]]:
    """Estimates and per-video seconds for each method over ``n_seeds`` noisy videos of one case."""
    out = {name: {"estimate": [], "seconds": []} for name in methods}
    chunks = range(0, n_seeds, CHUNK)
    for start in tqdm(chunks, desc=desc or "videos", unit="chunk", leave=False):
        n = min(CHUNK, n_seeds - start)
        v = paper_video(n_videos=n, seed=seed0 + start, **video)
        for name, method in methods.items():
            t0 = time.perf_counter()
            estimate = method(v.frames, v.dt, v.dx)
            elapsed = time.perf_counter() - t0
            out[name]["estimate"] += estimate.reshape(-1).tolist()
            out[name]["seconds"] += [elapsed / n] * n
    return out


def summarise(values: list[float], seconds: list[float] | None = None) -> dict[str, float]:
    """Median, 5-95 % range, median |error| (%) and the fraction within 1 % of the truth."""
    a = np.asarray(values, dtype=float)
    finite = a[np.isfinite(a)]
    err = np.abs(finite / A_TRUE - 1) * 100
    row = {
        "n": int(a.size),
        "n_finite": int(finite.size),
        "median": float(np.median(finite)) if finite.size else float("nan"),
        "p05": float(np.percentile(finite, 5)) if finite.size else float("nan"),
        "p95": float(np.percentile(finite, 95)) if finite.size else float("nan"),
        "median_abs_err_pct": float(np.median(err)) if finite.size else float("nan"),
        "within_1pct": float(np.mean(err <= 1.0)) if finite.size else 0.0,
    }
    if seconds is not None:
        row["seconds_per_video"] = float(np.median(seconds))
    return row


PEERS = {
    "spectral PDE fit (periodic, exact solver)": lambda f, dt, dx: spectral_fit(f, dt, dx),
    "spectral PDE fit (Neumann, exact solver)": lambda f, dt, dx: spectral_fit(f, dt, dx, boundary="neumann"),
    "NumPy/SciPy direct (sigma 4 px)": numpy_direct_estimate,
    "PySINDy weak form, tuned": lambda f, dt, dx: weak_sindy_estimate(f, dt, dx, tuned=True),
    "PySINDy weak form, defaults": lambda f, dt, dx: weak_sindy_estimate(f, dt, dx, tuned=False),
    "PySINDy strong form (PDE-FIND)": pde_find_estimate,
}


def peers_on_paper_case(n_seeds: int, crops: tuple[int | None, ...]) -> list[dict[str, object]]:
    """Peers and ANRA's default, one video at a time (timed per video), full frame and crops."""
    anra = ANRAEstimator(strict=False)
    anra(paper_video(n_videos=1, noise_sd=0.01, crop=80).frames, 1 / 27, 0.05)  # warm-up
    rows = []
    for crop in crops:
        results: dict[str, list[tuple]] = {"ANRA default": [], **{name: [] for name in PEERS}}
        for seed in tqdm(range(n_seeds), desc=f"peers crop={crop}", leave=False):
            v = paper_video(n_videos=1, seed=10_000 + seed, noise_sd=0.01, crop=crop)
            frames, dt, dx = v.frames[0].numpy(), v.dt, v.dx
            t0 = time.perf_counter()
            a = anra(v.frames[0], dt, dx).diffusivity.item()
            results["ANRA default"].append((a, time.perf_counter() - t0, True, "", float("nan")))
            for name, peer in PEERS.items():
                r = peer(frames, dt, dx)
                results[name].append((r.diffusivity, r.seconds, r.ok, r.note, r.peak_mb))
        for name, values in results.items():
            estimates = [v[0] if v[2] else float("nan") for v in values]
            errs = [abs(e / A_TRUE - 1) * 100 for e in estimates if np.isfinite(e)]
            rows.append(
                {
                    "crop": crop or 224,
                    "method": name,
                    "median_estimate": float(np.nanmedian(estimates)) if errs else float("nan"),
                    "median_abs_err_pct": float(np.median(errs)) if errs else float("nan"),
                    "seconds_per_video": float(np.median([v[1] for v in values])),
                    "peak_mb": float(np.median([v[4] for v in values])),
                    "ok": f"{sum(v[2] for v in values)}/{len(values)}",
                    "note": values[0][3],
                }
            )
    return rows


def sweeps(n_seeds: int) -> dict[str, list[dict[str, object]]]:
    """Median and 5-95 % of the default and the paper's estimator against noise, frame rate, crop."""
    methods = {DEFAULT: METHODS[DEFAULT], PAPER: METHODS[PAPER]}
    grid = {
        "noise_sd": [dict(noise_sd=s) for s in (0.001, 0.003, 0.01, 0.03, 0.05, 0.1)],
        "fps": [dict(noise_sd=0.01, fps=f) for f in (10.0, 27.0, 60.0, 120.0)],
        "crop_px": [dict(noise_sd=0.01, crop=c) for c in (None, 160, 112, 80)],
    }
    out: dict[str, list[dict[str, object]]] = {}
    for axis, cases in grid.items():
        out[axis] = []
        for case in tqdm(cases, desc=f"sweep {axis}", leave=False):
            results = run_methods(methods, n_seeds, seed0=20_000, **case)
            value = case.get(axis, case.get("crop")) if axis != "crop_px" else (case["crop"] or 224)
            for name, res in results.items():
                out[axis].append({axis: value, "method": name, **summarise(res["estimate"])})
    return out


GEOMETRIES = {
    "3 blobs on 30 C, 96 px, dx 0.5 mm, 30 fps, a 0.15": dict(),
    "6 blobs, 128 px": dict(blobs=Blobs(n_blobs=6), size=128),
    "a 0.05 mm^2/s": dict(a=0.05),
    "a 0.5 mm^2/s at 60 fps": dict(a=0.5, fps=60.0),
    "dx 0.2 mm, a 0.1": dict(dx=0.2, a=0.1),
    "10 fps, 20 frames": dict(fps=10.0, n_frames=20),
    "64 px frame": dict(size=64),
}


def geometries(n_seeds: int) -> list[dict[str, object]]:
    """The same default estimator on other scenes (blobs on a warm background, other rates and sizes)."""
    est = ANRAEstimator(strict=False)
    rows = []
    for name, options in tqdm(GEOMETRIES.items(), desc="geometries", leave=False):
        v = blobs_video(n_videos=n_seeds, seed=30_000, **options)
        estimate = est(v.frames, v.dt, v.dx).diffusivity
        err = (estimate / v.a - 1).abs() * 100
        rows.append(
            {
                "case": name,
                "a_true": v.a,
                "median_estimate": float(estimate.median()),
                "median_err_pct": float(((estimate / v.a - 1) * 100).median()),
                "max_abs_err_pct": float(err.max()),
            }
        )
    return rows


def noiseless_check() -> float:
    """Largest relative error (%) over modes and kernel sizes without noise (paper case, 112 px crop)."""
    v = paper_video(n_videos=1, noise_sd=0.0, crop=112)
    worst = 0.0
    for mode in ("lsq", "ratio"):
        for family, sizes in (("holoborodko", (3, 5, 7, 9, 11)), ("central", (3, 5, 7))):
            for size in sizes:
                for time_family, length in (("smooth", 5), ("smooth", 7), ("centred", 9), ("hybrid", 8)):
                    est = ANRAEstimator(
                        mode=mode,
                        laplacian_family=family,
                        laplacian_size=size,
                        time_family=time_family,
                        time_length=length,
                    )
                    a = float(est(v.frames, v.dt, v.dx).diffusivity)
                    worst = max(worst, abs(a / A_TRUE - 1) * 100)
    return worst


def kde_figure(results: dict[str, dict[str, list[float]]], path: Path) -> None:
    """The paper's Fig. 2: kernel density of the deviation a_hat - a, ANRA variants and baselines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import gaussian_kde

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    default = np.asarray(results[DEFAULT]["estimate"]) - A_TRUE
    zoom = 8 * float(np.std(default[np.isfinite(default)])) or 1e-3
    peak = 1.0
    for name, res in results.items():
        dev = np.asarray(res["estimate"]) - A_TRUE
        dev = dev[np.isfinite(dev)]
        if dev.size < 3 or np.ptp(dev) == 0:
            continue
        kde = gaussian_kde(dev)
        if abs(np.median(dev)) < zoom:
            grid = np.linspace(-zoom, zoom, 800)
            axes[0].plot(grid, kde(grid), label=name)
        lo, hi = np.percentile(dev, [1, 99])
        grid = np.concatenate([np.linspace(lo - (hi - lo), hi + (hi - lo), 1500), [0.0]])
        grid.sort()
        density = kde(grid)
        peak = max(peak, float(density.max()))
        axes[1].plot(grid, density, label=name)
    axes[0].set(
        title="ANRA variants near the truth (zoom)",
        xlabel="deviation a_hat - a  [mm^2/s]",
        ylabel="density [s/mm^2]",
    )
    axes[1].set(title="all methods (symlog x, log density)", xlabel="deviation a_hat - a  [mm^2/s]")
    axes[1].set_xscale("symlog", linthresh=1e-4)
    axes[1].set_yscale("log")
    axes[1].set_ylim(1e-3, peak * 3)
    for ax in axes:
        ax.axvline(0, color="k", lw=0.5)
    axes[0].legend(fontsize=7)
    axes[1].legend(fontsize=6, loc="upper left")
    fig.suptitle(f"Paper case (a = {A_TRUE}, noise sd 0.01, 27 Hz, 1 s): deviation over noise seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def sweep_figure(sweep: dict[str, list[dict[str, object]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    units = {"noise_sd": "noise sd [K]", "fps": "frame rate [Hz]", "crop_px": "crop [px]"}
    for ax, (axis, rows) in zip(axes, sweep.items(), strict=True):
        for name in (DEFAULT, PAPER):
            pts = [r for r in rows if r["method"] == name]
            x = [r[axis] for r in pts]
            med = [100 * (r["median"] / A_TRUE - 1) for r in pts]
            lo = [100 * (r["p05"] / A_TRUE - 1) for r in pts]
            hi = [100 * (r["p95"] / A_TRUE - 1) for r in pts]
            ax.plot(x, med, "o-", label=name)
            ax.fill_between(x, lo, hi, alpha=0.2)
        ax.axhline(0, color="k", lw=0.5)
        ax.set(xlabel=units[axis], ylabel="error of a [%] (median, 5-95 %)")
        if axis == "noise_sd":
            ax.set_xscale("log")
        ax.set_yscale("symlog", linthresh=0.01)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def markdown(report: dict[str, object]) -> str:
    lines = [
        f"Paper case, noise sd 0.01, {report['seeds']} seeds (truth a = {A_TRUE} mm^2/s):",
        "",
        "| method | median a | 5-95 % | median abs. error | seeds within 1 % | s / video |",
        "|---|---|---|---|---|---|",
    ]
    for name, row in report["table"].items():
        lines.append(
            f"| {name} | {row['median']:.4g} | {row['p05']:.4g} .. {row['p95']:.4g} | "
            f"{row['median_abs_err_pct']:.3g} % | {100 * row['within_1pct']:.0f} % | "
            f"{row['seconds_per_video']:.3f} |"
        )
    lines += [
        "",
        f"Peers on the same case ({report['peer_seeds']} seeds each; s / video on this machine):",
        "",
        "| crop | method | median a | median abs. error | s / video | peak MB | ok | note |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report["peers"]:
        peak = "" if r["peak_mb"] is None or not np.isfinite(r["peak_mb"]) else f"{r['peak_mb']:.0f}"
        lines.append(
            f"| {r['crop']} | {r['method']} | {r['median_estimate']:.4g} | {r['median_abs_err_pct']:.3g} % | "
            f"{r['seconds_per_video']:.3f} | {peak} | {r['ok']} | {r['note']} |"
        )
    lines += ["", "Sweeps (median error and 5-95 % range, %):", ""]
    for axis, rows in report["sweeps"].items():
        lines += [f"| {axis} | method | median error | 5-95 % |", "|---|---|---|---|"]
        for r in rows:
            lines.append(
                f"| {r[axis]} | {r['method']} | {100 * (r['median'] / A_TRUE - 1):+.3f} % | "
                f"{100 * (r['p05'] / A_TRUE - 1):+.2f} .. {100 * (r['p95'] / A_TRUE - 1):+.2f} % |"
            )
        lines.append("")
    lines += ["Other geometries, same default:", "", "| case | a | median error | max abs. error |"]
    lines.append("|---|---|---|---|")
    for r in report["geometries"]:
        lines.append(
            f"| {r['case']} | {r['a_true']} | {r['median_err_pct']:+.3f} % | {r['max_abs_err_pct']:.3f} % |"
        )
    lines += ["", f"Noiseless, every mode and kernel: worst error {report['noiseless_worst_pct']:.3f} %.", ""]
    lines += ["Acceptance:", ""] + [f"- {k}: {v}" for k, v in report["acceptance"].items()]
    return "\n".join(lines) + "\n"


def acceptance(report: dict[str, object]) -> dict[str, str]:
    table, sweep = report["table"], report["sweeps"]

    def verdict(ok: bool, text: str) -> str:
        return ("PASS " if ok else "FAIL ") + text

    d = table[DEFAULT]
    med_err = abs(d["median"] / A_TRUE - 1) * 100
    out = {
        "noise 0.01: median within 0.2 %, >= 90 % of seeds within 1 %": verdict(
            med_err <= 0.2 and d["within_1pct"] >= 0.9,
            f"median error {med_err:.3f} %, {100 * d['within_1pct']:.1f} % within 1 %",
        )
    }
    for noise, limit in ((0.05, 1.0), (0.1, 2.0)):
        row = next(r for r in sweep["noise_sd"] if r["method"] == DEFAULT and r["noise_sd"] == noise)
        e = abs(row["median"] / A_TRUE - 1) * 100
        out[f"noise {noise}: median within {limit} %"] = verdict(e <= limit, f"{e:.3f} %")
    for crop in (112, 80):
        row = next(r for r in sweep["crop_px"] if r["method"] == DEFAULT and r["crop_px"] == crop)
        e = abs(row["median"] / A_TRUE - 1) * 100
        out[f"crop {crop} px: median within 1 %"] = verdict(e <= 1.0, f"{e:.3f} %")
    worst_geo = max(abs(r["median_err_pct"]) for r in report["geometries"])
    out["other geometries: median within 2 %"] = verdict(worst_geo <= 2.0, f"worst {worst_geo:.3f} %")
    out["noiseless: every mode and kernel within 0.5 %"] = verdict(
        report["noiseless_worst_pct"] <= 0.5, f"worst {report['noiseless_worst_pct']:.3f} %"
    )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=200, help="noise seeds for the main table")
    parser.add_argument("--sweep-seeds", type=int, default=24, help="seeds per sweep point")
    parser.add_argument("--peer-seeds", type=int, default=3, help="seeds for PySINDy and the other peers")
    parser.add_argument("--out", type=Path, default=Path("results/paper_simulation"))
    parser.add_argument("--replot", action="store_true", help="redraw the figures from --out/results.json")
    args = parser.parse_args(argv)
    if args.replot:
        saved = json.loads((args.out / "results.json").read_text())
        kde_figure({k: {"estimate": v} for k, v in saved["estimates"].items()}, args.out / "kde.png")
        sweep_figure(saved["sweeps"], args.out / "sweeps.png")
        return 0
    torch.set_num_threads(max(1, torch.get_num_threads()))
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    results = run_methods(METHODS, args.seeds, noise_sd=0.01, desc="paper case")
    report: dict[str, object] = {
        "seeds": args.seeds,
        "peer_seeds": args.peer_seeds,
        "table": {name: summarise(r["estimate"], r["seconds"]) for name, r in results.items()},
        "peers": peers_on_paper_case(args.peer_seeds, (None, 112, 80)),
        "sweeps": sweeps(args.sweep_seeds),
        "geometries": geometries(max(args.sweep_seeds // 2, 4)),
        "noiseless_worst_pct": noiseless_check(),
        "estimates": {name: r["estimate"] for name, r in results.items()},
    }
    report["acceptance"] = acceptance(report)
    report["seconds_total"] = time.perf_counter() - t0
    (args.out / "results.json").write_text(json.dumps(report, indent=1))
    text = markdown(report)
    (args.out / "table.md").write_text(text)
    kde_figure(results, args.out / "kde.png")
    sweep_figure(report["sweeps"], args.out / "sweeps.png")
    print(text)
    print(f"wrote {args.out}/results.json, table.md, kde.png, sweeps.png in {report['seconds_total']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
