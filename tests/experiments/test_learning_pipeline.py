"""The learning-pipeline experiment in miniature: scenes written as .npz, read by ThermalVideoDataset through
a DataLoader, TissueFeatures as a fixed layer in the model and the raw-frame model both train (the loss
falls), with the shapes and the table the full run reports."""

from __future__ import annotations

from pathlib import Path

import torch

from anra_torch.data import VideoBatch
from anra_torch.tissue import TissueFeatures
from experiments.learning_pipeline import (
    FeatureSegmenter,
    RawSegmenter,
    Settings,
    loaders,
    run,
    table,
    write_scenes,
)

TINY = Settings(
    train=3,
    test=2,
    size=24,
    duration=6.0,
    peak=(63.0, 65.0),
    exposure=(2.0, 4.0),
    epochs=12,
    batch=2,
    workers=0,
    seeds=1,
    bootstrap=20,
)


def test_the_models_take_dataloader_batches(tmp_path: Path) -> None:
    facts = write_scenes(tmp_path, range(2), TINY)
    assert all(f["damaged_fraction"] > 0 for f in facts)  # 63-65 C for 2-4 s burns the spot's centre
    loader = loaders(tmp_path, TINY, shuffle=False)
    batch = next(iter(loader))
    assert isinstance(batch, VideoBatch) and tuple(batch.frames.shape) == (2, 13, 24, 24)  # 6 s at 2 Hz
    damage = batch.labels["damage"]
    assert damage.dtype == torch.bool and tuple(damage.shape) == (2, 24, 24)
    features = FeatureSegmenter()
    features.fit_scaling(loader)
    assert features.mean.shape == (13,) and bool((features.scale > 0).all())
    logits = features(batch)
    assert tuple(logits.shape) == (2, 24, 24) and bool(torch.isfinite(logits).all())
    # The kept maps are the fixed layer's on each video alone (log10(1e-6 + x) for the doses).
    alone = TissueFeatures()(batch.frames[1], float(batch.dt[1]), float(batch.dx[1]))
    omega = features.features.map_names.index("omega")
    kept = features.kept[batch.sources[1]][omega]
    torch.testing.assert_close(kept, torch.log10(1e-6 + alone.maps["omega"]), rtol=1e-12, atol=1e-12)
    raw = RawSegmenter(13)
    raw.fit_scaling(loader)
    assert tuple(raw(batch).shape) == (2, 24, 24)


def test_the_tiny_pipeline_trains_both_models_and_reports(tmp_path: Path) -> None:
    summary = run(tmp_path, TINY, log=lambda line: None)
    assert sorted(p.name for p in (tmp_path / "videos" / "train").iterdir()) == [
        "scene_0000.npz",
        "scene_0001.npz",
        "scene_0002.npz",
    ]
    for name in ("features in the model", "raw frames"):
        (curve,) = summary["loss_curves"][name]
        assert len(curve) == TINY.epochs and curve[-1] < 0.7 * curve[0]
    methods = summary["methods"]
    assert list(methods)[:2] == ["features in the model", "raw frames"]
    for m in methods.values():
        assert 0 <= m["iou"] <= m["f1"] <= 1  # IoU = F1 / (2 - F1) <= F1
        assert set(m["ci95"]) >= {"f1", "iou"}
    text = table(summary)
    assert "| features in the model |" in text and "| raw frames |" in text
    assert "features in the model - raw frames: F1" in text
