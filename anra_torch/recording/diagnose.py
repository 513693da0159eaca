"""What happens to a recording that is diagnosed: its copy, its phases, the phase described, its record.

One policy for ``anra diagnose`` and ``anra batch --diagnose``:

1. **Reading** (:func:`open_for_diagnosis`): a recording above
   :data:`~anra_torch.recording.DIAGNOSE_VALUES` pixel values is diagnosed on a block-averaged copy
   of the region where the temperature changes, read chunk by chunk
   (:func:`~anra_torch.recording.camera_copy`), unless every value is asked for; then the memory
   the diagnosis needs is checked against what is available.
2. **Phases** (:func:`~anra_torch.recording.diagnose_recording`): each phase diagnosed on its
   own; the longest analysed one is described in detail.
3. **The record** (:meth:`RecordingDiagnosis.to_record`): the ``anra diagnose --json`` object, with the
   measured source map's forecast when asked (:func:`~anra_torch.forecast.source_map_gain`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from anra_torch.effects import equation_text
from anra_torch.forecast import GainResult, SourceMapGain, extended_effects, source_map_gain
from anra_torch.recording import decimate
from anra_torch.recording.decimate import camera_copy
from anra_torch.recording.phase_diagnosis import PhaseDiagnosis, diagnose_recording
from anra_torch.recording.read import input_record, open_recording
from anra_torch.video import ROI, CalibrationTable, PathLike, Video, input_warnings

__all__ = [
    "DIAGNOSE_BYTES_PER_VALUE",
    "RecordingDiagnosis",
    "check_memory",
    "diagnose_video",
    "diagnosis_copy",
    "open_for_diagnosis",
]

DIAGNOSE_BYTES_PER_VALUE = 260
"""Peak memory of ``anra diagnose`` per pixel value of the recording, bytes (measured: 81 frames of 128 and
192 px peaked at 675 and 1106 MB, a slope of 260 B per value over a base of about 330 MB)."""

_BASE_BYTES = 330 * 2**20


def _available_bytes() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in bytes (None where there is none)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def check_memory(video: Video, *, full_resolution: bool = False) -> None:
    """Refuse, in one line, a recording whose diagnosis would not fit in the memory available (the
    diagnosis holds the recording and its term bank at once; the estimate reads any length in chunks).

    Raises:
        ValueError: more memory needed than ``MemAvailable`` says, with the way out.
    """
    t, h, w = video.frames.shape
    need = _BASE_BYTES + DIAGNOSE_BYTES_PER_VALUE * t * h * w
    available = _available_bytes()
    if available is not None and need > available:
        raise ValueError(
            f"{video.source}: diagnosing {t} frames of {h} x {w} px needs about {need / 2**30:.1f} GB of "
            f"memory, {available / 2**30:.1f} GB are available; diagnose a region (--roi X0,Y0,W,H) or "
            f"fewer frames{', or without --full-resolution' if full_resolution else ''}"
        )


def open_for_diagnosis(
    path: PathLike,
    *,
    dt: float | None = None,
    dx: float | None = None,
    roi: ROI | str | None = None,
    calibration: CalibrationTable | PathLike | None = None,
    full_resolution: bool = False,
    **objects: float,
) -> tuple[Video, dict[str, Any] | None]:
    """The recording as it is diagnosed, and the record of its block-averaged copy (None when whole).

    Above :data:`DIAGNOSE_VALUES` pixel values (unless ``full_resolution``) the recording is replaced by
    :func:`~anra_torch.recording.camera_copy` (a large ``.npy`` / uncompressed ``.npz`` is read chunk
    by chunk, never whole); then :func:`check_memory`.

    Args:
        path, dt, dx, roi, calibration, objects: as :func:`~anra_torch.recording.open_recording`.
        full_resolution: diagnose every pixel value, never a block-averaged copy.

    Shape:
        ``frames`` ``(T, H, W)`` (the copy's when decimated).

    Raises:
        ValueError: an unreadable recording, or one whose diagnosis would not fit in memory.
    """
    on_disk_above = None if full_resolution else decimate.DIAGNOSE_VALUES
    recording = open_recording(
        path, dt=dt, dx=dx, roi=roi, calibration=calibration, on_disk_above=on_disk_above
    )
    copy, decimated = diagnosis_copy(recording, full_resolution=full_resolution)
    check_memory(copy, full_resolution=full_resolution)
    return copy, decimated


def diagnosis_copy(recording: Video, *, full_resolution: bool = False) -> tuple[Video, dict[str, Any] | None]:
    """The recording as it is diagnosed: above :data:`~anra_torch.recording.DIAGNOSE_VALUES` pixel
    values (unless ``full_resolution``) its block-averaged copy
    (:func:`~anra_torch.recording.camera_copy`) with that copy's record, else itself and None.

    Shape:
        ``frames`` ``(T, H, W)`` -> the copy's ``(T', H', W')``.
    """
    if full_resolution:
        return recording, None
    return camera_copy(recording, decimate.DIAGNOSE_VALUES)


@dataclass
class RecordingDiagnosis:
    """A recording diagnosed phase by phase, and the phase described in detail.

    Attributes:
        recording: the recording as diagnosed (the block-averaged copy when ``decimated``).
        video: the described phase's frames.
        phases: every phase's :class:`~anra_torch.recording.PhaseDiagnosis`.
        main: the described phase (the longest analysed one).
        decimated: the copy's record (:func:`~anra_torch.recording.decimated_video`), or None.
        source_map: the measured source map's forecast of the described phase, when asked.
    """

    recording: Video
    video: Video
    phases: list[PhaseDiagnosis]
    main: PhaseDiagnosis
    decimated: dict[str, Any] | None = None
    source_map: SourceMapGain | None = None

    @property
    def result(self) -> GainResult | None:
        """The described phase's balance :class:`~anra_torch.forecast.GainResult` (None for a small box)."""
        return self.main.result

    def to_record(self) -> dict[str, Any]:
        """The ``anra diagnose --json`` object (see :mod:`anra_torch.cli.diagnose`)."""
        record = self._balance_record() if self.result is not None else self._small_box_record()
        record.update(phase=self.main.phase.name, phases=[p.to_record() for p in self.phases])
        if any(input_record(self.video).values()):
            record["input"] = input_record(self.video)
        if self.decimated is not None:
            for phase in record["phases"]:  # counted in the recording's frames (the copy's are blocks)
                phase["start_frame"] *= self.decimated["time_frames"]
                phase["stop_frame"] *= self.decimated["time_frames"]
            record.setdefault("input", {})["decimated"] = self.decimated
        return record

    def _small_box_record(self) -> dict[str, Any]:
        """The top-level keys for a phase analysed by the small-box models (no balance filters fit)."""
        main = self.main.to_record()
        return {
            "base": main["base"],
            "effects": main["effects"],
            "extended": {
                "model": self.main.model,
                "params": main["effects"][0]["params"],
                "prediction_rmse": self.main.extended_rmse,
            },
            "gain": self.main.gain,
            "noise_floor": self.main.noise_floor,
            "warnings": input_warnings(self.video),
        }

    def _balance_record(self) -> dict[str, Any]:
        result = self.result
        assert result is not None
        diagnosis = result.diagnosis
        diagnosed = extended_effects(diagnosis)  # timed from the first frame (result.effects: from the split)
        params: dict[str, Any] = {"a": diagnosis.base}
        params.update({e.name: dict(e.params) for e in diagnosed})
        record: dict[str, Any] = {
            "base": {"diffusivity": diagnosis.a_plain, "prediction_rmse": result.base_rmse},
            "effects": [
                {
                    "name": effect["name"],
                    "params": dict(effect["params"]),
                    "share": effect.get("share"),
                    "forecast_cost": effect.get("forecast_cost"),
                    "gain": gain,
                }
                for effect, gain in zip(diagnosis.effects, result.effect_gains, strict=True)
            ],
            "extended": {
                "equation": equation_text(diagnosis.base, diagnosed),
                "params": params,
                "prediction_rmse": result.extended_rmse,
            },
            "gain": result.gain,
            "noise_floor": result.noise_floor,
            "scale_px": result.scale_px,
            "time_window": result.time_window,
            "assimilated": result.assimilated,
            "gain_above_floor": result.gain_above_floor,
            "raw": {
                "base_rmse": result.base_rmse_raw,
                "extended_rmse": result.extended_rmse_raw,
                "gain": result.gain_raw,
                "noise_floor": result.noise_floor_raw,
            },
            "negligible": diagnosis.negligible,
        }
        if diagnosis.noise is not None:
            record["noise"] = diagnosis.noise.describe()
        if diagnosis.artefacts is not None:
            record["artefacts"] = diagnosis.artefacts.to_record()
        if self.source_map is not None:
            mapped = self.source_map
            record["source_map"] = {
                "equation": "dT/dt = a Lap T - b T + q(x, y)",
                "a": mapped.model.a,
                "b": mapped.model.b,
                "q_max": float(mapped.model.forcing.max()),
                "q_min": float(mapped.model.forcing.min()),
                "prediction_rmse": mapped.rmse,
                "gain": mapped.gain,
            }
        lines = input_warnings(self.video) + list(result.warnings) + list(self.main.warnings)
        record["warnings"] = list(dict.fromkeys(lines))  # the phase repeats some of the result's lines
        return record


def diagnose_video(
    video: Video,
    *,
    fit_fraction: float = 0.6,
    assimilate: int | None = None,
    source_map: bool = False,
    decimated: dict[str, Any] | None = None,
    hints: dict[str, Any] | None = None,
) -> RecordingDiagnosis:
    """Diagnose a recording phase by phase, as ``anra diagnose`` does, and describe its longest analysed
    phase.

    Args:
        video: the recording in memory (or its block-averaged copy, :func:`open_for_diagnosis`).
        fit_fraction: each phase's fraction diagnosed, in (0, 1); the rest is forecast.
        assimilate: fit frames assimilated into each model's starting state (default: all).
        source_map: also fit the measured source map on the described phase and forecast with it.
        decimated: the copy's record when ``video`` is a block-averaged copy.
        hints: every phase diagnosis' candidate shapes (:func:`~anra_torch.recording.flash_hints`).

    Returns:
        :class:`RecordingDiagnosis`.

    Shape:
        ``video.frames`` ``(T, H, W)``.

    Raises:
        ValueError: one line naming the file: a fit fraction outside (0, 1), no phase that could be analysed
            (with every phase's reason), a source map that cannot be fitted.
    """
    if not 0 < fit_fraction < 1:
        raise ValueError(f"--fit-fraction must be in (0, 1), got {fit_fraction:g}")
    try:
        phases = diagnose_recording(
            video.frames, video.dt, video.dx, video.t, fit_fraction=fit_fraction, assimilate=assimilate,
            measured_t=video.meta.get("measured_t"), hints=hints,
        )  # fmt: skip
    except (ValueError, TypeError) as err:
        raise ValueError(f"{video.source}: {err}") from err
    analysed = [p for p in phases if p.reason is None]
    if not analysed and len(phases) == 1:  # one phase: its own reason is the error
        raise ValueError(f"{video.source}: {phases[0].reason}")
    if not analysed:
        reasons = "; ".join(
            f"{p.phase.name} (frames {p.phase.start}-{p.phase.stop - 1}): {p.reason}" for p in phases
        )
        raise ValueError(f"{video.source}: no phase could be analysed: {reasons}")
    main = max(analysed, key=lambda p: p.phase.frames)
    part = video.span(main.phase.start, main.phase.stop)
    mapped = None
    if source_map and main.result is not None:
        try:
            mapped = source_map_gain(part.frames, part.dt, part.dx, main.result)
        except ValueError as err:
            raise ValueError(f"{video.source}: --source-map: {err}") from err
    return RecordingDiagnosis(video, part, phases, main, decimated, mapped)
