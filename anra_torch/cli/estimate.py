"""``anra estimate``: the diffusivity of one video.

``anra estimate --json`` prints one object on one line; its keys, units and meanings are in
``docs/reference/outputs.md`` ("anra estimate --json", checked against the command by
``tests/test_output_reference.py``). A video without measurable thermal activity still prints its flagged
object (``valid`` false) and exits with status 2.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from anra_torch.cli.arguments import (
    PROG,
    add_device_argument,
    add_video_arguments,
    clean_json,
    format_list,
    integer,
    json_line,
    open_input,
    print_input,
    relative,
)
from anra_torch.estimation import MODES, ANRAEstimator
from anra_torch.recording import estimate_recording, on_disk_above
from anra_torch.report import format_pm

__all__ = ["add_parser", "run"]


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
    add_device_argument(parser)
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


def run(args: argparse.Namespace) -> int:
    """Run ``anra estimate`` with the parsed ``args``; returns the exit status (0 ok, 2 error)."""
    est = ANRAEstimator(mode=args.mode, window=args.window, strict=False).to(args.device)  # the frames follow
    video = open_input(args, on_disk_above=on_disk_above(args.precision))
    done = estimate_recording(video, est, precision=args.precision, progress=sys.stderr.isatty())
    summary = done.to_record()
    if args.json:
        print(json_line(summary))
    summary = clean_json(summary)
    if not summary["valid"]:
        # No diffusivity: exit 2 in both modes; --json still printed its flagged record above.
        print(f"{PROG}: error: {video.source}: {summary['message']}", file=sys.stderr)
        return 2
    if not args.json:
        if done.result is not None:
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
