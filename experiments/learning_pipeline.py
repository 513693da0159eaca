"""Segment thermal damage end to end through a dataset and a DataLoader: TissueFeatures as a fixed layer
inside the model against the same network on the raw frames.

Scenes (where the surface peak does not decide the damage): tissue at 37 C, 32 x 32 px of 0.3 mm, with a
smooth random diffusivity field (0.08-0.20 mm^2/s, :func:`experiments.tissue_damage.smooth_field`) and a
perfusion field whose level differs from scene to scene (0.05-1.0 1/s, log-uniform, times a smooth 0.5-1.5
texture). A broad Gaussian spot (sigma 1.5-3 mm) sweeps 0-2 mm for an exposure of 2-30 s (log-uniform),
then the tissue cools until 45 s. The heating power is set so that every scene's surface peak is 57-61 C:
the heat equation with perfusion is linear in the source, so :func:`anra_torch.simulation.simulate_tissue`
(10 Hz) is run at unit power and scaled. At these temperatures skin needs seconds to minutes to be damaged
(Arrhenius), so long exposures damage where short ones at the same peak do not (at peaks of 63-67 C the
damage rate is so steep that the peak nearly decides: the ranges are chosen for that; ``--peak``,
``--exposure`` change them). The table's "true peak" row thresholds the noiseless peak temperature: how far
the peak alone gets. Truth: Arrhenius Omega (skin constants,
piecewise-linear) of the noiseless 10 Hz temperature, damaged where ``Omega >= 1``. Camera: every 5th frame
(2 Hz, 91 frames) plus white noise of ``--noise`` K (:func:`experiments.tissue_damage.camera`).

Each camera video is an ``.npz`` (its damage map an entry, read as a label); training and test videos are
read by :class:`anra_torch.data.ThermalVideoDataset` through a ``DataLoader`` (``--workers`` processes,
batches from :meth:`~anra_torch.data.ThermalVideoDataset.collate`).

Models (the same head: three 3 x 3 convolutions of 16 channels, the third dilated, ReLU, a 1 x 1 output;
inputs standardised per channel with the training set's mean and standard deviation, kept as buffers):

* features in the model: :class:`anra_torch.tissue.TissueFeatures` as a fixed layer (13 maps, the dose maps
  as ``log10(1e-6 + x)``, run by :meth:`anra_torch.data.VideoBatch.apply`) -> head. A fixed layer gives the
  same maps for the same video every epoch, so they are computed once per video and kept (exact);
* raw frames: the 91 frames as channels -> head.

Both trained with Adam (``--lr``, ``--epochs``, batch ``--batch``) on the pixel-wise binary cross-entropy
weighted by the training set's class ratio; decision threshold: the one that maximises F1 on the training
pixels (:func:`experiments.tissue_damage.best_threshold`). References without a network: the camera's raw
peak and the true (noiseless) peak thresholded the same way, and TissueFeatures' Omega map at 1.
Held-out metrics over the pooled pixels of the ``--test`` videos: F1 and IoU (damaged class), with 95 %
intervals from 1000 bootstrap resamples of the test videos (the same resamples for every model, so the
difference has its own interval).

    python -m experiments.learning_pipeline        # 32 training + 16 test videos, 60 epochs, 3 seeds

Result of that command (17 min on two cores shared with other jobs; 8 of the 16 test videos have no
damaged pixel, 214 of 16,384 test pixels are damaged, so the intervals are wide):

=========================================  ====================  ====================  ===================
model                                      F1 [95 %]             IoU [95 %]            F1 per seed
=========================================  ====================  ====================  ===================
features in the model                      0.688 [0.511, 0.797]  0.524 [0.343, 0.663]  0.688, 0.589, 0.690
raw frames (the same head)                 0.396 [0.210, 0.489]  0.246 [0.117, 0.323]  0.396, 0.278, 0.431
raw peak, threshold (no network)           0.683 [0.542, 0.777]  0.518 [0.372, 0.635]
true peak, threshold (no network)          0.623 [0.445, 0.735]  0.452 [0.286, 0.581]
TissueFeatures Omega >= 1 (no training)    0.824 [0.703, 0.905]  0.701 [0.542, 0.826]
=========================================  ====================  ====================  ===================

Features in the model - raw frames: F1 +0.292 [+0.149, +0.467], IoU +0.277 [+0.128, +0.441]: the fixed
layer beats the same network on the raw frames. It does not beat thresholding the camera's peak (F1 +0.005
[-0.133, +0.146]), and the learned head falls short of TissueFeatures' own Omega map at 1 without any
training (F1 -0.137 [-0.242, -0.030]): with 32 training videos, half without damage, the head overfits
(training loss 1.24 -> 0.11) more than it learns beyond the Arrhenius integral.

Writes ``table.md`` and ``results.json`` to ``--out`` (default results/learning_pipeline), the videos to
``--out``/videos.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn
from torch.utils.data import DataLoader

from anra_torch.data import ThermalVideoDataset, VideoBatch
from anra_torch.simulation import MovingSource, simulate_tissue
from anra_torch.tissue import TissueFeatures, arrhenius_omega
from anra_torch.video import save_npz
from experiments.tissue_damage import LOG_MAPS, best_threshold, camera, f1, smooth_field

F64 = torch.float64
DX = 0.3  # mm: 32 px span 9.6 mm, as the house's 48 px of 0.2 mm, at half the simulation's steps


@dataclass(frozen=True)
class Settings:
    """What one run simulates and trains (units: s, K, C, px)."""

    train: int = 32
    test: int = 16
    size: int = 32
    duration: float = 45.0
    noise: float = 0.5
    peak: tuple[float, float] = (57.0, 61.0)
    exposure: tuple[float, float] = (2.0, 30.0)
    width: tuple[float, float] = (1.5, 3.0)
    fine_dt: float = 0.1
    stride: int = 5
    epochs: int = 60
    batch: int = 4
    lr: float = 3e-3
    workers: int = 2
    seeds: int = 3
    bootstrap: int = 1000
    seed: int = 0


# ------------------------------------------------------------------------------------------- scenes
def scene(seed: int, settings: Settings) -> dict:
    """One scene: the noiseless camera frames, the true damage map and what decided it."""
    rng = np.random.default_rng(seed)
    n = settings.size
    a = smooth_field(rng, 0.08, 0.20)[:n, :n]
    level = math.exp(rng.uniform(math.log(0.05), math.log(1.0)))
    b = level * smooth_field(rng, 0.5, 1.5)[:n, :n]
    exposure = math.exp(rng.uniform(*np.log(settings.exposure)))
    length, angle = rng.uniform(0.0, 2.0), rng.uniform(0, 2 * np.pi)
    mid = rng.uniform(0.35 * n * DX, 0.65 * n * DX, size=2)
    half = 0.5 * length * np.array([np.cos(angle), np.sin(angle)])
    source = MovingSource(
        start=tuple(mid - half),
        end=tuple(mid + half),
        width=rng.uniform(*settings.width),
        power=1.0,
        t_on=0.0,
        t_off=max(1, round(exposure / settings.fine_dt)) * settings.fine_dt,
    )
    u0 = torch.full((n, n), 37.0, dtype=F64)
    frames = round(settings.duration / settings.fine_dt) + 1
    rise = simulate_tissue(u0, a, b, dx=DX, dt=settings.fine_dt, n_frames=frames, source=source) - 37.0
    peak = rng.uniform(*settings.peak)
    truth = 37.0 + (peak - 37.0) / float(rise.max()) * rise  # linear in the source: the power that gives peak
    omega = arrhenius_omega(truth, settings.fine_dt, rule="linear")
    return {
        "clean": truth[:: settings.stride],
        "dt": settings.fine_dt * settings.stride,
        "damage": omega >= 1.0,
        "exposure_s": source.t_off,
        "peak_c": peak,
        "perfusion_level": level,
    }


def write_scenes(folder: Path, seeds: range, settings: Settings) -> list[dict]:
    """Simulate the scenes of ``seeds`` and write each camera video (with its damage map) to ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    facts = []
    for seed in seeds:
        s = scene(seed, settings)
        frames = camera(s["clean"], settings.noise, seed)
        extra = {k: s[k] for k in ("exposure_s", "peak_c", "perfusion_level")}
        maps = {"damage": s["damage"], "true_peak": s["clean"].amax(0)}
        save_npz(folder / f"scene_{seed:04d}.npz", frames, dt=s["dt"], dx=DX, **maps, **extra)
        facts.append({**extra, "damaged_fraction": float(s["damage"].double().mean())})
    return facts


# ------------------------------------------------------------------------------------------- models
class Head(nn.Module):
    """A few convolutions from ``channels`` input maps to one damage logit per pixel.

    Shape:
        ``(B, C, H, W)`` -> ``(B, H, W)``.
    """

    def __init__(self, channels: int, width: int = 16) -> None:
        super().__init__()
        self.layers = nn.Sequential(
            nn.Conv2d(channels, width, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=2, dilation=2),
            nn.ReLU(),
            nn.Conv2d(width, 1, 1),
        )

    def forward(self, x: Tensor) -> Tensor:
        return self.layers(x)[:, 0]


class Segmenter(nn.Module):
    """Inputs of a batch (``inputs``), standardised with fixed training statistics, then the head.

    Shape:
        ``VideoBatch`` ``(B, T, H, W)`` -> logits ``(B, H, W)`` (0 outside each video's own pixels).
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.head = Head(channels)
        self.register_buffer("mean", torch.zeros(channels, dtype=torch.float32))
        self.register_buffer("scale", torch.ones(channels, dtype=torch.float32))

    def inputs(self, batch: VideoBatch) -> Tensor:
        raise NotImplementedError

    def standardised(self, batch: VideoBatch) -> Tensor:
        x = (self.inputs(batch).float() - self.mean.view(-1, 1, 1)) / self.scale.view(-1, 1, 1)
        return torch.where(batch.pixel_mask.unsqueeze(1), x, torch.zeros_like(x)).nan_to_num(0.0)

    def forward(self, batch: VideoBatch) -> Tensor:
        return self.head(self.standardised(batch))

    @torch.no_grad()
    def fit_scaling(self, loader: DataLoader) -> None:
        """Per-channel mean and standard deviation of the inputs over the loader's own pixels."""
        total = square = count = 0.0
        for batch in loader:
            x = self.inputs(batch).double().transpose(0, 1)[:, batch.pixel_mask]  # (C, pixels)
            total, square, count = total + x.sum(1), square + (x**2).sum(1), count + x.shape[1]
        mean = total / count
        self.mean.copy_(mean)
        self.scale.copy_((square / count - mean**2).clamp_min(1e-12).sqrt())


class FeatureSegmenter(Segmenter):
    """:class:`~anra_torch.tissue.TissueFeatures` as a fixed layer, then the head. The layer has no
    parameters and its output depends only on the video: it is kept per video after its first pass."""

    def __init__(self) -> None:
        features = TissueFeatures()
        super().__init__(len(features.map_names))
        self.features = features
        self.kept: dict[Path, Tensor] = {}

    def inputs(self, batch: VideoBatch) -> Tensor:
        if any(s not in self.kept for s in batch.sources):
            maps = batch.apply(self.features)
            channels = [
                torch.log10(1e-6 + maps.maps[n].clamp_min(0)) if n in LOG_MAPS else maps.maps[n]
                for n in self.features.map_names
            ]
            stacked = torch.stack(channels, 1)
            self.kept |= {s: stacked[k] for k, s in enumerate(batch.sources)}
        return torch.stack([self.kept[s] for s in batch.sources])


class RawSegmenter(Segmenter):
    """The raw frames as channels, then the head."""

    def inputs(self, batch: VideoBatch) -> Tensor:
        return batch.frames


# ----------------------------------------------------------------------------------------- training
def loaders(folder: Path, settings: Settings, *, shuffle: bool) -> DataLoader:
    """A DataLoader over the videos in ``folder`` with their ``damage`` maps as labels."""
    dataset = ThermalVideoDataset(folder, labels=("damage", "true_peak"))
    return DataLoader(
        dataset,
        batch_size=settings.batch,
        shuffle=shuffle,
        num_workers=settings.workers,
        collate_fn=dataset.collate,
        generator=torch.Generator().manual_seed(settings.seed),
        persistent_workers=settings.workers > 0,
    )


def train(model: Segmenter, loader: DataLoader, settings: Settings, seed: int) -> list[float]:
    """Adam on the class-weighted pixel-wise cross-entropy; the mean loss of every epoch."""
    torch.manual_seed(seed)
    for layer in model.head.layers:
        if isinstance(layer, nn.Conv2d):
            layer.reset_parameters()
    damaged = [batch.labels["damage"][batch.pixel_mask].double() for batch in loader]
    fraction = float(torch.cat(damaged).mean())
    weight = torch.tensor((1 - fraction) / max(fraction, 1e-6))
    optimiser = torch.optim.Adam(model.head.parameters(), lr=settings.lr)
    losses = []
    for _ in range(settings.epochs):
        total, count = 0.0, 0
        for batch in loader:
            mask = batch.pixel_mask
            logits = model(batch)[mask]
            target = batch.labels["damage"][mask].float()
            loss = nn.functional.binary_cross_entropy_with_logits(logits, target, pos_weight=weight)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            total, count = total + float(loss.detach()) * len(target), count + len(target)
        losses.append(total / count)
    return losses


@torch.no_grad()
def scores(loader: DataLoader, score: Callable[[VideoBatch], Tensor]) -> dict[str, Tensor]:
    """``score`` of every own pixel of the loader's videos, the truth and each pixel's video index."""
    out: dict[str, list[Tensor]] = {"score": [], "y": [], "video": []}
    seen = 0
    for batch in loader:
        mask = batch.pixel_mask
        out["score"].append(score(batch)[mask].double())
        out["y"].append(batch.labels["damage"][mask].bool())
        index = torch.arange(seen, seen + len(batch)).view(-1, 1, 1).expand_as(mask)
        out["video"].append(index[mask])
        seen += len(batch)
    return {k: torch.cat(v) for k, v in out.items()}


def iou(predicted: Tensor, y: Tensor) -> float:
    """Intersection over union of the damaged class (0 when neither predicts nor has any)."""
    union = float((predicted | y).sum())
    return float((predicted & y).sum()) / union if union else 0.0


def evaluate(
    train_scores: dict, test_scores: dict, settings: Settings, threshold: float | None = None
) -> dict:
    """F1 and IoU on the test pixels at the threshold chosen on the training pixels (or the one given)."""
    if threshold is None:
        threshold = best_threshold(train_scores["score"], train_scores["y"])
    predicted = test_scores["score"] >= threshold
    return {
        "threshold": threshold,
        "f1": f1(predicted, test_scores["y"]),
        "iou": iou(predicted, test_scores["y"]),
        "predicted": predicted,
    }


def bootstrap(results: dict[str, dict], y: Tensor, video: Tensor, settings: Settings) -> dict:
    """95 % intervals of F1 and IoU per method and of each method's difference to the first, over resampled
    test videos (the same resamples for all)."""
    rng = np.random.default_rng(settings.seed)
    ids = torch.unique(video)
    members = [torch.nonzero(video == v).flatten() for v in ids]
    names = list(results)
    draws: dict[str, dict[str, list[float]]] = {n: {"f1": [], "iou": []} for n in names}
    for _ in range(settings.bootstrap):
        index = torch.cat([members[i] for i in rng.integers(0, len(ids), len(ids))])
        for name in names:
            predicted = results[name]["predicted"][index]
            draws[name]["f1"].append(f1(predicted, y[index]))
            draws[name]["iou"].append(iou(predicted, y[index]))

    def interval(values: list[float]) -> list[float]:
        return [float(np.quantile(values, q)) for q in (0.025, 0.975)]

    out = {n: {m: interval(draws[n][m]) for m in ("f1", "iou")} for n in names}
    first = names[0]
    for name in names[1:]:
        for m in ("f1", "iou"):
            diff = np.array(draws[first][m]) - np.array(draws[name][m])
            out[name][f"{m}_{first}_minus_this"] = interval(list(diff))
    return out


# ---------------------------------------------------------------------------------------------- run
def run(out: Path, settings: Settings, *, log: Callable[[str], None] = print) -> dict:
    """Simulate, write, train both models (``settings.seeds`` initialisations each) and evaluate."""
    start = time.perf_counter()
    n_train, n_test = settings.train, settings.test
    facts = {
        "train": write_scenes(
            out / "videos" / "train", range(settings.seed, settings.seed + n_train), settings
        ),
        "test": write_scenes(
            out / "videos" / "test",
            range(settings.seed + n_train, settings.seed + n_train + n_test),
            settings,
        ),
    }
    timing = {"simulate_s": time.perf_counter() - start}
    log(f"simulated {n_train} + {n_test} scenes in {timing['simulate_s']:.0f} s")
    train_loader = loaders(out / "videos" / "train", settings, shuffle=True)
    train_fixed = loaders(out / "videos" / "train", settings, shuffle=False)
    test_loader = loaders(out / "videos" / "test", settings, shuffle=False)
    first = next(iter(test_loader))
    models: dict[str, Segmenter] = {
        "features in the model": FeatureSegmenter(),
        "raw frames": RawSegmenter(int(first.frames.shape[1])),
    }
    results: dict[str, dict] = {}
    curves: dict[str, list[list[float]]] = {}
    test_scores = {}
    for name, model in models.items():
        clock = time.perf_counter()
        model.fit_scaling(train_fixed)
        timing[f"{name}: first pass s"] = time.perf_counter() - clock
        runs = []
        for seed in range(settings.seeds):
            clock = time.perf_counter()
            losses = train(model, train_loader, settings, seed)
            tr = scores(train_fixed, model)
            te = scores(test_loader, model)
            result = evaluate(tr, te, settings)
            result |= {"seed": seed, "loss_first": losses[0], "loss_last": losses[-1]}
            result["train_s"] = time.perf_counter() - clock
            runs.append((result, te))
            curves.setdefault(name, []).append(losses)
            scored = f"F1 {result['f1']:.3f}, IoU {result['iou']:.3f}"
            log(f"{name}, seed {seed}: {scored} ({result['train_s']:.0f} s)")
        f1s = [r["f1"] for r, _ in runs]
        median = runs[int(np.argsort(f1s)[len(f1s) // 2])]  # the median seed's model is the one reported
        results[name] = median[0] | {"f1_all_seeds": f1s, "iou_all_seeds": [r["iou"] for r, _ in runs]}
        test_scores[name] = median[1]
    reference = test_scores["raw frames"]
    peak = {
        k: scores(loader, lambda b: b.frames.amax(1))
        for k, loader in (("tr", train_fixed), ("te", test_loader))
    }
    results["raw peak, threshold (no network)"] = evaluate(peak["tr"], peak["te"], settings)
    true = {
        k: scores(loader, lambda b: b.labels["true_peak"])
        for k, loader in (("tr", train_fixed), ("te", test_loader))
    }
    results["true peak, threshold (no network)"] = evaluate(true["tr"], true["te"], settings)
    features = models["features in the model"]
    column = features.features.map_names.index("omega")  # kept as log10(1e-6 + Omega)
    omega = scores(test_loader, lambda b: features.inputs(b)[:, column])
    results["TissueFeatures Omega >= 1 (no training)"] = evaluate(
        {}, omega, settings, threshold=math.log10(1 + 1e-6)
    )
    intervals = bootstrap(results, reference["y"], reference["video"], settings)
    timing["total_s"] = time.perf_counter() - start
    summary = {
        "settings": asdict(settings),
        "scenes": facts,
        "timing": timing,
        "loss_curves": curves,
        "methods": {
            name: {k: v for k, v in r.items() if k != "predicted"} | {"ci95": intervals[name]}
            for name, r in results.items()
        },
        "test_damaged_pixels": [int(reference["y"].sum()), len(reference["y"])],
    }
    return summary


def table(summary: dict) -> str:
    """The markdown table of a run's summary."""
    s = summary["settings"]
    damaged, pixels = summary["test_damaged_pixels"]
    exposures = [f["exposure_s"] for f in summary["scenes"]["test"]]
    peaks = [f["peak_c"] for f in summary["scenes"]["test"]]
    lines = [
        f"Damage segmentation on {s['test']} held-out videos ({damaged} of {pixels} pixels damaged), trained "
        f"on {s['train']}; surface peaks {min(peaks):.1f}-{max(peaks):.1f} C, exposures {min(exposures):.1f}-"
        f"{max(exposures):.1f} s, camera {1 / (s['fine_dt'] * s['stride']):g} Hz with {s['noise']:g} K "
        f"noise; {s['epochs']} epochs, median of "
        f"{s['seeds']} initialisations; 95 % intervals from {s['bootstrap']} bootstrap resamples of the test "
        "videos:",
        "",
        "| model | F1 [95 %] | IoU [95 %] | F1 of each initialisation |",
        "|---|---|---|---|",
    ]
    for name, m in summary["methods"].items():
        ci = m["ci95"]
        seeds = ", ".join(f"{v:.3f}" for v in m.get("f1_all_seeds", [])) or "-"
        lines.append(
            f"| {name} | {m['f1']:.3f} [{ci['f1'][0]:.3f}, {ci['f1'][1]:.3f}] | {m['iou']:.3f} "
            f"[{ci['iou'][0]:.3f}, {ci['iou'][1]:.3f}] | {seeds} |"
        )
    lines.append("")
    first = next(iter(summary["methods"]))
    for name, m in list(summary["methods"].items())[1:]:
        f_lo, f_hi = m["ci95"][f"f1_{first}_minus_this"]
        i_lo, i_hi = m["ci95"][f"iou_{first}_minus_this"]
        best = summary["methods"][first]
        lines.append(
            f"{first} - {name}: F1 {best['f1'] - m['f1']:+.3f} [{f_lo:+.3f}, {f_hi:+.3f}], "
            f"IoU {best['iou'] - m['iou']:+.3f} [{i_lo:+.3f}, {i_hi:+.3f}]."
        )
    return "\n".join(lines) + "\n"


def _pair(text: str) -> tuple[float, float]:
    low, high = (float(v) for v in text.split(","))
    return low, high


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    defaults = Settings()
    for key in ("train", "test", "epochs", "batch", "workers", "seeds", "bootstrap", "seed"):
        parser.add_argument(f"--{key}", type=int, default=getattr(defaults, key))
    for key in ("noise", "lr", "duration"):
        parser.add_argument(f"--{key}", type=float, default=getattr(defaults, key))
    for key in ("peak", "exposure", "width"):
        low, high = getattr(defaults, key)
        parser.add_argument(
            f"--{key}", type=_pair, default=(low, high), help=f"LOW,HIGH (default {low:g},{high:g})"
        )
    parser.add_argument("--out", default="results/learning_pipeline")
    args = parser.parse_args()
    torch.set_num_threads(1)  # small tensors: threads only contend
    settings = Settings(**{k: v for k, v in vars(args).items() if k != "out"})
    out = Path(args.out)
    summary = run(out, settings)
    text = table(summary)
    (out / "table.md").write_text(text)
    (out / "results.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(text)
    print(f"wrote {out / 'table.md'} and {out / 'results.json'} in {summary['timing']['total_s']:.0f} s")


if __name__ == "__main__":
    main()
