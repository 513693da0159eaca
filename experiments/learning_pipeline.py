"""Segment thermal damage across tissues end to end through a dataset and a DataLoader: a learned tissue model
whose damage dose is trained through :class:`~anra_torch.tissue.TissueFeatures`, against the same kind of
network on the raw frames and against the fixed rules.

Scenes (:mod:`experiments.tissue_scenes`): skin, liver and arterial wall, each with its published Arrhenius
constants and its own ranges of diffusivity and perfusion, one tissue or two in a field of view, heated by a
spot to a 50-85 C peak for 2-30 s: the span over which the three tissues' damage thresholds differ (54.0, 50.1
and 69.6 C for damage in one minute). That span is what makes tissue matter: a fixed rule cannot be right for
all three, so the skin-constant Omega rule and a single peak threshold lose by the design of the question (the
results page says so); the scenes themselves follow the bioheat model with the published constants. Each
camera video (32 x 32 px, 2 Hz, 45 s, 0.2 K noise) is an ``.npz`` with its ``damage`` and ``tissue`` maps,
read by :class:`anra_torch.data.ThermalVideoDataset` through ``DataLoader`` s with ``--workers`` processes; a
folder of scenes made with the same settings is reused.

Networks, trained with Adam on the pixel-wise cross-entropy weighted by the training set's class ratio
(:func:`train` is the loop of the guide ``docs/guides/training-loop.md``):

* **features in the model** (:class:`LearnedDose`): ``TissueFeatures`` as a fixed layer (its 13 maps, the
  doses as ``log10(1e-6 + x)``, and its cooling-fit diffusivity) -> three convolutions that give each pixel a
  mixture over ``--prototypes`` tissue prototypes -> each prototype's Arrhenius constants, learned (``T60`` in
  45-80 C, ``Ea`` in 1.5e5-8e5 J/mol) -> Omega of the layer's own denoised history through
  :func:`anra_torch.tissue.omega_with_constants` -> ``P(damaged) = sum_k p_k sigmoid(s (log10 Omega_k - c))``.
  The gradient flows through the dose into the constants and the mixture. Pixels whose history stays below
  43 C are set undamaged without a dose (no prototype reaches ``Omega = 1`` there within 60 s);
* **the layer's maps, head only** (:class:`MapsHead`): the same maps -> three convolutions -> a logit: the
  ablation of the learned dose (nothing is trained through the layer);
* **raw frames** (:class:`RawFrames`): the 91 frames as channels -> the same head.

References without a network: the camera's raw peak thresholded (the threshold of best F1 on the training
pixels); ``TissueFeatures``' Omega map (skin constants) at 1; and the oracle, Omega of the same denoised
history with each pixel's true tissue constants, at 1. Held-out F1 of the damaged class over the pooled pixels
of the ``--test`` videos, with 95 % intervals from ``--bootstrap`` resamples of the test videos (the same for
every method, so each difference has its own interval); each network's median initialisation is reported.

    python -m experiments.learning_pipeline              # 256 + 128 videos, 3 seeds: the results page's table
    python -m experiments.learning_pipeline --device cuda

Writes ``table.md`` and ``results.json`` (``differences``: the features-in-the-model network minus each
method, ``{"f1", "low", "high"}``; ``timing``: process CPU seconds of this process and of its DataLoader
workers) to ``--out`` (default results/learning_pipeline), the videos to ``--out``/videos.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn
from torch.utils.data import DataLoader

from anra_torch.data import ThermalVideoDataset, VideoBatch
from anra_torch.tissue import GAS_CONSTANT, TissueFeatures, omega_with_constants
from experiments.tissue_damage import LOG_MAPS
from experiments.tissue_scenes import TISSUES, SceneSettings, omega_of_tissues, write_scenes

F64 = torch.float64


@dataclass(frozen=True)
class Settings(SceneSettings):
    """The scenes (:class:`~experiments.tissue_scenes.SceneSettings`), how many, how the networks train."""

    train: int = 256
    test: int = 128
    epochs: int = 40
    batch: int = 16
    lr: float = 3e-3
    prototypes: int = 4
    workers: int = 2
    seeds: int = 3
    bootstrap: int = 1000
    seed: int = 0
    device: str = "cpu"


# ------------------------------------------------------------------------------------------- models
class LayerMaps:
    """:class:`~anra_torch.tissue.TissueFeatures` as a fixed layer: each video's 13 maps (the doses as
    ``log10(1e-6 + x)``) and its cooling-fit diffusivity, ``(B, 14, H, W)``, computed once and kept (a fixed
    layer gives the same maps every epoch); and the denoised history its doses are taken from."""

    def __init__(self) -> None:
        self.features = TissueFeatures()
        self.names = (*self.features.map_names, "cooling_diffusivity")
        self.kept: dict[Path, Tensor] = {}

    def __call__(self, batch: VideoBatch) -> Tensor:
        if any(s not in self.kept for s in batch.sources):
            out = batch.apply(self.features)
            maps = out.maps | {"cooling_diffusivity": out.cooling_diffusivity}
            logs = {n: torch.log10(1e-6 + maps[n].clamp_min(0)) for n in LOG_MAPS}
            stacked = torch.stack([logs.get(n, maps[n]) for n in self.names], 1).float()
            self.kept |= {s: stacked[k] for k, s in enumerate(batch.sources)}
        return torch.stack([self.kept[s] for s in batch.sources])

    def history(self, batch: VideoBatch) -> Tensor:
        """The frames (C) smoothed in space as the layer smooths them before its doses, float64."""
        frames = batch.frames.to(F64)
        return (
            self.features.history_smoother(frames)
            if self.features.history_smoothing(*frames.shape[-2:])
            else frames
        )


class Head(nn.Module):
    """Three 3 x 3 convolutions of 16 channels (the third dilated), ReLU, a 1 x 1 output.

    Shape:
        ``(B, C, H, W)`` -> ``(B, H, W)``.
    """

    def __init__(self, channels: int, out: int = 1, width: int = 16) -> None:
        super().__init__()
        self.layers = nn.Sequential(
            nn.Conv2d(channels, width, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=2, dilation=2),
            nn.ReLU(),
            nn.Conv2d(width, out, 1),
        )

    def forward(self, x: Tensor) -> Tensor:
        y = self.layers(x)
        return y[:, 0] if y.shape[1] == 1 else y


class Segmenter(nn.Module):
    """Standardised inputs of a batch -> one damage logit per pixel, and the loss the training loop minimises
    (the pixel-wise cross-entropy weighted by the training set's class ratio, over each video's own pixels).

    Shape:
        ``VideoBatch`` ``(B, T, H, W)`` -> logits ``(B, H, W)``.
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(channels))
        self.register_buffer("scale", torch.ones(channels))
        self.register_buffer("positive_weight", torch.ones(()))

    def inputs(self, batch: VideoBatch) -> Tensor:
        raise NotImplementedError

    def standardised(self, batch: VideoBatch) -> Tensor:
        x = (self.inputs(batch).float() - self.mean.view(-1, 1, 1)) / self.scale.view(-1, 1, 1)
        return torch.where(batch.pixel_mask.unsqueeze(1), x, torch.zeros_like(x)).nan_to_num(0.0)

    def loss(self, batch: VideoBatch) -> Tensor:
        mask = batch.pixel_mask
        logits = self(batch)[mask]
        target = batch.labels["damage"][mask].to(logits.dtype)
        return nn.functional.binary_cross_entropy_with_logits(
            logits, target, pos_weight=self.positive_weight.to(logits.dtype)
        )

    def parameter_groups(self, lr: float) -> list[dict]:
        return [{"params": list(self.parameters()), "lr": lr}]

    @torch.no_grad()
    def fit_scaling(self, loader: DataLoader) -> None:
        """Per-channel mean and sd of the inputs over the loader's own pixels; the damaged class's weight."""
        total = square = count = damaged = 0.0
        for batch in loader:
            batch = batch.to(self.mean.device)
            x = self.inputs(batch).double().transpose(0, 1)[:, batch.pixel_mask]  # (C, pixels)
            total, square, count = total + x.sum(1), square + (x**2).sum(1), count + x.shape[1]
            damaged += float(batch.labels["damage"][batch.pixel_mask].sum())
        mean = total / count
        self.mean.copy_(mean)
        self.scale.copy_((square / count - mean**2).clamp_min(1e-12).sqrt())
        self.positive_weight.fill_((count - damaged) / max(damaged, 1.0))


class RawFrames(Segmenter):
    """The raw frames as channels, then :class:`Head`."""

    def __init__(self, frames: int) -> None:
        super().__init__(frames)
        self.head = Head(frames)

    def inputs(self, batch: VideoBatch) -> Tensor:
        return batch.frames

    def forward(self, batch: VideoBatch) -> Tensor:
        return self.head(self.standardised(batch))


class MapsHead(Segmenter):
    """The fixed layer's maps (:class:`LayerMaps`), then :class:`Head`: no gradient through the layer."""

    def __init__(self, layer: LayerMaps) -> None:
        super().__init__(len(layer.names))
        self.layer, self.head = layer, Head(len(layer.names))

    def inputs(self, batch: VideoBatch) -> Tensor:
        return self.layer(batch)

    def forward(self, batch: VideoBatch) -> Tensor:
        return self.head(self.standardised(batch))


T60_RANGE = (45.0, 80.0)  # C: what a prototype's one-minute damage temperature may learn
ENERGY_RANGE = (1.5e5, 8e5)  # J/mol: its activation energy
HOT = 43.0  # C: below it all the record long, no prototype reaches Omega = 1 within 60 s


class LearnedDose(MapsHead):
    """The fixed layer's maps -> a mixture over ``prototypes`` tissues -> each one's learned Arrhenius
    constants -> Omega of the layer's denoised history through :func:`~anra_torch.tissue.omega_with_constants`
    -> ``P(damaged) = sum_k p_k sigmoid(s (log10 Omega_k - c))``; ``forward`` returns its logit (float64)."""

    def __init__(self, layer: LayerMaps, prototypes: int = 4) -> None:
        super().__init__(layer)
        self.head = Head(len(layer.names), out=prototypes)  # the mixture's logits
        low, high = T60_RANGE
        start = (torch.linspace(48.0, 76.0, prototypes, dtype=F64) - low) / (high - low)
        # Stored unconstrained; constants() gives them in physical units within their ranges.
        self.t60 = nn.Parameter(torch.logit(start))
        self.energy = nn.Parameter(torch.zeros(prototypes, dtype=F64))
        self.sharpness = nn.Parameter(torch.ones((), dtype=F64))
        self.offset = nn.Parameter(torch.zeros((), dtype=F64))

    def constants(self) -> dict[str, Tensor]:
        """Each prototype's ``t60`` (C), ``activation_energy`` (J/mol) and ``log_frequency`` (ln of 1/s)."""
        t60 = T60_RANGE[0] + (T60_RANGE[1] - T60_RANGE[0]) * torch.sigmoid(self.t60)
        low, high = (math.log(e) for e in ENERGY_RANGE)
        energy = torch.exp(low + (high - low) * torch.sigmoid(self.energy))
        log_a = energy / (GAS_CONSTANT * (t60 + 273.15)) - math.log(60.0)
        return {"t60": t60, "activation_energy": energy, "log_frequency": log_a}

    def parameter_groups(self, lr: float) -> list[dict]:
        constants = [self.t60, self.energy]
        rest = [p for p in self.parameters() if all(p is not c for c in constants)]
        return [{"params": rest, "lr": lr}, {"params": constants, "lr": 10 * lr}]

    def mixture(self, batch: VideoBatch) -> Tensor:
        """Each pixel's log-probabilities of the prototypes, ``(B, K, H, W)``."""
        return torch.log_softmax(self.head(self.standardised(batch)).double(), 1)

    def forward(self, batch: VideoBatch) -> Tensor:
        log_p = self.mixture(batch)
        history = self.layer.history(batch)
        hot = (history.amax(1) > HOT) & batch.pixel_mask
        out = torch.full(hot.shape, -30.0, dtype=F64, device=hot.device) + 0.0 * self.offset
        if not bool(hot.any()):
            return out
        temperatures = history.permute(0, 2, 3, 1)[hot].T  # (T, P)
        c = self.constants()
        k = len(c["t60"])
        omega = omega_with_constants(  # "hold": Omega is dt times the sum, so each pixel's own dt scales it
            temperatures.unsqueeze(-1),  # one history (T, P, 1) under the K prototypes' constants
            1.0,
            log_frequency=c["log_frequency"].view(k, 1, 1),
            activation_energy=c["activation_energy"].view(k, 1, 1),
        )[..., 0].T * batch.dt.to(F64).view(-1, 1, 1).expand(hot.shape)[hot].unsqueeze(1)  # (P, K)
        z = 3.0 * self.sharpness * (torch.log10(omega + 1e-6) - self.offset)
        mix = log_p.permute(0, 2, 3, 1)[hot]
        logit = torch.logsumexp(mix + nn.functional.logsigmoid(z), 1) - torch.logsumexp(
            mix + nn.functional.logsigmoid(-z), 1
        )
        return out.masked_scatter(hot, logit)


# ----------------------------------------------------------------------------------------- training
def make_loader(folder: Path, settings: Settings, *, shuffle: bool) -> DataLoader:
    """A DataLoader over the videos in ``folder`` with their ``damage`` and ``tissue`` maps as labels."""
    dataset = ThermalVideoDataset(folder, labels=("damage", "tissue"))
    return DataLoader(
        dataset,
        batch_size=settings.batch,
        shuffle=shuffle,
        num_workers=settings.workers,
        collate_fn=dataset.collate,
        generator=torch.Generator().manual_seed(settings.seed),
        persistent_workers=settings.workers > 0,
    )


def train(
    model: Segmenter, loader: DataLoader, settings: Settings, held_out: DataLoader | None = None
) -> dict:
    """Adam on ``model.loss``; the mean training loss of every epoch and the held-out loss every 5th."""
    optimiser = torch.optim.Adam(model.parameter_groups(settings.lr))
    curve: dict[str, list] = {"train": [], "held_out": []}
    for epoch in range(settings.epochs):
        total = count = 0.0
        for batch in loader:
            batch = batch.to(settings.device)
            loss = model.loss(batch)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            total, count = total + float(loss.detach()) * len(batch), count + len(batch)
        curve["train"].append(total / count)
        if held_out is not None and ((epoch + 1) % 5 == 0 or epoch == 0):
            with torch.no_grad():
                losses = [(float(model.loss(b.to(settings.device))), len(b)) for b in held_out]
            curve["held_out"].append([epoch + 1, sum(v * n for v, n in losses) / sum(n for _, n in losses)])
    return curve


@torch.no_grad()
def scores(loader: DataLoader, score: Callable[[VideoBatch], Tensor], device: str) -> dict[str, Tensor]:
    """``score`` of every own pixel of the loader's videos, the truth, tissue and video index of each."""
    out: dict[str, list[Tensor]] = {"score": [], "y": [], "tissue": [], "video": []}
    seen = 0
    for batch in loader:
        batch = batch.to(device)
        mask = batch.pixel_mask
        out["score"].append(score(batch)[mask].double().cpu())
        out["y"].append(batch.labels["damage"][mask].bool().cpu())
        out["tissue"].append(batch.labels["tissue"][mask].long().cpu())
        index = torch.arange(seen, seen + len(batch), device=mask.device).view(-1, 1, 1).expand_as(mask)
        out["video"].append(index[mask].cpu())
        seen += len(batch)
    return {k: torch.cat(v) for k, v in out.items()}


def f1(predicted: Tensor, y: Tensor) -> float:
    """F1 of the damaged class (0 when nothing is predicted nor damaged)."""
    tp, fp, fn = float((predicted & y).sum()), float((predicted & ~y).sum()), float((~predicted & y).sum())
    return 2 * tp / (2 * tp + fp + fn) if tp else 0.0


def best_threshold(score: Tensor, y: Tensor) -> float:
    """The threshold of largest F1 on these pixels (exact: every distinct score is tried)."""
    order = torch.argsort(score, descending=True)
    s, hits = score[order], y[order].double()
    tp, fp = hits.cumsum(0), (1 - hits).cumsum(0)
    last = torch.ones_like(s, dtype=torch.bool)
    last[:-1] = s[1:] != s[:-1]  # a cut between distinct scores only
    f = torch.where(last, 2 * tp / (tp + fp + hits.sum()), -1.0)
    return float(s[int(f.argmax())])


def counts(predicted: Tensor, y: Tensor, video: Tensor, n: int) -> np.ndarray:
    """Per-video true positives, false positives and false negatives, ``(n, 3)``."""
    parts = [predicted & y, predicted & ~y, ~predicted & y]
    return torch.stack([torch.bincount(video, p.long(), minlength=n) for p in parts], 1).double().numpy()


def bootstrap(tallies: dict[str, np.ndarray], first: str, settings: Settings) -> dict[str, dict]:
    """95 % intervals of each method's F1 and of ``first`` minus each, over resampled test videos (the same
    resamples for all)."""
    rng = np.random.default_rng(settings.seed)
    n = len(next(iter(tallies.values())))
    draws = rng.integers(0, n, (settings.bootstrap, n))

    def f1s(c: np.ndarray) -> np.ndarray:
        tp, fp, fn = c[draws].sum(1).T
        return np.where(tp > 0, 2 * tp / np.maximum(2 * tp + fp + fn, 1), 0.0)

    values = {name: f1s(c) for name, c in tallies.items()}
    interval = lambda v: [float(np.quantile(v, 0.025)), float(np.quantile(v, 0.975))]  # noqa: E731
    return {
        name: {"f1": interval(v), "difference": interval(values[first] - v) if name != first else None}
        for name, v in values.items()
    }


# ---------------------------------------------------------------------------------------------- run
METHODS = {
    "features": "features in the model (TissueFeatures + learned dose)",
    "maps_head": "the layer's maps, head only (no learned dose)",
    "raw_frames": "raw frames (the same head)",
    "raw_peak": "raw peak, threshold (no network)",
    "omega_skin": "Omega >= 1, skin constants (no training)",
    "omega_true": "Omega >= 1, each tissue's true constants (oracle)",
}


@torch.no_grad()
def learned_constants(model: LearnedDose, loader: DataLoader, device: str) -> dict:
    """The prototypes' constants and each tissue's mean mixture over its test pixels above 43 C."""
    k = len(model.t60)
    total = torch.zeros(len(TISSUES), k, dtype=F64)
    count = torch.zeros(len(TISSUES), dtype=F64)
    for batch in loader:
        batch = batch.to(device)
        p = model.mixture(batch).exp().permute(0, 2, 3, 1).cpu()
        hot = ((model.layer.history(batch).amax(1) > HOT) & batch.pixel_mask).cpu()
        for j in range(len(TISSUES)):
            where = hot & (batch.labels["tissue"].cpu() == j)
            total[j] += p[where].sum(0)
            count[j] += float(where.sum())
    mixture = total / count.clamp_min(1).unsqueeze(1)
    return {
        "prototypes": {name: v.tolist() for name, v in model.constants().items()},
        "mixture_by_tissue": {t.name: mixture[j].tolist() for j, t in enumerate(TISSUES)},
        "true_t60": {t.name: t.t60 for t in TISSUES},
    }


class _Clock:
    """Wall and process CPU seconds since the last lap (this process; its reaped workers at the end)."""

    def __init__(self) -> None:
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        self.start = (self.wall, self.cpu, self.children())

    @staticmethod
    def children() -> float:
        t = os.times()
        return t.children_user + t.children_system

    def lap(self) -> dict:
        wall, cpu = time.perf_counter(), time.process_time()
        out = {"wall_s": wall - self.wall, "cpu_s": cpu - self.cpu}
        self.wall, self.cpu = wall, cpu
        return out

    def total(self) -> dict:
        wall0, cpu0, children0 = self.start
        workers = self.children() - children0
        own = time.process_time() - cpu0
        return {
            "wall_s": time.perf_counter() - wall0,
            "cpu_s": own,
            "workers_cpu_s": workers,
            "all_cpu_s": own + workers,
        }


def train_networks(loaders: dict, layer: LayerMaps, settings: Settings, log: Callable[[str], None]) -> dict:
    """Every network, ``settings.seeds`` initialisations each; the median seed's test predictions."""
    frames = round(settings.duration / (settings.fine_dt * settings.stride)) + 1
    makers: dict[str, Callable[[], Segmenter]] = {
        "features": lambda: LearnedDose(layer, settings.prototypes),
        "maps_head": lambda: MapsHead(layer),
        "raw_frames": lambda: RawFrames(frames),
    }
    out = {}
    for name, make in makers.items():
        runs, clock = [], time.process_time()
        for seed in range(settings.seeds):
            torch.manual_seed(settings.seed + seed)
            model = make().to(settings.device)
            model.fit_scaling(loaders["train_fixed"])
            curve = train(model, loaders["train"], settings, loaders["test"])
            tr = scores(loaders["train_fixed"], model, settings.device)
            te = scores(loaders["test"], model, settings.device)
            threshold = best_threshold(tr["score"], tr["y"])
            runs.append({"f1": f1(te["score"] >= threshold, te["y"]), "predicted": te["score"] >= threshold})
            runs[-1] |= {"threshold": threshold, "curve": curve, "model": model}
            loss = f"{curve['train'][0]:.3f} -> {curve['train'][-1]:.3f}"
            log(f"{name}, seed {seed}: F1 {runs[-1]['f1']:.3f}, training loss {loss}")
        median = sorted(runs, key=lambda r: r["f1"])[len(runs) // 2]
        out[name] = {k: median[k] for k in ("f1", "threshold", "predicted")}
        out[name] |= {"f1_all_seeds": [r["f1"] for r in runs], "curves": [r["curve"] for r in runs]}
        out[name] |= {"cpu_s": time.process_time() - clock, "model": median["model"]}
    return out


def run(out: Path, settings: Settings, *, log: Callable[[str], None] = print) -> dict:
    """Simulate (or reuse) the scenes, train the networks, evaluate every method on the test videos."""
    clock = _Clock()
    first, middle, last = (
        settings.seed,
        settings.seed + settings.train,
        settings.seed + settings.train + settings.test,
    )
    facts = {
        "train": write_scenes(out / "videos" / "train", range(first, middle), settings),
        "test": write_scenes(out / "videos" / "test", range(middle, last), settings),
    }
    timing = {"scenes": clock.lap()}
    log(f"scenes: {settings.train} + {settings.test} ({timing['scenes']['cpu_s']:.0f} s CPU)")
    loaders = {
        "train": make_loader(out / "videos" / "train", settings, shuffle=True),
        "train_fixed": make_loader(out / "videos" / "train", settings, shuffle=False),
        "test": make_loader(out / "videos" / "test", settings, shuffle=False),
    }
    layer = LayerMaps()
    for name in ("train_fixed", "test"):  # the fixed layer's one pass over every video
        for batch in loaders[name]:
            layer(batch.to(settings.device))
    timing["layer"] = clock.lap()
    log(f"TissueFeatures on every video: {timing['layer']['cpu_s']:.0f} s CPU")
    networks = train_networks(loaders, layer, settings, log)
    timing |= {name: {"cpu_s": r.pop("cpu_s")} for name, r in networks.items()}
    clock.lap()
    device = settings.device
    test = scores(loaders["test"], lambda b: b.frames.amax(1), device)
    train_peak = scores(loaders["train_fixed"], lambda b: b.frames.amax(1), device)
    column = layer.names.index("omega")  # kept as log10(1e-6 + Omega)
    skin = scores(loaders["test"], lambda b: layer(b)[:, column], device)["score"]
    oracle = scores(
        loaders["test"], lambda b: omega_of_tissues(layer.history(b), b.dt, b.labels["tissue"]), device
    )["score"]
    predicted = {name: r["predicted"] for name, r in networks.items()}
    predicted["raw_peak"] = test["score"] >= best_threshold(train_peak["score"], train_peak["y"])
    predicted["omega_skin"] = skin >= math.log10(1 + 1e-6)
    predicted["omega_true"] = oracle >= 1.0
    learned = learned_constants(networks["features"]["model"], loaders["test"], device)
    del loaders
    gc.collect()  # the workers exit: their CPU time is counted
    timing["total"] = clock.total()
    y, video, tissue = test["y"], test["video"], test["tissue"]
    n = int(video.max()) + 1
    intervals = bootstrap({k: counts(p, y, video, n) for k, p in predicted.items()}, "features", settings)
    methods = {}
    for name, p in predicted.items():
        methods[name] = {"label": METHODS[name], "f1": f1(p, y), "ci95": intervals[name]["f1"]}
        methods[name]["f1_by_tissue"] = {
            t.name: f1(p[tissue == j], y[tissue == j]) for j, t in enumerate(TISSUES)
        }
        if name in networks:
            methods[name] |= {k: networks[name][k] for k in ("f1_all_seeds", "threshold")}
    best = methods["features"]["f1"]
    differences = {
        name: {
            "f1": best - m["f1"],
            "low": intervals[name]["difference"][0],
            "high": intervals[name]["difference"][1],
        }
        for name, m in methods.items()
        if name != "features"
    }
    return {
        "settings": asdict(settings),
        "methods": methods,
        "differences": differences,
        "learned_constants": learned,
        "loss_curves": {name: r["curves"] for name, r in networks.items()},
        "timing": timing,
        "test_pixels": {
            "damaged": int(y.sum()),
            "all": len(y),
            "by_tissue": {t.name: int((tissue == j).sum()) for j, t in enumerate(TISSUES)},
        },
        "scenes": facts,
    }


def table(summary: dict) -> str:
    """The markdown tables of a run's summary."""
    s, pixels, methods = summary["settings"], summary["test_pixels"], summary["methods"]
    names = [t.name for t in TISSUES]
    per_tissue = ", ".join(f"{pixels['by_tissue'][n]} {n}" for n in names)
    lines = [
        f"Damage segmentation on {s['test']} held-out videos ({pixels['damaged']} of {pixels['all']} pixels "
        f"damaged; {per_tissue}), trained on {s['train']}; peaks {s['peak'][0]:g}-{s['peak'][1]:g} C, "
        f"exposures {s['exposure'][0]:g}-{s['exposure'][1]:g} s, camera {s['noise']:g} K noise; "
        f"{s['epochs']} epochs, median of {s['seeds']} initialisations; 95 % intervals from {s['bootstrap']} "
        "bootstrap resamples of the test videos:",
        "",
        f"| method | F1 [95 %] | F1 of each initialisation | {' | '.join(f'F1 {n}' for n in names)} |",
        "|---|---|---|" + "---|" * len(names),
    ]
    for m in methods.values():
        seeds = ", ".join(f"{v:.3f}" for v in m.get("f1_all_seeds", [])) or "-"
        tissues = " | ".join(f"{m['f1_by_tissue'][n]:.3f}" for n in names)
        lines.append(
            f"| {m['label']} | {m['f1']:.3f} [{m['ci95'][0]:.3f}, {m['ci95'][1]:.3f}] | {seeds} | {tissues} |"
        )
    lines.append("")
    for name, d in summary["differences"].items():
        lines.append(
            f"- features in the model - {name}: F1 {d['f1']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}]"
        )
    learned = summary["learned_constants"]
    c = learned["prototypes"]
    lines += [
        "",
        "Learned prototypes (median seed): "
        + "; ".join(
            f"T60 {t:.1f} C, Ea {e / 1e5:.2f}e5 J/mol"
            for t, e in zip(c["t60"], c["activation_energy"], strict=True)
        )
        + ". Mean mixture on each tissue's test pixels above 43 C (true T60): "
        + "; ".join(
            f"{n} ({learned['true_t60'][n]:.1f} C) "
            + "/".join(f"{p:.2f}" for p in learned["mixture_by_tissue"][n])
            for n in names
        )
        + ".",
    ]
    lines += [
        "",
        "Training curves (mean over initialisations; held-out loss on the test videos, not used to stop):",
        "",
    ]
    lines += [
        "| network | epoch | "
        + " | ".join(str(e) for e, _ in summary["loss_curves"]["features"][0]["held_out"])
        + " |"
    ]
    lines += ["|---|---|" + "---|" * len(summary["loss_curves"]["features"][0]["held_out"])]
    for name, runs in summary["loss_curves"].items():
        epochs = [e for e, _ in runs[0]["held_out"]]
        train_loss = [np.mean([r["train"][e - 1] for r in runs]) for e in epochs]
        held = [np.mean([r["held_out"][i][1] for r in runs]) for i in range(len(epochs))]
        lines.append(f"| {name} | training loss | " + " | ".join(f"{v:.3f}" for v in train_loss) + " |")
        lines.append(f"| {name} | held-out loss | " + " | ".join(f"{v:.3f}" for v in held) + " |")
    t = summary["timing"]["total"]
    lines += [
        "",
        f"Process CPU time {t['all_cpu_s']:.0f} s ({t['cpu_s']:.0f} s this process, "
        f"{t['workers_cpu_s']:.0f} s its DataLoader workers), wall {t['wall_s']:.0f} s.",
    ]
    return "\n".join(lines) + "\n"


def _pair(text: str) -> tuple[float, float]:
    low, high = (float(v) for v in text.split(","))
    return low, high


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    defaults = Settings()
    for key in ("train", "test", "epochs", "batch", "prototypes", "workers", "seeds", "bootstrap", "seed"):
        parser.add_argument(f"--{key}", type=int, default=getattr(defaults, key))
    for key in ("noise", "lr", "duration", "mixed"):
        parser.add_argument(f"--{key}", type=float, default=getattr(defaults, key))
    for key in ("peak", "exposure", "width"):
        low, high = getattr(defaults, key)
        parser.add_argument(
            f"--{key}", type=_pair, default=(low, high), help=f"LOW,HIGH (default {low:g},{high:g})"
        )
    parser.add_argument("--device", default="cpu", help="where the layer and the networks run, e.g. cuda")
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
    print(f"wrote {out / 'table.md'} and {out / 'results.json'}")


if __name__ == "__main__":
    main()
