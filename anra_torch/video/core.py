"""The video types: :class:`Video` (frames with their spacing), its optional :class:`Truth`, and the
:class:`RawVideo` a format loader returns before :func:`anra_torch.video.load_video` checks it.

This module imports nothing else of :mod:`anra_torch.video`, so every format, step and writer can import it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

__all__ = ["PathLike", "RawVideo", "SingleFrameError", "Truth", "Video", "positive_spacing", "stack_frames"]

PathLike = str | os.PathLike[str]
UNIFORM_RTOL = 1e-3  # steps within 0.1 % of their mean count as uniform


class SingleFrameError(ValueError):
    """A recording of one frame where a time axis was needed (a frame period to read, frames to differentiate
    in time): :func:`anra_torch.recording.open_recording` words it for what the caller wanted."""


TRUTH_KEYS = ("a_true", "effects", "noise_sd", "seed")
"""The ``.npz`` keys a simulation stores its truth under (``anra simulate``, ``to_npz``)."""


@dataclass(frozen=True)
class Truth:
    """What a simulated video was made with, when its file records it (``anra simulate`` writes it).

    Attributes:
        a: the true diffusivity in mm^2/s (key ``a_true``), or None.
        effects: the hidden effects as records ``{"name", "params", "units"}`` (key ``effects``, a JSON
            list; parse them into :class:`anra_torch.effects.Effect` with ``Effect.from_dict``), or None.
        noise_sd: the standard deviation of the added noise in the data's unit, or None.
        seed: the random seed of the simulation, or None.
        clean: the noise-free frames in the data's unit, when known in memory (files do not store them).

    Shape:
        ``clean`` ``(T, H, W)``, like :attr:`Video.frames`.
    """

    a: float | None = None
    effects: tuple[dict[str, Any], ...] | None = None
    noise_sd: float | None = None
    seed: int | None = None
    clean: Tensor | None = None

    @classmethod
    def from_arrays(cls, arrays: dict[str, Any], source: object) -> Truth | None:
        """The truth stored under :data:`TRUTH_KEYS` in ``arrays`` (values as loaded), None without any.

        Raises:
            ValueError: an ``effects`` entry that is not a JSON list of effect records.
        """
        if not any(key in arrays for key in TRUTH_KEYS):
            return None
        effects = None
        if "effects" in arrays:
            text = str(np.asarray(arrays["effects"]).reshape(-1)[0])
            try:
                records = json.loads(text)
            except json.JSONDecodeError:
                records = None
            if not isinstance(records, list) or not all(isinstance(r, dict) and "name" in r for r in records):
                raise ValueError(
                    f"{source}: effects must be a JSON list of effect records "
                    f"({{name, params, units}}), got {text[:60]!r}"
                )
            effects = tuple(records)

        def scalar(key: str, kind: type) -> Any:
            return kind(np.asarray(arrays[key]).reshape(-1)[0]) if key in arrays else None

        return cls(
            a=scalar("a_true", float),
            effects=effects,
            noise_sd=scalar("noise_sd", float),
            seed=scalar("seed", int),
        )

    def with_clean(self, change: Callable[[Tensor], Tensor]) -> Truth:
        """The truth with ``change`` applied to :attr:`clean` (a crop, a resampling...), when it has one."""
        return self if self.clean is None else replace(self, clean=change(self.clean))


@dataclass(frozen=True)
class Video:
    """A thermal video read from a file or folder, with its spacing.

    Attributes:
        frames: temperatures in any linear unit, as stored (integer raw counts are kept; the estimator
            converts them to floats).
        dt: frame period in s (for non-uniform timestamps kept as they are: their median step).
        dx: pixel size in mm, or None when neither the file nor the caller gave one.
        t: timestamps in s when the file has them, else None.
        source: the file or folder it was read from (None for a video built in memory).
        meta: extra facts from the file: ``"unit"`` (temperature unit) when known, scalars such as
            ``"a_true"``, ``"dt_source"`` / ``"dx_source"`` (``"file"``, ``"t"`` or ``"argument"``),
            ``"format"``, and what the preparation did (``"resampled"``, ``"roi"``, ``"calibration"``,
            ``"steps"``; see :func:`anra_torch.video.prepare_video`).
        truth: what a simulation made it with (:class:`Truth`), when the file records it; else None.

    Shape:
        ``frames`` ``(T, H, W)``; ``t`` ``(T,)``.
    """

    frames: Tensor
    dt: float
    dx: float | None
    t: Tensor | None = None
    source: Path | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    truth: Truth | None = None

    @property
    def unit(self) -> str:
        """Temperature unit for labels (``"data units"`` when the file does not say)."""
        return str(self.meta.get("unit") or "data units")

    @property
    def name(self) -> str:
        """Short name for messages: the file name, or ``"<memory>"``."""
        return self.source.name if self.source is not None else "<memory>"

    @property
    def uniform(self) -> bool:
        """Whether the frames are evenly spaced by ``dt`` (True without timestamps)."""
        if self.t is None or self.t.numel() < 3:
            return True
        steps = torch.diff(self.t.double())
        return bool((steps - steps.mean()).abs().max() <= UNIFORM_RTOL * steps.mean())

    @property
    def on_disk(self) -> bool:
        """Whether the frames are left on disk to be read in chunks (a frame source with a ``window``, such
        as :class:`~anra_torch.video.LazyFrames`), not held in memory."""
        return not isinstance(self.frames, Tensor) and hasattr(self.frames, "window")

    def span(self, start: int, stop: int) -> Video:
        """Frames ``start .. stop - 1`` with their timestamps; frames on disk stay unread.

        Shape:
            ``frames`` ``(T, H, W)`` -> ``(stop - start, H, W)``.
        """
        frames = self.frames.window(start, stop) if self.on_disk else self.frames[start:stop]
        return replace(self, frames=frames, t=None if self.t is None else self.t[start:stop])

    def loaded(self) -> Video:
        """The video with its frames in memory: frames on disk read whole, others as they are."""
        if not self.on_disk:
            return self
        return replace(self, frames=torch.as_tensor(self.frames[0 : len(self.frames)], device="cpu"))

    def map_frames(self, change: Callable[[Tensor], Tensor], **changes: Any) -> Video:
        """The video with ``change`` applied to its frames and to the truth's clean frames, and the other
        fields in ``changes`` replaced (a step such as a crop keeps the truth in step with the frames)."""
        truth = self.truth.with_clean(change) if self.truth is not None else None
        return replace(self, frames=change(self.frames), truth=truth, **changes)


@dataclass
class RawVideo:
    """What a loader found in a file, before overrides and checks.

    Attributes:
        frames: the stored array (any shape or dtype; :func:`anra_torch.video.load_video` checks it).
        dt: frame period in s, or None.
        dx: pixel size in mm, or None.
        t: timestamps in s, or None.
        meta: extra facts (see :attr:`Video.meta`).
        truth: the simulation's truth when the file records it (see :class:`Truth`).

    Shape:
        ``frames`` ``(T, H, W)`` once checked; ``t`` ``(T,)``.
    """

    frames: Any
    dt: Any = None
    dx: Any = None
    t: Any = None
    meta: dict[str, Any] = field(default_factory=dict)
    truth: Truth | None = None


Loader = Callable[[Path], RawVideo]
"""Reads one file (or folder) into a :class:`RawVideo`."""


def stack_frames(frames: list[np.ndarray], names: list[Path], folder: Path) -> np.ndarray:
    """Stack per-frame 2D arrays into one video; a frame of another size is a one-line error naming it.

    Shape:
        ``T`` arrays ``(H, W)`` -> ``(T, H, W)``.
    """
    first = frames[0].shape
    for array, name in zip(frames, names, strict=True):
        if array.ndim != 2:
            raise ValueError(f"{name}: a frame must be a 2D matrix, got shape {tuple(array.shape)}")
        if array.shape != first:
            raise ValueError(
                f"{folder}: mixed frame sizes: {name.name} is {array.shape[0]} x {array.shape[1]} px, "
                f"{names[0].name} is {first[0]} x {first[1]} px; one folder must hold one video"
            )
    return np.stack(frames)


def positive_spacing(value: object, path: Path, name: str, unit: str, origin: str) -> float:
    """A positive finite float from a scalar-like ``value`` (``origin``: ``"in the file"`` or
    ``"(argument)"``, for the message).

    Shape:
        A scalar or one-element array -> float.

    Raises:
        ValueError: not one positive finite number.
    """
    try:
        array = np.asarray(value, dtype=np.float64)
        number = float(array.reshape(-1)[0]) if array.size == 1 else None
    except (TypeError, ValueError):
        number = None
    if number is None or not np.isfinite(number) or number <= 0:
        shown = np.asarray(value).tolist() if isinstance(value, np.ndarray) else value
        raise ValueError(f"{path}: {name} {origin} must be a positive finite number in {unit}, got {shown!r}")
    return number
