"""``anra diagnose``: which effects beyond heat diffusion act in a video, and do they forecast it better.

``anra diagnose --json`` prints one object: ``base`` (plain diffusivity, forecast RMSE), ``effects`` (name,
params, gain each), ``extended`` (equation, params, forecast RMSE), ``gain``, ``noise_floor``, ``scale_px``,
``time_window``, ``assimilated``, ``gain_above_floor``, ``raw``, ``negligible`` (effects significant but
below their physical size, with that size), ``noise`` (the measured noise model) and ``artefacts`` (the
camera artefacts found and masked); ``source_map`` with ``--source-map``;
``input`` when the video was prepared by --resample, --roi or --calibration, or diagnosed on a block-averaged
copy (``input.decimated``, above 2^22 pixel values unless --full-resolution); ``warnings``, a list of lines,
empty when all is well: input samples masked, the final model's diffusivity negative or outside every known
material, "the model does not explain the data" when its forecast RMSE stays above 3 noise floors (with the
ratio), a number not finite and reported as null; ``phase`` (the described phase's kind) and ``phases``
(every phase's record); ``defect_map`` with ``--maps FILE`` (a flash recording's plate time, lateral
diffusivities and defects; the maps themselves go to FILE, an ``.npz``). Every key with its unit:
docs/reference/outputs.md. On failure: ``{"path", "error"}``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from anra_torch.checks import atomic_output, check_output, one_line
from anra_torch.cli.arguments import (
    add_device_argument,
    add_video_arguments,
    clean_json,
    format_list,
    integer,
    json_line,
    number,
    object_parameters,
    open_input,
    print_input,
)
from anra_torch.flash import FlashMaps, flash_maps
from anra_torch.recording import diagnose_video, flash_hints, open_for_diagnosis
from anra_torch.report import write_diagnosis_report, write_flash_report, write_phase_report
from anra_torch.video import Video

__all__ = ["MAP_VALUES", "add_parser", "run"]

MAP_VALUES = 2**25
"""``--maps`` reads a recording of up to this many pixel values whole; a larger one is mapped on the
diagnosis' block-averaged copy."""


_DESCRIPTION = (
    "Diagnose which effects beyond heat diffusion (linear_loss, source, advection, "
    "anisotropy, heterogeneity, nonlinear_diffusion) act in the first part of a video, then forecast "
    "the rest with the plain heat equation and with the extended model (RK4, bounded by the measured "
    "frame edges), each "
    "from its own state assimilated from the fit frames, and compare their RMSE on the interior at "
    "the evaluation scale (forecasts and held-out frames smoothed alike by the diagnosis' Gaussian "
    "and a 9-frame moving average in time). gain = 1 - RMSE_extended / "
    "RMSE_plain; the noise floor is a perfect model's RMSE at that scale; 'raw' holds the same against "
    "unsmoothed frames. Exit status 2 on bad input."
)
"""``anra diagnose --help``'s description."""


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``diagnose`` to the ``anra`` subcommands (``commands``: what ``add_subparsers`` returned)."""
    parser = commands.add_parser(
        "diagnose",
        help="find hidden effects and test whether they forecast held-out frames better",
        description=_DESCRIPTION,
    )
    add_video_arguments(parser, format_list())
    add_device_argument(parser)
    parser.add_argument(
        "--fit-fraction",
        type=number("fraction of the frames", positive=True),
        default=0.6,
        metavar="F",
        help="fraction of the frames diagnosed, in (0, 1); the rest is forecast (default 0.6)",
    )
    parser.add_argument(
        "--assimilate",
        type=integer("frames", minimum=1),
        default=None,
        metavar="N",
        help="fit frames (the last N) assimilated into each model's starting state; 1 starts from the "
        "measured split frame (default: all the fit frames)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object: base, effects (with per-effect gain), extended, gain, noise_floor "
        "(an object with 'error' on failure)",
    )
    parser.add_argument(
        "--report",
        metavar="DIR",
        help="write to DIR phases.md (the phases' timeline, forecasts and residual maps) and report.md (the "
        "longest phase in detail: forecasts, residual, RMSE)",
    )
    parser.add_argument(
        "--full-resolution",
        action="store_true",
        help="diagnose every pixel and frame of a recording above 2^22 pixel values instead of a copy "
        "averaged over blocks of pixels and frames (needs about 260 bytes of memory per pixel value)",
    )
    parser.add_argument(
        "--source-map",
        action="store_true",
        help="also fit a stationary source map dT/dt = a Lap T - b T + q(x, y) on the same frames (a "
        "measured beam that is not a Gaussian spot) and report its forecast RMSE and gain ('source_map')",
    )
    _add_flash_arguments(parser)
    parser.set_defaults(run=run)


def _add_flash_arguments(parser: argparse.ArgumentParser) -> None:
    """``--maps`` and ``--layered``: a flash recording's defect map and its plate's layered forecast."""
    parser.add_argument(
        "--maps",
        metavar="FILE",
        help="a flash recording: also map per pixel the through-thickness time constant of the cooling "
        "(lateral conduction taken off) and the defects it shows, and write to FILE (.npz) defect_score, "
        "defect_mask, depth_fraction, depth_time and the contrasts tsr_d2, pct, ppt; the JSON gets "
        "'defect_map' (the plate's L^2/a_z, the defects), the report flash.md; the diagnosis looks for a "
        "delamination at the map's defects only (a second, delamination_2, at another of them)",
    )
    parser.add_argument(
        "--layered",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="with --maps: forecast the plate on layers through its thickness (the diffusion into depth and "
        "each delamination's face resolved), the default with --maps; --no-layered: by its surface alone "
        "(the balance's depth rates), as before; both measured on docs/results/flash.md",
    )


def _print_decimated(d: dict[str, Any]) -> None:
    frames, rows, cols = d["shape"]
    region = f" of the region x0, y0, width, height = {d['region']} px" if d["region"] else ""
    print(
        f"  diagnosed on a copy averaged over {d['space_px']} x {d['space_px']} px and {d['time_frames']} "
        f"frames{region} ({frames} frames of {rows} x {cols} px; spikes repaired first: "
        f"{d['repaired_spikes']}, dead or hot elements: {d['repaired_elements']}); phase frames count the "
        "recording's frames"
    )


def _write_reports(folder: Any, recording: Video, done: Any, maps: Any) -> list[Path]:
    """The phase report, the longest phase's diagnosis report (when the balance analysed it) and the
    defect map's report (with ``--maps``), written to ``folder``."""
    written = [write_phase_report(folder, recording, done.phases)]
    if done.result is not None:
        result = done.result
        written.append(
            write_diagnosis_report(folder, done.video, result.diagnosis, result, source_map=done.source_map)
        )
    if maps is not None:
        written.append(write_flash_report(folder, maps, recording.dx))
    return written


def _check_options(args: argparse.Namespace) -> None:
    """The options that need no video: the fit fraction, the outputs, ``--layered`` with ``--maps``."""
    if not 0 < args.fit_fraction < 1:
        raise ValueError(f"--fit-fraction must be in (0, 1), got {args.fit_fraction:g}")
    if args.report is not None:
        check_output(args.report, [args.video], name="--report", folder=True)
    if args.maps is not None:
        check_output(args.maps, [args.video], name="--maps")
    elif args.layered is not None:
        flag = "--layered" if args.layered else "--no-layered"
        raise ValueError(f"{flag} needs --maps FILE (the flash map's plate), got no --maps")


def run(args: argparse.Namespace) -> int:
    """Run ``anra diagnose`` with the parsed ``args``; returns the exit status (0 ok, 2 error)."""
    try:
        _check_options(args)
        recording, decimated = open_for_diagnosis(
            args.video,
            dt=args.dt,
            dx=args.dx,
            roi=args.roi,
            calibration=args.calibration,
            full_resolution=args.full_resolution,
            **object_parameters(args),
        )
        if args.device.type != "cpu":  # the diagnosis computes where its frames are
            recording = recording.loaded().map_frames(lambda f: torch.as_tensor(f).to(args.device))
        maps = None if args.maps is None else _flash_maps(args, recording, decimated is not None)
        done = diagnose_video(
            recording,
            fit_fraction=args.fit_fraction,
            assimilate=args.assimilate,
            source_map=args.source_map,
            decimated=decimated,
            hints=None if maps is None else flash_hints(maps.defects, layered=args.layered is not False),
        )
        summary = done.to_record()
    except (ValueError, TypeError, OSError) as err:
        if args.json:  # batch users keep a row
            print(json.dumps({"path": str(args.video), "error": one_line(err)}))
        raise
    video, result = done.video, done.result
    if maps is not None:
        summary["defect_map"] = maps.record()
        with atomic_output(args.maps) as temp, open(temp, "wb") as handle:
            np.savez_compressed(handle, **maps.arrays())
    if args.json:
        print(json_line(summary))
    else:
        print(f"{video.source}")
        print_input(video)
        if decimated is not None:
            _print_decimated(decimated)
        shown = clean_json(summary)
        _print_phases(shown)
        if result is not None:
            _print_balance(video, shown, result)
        if maps is not None:
            _print_maps(shown["defect_map"], args.maps)
        for line in shown["warnings"]:
            print(f"  warning: {line}")
    if args.report is not None:
        written = _write_reports(args.report, recording, done, maps)
        if not args.json:
            print(f"  report: {', '.join(str(p) for p in written)}")
    return 0


def _flash_maps(args: argparse.Namespace, recording: Video, decimated: bool) -> FlashMaps:
    """The flash maps of the recording read whole (up to :data:`MAP_VALUES`), else of the diagnosed copy."""
    source = recording
    if decimated:
        whole = open_input(args, on_disk_above=MAP_VALUES)
        source = recording if whole.on_disk else whole
    frames = torch.as_tensor(source.frames).to(args.device)
    return flash_maps(frames, source.dt, source.dx)


def _print_maps(record: dict[str, Any], path: str) -> None:
    """The defect map's summary: the plate's time constant and each defect."""
    se = record["plate_time_std_error"]
    reached = "" if record["back_wall_reached"] else " (back wall not reached: a lower bound)"
    print(
        f"  defect map ({path}): plate L^2/a_z = {_n(record['plate_time'])} +- {_n(se, '.2g')} s{reached}; "
        f"{len(record['defects'])} defect(s)"
    )
    for d in record["defects"]:
        edge = ", runs out of the frame" if d["touches_edge"] else ""
        print(
            f"    at ({d['x']:.2f}, {d['y']:.2f}) mm, {d['area']:.3g} mm^2, depth fraction "
            f"{d['depth_fraction']:.2f}{edge}"
        )


def _n(value: float | None, spec: str = ".4g") -> str:
    """A number for the human summary, "n/a" for a non-finite one (null in the JSON)."""
    return "n/a" if value is None else format(value, spec)


def _print_phases(summary: dict[str, Any]) -> None:
    """One line per phase: its kind and frames, the diffusivity, the chosen extension and its gain."""
    for p in summary["phases"]:
        frames = f"frames {p['start_frame']}-{p['stop_frame'] - 1}"
        where = f"  {p['kind']} ({frames}, t {p['t_start']:.4g}-{p['t_stop']:.4g} s)"
        if not p["analysed"]:
            print(f"{where}: not analysed: {p['reason']}")
            continue
        base = p["base"]
        if base["diffusivity"] is None and "diffusivity_lower_bound" in base:
            bound = base["diffusivity_lower_bound"]
            a = f"a unresolved (conduction faster than a frame: a > {bound:.3g} mm^2/s)"
        else:
            flag = f" [{', '.join(base['flags'])}]" if base.get("flags") else ""
            se = f" +- {base['std_error']:.2g}" if base.get("std_error") is not None else ""
            a = f"a = {_n(base['diffusivity'])}{se} mm^2/s{flag}"
        names = ", ".join(e["name"] for e in p["effects"]) or "none"
        print(
            f"{where}: {a}; causes: {names}; extended model {p['model']}, gain {_n(p['gain'], '.3f')} "
            f"(noise floor {_n(p['noise_floor'], '.3g')})"
        )


def _print_balance(video: Video, summary: dict[str, Any], result: Any) -> None:
    """The human summary of a phase analysed through the balance (plain and extended forecasts)."""
    base, ext = summary["base"], summary["extended"]
    print(f"  details of the longest phase ({summary['phase']}):")
    print(
        f"  plain heat equation: a = {_n(base['diffusivity'])} mm^2/s, forecast RMSE "
        f"{_n(base['prediction_rmse'])} (noise floor {_n(summary['noise_floor'])} {video.unit}, frames "
        f"smoothed by a {_n(summary['scale_px'], 'g')} px Gaussian and averaged over "
        f"{summary['time_window']} frames; forecasts from the state of the last {summary['assimilated']} "
        "fit frames)"
    )
    if summary["effects"]:
        found = ", ".join(f"{e['name']} (gain {_n(e['gain'], '.2f')})" for e in summary["effects"])
        print(f"  effects: {found}")
        print(f"  extended: {ext['equation']}")
        print(f"  extended forecast RMSE {_n(ext['prediction_rmse'])}, gain {_n(summary['gain'], '.3f')}")
    else:
        print("  no effect beyond heat diffusion found (gain 0)")
    if "source_map" in summary:
        sm = summary["source_map"]
        print(
            f"  source map: a = {_n(sm['a'])} mm^2/s, b = {_n(sm['b'])} 1/s, q {_n(sm['q_min'])} to "
            f"{_n(sm['q_max'])} {video.unit}/s; forecast RMSE {_n(sm['prediction_rmse'])}, "
            f"gain {_n(sm['gain'], '.3f')}"
        )
    print(
        f"  diagnosed frames 0-{result.split}, forecast {result.held_out} held-out frames "
        f"in {result.elapsed:.1f} s"
    )
