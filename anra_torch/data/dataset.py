"""A ``torch.utils.data.Dataset`` of thermal videos: a folder, a glob, a manifest CSV or a list of paths.

:class:`ThermalVideoDataset` finds its videos when it is built, reading names and manifest cells but no
frame, and reads each one in ``__getitem__`` through the recording policy of every command,
:func:`anra_torch.recording.open_recording`. It holds only paths, numbers and strings, so it pickles and
works in ``DataLoader`` workers; every file is opened in the worker that reads it.

Sources:

- a folder: every file whose suffix a loader of :data:`anra_torch.video.REGISTRY` knows and every
  sub-folder of frame files, :data:`anra_torch.video.FOLDER_REGISTRY`, is one video; other entries are
  left out and listed in :attr:`~ThermalVideoDataset.skipped` with the reason. Not recursive: a tree of
  videos is a glob such as ``"root/**/*.npz"``;
- a glob pattern with ``*``, ``?``, ``[`` or a recursive ``**``: every match, sorted;
- a manifest: a ``.csv`` whose header has a ``path`` column, relative to the manifest's folder, optional
  ``dt`` in s and ``dx`` in mm columns that override the file's spacing where filled, and every other
  column a label;
- a list of paths.

Labels travel in ``video.meta["labels"]``, name -> number, text, tensor or None: the manifest's columns
and the entries named in ``labels`` read from each ``.npz`` file. What the recording policy does to each
file and how a manifest's cells are read: ``docs/guides/training-loop.md``, section "The dataset's
sources".
"""

from __future__ import annotations

import csv
import glob
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from anra_torch.checks import one_line
from anra_torch.data.collate import COLLATE_MODES, SkippedVideo, VideoBatch, collate
from anra_torch.estimation import CHUNKED_VALUES
from anra_torch.recording import open_recording
from anra_torch.video import FOLDER_REGISTRY, REGISTRY, CalibrationTable, PathLike, Video, is_flir_csv

__all__ = ["MANIFEST_SPACING", "ON_ERROR", "ThermalVideoDataset", "read_labels"]

MANIFEST_SPACING = ("dt", "dx")
"""Manifest columns that give a video's spacing, ``dt`` in s and ``dx`` in mm, overriding the file's; the
``path`` column names the video, every other column is a label."""

ON_ERROR = ("skip", "raise")
"""What an item that cannot be read does: becomes a :class:`~anra_torch.data.SkippedVideo` with a warning,
which :meth:`ThermalVideoDataset.collate` leaves out of its batch and lists, or raises its one-line error."""

_GLOB = frozenset("*?[")


@dataclass(frozen=True)
class _Entry:
    """One video of the dataset: its path, the spacing the manifest gives (None: the file's), its labels."""

    path: Path
    dt: float | None = None
    dx: float | None = None
    labels: dict[str, Any] = field(default_factory=dict)


class ThermalVideoDataset(Dataset):
    """Thermal videos from a folder, a glob, a manifest CSV or a list of paths, read lazily, item by item.

    Args:
        source: a folder, a glob pattern, a manifest ``.csv`` (a ``path`` column) or a sequence of paths
            as the module docstring lists them.
        dt: frame period in s for the videos whose file records none, such as a FLIR CSV export or a
            ``.npy``; a file's own ``dt`` or timestamps are kept, and a manifest's ``dt`` column overrides
            them.
        dx: pixel size in mm for the videos whose file records none, by the same rule.
        labels: entries of each ``.npz`` file to return as labels, scalars or arrays; an ``.npz`` without
            one of them is an error, other formats have None.
        transform: applied to each :class:`~anra_torch.video.Video` after reading, e.g.
            :class:`~anra_torch.data.RegionOfInterest`; it runs in the worker, so it must pickle.
        calibration: a table mapping apparent to true temperatures, or the path of its CSV, for every
            video.
        on_disk_above: leave a ``.npy`` or uncompressed ``.npz`` of more pixel values than this on disk, read
            in chunks; None reads every file whole. The default is
            :data:`~anra_torch.estimation.CHUNKED_VALUES`, as ``anra estimate``.
        collate_mode: how :meth:`collate` batches videos of different shapes, one of :data:`COLLATE_MODES`.
        on_error: what an item that cannot be read does, one of :data:`ON_ERROR`: ``"skip"``, the default,
            returns a :class:`~anra_torch.data.SkippedVideo` with the one-line reason, warns with a
            :class:`RuntimeWarning` and records it in :attr:`failed`; :meth:`collate` leaves it out of the
            batch and lists it in ``batch.skipped``. ``"raise"`` raises the error.

    Shape:
        Items: :class:`~anra_torch.video.Video` with frames ``(T, H, W)``, each its own size;
        :meth:`collate` -> :class:`~anra_torch.data.VideoBatch` with frames ``(B, T, H, W)``.

    Raises:
        TypeError: a source that is not a path, a pattern or a sequence of paths; a transform that is not
            callable.
        ValueError: a missing source, no video found, a manifest row without a path or with a spacing that
            is not a positive number, a non-positive ``dt`` or ``dx``, an unknown ``collate_mode`` or
            ``on_error``. A ``.csv`` without a ``path`` column is read as a FLIR export, not a manifest.

    Example:
        >>> import tempfile, numpy as np
        >>> from anra_torch.video import save_npz
        >>> folder = Path(tempfile.mkdtemp())
        >>> for k in range(3):
        ...     _ = save_npz(folder / f"v{k}.npz", np.zeros((6, 8, 8 + k)), dt=0.1, dx=0.2, a_true=0.1 * k)
        >>> dataset = ThermalVideoDataset(folder, labels=("a_true",))
        >>> len(dataset), dataset[2].frames.shape, dataset[2].meta["labels"]["a_true"]
        (3, torch.Size([6, 8, 10]), 0.2)
        >>> batch = dataset.collate([dataset[0], dataset[2]])
        >>> tuple(batch.frames.shape), batch.padding.tolist()
        ((2, 6, 8, 10), [96, 0])
    """

    def __init__(
        self,
        source: PathLike | Sequence[PathLike],
        *,
        dt: float | None = None,
        dx: float | None = None,
        labels: Sequence[str] = (),
        transform: Callable[[Video], Video] | None = None,
        calibration: CalibrationTable | PathLike | None = None,
        on_disk_above: int | None = CHUNKED_VALUES,
        collate_mode: str = "pad",
        on_error: str = "skip",
    ) -> None:
        for name, value, unit in (("dt", dt, "s"), ("dx", dx, "mm")):
            if value is not None and not (isinstance(value, int | float) and 0 < value < float("inf")):
                raise ValueError(f"{name} must be a positive number in {unit} or None, got {value!r}")
        if transform is not None and not callable(transform):
            raise TypeError(f"transform must be callable (Video -> Video), got {type(transform).__name__}")
        if collate_mode not in COLLATE_MODES:
            raise ValueError(f"collate_mode must be one of {', '.join(COLLATE_MODES)}, got {collate_mode!r}")
        if on_error not in ON_ERROR:
            raise ValueError(f"on_error must be one of {', '.join(ON_ERROR)}, got {on_error!r}")
        if isinstance(labels, str):
            labels = (labels,)
        self.dt, self.dx = dt, dx
        self.labels = tuple(labels)
        self.transform = transform
        self.calibration = calibration
        self.on_disk_above = on_disk_above
        self.collate_mode = collate_mode
        self.on_error = on_error
        self.skipped: dict[str, str] = {}
        """Entries of a source folder left out: name -> why (not a video)."""
        self.failed: dict[str, str] = {}
        """Items skipped as unreadable in this process: path -> the one-line reason (a ``DataLoader``
        worker's are in its batches' ``skipped``)."""
        self.entries = self._entries(source)
        if not self.entries:
            why = (
                f" (left out: {', '.join(f'{k}: {v}' for k, v in self.skipped.items())})"
                if self.skipped
                else ""
            )
            raise ValueError(
                f"source {os.fspath(source) if _is_path(source) else source!r}: no video found{why}"
            )

    # ---------------------------------------------------------------------------------------- sources
    def _entries(self, source: PathLike | Sequence[PathLike]) -> list[_Entry]:
        if not _is_path(source):
            if isinstance(source, Sequence) and all(_is_path(p) for p in source):
                return [_Entry(Path(p)) for p in source]
            raise TypeError(
                "source must be a folder, a glob pattern, a manifest .csv or a sequence of paths, "
                f"got {type(source).__name__}"
            )
        path = Path(source)
        if path.is_dir():
            return self._folder(path)
        if path.is_file() and path.suffix.lower() == ".csv" and _manifest_header(path) is not None:
            return _manifest(path)
        if path.exists():
            return [_Entry(path)]
        if _GLOB & set(os.fspath(source)):
            return [_Entry(Path(p)) for p in sorted(glob.glob(os.fspath(source), recursive=True))]
        raise ValueError(f"source {os.fspath(source)}: no such file or folder")

    def _folder(self, folder: Path) -> list[_Entry]:
        entries = []
        for child in sorted(folder.iterdir()):
            name = child.name
            if name.startswith("."):
                continue
            if child.is_dir():
                if _has_frame_files(child):
                    entries.append(_Entry(child))
                else:
                    self.skipped[name] = f"a folder without frame files ({', '.join(FOLDER_REGISTRY)})"
            elif not any(name.lower().endswith(suffix) for suffix in REGISTRY):
                self.skipped[name] = "not a video format"
            elif name.lower().endswith(".csv") and _manifest_header(child) is not None:
                self.skipped[name] = "a manifest (pass it as the source)"
            elif name.lower().endswith(".csv") and not is_flir_csv(child):
                self.skipped[name] = "a CSV without 'Frame N,' blocks (not a FLIR export)"
            else:
                entries.append(_Entry(child))
        return entries

    # ------------------------------------------------------------------------------------------ items
    def __len__(self) -> int:
        return len(self.entries)

    @property
    def sources(self) -> tuple[Path, ...]:
        """The path of every video, in item order."""
        return tuple(entry.path for entry in self.entries)

    def __getitem__(self, index: int) -> Video | SkippedVideo:
        """Read video ``index`` in the calling worker, its labels, then ``transform``.

        An item that cannot be read is skipped or raises, by ``on_error``.

        Shape:
            ``frames`` ``(T, H, W)``; labels as stored.

        Raises:
            IndexError: ``index`` out of range.
            ValueError: with ``on_error="raise"``, every error of
                :func:`~anra_torch.recording.open_recording`, such as an unreadable file or no frame period
                and no ``dt``; a label missing from an ``.npz`` file; a transform's.
        """
        if not -len(self) <= index < len(self):
            raise IndexError(f"index must be in [{-len(self)}, {len(self) - 1}], got {index}")
        entry = self.entries[index]
        try:
            video = self._read(entry)
            labels = {**entry.labels, **read_labels(entry.path, self.labels)}
            labels = {k: _label_value(v, entry.path) for k, v in labels.items()}
            video = replace(video, meta={**video.meta, "labels": labels})
            return self.transform(video) if self.transform is not None else video
        except (ValueError, OSError) as err:  # this file's fault; a bug elsewhere still raises
            if self.on_error == "raise":
                raise
            reason = one_line(err)
            reason = reason if str(entry.path) in reason else f"{entry.path}: {reason}"
            self.failed[str(entry.path)] = reason
            warnings.warn(f"skipped, cannot be read: {reason}", RuntimeWarning, stacklevel=2)
            return SkippedVideo(entry.path, reason)

    def _read(self, entry: _Entry) -> Video:
        """The recording with the manifest's spacing (overriding) or else the dataset's (where the file
        records none)."""

        def read(dt: float | None) -> Video:
            return open_recording(
                entry.path,
                dt=dt,
                dx=entry.dx,
                calibration=self.calibration,
                need_dx=False,
                need_time=False,
                on_disk_above=self.on_disk_above,
            )

        try:
            video = read(entry.dt)
        except ValueError as err:
            if entry.dt is not None or self.dt is None or "no frame period" not in str(err):
                raise
            video = read(self.dt)
            video = replace(video, meta={**video.meta, "dt_source": "dataset"})
        if video.dx is None and self.dx is not None:
            video = replace(video, dx=float(self.dx), meta={**video.meta, "dx_source": "dataset"})
        return video

    def collate(self, videos: Sequence[Video | SkippedVideo]) -> VideoBatch:
        """:func:`anra_torch.data.collate` with this dataset's ``collate_mode``, as a ``collate_fn``.

        Skipped items are left out and listed in ``batch.skipped``.

        Shape:
            ``B`` videos ``(T_i, H_i, W_i)`` -> frames ``(B, T, H, W)``.
        """
        return collate(videos, mode=self.collate_mode)

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({len(self)} videos, dt={self.dt}, dx={self.dx}, labels={self.labels}, "
            f"collate_mode={self.collate_mode!r}, on_error={self.on_error!r})"
        )


# ------------------------------------------------------------------------------------------ helpers
def _is_path(value: object) -> bool:
    return isinstance(value, str | os.PathLike)


def _has_frame_files(folder: Path) -> bool:
    return any(
        child.is_file() and child.name.lower().endswith(suffix)
        for child in folder.iterdir()
        for suffix in FOLDER_REGISTRY
    )


def _manifest_header(path: Path) -> list[str] | None:
    """The manifest's column names when ``path`` is a manifest (a ``path`` column), else None."""
    try:
        with open(path, encoding="utf-8-sig", newline="") as handle:
            first = handle.readline()
    except (OSError, UnicodeDecodeError):
        return None
    columns = [c.strip().lower() for c in next(csv.reader([first]), [])]
    return columns if "path" in columns else None


def _manifest(path: Path) -> list[_Entry]:
    """The rows of a manifest: paths relative to its folder, spacing that overrides the file's, labels."""
    with open(path, encoding="utf-8-sig", newline="") as handle:
        rows = list(csv.DictReader(handle))
    entries = []
    for number, row in enumerate(rows, start=2):
        cells = {k.strip(): (v or "").strip() for k, v in row.items() if k is not None}
        named = {k.lower(): k for k in cells}
        cell = cells.pop(named["path"])
        if not cell:
            raise ValueError(f"{path}: line {number}: empty path")
        spacing = {}
        for name, unit in zip(MANIFEST_SPACING, ("s", "mm"), strict=True):
            text = cells.pop(named[name]) if name in named else ""
            spacing[name] = _manifest_number(text, path, number, name, unit) if text else None
        labels = {k: _manifest_label(v, path.parent) for k, v in cells.items() if k}
        target = Path(cell) if Path(cell).is_absolute() else path.parent / cell
        entries.append(_Entry(target, spacing["dt"], spacing["dx"], labels))
    return entries


def _manifest_number(text: str, path: Path, line: int, name: str, unit: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < float("inf"):
        raise ValueError(f"{path}: line {line}: {name} must be a positive number in {unit}, got {text!r}")
    return value


def _manifest_label(text: str, folder: Path) -> Any:
    """A manifest cell as a label: None (empty), a float, a ``.npy`` path to read later, or the text."""
    if not text:
        return None
    try:
        return float(text)
    except ValueError:
        pass
    if text.lower().endswith(".npy") and (folder / text).is_file():
        return folder / text
    return text


def _label_value(value: Any, source: Path) -> Any:
    """A label as an item carries it: a ``.npy`` path read into a tensor, arrays as tensors."""
    if isinstance(value, Path):
        try:
            with open(value, "rb") as handle:
                value = np.load(handle, allow_pickle=False)
        except (OSError, ValueError) as err:
            raise ValueError(f"{source}: label file {value} cannot be read as .npy ({err})") from err
    if isinstance(value, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(value)) if value.ndim else value.item()
    return value


def read_labels(path: PathLike, names: Sequence[str]) -> dict[str, Any]:
    """The entries ``names`` of an ``.npz`` file as labels; ``{name: None}`` for a file of another format.

    Returns:
        name -> the array as read, or a scalar as a Python number or text.

    Shape:
        Each label as stored, e.g. a per-pixel map ``(H, W)``.

    Raises:
        ValueError: an ``.npz`` that cannot be read, or lacks one of ``names``.
    """
    path = Path(path)
    if not names:
        return {}
    if not (path.is_file() and path.name.lower().endswith(".npz")):
        return dict.fromkeys(names)
    try:
        with open(path, "rb") as handle, np.load(handle, allow_pickle=False) as archive:
            missing = [n for n in names if n not in archive.files]
            if missing:
                raise ValueError(
                    f"{path}: no label {missing[0]!r} in the file; it holds {', '.join(archive.files)}"
                )
            arrays = {n: archive[n] for n in names}
    except (OSError, EOFError) as err:
        raise ValueError(f"{path}: cannot read labels ({err})") from err
    return {n: a.item() if a.ndim == 0 else a for n, a in arrays.items()}
