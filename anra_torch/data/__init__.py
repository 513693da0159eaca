"""Thermal videos for ``torch.utils.data``: a dataset over files, batches that the layers take, transforms.

- :mod:`~anra_torch.data.dataset`: :class:`ThermalVideoDataset` over a folder, a glob, a manifest CSV or a
  list of paths, read lazily and worker-safe; its items are :class:`~anra_torch.video.Video` with their
  labels in ``meta["labels"]``, or a :class:`SkippedVideo` for a file that cannot be read;
- :mod:`~anra_torch.data.collate`: :func:`collate` stacks videos into a :class:`VideoBatch`, padding or
  cropping different shapes, and :meth:`VideoBatch.apply` runs a layer with each video seeing only its own
  samples;
- :mod:`~anra_torch.data.transforms`: :class:`RegionOfInterest`, :class:`Resample`, :class:`SelectPhase`,
  :class:`Compose`, by the library's own steps.

Example:
    >>> import tempfile, numpy as np
    >>> from torch.utils.data import DataLoader
    >>> from anra_torch.video import save_npz
    >>> folder = tempfile.mkdtemp()
    >>> for k in range(4):
    ...     _ = save_npz(f"{folder}/v{k}.npz", np.zeros((8, 24, 24 + 4 * k)), dt=0.1, dx=0.2)
    >>> dataset = ThermalVideoDataset(folder)
    >>> batch = next(iter(DataLoader(dataset, batch_size=4, collate_fn=dataset.collate)))
    >>> tuple(batch.frames.shape), batch.mode, batch.padding.tolist()
    ((4, 8, 24, 36), 'pad', [2304, 1536, 768, 0])

Shape:
    Items ``(T, H, W)``; batches ``(B, T, H, W)``.
"""

from anra_torch.data.collate import COLLATE_MODES, SkippedVideo, VideoBatch, collate
from anra_torch.data.dataset import MANIFEST_SPACING, ON_ERROR, ThermalVideoDataset, read_labels
from anra_torch.data.transforms import PHASES, Compose, RegionOfInterest, Resample, SelectPhase

__all__ = [
    "COLLATE_MODES",
    "MANIFEST_SPACING",
    "ON_ERROR",
    "PHASES",
    "Compose",
    "RegionOfInterest",
    "Resample",
    "SelectPhase",
    "SkippedVideo",
    "ThermalVideoDataset",
    "VideoBatch",
    "collate",
    "read_labels",
]
