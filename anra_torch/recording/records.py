"""A recording's estimate as records: each phase's, the recording's (``anra estimate --json``) and its
``anra batch`` row.

:meth:`RecordingEstimate.to_record` is the ``anra estimate --json`` object; :meth:`RecordingEstimate.row`
the ``anra batch`` row (their keys: ``docs/reference/outputs.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from anra_torch.balance import PreparedBatch
from anra_torch.checks import depth_bias, join_messages
from anra_torch.estimation import ANRAEstimator, ANRAResult
from anra_torch.recording.read import input_record
from anra_torch.video import Phase, Video, input_warnings

__all__ = ["PHASE_KEYS", "PhaseEstimate", "RecordingEstimate", "phase_head", "shape_record"]

PHASE_KEYS = ("diffusivity", "std_error", "valid", "message", "warnings")
"""What each entry of ``phases`` takes from its estimate (a valid one's flags are in ``warnings``)."""


def phase_head(phase: Phase) -> dict[str, Any]:
    """The keys that place a phase in its recording: ``kind``, ``start_frame``, ``stop_frame``, and
    ``t_start`` and ``t_stop`` in s."""
    return {
        "kind": phase.name,
        "start_frame": phase.start,
        "stop_frame": phase.stop,
        "t_start": phase.t_start,
        "t_stop": phase.t_stop,
    }


def shape_record(shape: tuple[int, ...], spacing: Video) -> dict[str, Any]:
    """``frames``, ``height``, ``width`` of frames of ``shape`` ``(T, H, W)`` and the ``dt`` in s, ``dx`` in
    mm of ``spacing``."""
    t, h, w = shape
    return {"frames": t, "height": h, "width": w, "dt": spacing.dt, "dx": spacing.dx}


@dataclass
class PhaseEstimate:
    """One phase of a recording, its route and its estimate.

    Attributes:
        phase: the :class:`~anra_torch.video.Phase` (kind, frames, times).
        part: the phase's frames as a :class:`~anra_torch.video.Video` (unread when on disk).
        route: ``"too_short"``, ``"small_box"``, ``"chunked"`` or ``"whole"``.
        result: the estimator's (batched) result for ``"chunked"`` and ``"whole"``.
        index: this phase's video in ``result``.
        small_box: the small-box record (``diffusivity``, ``std_error``, ``valid``, ``message``, ...).
        chunked: ``chunk_frames``, ``frames_used`` and ``pilot`` of a chunked estimate.
        depth_aware: the depth-aware record (or ``{"error": ...}``) where it was fitted.
        seconds: wall time of this phase's estimate (its share of a batched call), s.
        prepared: the phase's frames as the estimator prepares them, measured once with the phases
            (a recording of one phase read whole), or None.
    """

    phase: Phase
    part: Video
    route: str
    result: ANRAResult | None = None
    index: int = 0
    small_box: dict[str, Any] | None = None
    chunked: dict[str, Any] | None = None
    depth_aware: dict[str, Any] | None = None
    seconds: float = 0.0
    prepared: PreparedBatch | None = field(default=None, repr=False)

    def estimate_record(self) -> dict[str, Any]:
        """The estimate's own record: :meth:`ANRAResult.to_record` or the small-box record."""
        if self.result is not None:
            return self.result.to_record(self.index, unit=self.part.unit)
        return dict(self.small_box or {})

    @property
    def valid(self) -> bool:
        return self.route != "too_short" and bool(self.estimate_record()["valid"])

    def to_record(self) -> dict[str, Any]:
        """The phase as an element of ``anra estimate --json``'s ``phases``."""
        head = phase_head(self.phase)
        if self.route == "too_short":
            return {**head, "diffusivity": None, "valid": False, "message": "too short", "warnings": []}
        if self.result is None:
            return {"warnings": [], **head, **self.estimate_record()}
        record = self.estimate_record()
        own = {key: record[key] for key in PHASE_KEYS}
        own["warnings"] = own["warnings"] + depth_bias(own["diffusivity"], self.depth_aware)
        return {"warnings": [], **head, **own, "depth_aware": self.depth_aware}


@dataclass
class RecordingEstimate:
    """A recording's estimate: every phase's, and the phase that describes the recording.

    Attributes:
        video: the recording.
        phases: every phase's :class:`PhaseEstimate`, in time order (one ``"recording"`` phase for a
            recording of one phase).
        described: the phase the recording's diffusivity is measured on (see the module text).
        several: whether the recording has more than one phase.
        estimator: the estimator's settings (``mode``, ``window``) for the record.
        elapsed: wall time of the whole estimate (phases, every phase's estimate, depth), s.
    """

    video: Video
    phases: list[PhaseEstimate]
    described: PhaseEstimate
    several: bool
    estimator: ANRAEstimator = field(repr=False)
    elapsed: float = 0.0

    @property
    def result(self) -> ANRAResult | None:
        """The described phase's estimator result (None for a small box)."""
        return self.described.result

    def to_record(self) -> dict[str, Any]:
        """The ``anra estimate --json`` object (see :mod:`anra_torch.cli.estimate`)."""
        d = self.described
        record = _summary(d, self.estimator, self.elapsed) if d.result is not None else _small_summary(d)
        phases = [p.to_record() for p in self.phases] if self.several else [_one_phase(d, record)]
        described = next((r for p, r in zip(self.phases, phases, strict=True) if p is d), None)
        depth = (described or {}).get("depth_aware") if self.several else d.depth_aware
        record["depth_aware"] = depth
        record["warnings"] += depth_bias(record["diffusivity"], depth)
        record["chunked"] = d.chunked
        record["phase"] = d.phase.name
        record["phases"] = phases
        if any(input_record(self.video).values()):
            record["input"] = input_record(self.video)
        return record

    def row(self) -> dict[str, Any]:
        """The ``anra batch`` row (without its resume columns; see :mod:`anra_torch.batch`)."""
        d = self.described
        record = d.estimate_record()
        warnings = [*input_warnings(self.video), *(record.get("warnings") or [])]
        warnings += depth_bias(record["diffusivity"], d.depth_aware)
        ok = bool(record["valid"])
        columns = _ROW_COLUMNS if d.result is not None else ("diffusivity", "std_error")
        roi, calibration = self.video.meta.get("roi"), self.video.meta.get("calibration")
        return {
            "path": str(self.video.source),
            "status": "ok" if ok else "error",
            "error": "" if ok else f"{self.video.source}: {record['message']}",
            **{key: record.get(key) for key in columns},
            **shape_record(d.part.frames.shape, self.video),
            "a_true": self.video.truth.a if self.video.truth is not None else None,
            "seconds": d.seconds,
            "roi": ",".join(str(v) for v in roi) if roi else None,
            "calibration": calibration["table"] if calibration else None,
            "message": join_messages([*warnings, record.get("message")]),
            "frames_used": None if d.chunked is None else d.chunked["frames_used"],
            "phase": d.phase.name if self.several else None,
        }


_ROW_COLUMNS = (
    "diffusivity",
    "std_error",
    "smoothing_px",
    "noise_sd",
    "reliability",
    "n_masked",
    "explained",
)
"""The batch columns taken as they are from :meth:`~anra_torch.estimation.ANRAResult.to_record`."""


def _summary(d: PhaseEstimate, est: ANRAEstimator, elapsed: float) -> dict[str, Any]:
    """The ``estimate --json`` keys of an estimator result: its record with the phase's shape and spacing,
    the estimator's settings and timing."""
    part, result = d.part, d.result
    assert result is not None
    record = result.to_record(d.index, unit=part.unit)
    units = record["units"]
    summary: dict[str, Any] = {
        "path": str(part.source),
        **{key: record[key] for key in ("diffusivity", "std_error", "valid", "message")},
        "warnings": input_warnings(part) + record["warnings"],
        **shape_record(part.frames.shape, part),
        "mode": est.mode,
        **{key: record[key] for key in ("smoothing_px", "noise_sd", "reliability", "explained", "n_masked")},
        **{key: record[key] for key in ("noise", "artefacts")},
        "window_px": est.window,
        "field_median": None,
        "field_coverage": None,
        "a_true": part.truth.a if part.truth is not None else None,
        "elapsed_s": round(elapsed, 3),
        "units": {
            **{key: units[key] for key in ("diffusivity", "std_error")},
            "dt": "s",
            "dx": "mm",
            **{key: units[key] for key in ("smoothing_px", "noise_sd")},
            "elapsed_s": "s",
        },
    }
    if result.field is not None:
        field = result.field[d.index] if result.field.ndim == 3 else result.field
        finite = field[field.isfinite()]
        summary["field_coverage"] = float(finite.numel() / field.numel())
        if finite.numel():
            summary["field_median"] = float(finite.median())
    return summary


def _small_summary(d: PhaseEstimate) -> dict[str, Any]:
    """The ``estimate --json`` keys of a small-box estimate."""
    small = dict(d.small_box or {})
    flagged = [small["message"]] if not small["valid"] else []
    summary = {"path": str(d.part.source), **small, "warnings": input_warnings(d.part) + flagged}
    summary.update(shape_record(d.part.frames.shape, d.part))
    return summary


def _one_phase(d: PhaseEstimate, summary: dict[str, Any]) -> dict[str, Any]:
    """The ``phases`` element of a recording of one phase: the summary's own keys."""
    head = phase_head(d.phase)
    own = {key: summary.get(key) for key in PHASE_KEYS}
    own["warnings"] = list(own["warnings"] or []) + depth_bias(summary.get("diffusivity"), d.depth_aware)
    return {**head, **own, "depth_aware": d.depth_aware}
