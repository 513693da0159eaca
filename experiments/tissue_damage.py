"""Classify thermally damaged pixels from surface features: raw temperature vs the ANRA feature set.

Scene (synthetic electrosurgery): tissue at 37 C, 48 x 48 px of 0.2 mm, with a smooth random diffusivity
field (0.08-0.20 mm^2/s) and perfusion field (0.05-0.50 1/s). A Gaussian tip (sigma 0.5-1.0 mm, peak
heating 15-120 K/s) sweeps a straight 0-4 mm path for 1-10 s, then the tissue cools until 12 s.
:func:`anra_torch.simulation.simulate_tissue` integrates it (RK4 on torchdiffeq) at 50 Hz.

Truth: Arrhenius Omega (skin constants) of the noiseless 50 Hz temperature (piecewise-linear rule);
a pixel is damaged when ``Omega >= 1``.

Camera: every 10th frame (5 Hz) plus white noise of sd ``--noise`` K (default a sweep 0.5, 2, 5: from a
good camera to one disturbed by smoke and steam).

Feature sets per pixel (from the camera video only):

* raw temperature: peak, mean, last and standard deviation over time of the raw frames (4 features);
* ANRA: every map of :class:`anra_torch.tissue.TissueFeatures` (13 features: dose, denoised peak,
  times above 43/50/60 C, Holoborodko rates, RTC attention, local diffusivity and confidence, loss rate,
  source), the dose maps as ``log10(1e-6 + x)``.

Classifier: logistic regression in torch (standardised features, L-BFGS, L2 1e-4) trained on the pixels
of ``--train`` videos; tested on the pixels of ``--test`` held-out videos. F1 at the threshold that
maximises F1 on the training pixels; ROC AUC by the Mann-Whitney rank sum; the margin's 95 % interval
from 200 bootstrap resamples of the held-out videos. A classifier-free baseline thresholds ANRA's Omega
map at 1.

    python -m experiments.tissue_damage                      # 24 training + 12 test videos, 3 noise levels
    python -m experiments.tissue_damage --noise 1.0          # one noise level

Writes ``table.md``, ``results.json`` and ``figure.png`` to ``--out`` (default results/tissue_damage)
and copies the figure to ``docs/tissue_damage.png``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from anra_torch.layers import GaussianSmoothing
from anra_torch.simulation import MovingSource, simulate_tissue
from anra_torch.tissue.dose import arrhenius_omega
from anra_torch.tissue.features import TissueFeatures

F64 = torch.float64
SIZE, DX = 48, 0.2  # px, mm
FINE_DT, STRIDE = 0.02, 10  # s between simulated frames; camera keeps every STRIDE-th
DURATION = 12.0  # s
LOG_MAPS = ("cem43_minutes", "omega", "time_above_43", "time_above_50", "time_above_60")


def smooth_field(rng: np.random.Generator, low: float, high: float) -> torch.Tensor:
    """A smooth random field between ``low`` and ``high``, ``(SIZE, SIZE)``."""
    noise = torch.from_numpy(rng.standard_normal((1, SIZE, SIZE)))
    field = GaussianSmoothing(6.0, border="reflect")(noise)[0]
    field = (field - field.min()) / (field.max() - field.min())
    return low + (high - low) * field


def scene(seed: int) -> dict:
    """One scene: the noiseless camera frames, the true Omega map and damage."""
    rng = np.random.default_rng(seed)
    a = smooth_field(rng, 0.08, 0.20)
    b = smooth_field(rng, 0.05, 0.50)
    length, angle = rng.uniform(0.0, 4.0), rng.uniform(0, 2 * np.pi)
    mid = rng.uniform(3.5, SIZE * DX - 3.5, size=2)
    half = 0.5 * length * np.array([np.cos(angle), np.sin(angle)])
    source = MovingSource(
        start=tuple(mid - half),
        end=tuple(mid + half),
        width=rng.uniform(0.5, 1.0),
        power=rng.uniform(15.0, 120.0),
        t_on=0.0,
        t_off=round(rng.uniform(1.0, 10.0) / FINE_DT) * FINE_DT,
    )
    u0 = torch.full((SIZE, SIZE), 37.0, dtype=F64)
    n_fine = round(DURATION / FINE_DT) + 1
    truth = simulate_tissue(u0, a, b, dx=DX, dt=FINE_DT, n_frames=n_fine, source=source)
    omega = arrhenius_omega(truth, FINE_DT, rule="linear")
    return {
        "clean": truth[::STRIDE],
        "dt": FINE_DT * STRIDE,
        "omega": omega,
        "damaged": omega >= 1.0,
        "truth": truth,
    }


def camera(clean: torch.Tensor, noise: float, seed: int) -> torch.Tensor:
    """The camera's frames: ``clean`` plus white noise of sd ``noise`` K."""
    rng = np.random.default_rng(10_000 + seed)
    return clean + noise * torch.from_numpy(rng.standard_normal(tuple(clean.shape)))


def raw_features(camera: torch.Tensor) -> torch.Tensor:
    """Per-pixel raw-temperature statistics, ``(P, 4)``."""
    stats = [camera.amax(0), camera.mean(0), camera[-1], camera.std(0)]
    return torch.stack([s.flatten() for s in stats], 1)


def anra_features(camera: torch.Tensor, dt: float, extractor: TissueFeatures) -> tuple[torch.Tensor, dict]:
    """Per-pixel ANRA feature maps, ``(P, F)``, and the maps."""
    out = extractor(camera, dt, DX)
    columns = []
    for name, m in out.maps.items():
        columns.append(torch.log10(1e-6 + m.clamp_min(0)) if name in LOG_MAPS else m)
    return torch.stack([c.flatten() for c in columns], 1), out.maps


class Logistic:
    """Logistic regression on standardised features (L-BFGS, L2 penalty)."""

    def __init__(self, l2: float = 1e-4) -> None:
        self.l2 = l2

    def fit(self, x: torch.Tensor, y: torch.Tensor) -> Logistic:
        self.mean, self.scale = x.mean(0), x.std(0).clamp_min(1e-12)
        z = (x - self.mean) / self.scale
        self.w = torch.zeros(x.shape[1], dtype=F64, requires_grad=True)
        self.b = torch.zeros((), dtype=F64, requires_grad=True)
        optimiser = torch.optim.LBFGS([self.w, self.b], max_iter=500, line_search_fn="strong_wolfe")
        target = y.to(F64)

        def closure() -> torch.Tensor:
            optimiser.zero_grad()
            logits = z @ self.w + self.b
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, target)
            loss = loss + self.l2 * (self.w**2).sum()
            loss.backward()
            return loss

        optimiser.step(closure)
        return self

    def score(self, x: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return torch.sigmoid(((x - self.mean) / self.scale) @ self.w + self.b)


def roc_auc(score: torch.Tensor, y: torch.Tensor) -> float:
    """Area under the ROC curve: the Mann-Whitney U statistic with average ranks for ties."""
    s = score.numpy().astype(np.float64)
    _, inverse, counts = np.unique(s, return_inverse=True, return_counts=True)
    average_rank = np.cumsum(counts) - 0.5 * (counts - 1)  # 1-based ranks, ties averaged
    ranks = average_rank[inverse]
    pos = y.numpy().astype(bool)
    n_pos, n_neg = pos.sum(), (~pos).sum()
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def f1(predicted: torch.Tensor, y: torch.Tensor) -> float:
    tp = float((predicted & y).sum())
    fp = float((predicted & ~y).sum())
    fn = float((~predicted & y).sum())
    return 2 * tp / (2 * tp + fp + fn) if tp > 0 else 0.0


def best_threshold(score: torch.Tensor, y: torch.Tensor) -> float:
    candidates = torch.quantile(score, torch.linspace(0.5, 0.999, 200, dtype=F64))
    values = [f1(score >= t, y) for t in candidates]
    return float(candidates[int(np.argmax(values))])


def roc_curve(score: torch.Tensor, y: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    order = torch.argsort(score, descending=True)
    hits = y[order].numpy().astype(np.float64)
    tpr = np.concatenate([[0], np.cumsum(hits) / hits.sum()])
    fpr = np.concatenate([[0], np.cumsum(1 - hits) / (1 - hits).sum()])
    return fpr, tpr


def evaluate(data: dict) -> dict:
    """Train on the training pixels, score the held-out pixels: F1, ROC AUC per feature set."""
    ytr, yte = data["train"]["y"], data["test"]["y"]
    methods, scores = {}, {}
    for name, key in (("raw temperature", "raw"), ("ANRA", "anra")):
        model = Logistic().fit(data["train"][key], ytr)
        threshold = best_threshold(model.score(data["train"][key]), ytr)
        score = model.score(data["test"][key])
        scores[name] = score
        methods[name] = {
            "f1": f1(score >= threshold, yte),
            "roc_auc": roc_auc(score, yte),
            "threshold": threshold,
        }
    omega = data["test"]["omega_map"]
    scores[OMEGA_RULE] = omega
    methods[OMEGA_RULE] = {"f1": f1(omega >= 1.0, yte), "roc_auc": roc_auc(omega, yte), "threshold": 1.0}
    raw, anra = methods["raw temperature"], methods["ANRA"]
    margin = {"f1": anra["f1"] - raw["f1"], "roc_auc": anra["roc_auc"] - raw["roc_auc"]}
    # 95 % interval of the margin over held-out videos (bootstrap: resample whole videos).
    video = data["test"]["video"]
    rng = np.random.default_rng(0)
    ids = torch.unique(video)
    samples = {"f1": [], "roc_auc": []}
    for _ in range(BOOTSTRAP):
        chosen = ids[torch.from_numpy(rng.integers(0, len(ids), len(ids)))]
        index = torch.cat([torch.nonzero(video == v).flatten() for v in chosen])
        y = yte[index]
        if not bool(y.any()):
            continue
        r, a = scores["raw temperature"][index], scores["ANRA"][index]
        samples["f1"].append(f1(a >= anra["threshold"], y) - f1(r >= raw["threshold"], y))
        samples["roc_auc"].append(roc_auc(a, y) - roc_auc(r, y))
    margin["f1_95"] = [float(np.quantile(samples["f1"], q)) for q in (0.025, 0.975)]
    margin["roc_auc_95"] = [float(np.quantile(samples["roc_auc"], q)) for q in (0.025, 0.975)]
    return {"methods": methods, "margin": margin, "scores": scores}


BOOTSTRAP = 200


OMEGA_RULE = "ANRA Omega >= 1 (no training)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--train", type=int, default=24, help="training videos")
    parser.add_argument("--test", type=int, default=12, help="held-out test videos")
    parser.add_argument("--noise", default="0.5,2,5", help="camera noise sd values in K, comma separated")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="results/tissue_damage")
    parser.add_argument("--docs", default="docs", help="folder the figure is copied to ('' to skip)")
    args = parser.parse_args()
    noises = [float(v) for v in args.noise.split(",")]
    torch.set_num_threads(1)  # small tensors: threads only contend
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    extractor = TissueFeatures()
    sets: dict[float, dict[str, dict[str, list]]] = {n: {"train": {}, "test": {}} for n in noises}
    example = None
    peaks = []  # true peak temperature of each scene, C
    for k in tqdm(range(args.train + args.test), desc="videos"):
        split = "train" if k < args.train else "test"
        seed = args.seed * 1000 + k
        video = scene(seed)
        peaks.append(float(video["truth"].max()))
        for noise in noises:
            frames = camera(video["clean"], noise, seed)
            anra, maps = anra_features(frames, video["dt"], extractor)
            rows = sets[noise][split]
            rows.setdefault("raw", []).append(raw_features(frames))
            rows.setdefault("anra", []).append(anra)
            rows.setdefault("omega_map", []).append(maps["omega"].flatten())
            rows.setdefault("y", []).append(video["damaged"].flatten())
            rows.setdefault("video", []).append(torch.full((SIZE * SIZE,), k))
            damaged = int(video["damaged"].sum())
            if split == "test" and noise == noises[-1] and (example is None or damaged > example[-1]):
                example = (video, frames, maps, noise, damaged)  # the test video with the largest burn
    results: dict = {
        "settings": {
            "train_videos": args.train,
            "test_videos": args.test,
            "camera_hz": 1 / (FINE_DT * STRIDE),
            "truth_hz": 1 / FINE_DT,
            "duration_s": DURATION,
            "size_px": SIZE,
            "dx_mm": DX,
            "seed": args.seed,
            "true_peak_c": {"min": min(peaks), "median": float(np.median(peaks)), "max": max(peaks)},
        },
        "features": {"raw temperature": ["peak", "mean", "last", "std"], "ANRA": list(extractor.map_names)},
        "by_noise": {},
    }
    lines = [
        f"Damaged-pixel classification (Omega >= 1 of the true temperature) on {args.test} held-out videos, "
        f"logistic regression trained on {args.train} videos; camera {1 / (FINE_DT * STRIDE):g} Hz; "
        f"true peak temperatures of the {len(peaks)} scenes {min(peaks):.0f}-{max(peaks):.0f} C, median "
        f"{np.median(peaks):.0f} C:",
        "",
        "| camera noise sd (K) | damaged pixels (test) | features | F1 | ROC AUC |",
        "|---|---|---|---|---|",
    ]
    last_scores = None
    for noise in noises:
        data = {s: {k: torch.cat(v) for k, v in rows.items()} for s, rows in sets[noise].items()}
        yte = data["test"]["y"]
        evaluation = evaluate(data)
        last_scores = (evaluation.pop("scores"), yte)
        evaluation["damaged_pixels_test"] = [int(yte.sum()), len(yte)]
        evaluation["damaged_fraction_train"] = float(data["train"]["y"].double().mean())
        results["by_noise"][f"{noise:g}"] = evaluation
        for name, m in evaluation["methods"].items():
            lines.append(
                f"| {noise:g} | {int(yte.sum())} / {len(yte)} | {name} | {m['f1']:.3f} | {m['roc_auc']:.4f} |"
            )
    lines.append("")
    for noise in noises:
        margin = results["by_noise"][f"{noise:g}"]["margin"]
        f1_lo, f1_hi = margin["f1_95"]
        auc_lo, auc_hi = margin["roc_auc_95"]
        lines.append(
            f"Margin ANRA - raw at {noise:g} K: F1 {margin['f1']:+.3f} (95 % bootstrap over test videos "
            f"{f1_lo:+.3f} to {f1_hi:+.3f}), ROC AUC {margin['roc_auc']:+.4f} "
            f"({auc_lo:+.4f} to {auc_hi:+.4f})."
        )
    results["elapsed_s"] = time.perf_counter() - start
    table = "\n".join(lines) + "\n"
    (out / "table.md").write_text(table)
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    figure = plot(example, *last_scores, out / "figure.png")
    if args.docs:
        Path(args.docs).mkdir(parents=True, exist_ok=True)
        shutil.copy(figure, Path(args.docs) / "tissue_damage.png")
    print(table)
    print(f"wrote {out / 'table.md'}, {out / 'results.json'}, {figure} in {results['elapsed_s']:.0f} s")


def plot(example: tuple, scores: dict[str, torch.Tensor], y: torch.Tensor, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(16, 4))
    video, frames, maps, noise, _ = example
    extent = (0, SIZE * DX, SIZE * DX, 0)
    image = axes[0].imshow(video["truth"].amax(0).numpy(), extent=extent, cmap="inferno")
    fig.colorbar(image, ax=axes[0], label="C")
    axes[0].contour(
        video["damaged"].numpy().astype(float), levels=[0.5], colors="cyan", extent=extent, origin="upper"
    )
    axes[0].set_title("true peak T; damage (cyan)")
    noisy = axes[1].imshow(frames.amax(0).numpy(), extent=extent, cmap="inferno")
    fig.colorbar(noisy, ax=axes[1], label="C")
    axes[1].set_title(f"camera peak ({1 / (FINE_DT * STRIDE):g} Hz, noise {noise:g} K)")
    omega = axes[2].imshow(np.log10(1e-6 + maps["omega"].numpy()), extent=extent, cmap="viridis")
    fig.colorbar(omega, ax=axes[2], label="log10 Omega")
    axes[2].contour(
        video["damaged"].numpy().astype(float), levels=[0.5], colors="red", extent=extent, origin="upper"
    )
    axes[2].set_title("ANRA Omega; true damage (red)")
    for ax in axes[:3]:
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    for name, score in scores.items():
        fpr, tpr = roc_curve(score, y)
        axes[3].plot(fpr, tpr, label=f"{name} (AUC {roc_auc(score, y):.4f})")
    axes[3].set_xscale("log")
    axes[3].set_xlim(1e-4, 1)
    axes[3].set_xlabel("false-positive rate")
    axes[3].set_ylabel("true-positive rate")
    axes[3].set_title(f"held-out ROC at noise {noise:g} K")
    axes[3].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


if __name__ == "__main__":
    main()
