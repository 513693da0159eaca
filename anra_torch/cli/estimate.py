"""``anra estimate``: the diffusivity of one video.

``anra estimate --json`` prints one object on one line:

- ``path``; ``diffusivity`` and ``std_error`` (mm^2/s, null when no estimate); ``valid`` (bool) and
  ``message`` (the reason when not valid, else "");
- ``warnings``: a list of lines, empty when all is well: input samples masked (non-finite or beyond
  +-1e6), a significantly negative diffusivity, one outside every known material (about 1e-3 to 2e3
  mm^2/s, with the likely unit mix-up of dt or dx), a plain heat equation that explains under 90 % of
  dT/dt (a poor fit: see ``explained``), a number not finite and reported as null;
- ``frames``, ``height``, ``width`` (px); ``dt`` (s); ``dx`` (mm); ``mode``;
- ``smoothing_px`` (the Gaussian sigma chosen from the data); ``noise_sd`` (data units); ``reliability``
  (signal fraction of the regressor energy, 1 is noiseless); ``explained`` (the share of dT/dt, above its
  noise, that ``a Lap T`` explains: 1 for pure heat transfer; null in ratio mode, absent for a small box);
  ``n_masked`` (non-finite pixel values);
- ``window_px``, ``field_median`` (mm^2/s), ``field_coverage`` (pixel fraction) with ``--window``, else null;
- ``a_true`` (mm^2/s) when the file records the truth, else null; ``elapsed_s``; ``units`` (key -> unit);
- ``input`` (``resampled``, ``roi``, ``calibration``) when the video was prepared by those flags;
- ``chunked`` when the recording was read in time chunks (more than
  :data:`~anra_torch.chunked.CHUNKED_VALUES` pixel values,
  or ``--precision``; :func:`anra_torch.chunked.estimate_chunked`): ``chunk_frames``, ``frames_used`` (fewer
  than ``frames`` when ``--precision`` was reached early), ``pilot`` (``[start, stop)`` frames of the blocks
  that chose the smoothing and measured the noise), else null. A ``.npy`` file or an uncompressed ``.npz``
  is then read chunk by chunk, never whole.

A video without measurable thermal activity still prints its flagged object with ``--json`` (``valid``
false) and exits with status 2.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from typing import Any

from anra_torch.chunked import CHUNKED_VALUES, estimate_chunked
from anra_torch.cli.arguments import (
    PROG,
    add_video_arguments,
    clean_json,
    format_list,
    input_record,
    integer,
    json_line,
    load_input,
    object_parameters,
    print_input,
    relative,
)
from anra_torch.estimator import MODES, ANRAEstimator, ANRAResult
from anra_torch.flags import POOR_FIT, depth_bias
from anra_torch.forecast.recording import find_phases
from anra_torch.report import format_pm
from anra_torch.selection.depth_aware import depth_aware_diffusivity
from anra_torch.video import MIN_PHASE_FRAMES, Phase, Video, input_warnings
from anra_torch.video.lazy import frame_span, in_memory, lazy_video
from anra_torch.video.phases import SOURCE_FREE, phase_preference

__all__ = ["add_parser", "phase_diffusivities", "run"]


_PHASE_KEYS = ("diffusivity", "std_error", "valid", "message", "warnings")
"""What each entry of ``phases`` takes from its estimate (a valid one's flags are in ``warnings``)."""


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``estimate`` to the ``anra`` subcommands (``commands``: what ``add_subparsers`` returned)."""
    formats = format_list()
    parser = commands.add_parser(
        "estimate",
        help="estimate the diffusivity (mm^2/s) of a video file",
        description=f"Estimate the diffusivity a (mm^2/s) of one video ({formats}). The spatial smoothing is "
        "chosen from the data; exit status 2 when no diffusivity can be estimated.",
    )
    add_video_arguments(parser, formats)
    parser.add_argument(
        "--mode",
        choices=MODES,
        default="lsq",
        help="lsq: weighted least squares with errors-in-variables correction (default); "
        "ratio: the paper's attention-weighted average of dT/dt / Laplacian",
    )
    parser.add_argument(
        "--window",
        type=integer("px", minimum=1, odd=True),
        metavar="PX",
        help="also estimate a windowed field a(x, y) in mm^2/s over PX x PX pixel windows (odd)",
    )
    parser.add_argument(
        "--precision",
        type=relative,
        metavar="PCT",
        help="read the recording in chunks and stop once the diffusivity's relative standard error reaches "
        "PCT (e.g. 0.1%%); the output says how many frames were used (the recording is taken as one phase)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (diffusivity and std_error in mm^2/s, dt in s, dx in mm, ...)",
    )
    parser.set_defaults(run=run)


def _summary(video: Video, result: ANRAResult, est: ANRAEstimator, elapsed: float) -> dict[str, Any]:
    """The ``estimate --json`` object (also the source of the human summary): the result's
    :meth:`~ANRAResult.to_record` with the video's shape and spacing, the estimator's settings and timing."""
    t, h, w = video.frames.shape
    record = result.to_record(unit=video.unit)
    units = record["units"]
    summary: dict[str, Any] = {
        "path": str(video.source),
        **{key: record[key] for key in ("diffusivity", "std_error", "valid", "message")},
        "warnings": input_warnings(video) + record["warnings"],
        "frames": t,
        "height": h,
        "width": w,
        "dt": video.dt,
        "dx": video.dx,
        "mode": est.mode,
        **{key: record[key] for key in ("smoothing_px", "noise_sd", "reliability", "explained", "n_masked")},
        **{key: record[key] for key in ("noise", "artefacts")},
        "window_px": est.window,
        "field_median": None,
        "field_coverage": None,
        "a_true": video.truth.a if video.truth is not None else None,
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
        finite = result.field[result.field.isfinite()]
        summary["field_coverage"] = float(finite.numel() / result.field.numel())
        if finite.numel():
            summary["field_median"] = float(finite.median())
    return summary


def _shown(value: float | None, spec: str = ".4g") -> str:
    """A number for the human summary, "n/a" when not finite (JSON null)."""
    return "n/a" if value is None or not math.isfinite(value) else format(value, spec)


def _print_summary(s: dict[str, Any]) -> None:
    a = s["diffusivity"]
    print(f"{s['path']}")
    print(f"  diffusivity a = {format_pm(a, s['std_error'], 'mm^2/s')} ({s['mode']}, ± 1 standard error)")
    print(
        f"  video: {s['frames']} frames of {s['height']} x {s['width']} px, "
        f"dt = {s['dt']:.6g} s ({1 / s['dt']:.4g} Hz), dx = {s['dx']:.6g} mm"
    )
    print(
        f"  smoothing {s['smoothing_px']:g} px (chosen from the data), noise sd {_shown(s['noise_sd'])} "
        f"{s['units']['noise_sd']}, reliability {_shown(s['reliability'], '.3f')}"
    )
    if s.get("explained") is not None:
        print(f"  the plain heat equation explains {100 * s['explained']:.1f} % of dT/dt (above its noise)")
    if s.get("depth_aware"):
        print(f"  {_depth_aware_line(s['depth_aware'])}")
    if s["n_masked"]:
        print(f"  masked {s['n_masked']} non-finite pixel values")
    if s.get("chunked"):
        c = s["chunked"]
        print(
            f"  read in chunks of {c['chunk_frames']} frames: {c['frames_used']} of {s['frames']} frames used"
        )
    for line in s["warnings"]:
        print(f"  warning: {line}")
    if s["window_px"] is not None:
        median = f"median {s['field_median']:.4g} mm^2/s" if s["field_median"] is not None else "no estimate"
        print(
            f"  field ({s['window_px']} px windows): {median} on {100 * s['field_coverage']:.1f} % of pixels"
        )
    if s["a_true"] is not None:
        truth = float(s["a_true"])
        error = f" (error {100 * (a - truth) / truth:+.3g} %)" if truth else ""
        print(f"  file's a_true = {truth:g} mm^2/s{error}")
    print(f"  took {s['elapsed_s']:.2f} s")


def _depth_aware_line(d: dict[str, Any]) -> str:
    """The human line of a :func:`_depth_aware` record."""
    if "error" in d:
        return f"depth-aware fit not made: {d['error']}"
    values = d["by_smoothing"]
    scales = f"{min(values, key=float)}-{max(values, key=float)} px"
    a = format_pm(d["diffusivity"], d["std_error"], "mm^2/s")
    if d["consistent"]:
        return f"depth-aware a = {a} (a loss rate free in each frame: heat into depth or the air; {scales})"
    if len(values) == 1:
        only = f"{d['smoothing_px']:g} px"
        return f"depth-aware a = {a} (a loss rate free in each frame), at {only} only: not checked"
    low, high = min(values.values()), max(values.values())
    return (
        f"depth-aware a = {a} (a loss rate free in each frame), but {low:.3g}-{high:.3g} mm^2/s over "
        f"{scales}: no lateral diffusivity describes these frames"
    )


def _depth_aware(
    part: Video, result: ANRAResult | None, kind: str, reading: _Reading, *, heated: bool = False
) -> dict[str, Any] | None:
    """For a source-free run (read whole, not in chunks) that follows a heating (``heated``: the source laid
    heat down that now flows into depth) or whose plain heat equation explains less than
    :data:`~anra_torch.flags.POOR_FIT` of dT/dt: the :func:`depth_aware_diffusivity` record, or
    ``{"error": ...}`` when it cannot be fitted; None otherwise."""
    if result is None or reading.chunked or kind not in SOURCE_FREE:
        return None
    explained = result.to_record(unit=part.unit)["explained"]
    if not heated and (explained is None or not explained < POOR_FIT):
        return None
    try:
        return depth_aware_diffusivity(in_memory(part.frames), part.dt, part.dx).to_record()
    except ValueError as err:
        return {"error": str(err)}


def _small_box_record(video: Video) -> dict[str, Any]:
    """A region too small for the filters: :func:`~anra_torch.forecast.small_box.small_box_estimate`."""
    from anra_torch.forecast.small_box import small_box_estimate

    return small_box_estimate(video.frames, video.dt, video.dx)


class _Reading:
    """How ``anra estimate`` reads a recording: whole, or in time chunks (with a precision target)."""

    def __init__(self, video: Video, est: ANRAEstimator, precision: float | None) -> None:
        values = math.prod(video.frames.shape)
        self.chunked = precision is not None or values > CHUNKED_VALUES
        if self.chunked and (est.mode != "lsq" or est.window is not None):
            if precision is not None:
                raise ValueError(
                    "--precision reads the recording in chunks: it needs --mode lsq without --window"
                )
            self.chunked = False
        self.precision = precision
        self.details: dict[str, Any] | None = None

    def estimate(self, video: Video, est: ANRAEstimator) -> ANRAResult:
        if not self.chunked:
            return est(in_memory(video.frames), video.dt, video.dx)
        done = estimate_chunked(
            video.frames,
            video.dt,
            video.dx,
            estimator=est,
            precision=self.precision,
            progress=sys.stderr.isatty(),
        )
        self.details = {
            "chunk_frames": done.chunk_frames,
            "frames_used": done.frames_used,
            "pilot": [list(block) for block in done.pilot],
        }
        return done.result


def _estimate(
    video: Video, est: ANRAEstimator, reading: _Reading
) -> tuple[dict[str, Any], ANRAResult | None]:
    """The estimate of one run of frames: ANRA where its filters fit, else the small-box record."""
    t, h, w = video.frames.shape
    if min(h, w) < est.minimum_frame_size and t >= est.time.length:  # too few frames: the estimator says so
        try:
            return _small_box_record(replace(video, frames=in_memory(video.frames))), None
        except ValueError as small:
            raise ValueError(f"{video.source}: {small}") from small
    try:
        return {}, reading.estimate(video, est)
    except ValueError as err:
        raise ValueError(f"{video.source}: {err}") from err


def _phases(
    video: Video, est: ANRAEstimator, phases: list[Phase], reading: _Reading
) -> tuple[list[dict[str, Any]], Phase | None, tuple[dict[str, Any], ANRAResult | None] | None]:
    """Every phase's estimate; the phase the top level describes (the longest valid source-free one:
    cooling, then baseline or steady; else the longest) and its :func:`_estimate`; None and None when every
    phase is too short (the top level then describes the whole recording)."""
    records, chosen = [], None
    for phase in phases:
        head = {"kind": phase.name, "start_frame": phase.start, "stop_frame": phase.stop}
        head.update(t_start=phase.t_start, t_stop=phase.t_stop)
        if phase.frames < MIN_PHASE_FRAMES:
            records.append(
                {**head, "diffusivity": None, "valid": False, "message": "too short", "warnings": []}
            )
            continue
        part = _part(video, phase)
        record, result = _estimate(part, est, reading)
        if result is not None:
            record = {k: result.to_record(unit=video.unit)[k] for k in _PHASE_KEYS}
            heated = any(r["kind"] == "heating" for r in records)
            record["depth_aware"] = _depth_aware(part, result, phase.name, reading, heated=heated)
            record["warnings"] += depth_bias(record["diffusivity"], record["depth_aware"])
        records.append({"warnings": [], **head, **record})
        source_free, *rest = phase_preference(phase)
        rank = (source_free and bool(record["valid"]), *rest)
        if chosen is None or rank > chosen[0]:
            chosen = (rank, phase, (record if result is None else {}, result))
    return records, *((chosen[1], chosen[2]) if chosen else (None, None))


def _described(records: list[dict[str, Any]], phase: Phase | None) -> dict[str, Any] | None:
    """The record of ``phase`` among ``records`` (None when every phase was too short)."""
    return next((r for r in records if phase is not None and r["start_frame"] == phase.start), None)


def phase_diffusivities(video: Video) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """The phases of a recording held in memory, each with its estimate as ``anra estimate`` gives it
    (``kind``, frames, times, ``diffusivity``, ...), and the record of the phase its top level would
    describe (the longest valid source-free one); ``([], None)`` for a recording of one phase."""
    est = ANRAEstimator(strict=False)
    phases = find_phases(video.frames, video.t, dt=video.dt, measured_t=video.meta.get("measured_t"))
    if len(phases) < 2:
        return [], None
    records, phase, _ = _phases(video, est, phases, _Reading(video, est, None))
    return records, _described(records, phase)


def _part(video: Video, phase: Phase) -> Video:
    span = slice(phase.start, phase.stop)
    frames = frame_span(video.frames, phase.start, phase.stop)
    return replace(video, frames=frames, t=None if video.t is None else video.t[span])


def _open(args: argparse.Namespace) -> Video:
    """The recording: a large ``.npy`` / uncompressed ``.npz`` / FLIR sequence left on disk to be read in
    chunks, else
    loaded and prepared (:func:`~anra_torch.cli.arguments.load_input`)."""
    if args.roi is None and args.calibration is None:
        lazy = lazy_video(args.video, dt=args.dt, dx=args.dx, **object_parameters(args))
        if lazy is not None and (args.precision is not None or math.prod(lazy.frames.shape) > CHUNKED_VALUES):
            return lazy
    return load_input(args)


def run(args: argparse.Namespace) -> int:
    """Run ``anra estimate`` with the parsed ``args``; returns the exit status (0 ok, 2 error)."""
    est = ANRAEstimator(mode=args.mode, window=args.window, strict=False)
    video = _open(args)
    start = time.perf_counter()
    reading = _Reading(video, est, args.precision)
    # With --precision the recording is one phase: finding phases would read all of it.
    phases = (
        find_phases(video.frames, video.t, dt=video.dt, measured_t=video.meta.get("measured_t"))
        if args.precision is None
        else []
    )
    phases = phases or [
        Phase("recording", 0, video.frames.shape[0], 0.0, video.dt * (video.frames.shape[0] - 1))
    ]
    records, phase, estimated = (
        _phases(video, est, phases, reading) if len(phases) > 1 else ([], phases[0], None)
    )
    part = video if phase is None or len(phases) == 1 else _part(video, phase)  # None: every phase too short
    small, result = estimated if estimated is not None else _estimate(part, est, reading)
    if result is None:
        flagged = [small["message"]] if not small["valid"] else []
        summary = {"path": str(video.source), **small, "warnings": input_warnings(video) + flagged}
        summary["frames"] = part.frames.shape[0]
        summary.update(height=part.frames.shape[1], width=part.frames.shape[2], dt=video.dt, dx=video.dx)
    else:
        summary = _summary(part, result, est, time.perf_counter() - start)
    if not records:  # one phase
        head = {"kind": phase.name, "start_frame": phase.start, "stop_frame": phase.stop}
        head.update(t_start=phase.t_start, t_stop=phase.t_stop)
        summary["depth_aware"] = _depth_aware(part, result, phase.name, reading)
        summary["warnings"] += depth_bias(summary["diffusivity"], summary["depth_aware"])
        records = [{**head, **{k: summary.get(k) for k in (*_PHASE_KEYS, "depth_aware")}}]
    else:  # the described phase's (none when every phase is too short)
        summary["depth_aware"] = (_described(records, phase) or {}).get("depth_aware")
        summary["warnings"] += depth_bias(summary["diffusivity"], summary["depth_aware"])
    summary["chunked"] = reading.details
    summary["phase"] = phase.name if phase is not None else "recording"
    summary["phases"] = records
    if any(input_record(video).values()):
        summary["input"] = input_record(video)
    if args.json:
        print(json_line(summary))
    summary = clean_json(summary)
    if not summary["valid"]:
        # No diffusivity: exit 2 in both modes; --json still printed its flagged record above.
        print(f"{PROG}: error: {video.source}: {summary['message']}", file=sys.stderr)
        return 2
    if not args.json:
        if result is not None:
            _print_summary(summary)
        else:
            print(summary["path"])
            print(f"  diffusivity a = {summary['diffusivity']:.4g} mm^2/s ({summary['message']})")
        _print_phases(summary)
        print_input(video)
    return 0


def _print_phases(summary: dict[str, Any]) -> None:
    """The phases and their diffusivities, when the recording has more than one."""
    if len(summary["phases"]) < 2:
        return
    print(f"  the diffusivity above is the {summary['phase']} phase's; every phase:")
    for p in summary["phases"]:
        a = "none" if p["diffusivity"] is None else f"{p['diffusivity']:.4g} mm^2/s"
        note = f" ({p['message']})" if p.get("message") else ""
        print(f"    {p['kind']} (frames {p['start_frame']}-{p['stop_frame'] - 1}): a = {a}{note}")
