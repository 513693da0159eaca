"""Thermal videos through a ``torch.utils.data.DataLoader``: the estimator as a layer of a pipeline.

Four simulated videos of two sizes are written to a folder; :class:`anra_torch.data.ThermalVideoDataset`
reads them lazily (as every command reads a recording) and its ``collate`` pads them into one
:class:`~anra_torch.data.VideoBatch`; :meth:`VideoBatch.apply` runs the estimator with every video seeing
only its own pixels. The estimate is differentiable: the gradient of a loss on it reaches the frames.

    python examples/dataloader.py
"""

import tempfile
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from anra_torch import ANRAEstimator, ThermalVideoDataset
from anra_torch.simulation import Blobs, blobs_video
from anra_torch.video import save_npz

folder = Path(tempfile.mkdtemp())
for k, a in enumerate([0.1, 0.15, 0.2, 0.25]):
    size = 40 if k % 2 else 48
    video = blobs_video(
        n_videos=1, a=a, size=size, n_frames=16, noise_sd=0.01, seed=k, blobs=Blobs(sigma_range_px=(4.0, 8.0))
    )
    save_npz(folder / f"v{k}.npz", video.frames[0].numpy(), dt=video.dt, dx=video.dx)

dataset = ThermalVideoDataset(folder)
loader = DataLoader(dataset, batch_size=2, collate_fn=dataset.collate)
estimator = ANRAEstimator(smoothing=2.0)  # one fixed smoothing: a smooth function of the frames
for batch in loader:
    print(tuple(batch.frames.shape), batch.mode, [p.name for p in batch.sources])
    result = batch.apply(estimator)
    print("  a =", [round(v, 4) for v in result.diffusivity.tolist()], "mm^2/s")

# Gradients flow from the estimate back to the frames (e.g. to train what produced them).
frames = dataset[0].frames.clone().requires_grad_(True)
a = estimator(frames, dataset[0].dt, dataset[0].dx).diffusivity
a.backward()
print(f"d a / d frames: shape {tuple(frames.grad.shape)}, finite {bool(torch.isfinite(frames.grad).all())}")
