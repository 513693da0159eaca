"""Damage in depth from the surface video: the depth model against what a user would do instead.

Scenes (:func:`anra_torch.simulation.bioheat_scenes.random_scene`, simulated by the independent 3-D
finite-volume solver :func:`anra_torch.simulation.bioheat_reference.simulate_bioheat`, which shares no code
with the depth model): skin-like tissue (``a`` 0.10-0.20 mm^2/s, perfusion 0-0.01 1/s, loss to air),
a far-infrared laser spot, a sweeping tip or a contact probe (cycling with the seed), exposures of
0.5-60 s and surface peaks of 60-95 C; a camera of 48 x 48 px at 5-30 Hz with white noise of ``--noise``
K. Truth: the 3-D Omega's damage depth under each pixel (mean of its 2 x 2 fine columns). Near-infrared
(volumetric) scenes are run apart: the depth model must flag them.

What is measured, per pixel of every scene (``deep``: true damage deeper than 0.5 mm):

* the depth model with the MEASURED ``a`` and ``b``
  (:func:`anra_torch.tissue.depth_fit.fit_depth_parameters`, zero surface flux after the switch-off) and
  their standard errors carried into ``damage_depth_std`` (:func:`anra_torch.tissue.damage_in_depth`);
* the same model with the textbook diffusivity 0.14 mm^2/s (and the measured ``b``), with the TRUE ``a``
  and ``b`` (what the solver itself gets right), and per-pixel 1-D (no lateral terms, true ``a`` and ``b``);
* the diffusivity the library's other estimates would give on the same cooling frames: the plain ANRA
  global estimate (:class:`anra_torch.estimation.ANRAEstimator`) and the depth-aware fit
  (:func:`anra_torch.selection.depth_aware.depth_aware_diffusivity`);
* surface-only baselines for deep / not deep: the surface peak temperature (threshold trained), surface
  ``Omega >= 1``, surface ``ln Omega`` (threshold trained) and a logistic regression on the raw surface
  history (peak, mean, last, sd, times above 45/50/55/60 C, ``ln Omega``, ``ln CEM43``), trained by 4-fold
  cross-validation over scenes (the classifier and threshold helpers of ``experiments/tissue_damage.py``).

F1 of deep / not deep, the depth model's margin over each baseline with a 95 % bootstrap interval
(resampling scenes), the median depth error where the true damage is deeper than 0.2 mm (all scenes, and
on the scenes whose ``a`` differs from 0.14 by 30 % or more: ``max(a / 0.14, 0.14 / a) >= 1.3``, measured
against textbook), and the coverage of the +-2 standard-error band over damaged pixels.

    python -m experiments.damage_depth                       # 40 scenes + 8 near-infrared, 0.3 K
    python -m experiments.damage_depth --scenes 24 --near-infrared 4
    python -m experiments.damage_depth --shard 0/2 &  # fill the cache in two processes, then
    python -m experiments.damage_depth --shard 1/2; wait; python -m experiments.damage_depth

Simulations and per-scene analyses are cached in ``--out/cache`` (an analysis is redone when the depth
model's source or :func:`analyse` changes; delete the simulations after changing the simulator).
Writes ``table.md``, ``results.json`` and ``figure.png`` to ``--out`` (default ``results/damage_depth``).
"""

from __future__ import annotations

import argparse
import json
import pickle
import time
from pathlib import Path

import numpy as np
import torch

from anra_torch.estimation import ANRAEstimator
from anra_torch.selection import depth_aware_diffusivity
from anra_torch.simulation import camera_frames, random_scene, simulate_bioheat
from anra_torch.tissue import arrhenius_omega, cem43, damage_in_depth, fit_depth_parameters
from experiments.tissue_damage import Logistic, best_threshold  # the house's classifier helpers, reused

F64 = torch.float64
DEEP, DAMAGED = 0.5, 0.2  # mm
TEXTBOOK = 0.14  # mm^2/s
FAR = 1.3  # max(a / 0.14, 0.14 / a) of the scenes where measured is compared with textbook
BOOTSTRAP = 1000
FOLDS = 4
VERSION = "1"  # part of every cache name: bump it when the simulator or the scenes change
MODEL = "depth model (measured a, b)"
BASELINES = ("surface peak T", "surface Omega >= 1", "surface ln Omega", "raw-history classifier")


def simulate(seed: int, kind: str | None, cache: Path):
    """The reference simulation of scene ``seed`` (cached)."""
    path = cache / f"scene_v{VERSION}_{kind or 'cycle'}_{seed}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    result = simulate_bioheat(random_scene(seed, kind=kind))
    path.write_bytes(pickle.dumps(result))
    return result


def surface_features(frames: torch.Tensor, dt: float) -> np.ndarray:
    """Per-pixel features of the raw surface history ``(P, 10)``."""
    stats = [frames.amax(0), frames.mean(0), frames[-1], frames.std(0)]
    stats += [(frames >= t).sum(0) * dt for t in (45.0, 50.0, 55.0, 60.0)]
    stats += [torch.log(arrhenius_omega(frames, dt, rule="linear").clamp_min(1e-30))]
    stats += [torch.log(cem43(frames, dt, rule="linear").clamp_min(1e-30))]
    return torch.stack([s.flatten().to(F64) for s in stats], 1).numpy()


def other_diffusivities(frames: torch.Tensor, start: int, dt: float, dx: float) -> dict[str, float]:
    """What the plain ANRA estimate and the depth-aware fit read on the cooling frames (NaN if they fail)."""
    cooling = frames[start:]
    out = {}
    try:
        out["ANRA global"] = float(ANRAEstimator()(cooling, dt, dx).diffusivity)
    except ValueError:
        out["ANRA global"] = float("nan")
    try:
        out["depth-aware"] = depth_aware_diffusivity(cooling, dt, dx).diffusivity
    except ValueError:
        out["depth-aware"] = float("nan")
    return out


def analyse(result, noise: float, seed: int) -> dict:
    """Every method's depth map and the surface features of one scene at camera noise ``noise``."""
    scene = result.scene
    frames = torch.from_numpy(camera_frames(result, noise, 10_000 + seed))
    truth_a, truth_b = scene.tissue.diffusivity, scene.tissue.perfusion
    body = scene.tissue.body_temperature
    start = time.perf_counter()
    fit = fit_depth_parameters(frames, result.dt, result.dx, body_temperature=body)
    fit_s = time.perf_counter() - start
    common = {"body_temperature": body}
    out = {
        "fit_s": fit_s,
        "valid": bool(fit.valid),
        "volumetric": bool(fit.volumetric),
        "misfit": float(fit.misfit),
    }
    out |= {"a": truth_a, "b": truth_b, "a_fit": float(fit.diffusivity), "a_std": float(fit.diffusivity_std)}
    out |= {"b_fit": float(fit.loss_rate), "b_std": float(fit.loss_rate_std), "label": scene.label}
    out |= {
        "dt": result.dt,
        "dx": result.dx,
        "frames": int(frames.shape[0]),
        "noise_fit": float(fit.noise_sd),
    }
    out["truth"] = result.damage_depth.flatten()
    out["surface_peak"] = float(result.frames.max())
    out["exposure"] = scene.sources[0].t_off - scene.sources[0].t_on
    if bool(fit.valid):
        start = time.perf_counter()
        maps = damage_in_depth(
            frames,
            result.dt,
            result.dx,
            diffusivity=fit.diffusivity,
            loss_rate=fit.loss_rate,
            diffusivity_std=fit.diffusivity_std,
            loss_rate_std=fit.loss_rate_std,
            noise_sd=fit.noise_sd,
            **common,
        )
        out["depth_s"] = time.perf_counter() - start
        out[MODEL] = maps.damage_depth.flatten().numpy()
        out["std"] = maps.damage_depth_std.flatten().numpy()
        out["profile"] = (maps.depths.numpy(), maps.peak[:, 24, 24].numpy(), maps.peak_std[:, 24, 24].numpy())
        textbook = damage_in_depth(
            frames, result.dt, result.dx, diffusivity=TEXTBOOK, loss_rate=fit.loss_rate, **common
        )
        out["textbook a = 0.14"] = textbook.damage_depth.flatten().numpy()
    exact = dict(diffusivity=truth_a, loss_rate=truth_b, **common)
    out["true a, b"] = damage_in_depth(frames, result.dt, result.dx, **exact).damage_depth.flatten().numpy()
    out["per-pixel 1-D (true a, b)"] = (
        damage_in_depth(frames, result.dt, result.dx, lateral=False, **exact).damage_depth.flatten().numpy()
    )
    out |= other_diffusivities(frames, int(fit.cooling_start), result.dt, result.dx)
    out["features"] = surface_features(frames, result.dt)
    out["example"] = (
        result.damage_depth,
        maps.damage_depth.numpy() if bool(fit.valid) else None,
        result.frames.max(0),
    )
    out["true_profile"] = (result.depths, result.peak[:, 24, 24])
    return out


def code_version() -> str:
    """A digest of the depth model's source and of :func:`analyse`: cached analyses are redone when they
    change."""
    import hashlib
    import inspect

    import anra_torch.tissue as tissue

    digest = hashlib.sha256(inspect.getsource(analyse).encode())
    for path in sorted(Path(tissue.__file__).parent.glob("*.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:10]


def run(seeds: list[int], kind: str | None, noise: float, cache: Path) -> list[dict]:
    """Analyses of the scenes ``seeds`` (cached per code version)."""
    records, version = [], code_version()
    for seed in seeds:
        path = cache / f"analysis_v{VERSION}_{version}_{kind or 'cycle'}_{seed}_{noise:g}.pkl"
        if path.exists():
            records.append(pickle.loads(path.read_bytes()))
            continue
        start = time.perf_counter()
        record = analyse(simulate(seed, kind, cache), noise, seed) | {"seed": seed}
        path.write_bytes(pickle.dumps(record))
        records.append(record)
        print(f"scene {seed} ({record['label']}): {time.perf_counter() - start:.0f} s", flush=True)
    return records


# ------------------------------------------------------------------------------------------ evaluation
def classifications(records: list[dict]) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Deep / not deep per pixel: truth, scene index and every method's prediction (baselines trained by
    cross-validation over scenes)."""
    y = np.concatenate([r["truth"] > DEEP for r in records])
    scene = np.concatenate([np.full(r["truth"].size, i) for i, r in enumerate(records)])
    x = np.concatenate([r["features"] for r in records])
    predictions = {MODEL: np.concatenate([r[MODEL] > DEEP for r in records])}
    predictions["surface Omega >= 1"] = x[:, 8] >= 0.0
    for name in ("surface peak T", "surface ln Omega", "raw-history classifier"):
        predictions[name] = np.zeros_like(y)
    folds = np.arange(len(records)) % FOLDS
    for fold in range(FOLDS):
        test = np.isin(scene, np.flatnonzero(folds == fold))
        yt = torch.from_numpy(y[~test])
        for name, column in (("surface peak T", 0), ("surface ln Omega", 8)):
            score = torch.from_numpy(x[~test, column])
            predictions[name][test] = x[test, column] >= best_threshold(score, yt)
        model = Logistic().fit(torch.from_numpy(x[~test]), yt)
        threshold = best_threshold(model.score(torch.from_numpy(x[~test])), yt)
        predictions["raw-history classifier"][test] = (
            model.score(torch.from_numpy(x[test])) >= threshold
        ).numpy()
    return y, scene, predictions


def f1_counts(predicted: np.ndarray, y: np.ndarray, scene: np.ndarray, n: int) -> np.ndarray:
    """Per scene (TP, FP, FN), ``(n, 3)``."""
    counts = np.zeros((n, 3))
    for k, hit in enumerate((predicted & y, predicted & ~y, ~predicted & y)):
        counts[:, k] = np.bincount(scene, weights=hit.astype(float), minlength=n)
    return counts


def f1_of(counts: np.ndarray) -> float:
    tp, fp, fn = counts.sum(0)
    return 2 * tp / (2 * tp + fp + fn) if tp > 0 else 0.0


def interval(samples: list[float]) -> list[float]:
    return [float(np.quantile(samples, q)) for q in (0.025, 0.975)]


def f1_table(records: list[dict], rng: np.random.Generator) -> dict:
    """F1 of every method and the model's margin over each baseline with its 95 % bootstrap interval."""
    y, scene, predictions = classifications(records)
    n = len(records)
    counts = {name: f1_counts(p.astype(bool), y, scene, n) for name, p in predictions.items()}
    draws = [rng.integers(0, n, n) for _ in range(BOOTSTRAP)]
    out = {
        "deep_pixels": int(y.sum()),
        "pixels": int(y.size),
        "deep_scenes": int(sum((r["truth"] > DEEP).any() for r in records)),
    }
    out["f1"] = {name: f1_of(c) for name, c in counts.items()}
    out["f1_95"] = {name: interval([f1_of(c[d]) for d in draws]) for name, c in counts.items()}
    out["margin"] = {}
    for name in BASELINES:
        samples = [f1_of(counts[MODEL][d]) - f1_of(counts[name][d]) for d in draws]
        out["margin"][name] = {"value": out["f1"][MODEL] - out["f1"][name], "95": interval(samples)}
    return out


def errors(
    records: list[dict], method: str, subset: list[int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Absolute depth errors (mm) where the true damage is deeper than 0.2 mm, and their scene index."""
    chosen = range(len(records)) if subset is None else subset
    err, scene = [], []
    for i in chosen:
        r = records[i]
        if method not in r:
            continue
        mask = r["truth"] > DAMAGED
        err.append(np.abs(r[method][mask] - r["truth"][mask]))
        scene.append(np.full(int(mask.sum()), i))
    return (np.concatenate(err), np.concatenate(scene)) if err else (np.zeros(0), np.zeros(0, int))


def median_with_interval(err: np.ndarray, scene: np.ndarray, rng: np.random.Generator) -> dict:
    if not err.size:
        return {"median": float("nan"), "95": [float("nan")] * 2, "pixels": 0}
    ids = np.unique(scene)
    by_scene = {i: err[scene == i] for i in ids}
    samples = [
        np.median(np.concatenate([by_scene[i] for i in rng.choice(ids, len(ids))])) for _ in range(BOOTSTRAP)
    ]
    return {"median": float(np.median(err)), "95": interval(samples), "pixels": int(err.size)}


DEPTH_METHODS = (MODEL, "textbook a = 0.14", "true a, b", "per-pixel 1-D (true a, b)")


def depth_table(records: list[dict], rng: np.random.Generator) -> dict:
    """Median depth errors where the damage is deeper than 0.2 mm: every method on every scene, and
    measured against textbook on the scenes whose ``a`` is 30 % or more from 0.14."""
    out = {"all": {m: median_with_interval(*errors(records, m), rng) for m in DEPTH_METHODS}}
    far = [i for i, r in enumerate(records) if max(r["a"] / TEXTBOOK, TEXTBOOK / r["a"]) >= FAR]
    out["far_scenes"] = len(far)
    out["far"] = {m: median_with_interval(*errors(records, m, far), rng) for m in DEPTH_METHODS[:2]}
    model, scene = errors(records, MODEL, far)
    textbook, _ = errors(records, "textbook a = 0.14", far)
    if model.size:
        ids = np.unique(scene)
        samples = []
        for _ in range(BOOTSTRAP):
            pick = np.concatenate([np.flatnonzero(scene == i) for i in rng.choice(ids, len(ids))])
            samples.append(float(np.median(textbook[pick]) - np.median(model[pick])))
        out["far_margin"] = {"value": float(np.median(textbook) - np.median(model)), "95": interval(samples)}
    return out


def calibration(records: list[dict]) -> dict:
    """Share of damaged pixels whose true depth lies within the reported depth +- 2 standard errors."""
    out = {}
    for name, floor in (("damaged (true depth > 0)", 0.0), ("true depth > 0.2 mm", DAMAGED)):
        inside, total, z = 0, 0, []
        for r in records:
            if MODEL not in r:
                continue
            mask = r["truth"] > floor
            err = np.abs(r[MODEL][mask] - r["truth"][mask])
            inside += int((err <= 2.0 * r["std"][mask]).sum())
            total += int(mask.sum())
            z.append(err / np.maximum(r["std"][mask], 1e-12))
        out[name] = {
            "coverage": inside / max(total, 1),
            "pixels": total,
            "median_abs_z": float(np.median(np.concatenate(z))) if z else float("nan"),
        }
    return out


def parameters(records: list[dict]) -> dict:
    """How far each diffusivity estimate is from the truth (median |relative error|), and the measured
    ``a``'s and ``b``'s standard scores."""
    rel = lambda key: [abs(r[key] / r["a"] - 1) for r in records if np.isfinite(r.get(key, np.nan))]  # noqa: E731
    out = {
        name: {"median_rel_error": float(np.median(rel(key))) if rel(key) else None, "scenes": len(rel(key))}
        for name, key in (
            ("depth model fit", "a_fit"),
            ("ANRA global", "ANRA global"),
            ("depth-aware", "depth-aware"),
        )
    }
    valid = [r for r in records if r["valid"]]
    out["a_z_median_abs"] = float(np.median([abs(r["a_fit"] - r["a"]) / r["a_std"] for r in valid]))
    out["b_bias_median"] = float(np.median([r["b_fit"] - r["b"] for r in valid]))
    out["valid_fits"] = len(valid)
    out["flagged_volumetric"] = sum(r["volumetric"] for r in records)
    out["misfit_max"] = max(r["misfit"] for r in valid) if valid else None
    return out


def near_infrared(records: list[dict]) -> dict:
    """The volumetric scenes: flagged or not, their misfit and the depth error they would get."""
    rows = []
    for r in records:
        mask = r["truth"] > DAMAGED
        err = (
            float(np.median(np.abs(r[MODEL][mask] - r["truth"][mask]))) if MODEL in r and mask.any() else None
        )
        rows.append(
            {
                "seed": r["seed"],
                "flagged": r["volumetric"],
                "misfit": r["misfit"],
                "a_fit": r["a_fit"],
                "a": r["a"],
                "max_true_depth": float(r["truth"].max()),
                "median_error_deeper_0.2": err,
            }
        )
    return {"scenes": len(rows), "flagged": sum(row["flagged"] for row in rows), "rows": rows}


# ------------------------------------------------------------------------------------------ report
def table(results: dict) -> str:
    s, f, d, c, p = (results[k] for k in ("settings", "f1", "depth", "calibration", "parameters"))
    lines = [
        f"Damage depth from the surface video on {s['scenes']} independent 3-D scenes (camera noise "
        f"{s['noise']:g} K; {f['deep_scenes']} scenes with damage deeper than {DEEP} mm, {f['deep_pixels']} "
        f"of {f['pixels']} pixels):",
        "",
        "| method | median depth error (mm), true depth > 0.2 mm | 95 % interval | F1 deep (> 0.5 mm) "
        "| 95 % |",
        "|---|---|---|---|---|",
    ]
    for m in DEPTH_METHODS:
        e = d["all"][m]
        f1_text = (
            f"{f['f1'][m]:.3f} | {f['f1_95'][m][0]:.3f}-{f['f1_95'][m][1]:.3f}" if m in f["f1"] else "| "
        )
        lines.append(f"| {m} | {e['median']:.4f} | {e['95'][0]:.4f}-{e['95'][1]:.4f} | {f1_text} |")
    for name in BASELINES:
        g = f["margin"][name]
        lines.append(
            f"| {name} | - | - | {f['f1'][name]:.3f} | margin of the model {g['value']:+.3f} "
            f"({g['95'][0]:+.3f} to {g['95'][1]:+.3f}) |"
        )
    far = d["far"]
    lines += [
        "",
        f"Scenes whose a is 30 % or more from 0.14 mm^2/s ({d['far_scenes']}): median error measured "
        f"{far[MODEL]['median']:.4f} mm, textbook {far['textbook a = 0.14']['median']:.4f} mm"
        + (
            f"; textbook - measured {d['far_margin']['value']:+.4f} mm "
            f"(95 % {d['far_margin']['95'][0]:+.4f} to "
            f"{d['far_margin']['95'][1]:+.4f})."
            if "far_margin" in d
            else "."
        ),
        "",
        "Calibration (true depth inside the reported depth +- 2 standard errors): "
        + "; ".join(
            f"{k}: {v['coverage']:.1%} of {v['pixels']} pixels (median |z| {v['median_abs_z']:.2f})"
            for k, v in c.items()
        )
        + ".",
        "",
        "Diffusivity against the truth (median |relative error|): "
        + ", ".join(
            f"{k} {v['median_rel_error']:.1%} ({v['scenes']} scenes)"
            for k, v in p.items()
            if isinstance(v, dict) and v["median_rel_error"] is not None
        )
        + f"; measured a's median |z| {p['a_z_median_abs']:.2f}; b's median bias "
        f"{p['b_bias_median']:+.4f} 1/s; {p['flagged_volumetric']} surface-heated scenes flagged volumetric "
        f"(largest misfit {p['misfit_max']:.3g}).",
    ]
    if "near_infrared" in results:
        n = results["near_infrared"]
        lines.append(f"Near-infrared (volumetric) scenes flagged: {n['flagged']} of {n['scenes']}.")
    return "\n".join(lines) + "\n"


def plot(records: list[dict], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(19, 4.3))
    peak = np.concatenate([r["features"][:, 0] for r in records])
    truth = np.concatenate([r["truth"] for r in records])
    exposure = np.concatenate([np.full(r["truth"].size, r["exposure"]) for r in records])
    hot = truth > 0
    sc = axes[0].scatter(peak[hot], truth[hot], c=np.log10(exposure[hot]), s=2, cmap="viridis")
    fig.colorbar(sc, ax=axes[0], label="log10 exposure (s)")
    axes[0].set_xlabel("camera peak (C)")
    axes[0].set_ylabel("true damage depth (mm)")
    axes[0].set_title("equal surface peaks, different depths")
    for m, colour in zip(DEPTH_METHODS, ("C3", "C0", "k", "C1"), strict=True):
        est = np.concatenate([r[m] for r in records if m in r])
        tr = np.concatenate([r["truth"] for r in records if m in r])
        keep = tr > 0
        axes[1].plot(tr[keep], est[keep], ".", ms=1.5, color=colour, label=m, alpha=0.5)
    lim = float(truth.max()) * 1.05
    axes[1].plot([0, lim], [0, lim], "k--", lw=0.8)
    axes[1].set_xlabel("true damage depth (mm)")
    axes[1].set_ylabel("estimated (mm)")
    axes[1].legend(fontsize=7, markerscale=5)
    example = max((r for r in records if MODEL in r), key=lambda r: r["truth"].max())
    true_map, est_map, _ = example["example"]
    image = axes[2].imshow(np.concatenate([true_map, est_map], 1), cmap="magma")
    fig.colorbar(image, ax=axes[2], label="mm")
    axes[2].set_title(f"scene {example['seed']} ({example['label']}): truth | depth model")
    z, peak_profile, peak_std = example["profile"]
    tz, tpeak = example["true_profile"]
    axes[3].plot(tpeak, tz, "k-", label="3-D reference")
    axes[3].plot(peak_profile, z, "C3--", label="depth model")
    axes[3].fill_betweenx(z, peak_profile - 2 * peak_std, peak_profile + 2 * peak_std, color="C3", alpha=0.2)
    axes[3].set_ylim(float(z.max()), 0)
    axes[3].set_xlabel("peak temperature (C)")
    axes[3].set_ylabel("depth (mm)")
    axes[3].set_title("centre pixel: peak temperature profile")
    axes[3].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", type=int, default=40, help="surface-heated scenes (seeds 0..N-1)")
    parser.add_argument("--near-infrared", type=int, default=8, help="volumetric scenes (seeds 100..)")
    parser.add_argument("--noise", type=float, default=0.3, help="camera noise sd in K")
    parser.add_argument("--out", default="results/damage_depth")
    parser.add_argument(
        "--shard",
        default="",
        help="K/N: only analyse the scenes whose seed is K mod N (fills the cache; no table)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    out = Path(args.out)
    cache = out / "cache"
    cache.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    if args.shard:
        k, n = (int(v) for v in args.shard.split("/"))
        run([s for s in range(args.scenes) if s % n == k], None, args.noise, cache)
        run(
            [s for s in range(100, 100 + args.near_infrared) if s % n == k],
            "near_infrared",
            args.noise,
            cache,
        )
        return
    records = run(list(range(args.scenes)), None, args.noise, cache)
    rng = np.random.default_rng(0)
    results = {
        "settings": {
            "scenes": args.scenes,
            "noise": args.noise,
            "deep_mm": DEEP,
            "damaged_mm": DAMAGED,
            "textbook": TEXTBOOK,
            "bootstrap": BOOTSTRAP,
            "folds": FOLDS,
        },
        "f1": f1_table(records, rng),
        "depth": depth_table(records, rng),
        "calibration": calibration(records),
        "parameters": parameters(records),
    }
    if args.near_infrared:
        nir = run(list(range(100, 100 + args.near_infrared)), "near_infrared", args.noise, cache)
        results["near_infrared"] = near_infrared(nir)
    results["scenes"] = [
        {
            k: r[k]
            for k in (
                "seed",
                "label",
                "a",
                "a_fit",
                "a_std",
                "b",
                "b_fit",
                "b_std",
                "misfit",
                "exposure",
                "surface_peak",
                "ANRA global",
                "depth-aware",
                "frames",
                "dt",
                "dx",
            )
        }
        | {"max_true_depth": float(r["truth"].max())}
        for r in records
    ]
    results["elapsed_s"] = time.perf_counter() - start
    text = table(results)
    (out / "table.md").write_text(text)
    (out / "results.json").write_text(json.dumps(results, indent=2, default=float) + "\n")
    figure = plot(records, out / "figure.png")
    print(text)
    print(f"wrote {out / 'table.md'}, {out / 'results.json'}, {figure} in {results['elapsed_s']:.0f} s")


if __name__ == "__main__":
    main()
