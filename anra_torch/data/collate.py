"""Batches of thermal videos: :func:`collate` stacks videos into a :class:`VideoBatch` that the estimator and
the tissue features take.

Videos of one shape are stacked as they are. Videos of different shapes are, by ``mode``:

- ``"pad"``, the default: padded at the end to the largest ``T``, ``H``, ``W`` with NaN, the value every
  analysis of the package masks and counts; :attr:`VideoBatch.mask` marks each video's own samples and
  :attr:`VideoBatch.padding` counts the others;
- ``"crop"``: cut to the smallest ``T``, the first frames, and the smallest ``H`` x ``W``, the centre of
  each frame;
- ``"same"``: refused, with one line naming the shapes.

:meth:`VideoBatch.apply` runs a layer so that each video sees only its own samples. Spatial labels are
cropped or padded with their video, numeric labels become ``(B,)`` tensors, text stays a tuple. What the
padding does to the layers, and why :meth:`VideoBatch.apply` exists: ``docs/guides/training-loop.md``,
section "Videos of different shapes".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.video import Video, crop

__all__ = ["COLLATE_MODES", "SkippedVideo", "VideoBatch", "collate"]

COLLATE_MODES = ("pad", "crop", "same")
"""How :func:`collate` batches videos of different shapes: pad with NaN, crop to the common part, refuse."""

_F64 = torch.float64


@dataclass(frozen=True)
class SkippedVideo:
    """An item a dataset with ``on_error="skip"`` could not read: its file and why, in one line.

    :func:`collate` leaves it out of the batch and lists it in :attr:`VideoBatch.skipped`.

    Attributes:
        path: the file, or folder of frame files.
        reason: the one-line error.

    Shape:
        No tensors.
    """

    path: Path
    reason: str


@dataclass(frozen=True)
class VideoBatch:
    """Videos stacked for a batched layer, with their spacing, times, own sizes and labels.

    Attributes:
        frames: temperatures, NaN outside each video's own samples with ``"pad"``.
        dt: frame periods in s.
        dx: pixel sizes in mm, or None when no video has one.
        t: each frame's time in s, the video's timestamps else ``k dt``; NaN on padded frames.
        sizes: each video's own ``(T, H, W)`` in the batch, after a crop; int64.
        labels: name -> a ``(B, ...)`` tensor for numbers and spatial maps, else a tuple of B values.
        sources: each video's file or folder; None for a video built in memory.
        meta: each video's :attr:`~anra_torch.video.Video.meta` without its labels.
        mode: what :func:`collate` did: ``"same"`` for one shape, ``"pad"`` or ``"crop"``.
        skipped: the unreadable items left out, :class:`SkippedVideo` in item order; a batch of nothing
            else holds no video and has ``len`` 0.

    Shape:
        ``frames`` ``(B, T, H, W)``; ``dt``, ``dx`` ``(B,)``; ``t`` ``(B, T)``; ``sizes`` ``(B, 3)``;
        ``mask`` ``(B, T, H, W)``; ``pixel_mask`` ``(B, H, W)``; ``padding`` ``(B,)``.
    """

    frames: Tensor
    dt: Tensor
    dx: Tensor | None
    t: Tensor
    sizes: Tensor
    labels: dict[str, Any]
    sources: tuple[Path | None, ...]
    meta: tuple[dict[str, Any], ...]
    mode: str = "same"
    skipped: tuple[SkippedVideo, ...] = ()

    def __len__(self) -> int:
        return self.frames.shape[0]

    @property
    def mask(self) -> Tensor:
        """True on each video's own samples, False on padding, ``(B, T, H, W)`` on the frames' device."""
        b, t, h, w = self.frames.shape
        return self._inside(t, 0).view(b, t, 1, 1) & self.pixel_mask.unsqueeze(1)

    @property
    def pixel_mask(self) -> Tensor:
        """True on each video's own pixels, ``(B, H, W)``."""
        b, _, h, w = self.frames.shape
        return self._inside(h, 1).view(b, h, 1) & self._inside(w, 2).view(b, 1, w)

    def _inside(self, n: int, axis: int) -> Tensor:
        """``(B, n)``: whether each index below ``n`` lies in each video's own size along ``axis``."""
        sizes = self.sizes.to(self.frames.device)
        return torch.arange(n, device=sizes.device).unsqueeze(0) < sizes[:, axis : axis + 1]

    @property
    def padding(self) -> Tensor:
        """Samples of each video that are padding, not its own, ``(B,)`` int64."""
        return math.prod(self.frames.shape[1:]) - self.sizes.prod(1)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> VideoBatch:
        """The batch on ``device``, its frames and floating spatial labels in ``dtype``; spacing and times
        stay float64.

        Shape:
            Unchanged.
        """
        return self._map(lambda x, floating: x.to(device=device, dtype=dtype if floating else None))

    def pin_memory(self) -> VideoBatch:
        """The batch in pinned memory; ``DataLoader(pin_memory=True)`` calls it."""
        return self._map(lambda x, floating: x.pin_memory())

    def _map(self, change: Callable[[Tensor, bool], Tensor]) -> VideoBatch:
        def spacing(x: Tensor | None) -> Tensor | None:
            return None if x is None else change(x, False)

        labels = {
            k: change(v, v.is_floating_point() and v.ndim > 1) if isinstance(v, Tensor) else v
            for k, v in self.labels.items()
        }
        return replace(
            self,
            frames=change(self.frames, True),
            dt=spacing(self.dt),
            dx=spacing(self.dx),
            t=change(self.t, False),
            sizes=change(self.sizes, False),
            labels=labels,
        )

    def apply(self, layer: Callable[..., Any]) -> Any:
        """``layer(frames, dt, dx)`` with each video seeing only its own samples.

        The layer is called once per distinct video size, each call with its videos cut to their own
        frames. The results are put back in batch order: tensors padded outside each video's own frame with
        NaN, False for booleans, 0 for integers; a map only some calls return is filled likewise for the
        others' videos.

        Args:
            layer: called as ``layer(frames, dt, dx)`` with ``frames`` ``(b, T_i, H_i, W_i)``, ``dt``
                ``(b,)`` and ``dx`` ``(b,)`` or None, e.g. an :class:`~anra_torch.estimation.ANRAEstimator`
                or a :class:`~anra_torch.tissue.TissueFeatures`.

        Returns:
            The layer's result for the whole batch, batched: a tensor, a tuple or dict of tensors, a tuple
            of one value per video, or a dataclass of them such as
            :class:`~anra_torch.estimation.ANRAResult`.

        Shape:
            ``frames`` ``(B, T, H, W)`` -> per-video results ``(B, ...)``, maps ``(B, H, W)``.

        Raises:
            ValueError: what the layer raises, with the videos it was given; a batch without a video, every
                item skipped.
        """
        if not len(self):
            gone = "; ".join(f"{s.path.name}: {s.reason}" for s in self.skipped) or "none given"
            raise ValueError(f"the batch holds no video (skipped: {gone}); leave it out of the loop")
        sizes = [tuple(row) for row in self.sizes.tolist()]
        groups = sorted(set(sizes))
        if groups == [tuple(self.frames.shape[1:])]:
            return self._call(layer, list(range(len(sizes))))
        parts = []
        for t, h, w in groups:
            members = [i for i, size in enumerate(sizes) if size == (t, h, w)]
            parts.append((members, self._call(layer, members, (t, h, w))))
        return _merge([r for _, r in parts], [i for i, _ in parts], len(self))

    def _call(
        self, layer: Callable[..., Any], members: list[int], size: tuple[int, ...] | None = None
    ) -> Any:
        """``layer`` on the videos ``members`` cut to ``size``; its ValueError names them."""
        index = torch.tensor(members, device=self.frames.device)
        frames = self.frames if size is None else self.frames[index][:, : size[0], : size[1], : size[2]]
        dt = self.dt if size is None else self.dt[index.to(self.dt.device)]
        dx = self.dx if size is None or self.dx is None else self.dx[index.to(self.dx.device)]
        try:
            return layer(frames, dt, dx)
        except ValueError as err:
            names = ", ".join(self.sources[i].name if self.sources[i] else "<memory>" for i in members)
            raise ValueError(f"{names}: {err}") from None


# -------------------------------------------------------------------------------------------- collate
def _check(videos: Sequence[Video], mode: str, dtype: torch.dtype | None) -> None:
    """:func:`collate`'s checks of its arguments (its ``Raises``, but for what the videos hold)."""
    if mode not in COLLATE_MODES:
        raise ValueError(f"mode must be one of {', '.join(COLLATE_MODES)}, got {mode!r}")
    if isinstance(videos, Video) or not isinstance(videos, Sequence) or not videos:
        raise TypeError(f"videos must be a non-empty sequence of Video, got {type(videos).__name__}")
    wrong = next((v for v in videos if not isinstance(v, Video | SkippedVideo)), None)
    if wrong is not None:
        raise TypeError(
            f"videos must be a non-empty sequence of Video, got an item of {type(wrong).__name__}"
        )
    if dtype is not None and not dtype.is_floating_point:
        raise TypeError(f"dtype must be a floating dtype, got {dtype}")


def _aligned(
    videos: list[Video], shapes: list[tuple[int, ...]], mode: str
) -> tuple[list[Video], tuple[int, ...], list[tuple[int, int]]]:
    """The videos cropped to their common centre (``"crop"``) or as they are, the batch's ``(T, H, W)``,
    and each video's ``(x, y)`` offset in px in its own frame."""
    if mode == "crop":
        target = tuple(min(s[k] for s in shapes) for k in range(3))
        offsets = [((s[2] - target[2]) // 2, (s[1] - target[1]) // 2) for s in shapes]
        return [_crop(v, target, o) for v, o in zip(videos, offsets, strict=True)], target, offsets
    return videos, tuple(max(s[k] for s in shapes) for k in range(3)), [(0, 0)] * len(videos)


def collate(videos: Sequence[Video], *, mode: str = "pad", dtype: torch.dtype | None = None) -> VideoBatch:
    """Stack videos into a :class:`VideoBatch`, padding or cropping videos of different shapes by ``mode``.

    Frames left on disk are read here, in the ``DataLoader`` worker.

    Args:
        videos: items of :class:`~anra_torch.data.ThermalVideoDataset` or any
            :class:`~anra_torch.video.Video`, labels in ``meta["labels"]``. A :class:`SkippedVideo` item is
            left out and listed in :attr:`VideoBatch.skipped`; only skipped items give an empty batch.
        mode: one of :data:`COLLATE_MODES`: ``"pad"`` with NaN, the default; ``"crop"`` to the common
            first frames and centre; ``"same"`` refuses different shapes.
        dtype: of the frames; by default the videos' common floating dtype, the default dtype for
            integer counts.

    Returns:
        The :class:`VideoBatch`.

    Shape:
        ``B`` videos ``(T_i, H_i, W_i)`` -> frames ``(B, T, H, W)``: the largest sizes with ``"pad"``, the
        smallest with ``"crop"``.

    Raises:
        TypeError: not a non-empty sequence of videos; a non-floating ``dtype``.
        ValueError: an unknown ``mode``; different shapes with ``"same"``; some videos with a pixel size and
            some without; a label of different shapes that is not a per-pixel map.
    """
    _check(videos, mode, dtype)
    skipped = tuple(v for v in videos if isinstance(v, SkippedVideo))
    videos = [v for v in videos if isinstance(v, Video)]
    if not videos:
        return _empty(skipped, dtype or torch.get_default_dtype())
    videos = [replace(v, frames=_tensor(v.loaded().frames)) for v in videos]
    shapes = [tuple(v.frames.shape) for v in videos]
    if len(set(shapes)) > 1 and mode == "same":
        raise ValueError(
            f"videos must have one shape with mode='same', got {', '.join(map(str, sorted(set(shapes))))}; "
            "mode='pad' or 'crop' batches them"
        )
    dtype = dtype or _common_dtype(videos)
    device = videos[0].frames.device  # every tensor of the batch is made there
    mode = "same" if len(set(shapes)) == 1 else mode
    videos, target, offsets = _aligned(videos, shapes, mode)
    frames = torch.stack([_padded(v.frames.to(device, dtype), target) for v in videos])
    times = torch.stack([_padded(_times(v, device), target[:1]) for v in videos])
    sizes = torch.tensor([tuple(v.frames.shape) for v in videos], dtype=torch.int64, device=device)
    labels = _labels(videos, shapes, offsets, target, device)
    return VideoBatch(
        frames=frames,
        dt=torch.tensor([v.dt for v in videos], dtype=_F64, device=device),
        dx=_pixel_sizes(videos, device),
        t=times,
        sizes=sizes,
        labels=labels,
        sources=tuple(v.source for v in videos),
        meta=tuple({k: x for k, x in v.meta.items() if k != "labels"} for v in videos),
        mode=mode,
        skipped=skipped,
    )


def _empty(skipped: tuple[SkippedVideo, ...], dtype: torch.dtype) -> VideoBatch:
    """The batch of items that were all skipped: no video."""
    cpu = torch.device("cpu")
    return VideoBatch(
        frames=torch.zeros((0, 0, 0, 0), dtype=dtype, device=cpu),
        dt=torch.zeros(0, dtype=_F64, device=cpu),
        dx=None,
        t=torch.zeros((0, 0), dtype=_F64, device=cpu),
        sizes=torch.zeros((0, 3), dtype=torch.int64, device=cpu),
        labels={},
        sources=(),
        meta=(),
        skipped=skipped,
    )


def _tensor(frames: Any) -> Tensor:
    """Frames as a tensor: a tensor as it is (``torch.as_tensor`` would move it to the default device),
    an array on the CPU."""
    return frames if isinstance(frames, Tensor) else torch.as_tensor(frames, device="cpu")


def _common_dtype(videos: Sequence[Video]) -> torch.dtype:
    dtype = videos[0].frames.dtype
    for video in videos[1:]:
        dtype = torch.promote_types(dtype, video.frames.dtype)
    if not dtype.is_floating_point:
        return torch.get_default_dtype()
    return dtype if dtype in (torch.float32, _F64) else torch.float32


def _crop(video: Video, target: tuple[int, ...], offset: tuple[int, int]) -> Video:
    """The first ``target[0]`` frames and the ``target[1:]`` px around the centre (the library's crop)."""
    part = video.span(0, target[0]) if video.frames.shape[0] > target[0] else video
    if tuple(part.frames.shape[1:]) == target[1:]:
        return part
    return crop(part, (offset[0], offset[1], target[2], target[1]))  # labels: cut in _tensor_label


def _padded(x: Tensor, target: Sequence[int]) -> Tensor:
    """``x`` padded at the end of its last ``len(target)`` dimensions to ``target`` (NaN; 0 for integers
    and booleans)."""
    pad = []
    for size, want in zip(reversed(x.shape[x.ndim - len(target) :]), reversed(target), strict=True):
        pad += [0, want - size]
    if not any(pad):
        return x
    if x.dtype == torch.bool:
        return F.pad(x.to(torch.uint8), pad, value=0).bool()
    return F.pad(x, pad, value=float("nan") if x.is_floating_point() else 0)


def _times(video: Video, device: torch.device) -> Tensor:
    if video.t is not None:
        return video.t.to(device, _F64)
    return torch.arange(video.frames.shape[0], dtype=_F64, device=device) * video.dt


def _pixel_sizes(videos: Sequence[Video], device: torch.device) -> Tensor | None:
    known = [v.dx is not None for v in videos]
    if not any(known):
        return None
    if not all(known):
        without = ", ".join(v.name for v in videos if v.dx is None)
        raise ValueError(
            f"dx: {without} have no pixel size while the other videos have one; give dx "
            "(ThermalVideoDataset(dx=...) or a manifest's dx column)"
        )
    return torch.tensor([v.dx for v in videos], dtype=_F64, device=device)


def _labels(
    videos: Sequence[Video],
    shapes: Sequence[tuple[int, ...]],
    offsets: Sequence[tuple[int, int]],
    target: tuple,
    device: torch.device,
) -> dict[str, Any]:
    """Each label over the batch: numbers -> ``(B,)``, tensors stacked (per-pixel maps cropped or padded
    with their video), anything else a tuple."""
    names: dict[str, None] = {}
    for video in videos:
        names |= dict.fromkeys(video.meta.get("labels") or {})
    out: dict[str, Any] = {}
    for name in names:
        values = [(v.meta.get("labels") or {}).get(name) for v in videos]
        if all(isinstance(x, bool | int | float) or x is None for x in values) and any(
            x is not None for x in values
        ):
            numbers = [math.nan if x is None else float(x) for x in values]
            out[name] = torch.tensor(numbers, dtype=_F64, device=device)
        elif all(isinstance(x, Tensor) for x in values):
            out[name] = _tensor_label(name, values, shapes, offsets, target)
        else:
            out[name] = tuple(values)
    return out


def _tensor_label(
    name: str, values: list[Tensor], shapes: Sequence[tuple[int, ...]], offsets: Sequence, target: tuple
) -> Tensor:
    if len({tuple(x.shape) for x in values}) == 1 and len(set(shapes)) == 1:
        return torch.stack(values)
    spatial = all(x.ndim >= 2 and tuple(x.shape[-2:]) == s[1:] for x, s in zip(values, shapes, strict=True))
    if not spatial:
        raise ValueError(
            f"label {name!r}: tensors of different shapes ({', '.join(str(tuple(x.shape)) for x in values)}) "
            "that are not per-pixel maps of their videos cannot be batched"
        )
    h, w = target[1:]
    cut = [x[..., y0 : y0 + h, x0 : x0 + w] for x, (x0, y0) in zip(values, offsets, strict=True)]
    return torch.stack([_padded(x, (h, w)) for x in cut])


# ---------------------------------------------------------------------------------------------- merge
def _merge(values: list[Any], indices: list[list[int]], batch: int) -> Any:
    """Per-group results of :meth:`VideoBatch.apply` back in batch order (see there)."""
    present = [v for v in values if v is not None]
    if not present:
        return None
    first = present[0]
    if isinstance(first, Tensor):
        return _merge_tensors(values, indices, batch)
    if is_dataclass(first) and not isinstance(first, type):
        merged = {f.name: _merge([getattr(v, f.name) for v in values], indices, batch) for f in fields(first)}
        return replace(first, **merged)
    if isinstance(first, dict):
        keys: dict[Any, None] = {}
        for value in present:
            keys |= dict.fromkeys(value)
        return {k: _merge([None if v is None else v.get(k) for v in values], indices, batch) for k in keys}
    if isinstance(first, tuple | list) and first and all(isinstance(x, Tensor) for x in first):  # (a, b)
        return type(first)(_merge([v[k] for v in values], indices, batch) for k in range(len(first)))
    if isinstance(first, tuple | list) and all(
        v is not None and len(v) == len(i) for v, i in zip(values, indices, strict=True)
    ):  # one value per video (messages, records)
        out: list[Any] = [None] * batch
        for value, index in zip(values, indices, strict=True):
            for item, i in zip(value, index, strict=True):
                out[i] = item
        return type(first)(out)
    return first


def _merge_tensors(values: list[Tensor | None], indices: list[list[int]], batch: int) -> Tensor:
    first = next(v for v in values if v is not None)
    shape = [max(v.shape[k] for v in values if v is not None) for k in range(1, first.ndim)]
    fill = False if first.dtype == torch.bool else (math.nan if first.is_floating_point() else 0)
    out = torch.full((batch, *shape), fill, dtype=first.dtype, device=first.device)
    for value, index in zip(values, indices, strict=True):
        if value is not None:
            region = (torch.tensor(index, device=out.device), *(slice(0, n) for n in value.shape[1:]))
            out[region] = value
    return out
