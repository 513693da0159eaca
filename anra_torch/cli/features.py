"""``anra features``: per-pixel tissue features of one video (thermal dose, peak, rates, ANRA maps)."""

from __future__ import annotations

import argparse
from typing import Any

import torch

from anra_torch.balance import PreparedBatch, prepare_batch
from anra_torch.checks import check_output
from anra_torch.cli.arguments import (
    add_device_argument,
    add_video_arguments,
    format_list,
    json_line,
    number,
    open_input,
    print_input,
)
from anra_torch.recording import input_record, phase_diffusivities
from anra_torch.report import write_depth_report
from anra_torch.tissue import RULES, feature_summary, save_feature_maps
from anra_torch.video import Video

__all__ = ["MAX_THICKNESS", "add_parser", "run"]

TIME_FILTER_FRAMES = 5
"""Frames of the ANRA estimator's time filter (its default, as ``anra features`` and the phases use it):
fewer, and nothing is measured ahead (the estimator says why it cannot run)."""

MAX_THICKNESS = 1000.0
"""Thickest ``--thickness`` in mm: a layer of a metre is beyond any tissue and any recording's reach (heat
spreads ``sqrt(a t)``, 22 mm in an hour at 0.14 mm^2/s), and the solver's grid grows with its logarithm."""


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``features`` to the ``anra`` subcommands (``commands``: what ``add_subparsers`` returned)."""
    parser = commands.add_parser(
        "features",
        help="tissue features of a video: thermal dose (CEM43, Omega), peak, rates, ANRA maps",
        description="Per-pixel tissue features of one video: peak temperature, time above 43/50/60 C, "
        "CEM43 (min), Arrhenius Omega (skin constants), heating and cooling rates (K/s), RTC attention, "
        "local diffusivity (mm^2/s) and its confidence, loss rate (1/s) and source (K) maps. "
        "Temperatures are reported in Celsius. Non-finite values are masked and counted. The dose, peak "
        "and times above work on any frame size, down to one pixel, and need no --dx; the rate and ANRA "
        "maps need --dx (or the file's) and frames the filters fit (20 x 20 px, 5 frames), else they are "
        "absent with the reason ('absent' in the JSON). A recording with a heating and a cooling reports "
        "the source-free phase's global diffusivity, as anra estimate does, and lists its phases.",
    )
    add_video_arguments(parser, format_list())
    add_device_argument(parser)
    parser.add_argument(
        "--units", choices=("C", "K"), default="C", help="temperature unit of the frames (default C)"
    )
    parser.add_argument(
        "--rule",
        choices=RULES,
        default="linear",
        help="dose integration: linear (default; the frames joined by straight lines over the recorded span "
        "(T - 1) dt) or hold (each frame held for dt, T dt: the Sapareto-Dewey sum)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object: cem43_minutes_max, omega_max, peak_temperature_max, ... with units",
    )
    parser.add_argument("--out", metavar="MAPS.npz", help="save the maps (one (H, W) array each) to MAPS.npz")
    parser.add_argument(
        "--depth",
        action="store_true",
        help="also map the damage in depth under each pixel (needs --dx and a recorded cooling): a and b "
        "fitted on the cooling, the bioheat equation solved under the frame with the frames as its surface "
        "(surface heating); adds damage_depth_mm, damage_depth_std_mm, cem43_depth_mm(_std_mm) and the depth "
        "profiles to --out, and the assumptions to the JSON ('depth')",
    )
    parser.add_argument(
        "--thickness",
        type=number("mm", positive=True, maximum=MAX_THICKNESS),
        metavar="MM",
        help=f"with --depth: a layer this thick over tissue at body temperature, in (0, {MAX_THICKNESS:g}] "
        "mm (default a half-space; a thicker layer is one: leave the flag out)",
    )
    parser.add_argument(
        "--report",
        metavar="DIR",
        help="with --depth: write DIR/depth.md with the depth map and depth profiles",
    )
    parser.set_defaults(run=run)


def _print_summary(video: Video, record: dict[str, Any], depth: bool, depth_absent: str) -> None:
    """The text ``anra features`` prints without ``--json``: the record's headline values, with units."""
    print(f"{video.source}: {record['frames']} frames of {record['height']} x {record['width']} px")
    print_input(video)
    for key in (
        "peak_temperature_max",
        "cem43_minutes_max",
        "omega_max",
        "damaged_fraction",
        "diffusivity_global",
        *(("damage_depth_mm_max",) if depth else ()),
    ):
        value = record.get(key)
        shown = "n/a" if value is None else f"{value:.4g} {record['units'][key]}"
        if value is None and key == "damage_depth_mm_max" and depth_absent:
            shown += f" ({depth_absent})"
        of_phase = key == "diffusivity_global" and record["diffusivity_phase"]
        print(f"  {key}: {shown}" + (f" (the {record['diffusivity_phase']} phase's)" if of_phase else ""))
    if record["message"]:
        print(f"  note: {record['message']}")
    if record["out"]:
        print(f"  maps: {record['out']}")
    if record.get("report"):
        print(f"  report: {record['report']}")


def _measured(frames: torch.Tensor) -> PreparedBatch | None:
    """The frames' artefacts and noise measured once (:func:`~anra_torch.balance.prepare_batch`), for the
    ANRA maps and the phases' search and estimates alike; None where the estimator would not take them (it
    then says why itself)."""
    if frames.ndim != 3 or frames.dtype not in (torch.float32, torch.float64):
        return None  # half precision and integers: the estimator converts them itself
    if frames.shape[0] < TIME_FILTER_FRAMES:
        return None
    try:
        return prepare_batch(frames[None])
    except ValueError:
        return None


def run(args: argparse.Namespace) -> int:
    """Run ``anra features`` with the parsed ``args``; returns the exit status (0 ok, 2 error)."""
    if args.report is not None and not args.depth:
        raise ValueError("--report draws the depth maps: pass --depth with it")
    if args.thickness is not None and not args.depth:
        raise ValueError("--thickness is the depth model's layer: pass --depth with it")
    if args.out is not None:
        maps_path = args.out if str(args.out).endswith(".npz") else f"{args.out}.npz"
        check_output(args.out, [args.video], name="--out")
        check_output(maps_path, [args.video], name="--out")
    if args.report is not None:
        check_output(args.report, [args.video], name="--report", folder=True)
    video = open_input(args, need_dx=False, need_time=False)
    options = {"depth": True, "thickness": args.thickness} if args.depth else {}
    try:
        frames = torch.as_tensor(video.frames).to(args.device)  # the features compute where the frames are
        measured = _measured(frames) if video.dx is not None else None
        record, maps = feature_summary(
            frames, video.dt, video.dx, units=args.units, rule=args.rule, measured=measured, **options
        )
    except (ValueError, TypeError) as err:
        raise ValueError(f"{video.source}: {err}") from err
    depth_absent = record["absent"].get("damage_depth_mm") or ""
    if args.thickness is not None and depth_absent.startswith("thickness "):  # the flag's fault: say so
        raise ValueError(f"{video.source}: --{depth_absent}")
    record = {"path": str(video.source), **record, "out": None, "phases": [], "diffusivity_phase": None}
    if video.dx is not None and record.get("diffusivity_global") is not None:
        # A recording with a heating and a cooling: its diffusivity is the source-free phase's, as in estimate
        # (the dose and the maps stay the whole recording's).
        phases, described = phase_diffusivities(video, measured=measured)
        if phases:
            record["phases"] = phases
            record["diffusivity_phase"] = None if described is None else described["kind"]
            record["diffusivity_global"] = None if described is None else described["diffusivity"]
    if any(input_record(video).values()):
        record["input"] = input_record(video)
    if args.out is not None:
        record["out"] = save_feature_maps(args.out, maps, dt=video.dt, dx=video.dx)
    if args.report is not None and maps.depth is not None:
        record["report"] = str(
            write_depth_report(args.report, str(video.source), maps.depth, float(video.dx))
        )
    if args.json:
        print(json_line(record))
        return 0
    _print_summary(video, record, args.depth, depth_absent)
    return 0
