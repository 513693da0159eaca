"""The learning-pipeline experiment in miniature: multi-tissue scenes written as .npz, read by
ThermalVideoDataset through DataLoaders, the learned dose trained through TissueFeatures (its gradient
checked), the networks and the rules compared, the results' differences and the guide's loop."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest
import torch
from torch.func import functional_call

from anra_torch.data import VideoBatch
from anra_torch.tissue import TissueFeatures
from experiments.learning_pipeline import (
    HOT,
    LayerMaps,
    LearnedDose,
    Settings,
    best_threshold,
    make_loader,
    run,
    table,
    train,
)
from experiments.tissue_scenes import write_scenes

ROOT = Path(__file__).resolve().parents[2]
TINY = Settings(
    train=6, test=4, size=24, duration=12.0, epochs=3, batch=3, workers=0, seeds=1, bootstrap=50, mixed=0.5
)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("scenes")
    write_scenes(folder, range(TINY.train), TINY)
    return folder


@pytest.fixture(scope="module")
def batch(scenes: Path) -> VideoBatch:
    return next(iter(make_loader(scenes, TINY, shuffle=False)))


def test_the_layer_keeps_its_maps_and_the_cooling_diffusivity(batch: VideoBatch) -> None:
    layer = LayerMaps()
    maps = layer(batch)
    assert maps.shape == (3, 14, 24, 24) and layer.names[-1] == "cooling_diffusivity"
    alone = TissueFeatures()(batch.frames[1].double(), float(batch.dt[1]), float(batch.dx[1]))
    omega = layer.names.index("omega")
    torch.testing.assert_close(maps[1, omega], torch.log10(1e-6 + alone.maps["omega"]).float())
    torch.testing.assert_close(maps[1, -1], alone.cooling_diffusivity.float())
    assert set(layer.kept) == set(batch.sources)


def test_the_learned_dose_trains_through_the_layer(batch: VideoBatch) -> None:
    """The loss's gradient reaches every prototype's constants through the dose, and a gradcheck (float64)
    of the logits in those constants passes on the batch's hot pixels."""
    torch.manual_seed(0)
    model = LearnedDose(LayerMaps(), prototypes=3)
    logits = model(batch)
    assert logits.shape == (3, 24, 24) and logits.dtype == torch.float64
    hot = model.layer.history(batch).amax(1) > HOT
    assert bool(hot.any()) and bool((logits[~hot] == -30.0).all())
    model.loss(batch).backward()
    assert bool((model.t60.grad != 0).all()) and bool((model.energy.grad != 0).all())
    assert model.head.layers[0].weight.grad.abs().sum() > 0  # the mixture learns through the dose too

    def hot_logits(t60: torch.Tensor, energy: torch.Tensor) -> torch.Tensor:
        return functional_call(model, {"t60": t60, "energy": energy}, (batch,))[hot][:40]

    start = (
        model.t60.detach().clone().requires_grad_(True),
        model.energy.detach().clone().requires_grad_(True),
    )
    assert torch.autograd.gradcheck(hot_logits, start, eps=1e-6, atol=1e-5, rtol=1e-4)
    c = model.constants()
    assert torch.allclose(c["t60"], torch.tensor([48.0, 62.0, 76.0], dtype=torch.float64))


def test_the_best_threshold_is_exact() -> None:
    score = torch.tensor([0.1, 0.9, 0.8, 0.4, 0.7, 0.4], dtype=torch.float64)
    y = torch.tensor([False, True, True, False, True, True])
    assert best_threshold(score, y) == pytest.approx(0.4)  # F1 0.889; at 0.7: 0.857
    assert best_threshold(score, torch.tensor([False, True, False, False, False, False])) == pytest.approx(
        0.9
    )


@pytest.mark.slow
def test_the_tiny_pipeline_compares_every_method(tmp_path: Path) -> None:
    summary = run(tmp_path, TINY, log=lambda line: None)
    methods = summary["methods"]
    assert list(methods) == ["features", "maps_head", "raw_frames", "raw_peak", "omega_skin", "omega_true"]
    for m in methods.values():
        assert 0 <= m["f1"] <= 1 and m["ci95"][0] <= m["ci95"][1]
        assert set(m["f1_by_tissue"]) == {"skin", "liver", "arterial wall"}
    assert methods["omega_true"]["f1"] > 0.8  # the oracle's own history: noise and smoothing only
    assert set(summary["differences"]) == {"maps_head", "raw_frames", "raw_peak", "omega_skin", "omega_true"}
    for name, d in summary["differences"].items():
        assert d["low"] <= d["high"]
        assert d["f1"] == pytest.approx(methods["features"]["f1"] - methods[name]["f1"])
    for curves in summary["loss_curves"].values():
        (curve,) = curves
        assert len(curve["train"]) == TINY.epochs and curve["train"][-1] < curve["train"][0]
        assert [e for e, _ in curve["held_out"]] == [1]
    learned = summary["learned_constants"]
    assert len(learned["prototypes"]["t60"]) == TINY.prototypes
    assert learned["true_t60"]["liver"] == pytest.approx(50.1, abs=0.05)
    timing = summary["timing"]["total"]
    assert timing["all_cpu_s"] == pytest.approx(timing["cpu_s"] + timing["workers_cpu_s"])
    text = table(summary)
    assert "| features in the model (TissueFeatures + learned dose) |" in text
    assert "features in the model - omega_skin: F1" in text


def python_blocks(page: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", page.read_text(), re.M | re.S)


def test_the_guides_training_loop_is_the_experiments() -> None:
    """The guide's loop (optimiser to step) is :func:`train`'s, statement by statement in order; the guide's
    block itself runs as pasted in ``tests/test_guides.py``."""
    (block,) = python_blocks(ROOT / "docs" / "guides" / "training-loop.md")
    strip = lambda line: line.split("#")[0].strip()  # noqa: E731
    lines = block.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("optimiser = "))
    last = next(i for i, line in enumerate(lines) if "optimiser.step()" in line)
    guide = [strip(line) for line in lines[first : last + 1] if strip(line)]
    source = [strip(line) for line in inspect.getsource(train).splitlines() if strip(line)]
    position = 0
    for statement in guide:
        assert statement in source[position:], f"the guide's {statement!r} is not in train() in this order"
        position = source.index(statement, position) + 1
