"""What the ``anra`` commands share: the parser class, flag types, the video flags and the input preparation.

Every command that reads a video adds its flags with :func:`add_video_arguments` (``batch``: the spacing and
region flags without VIDEO) and reads it with :func:`open_input`, i.e.
:func:`anra_torch.recording.open_recording`.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from typing import Any

import torch

from anra_torch.recording import open_recording
from anra_torch.video import REGISTRY, Video

PROG = "anra"


def format_list() -> str:
    """The video file suffixes ``anra`` reads, for help texts (``.npz, .npy, ...``)."""
    return ", ".join(REGISTRY)


def add_spacing_arguments(parser: argparse.ArgumentParser, source: str) -> None:
    """--dt, --dx and --resample, shared by every command that reads videos (``source``: "the file(s)")."""
    parser.add_argument(
        "--dt", type=number("s", positive=True), metavar="S", help=f"frame period in s (overrides {source})"
    )
    parser.add_argument(
        "--dx", type=number("mm", positive=True), metavar="MM", help=f"pixel size in mm (overrides {source})"
    )
    parser.add_argument(
        "--resample",
        action="store_true",
        help="kept for compatibility: non-uniform timestamps (e.g. FLIR EXIF times) are always interpolated "
        "onto a uniform step (resample.default_step), and the output states it",
    )


def add_video_arguments(parser: argparse.ArgumentParser, formats: str) -> None:
    """VIDEO, --dt, --dx, --resample, --roi and --calibration, shared by the commands that read a video."""
    parser.add_argument(
        "video",
        metavar="VIDEO",
        help=f"video file ({formats}) or a folder with one file per frame (FLIR .jpg, .csv/.txt matrices, "
        "timed by a times.txt, '# t = 5 s' lines or names such as frame_005s.txt); frames (T, H, W)",
    )
    add_spacing_arguments(parser, "the file")
    add_region_arguments(parser)
    add_object_arguments(parser)


OBJECT_FLAGS = {
    "emissivity": ("--emissivity", "E", "object emissivity in (0, 1]"),
    "reflected_temp": ("--reflected-temp", "DEGC", "reflected apparent temperature in degC"),
    "distance": ("--distance", "M", "object distance in m"),
    "atmospheric_temp": ("--atmospheric-temp", "DEGC", "atmospheric temperature in degC"),
    "humidity": ("--humidity", "PERCENT", "relative humidity in %%"),
}
"""The object parameters of a FLIR radiometric recording a user may set: keyword -> (flag, metavar, help)."""


def add_object_arguments(parser: argparse.ArgumentParser) -> None:
    """--emissivity, --reflected-temp, --distance, --atmospheric-temp, --humidity: the object parameters of a
    FLIR recording (.jpg, .fff, .seq, .csq) that replace those stored in the file."""
    for key, (flag, metavar, text) in OBJECT_FLAGS.items():
        parser.add_argument(
            flag,
            dest=key,
            type=float,
            metavar=metavar,
            help=f"{text} (FLIR .jpg, .fff, .seq, .csq: replaces the file's value; the output says which)",
        )


def object_parameters(args: argparse.Namespace) -> dict[str, float]:
    """The object parameters given on the command line, as keywords of
    :func:`~anra_torch.video.load_video` (none for a command without the flags)."""
    return {key: getattr(args, key) for key in OBJECT_FLAGS if getattr(args, key, None) is not None}


def add_device_argument(parser: argparse.ArgumentParser) -> None:
    """--device: where the command computes (the frames are moved there; the results do not depend on it
    beyond rounding)."""
    parser.add_argument(
        "--device",
        type=device,
        default=torch.device("cpu"),
        metavar="DEVICE",
        help="compute on this torch device: cpu (default), cuda, cuda:1, mps, where present",
    )


def add_region_arguments(parser: argparse.ArgumentParser) -> None:
    """--roi and --calibration: what :func:`prepare_video` does after loading."""
    parser.add_argument(
        "--roi",
        metavar="X0,Y0,W,H",
        help="analyse only this region (px: first column, first row, width, height)",
    )
    parser.add_argument(
        "--calibration",
        metavar="CSV",
        help="map apparent to true temperature with a table of 'true,apparent' rows "
        "(e.g. calibration_og.csv)",
    )


def open_input(
    args: argparse.Namespace,
    *,
    need_dx: bool = True,
    need_time: bool = True,
    on_disk_above: int | None = None,
) -> Video:
    """The recording of VIDEO with --dt, --dx, --roi and --calibration, as every command reads it
    (:func:`~anra_torch.recording.open_recording`: left on disk above ``on_disk_above`` pixel values, else
    prepared; ``meta`` says what was done). ``need_dx=False`` accepts a video without pixel size,
    ``need_time=False`` a single frame (with --dt)."""
    try:
        return open_recording(
            args.video,
            dt=args.dt,
            dx=args.dx,
            roi=args.roi,
            calibration=args.calibration,
            need_dx=need_dx,
            need_time=need_time,
            on_disk_above=on_disk_above,
            **object_parameters(args),
        )
    except ValueError as err:  # the library's hint names its argument; here the flag is the fix
        raise ValueError(
            str(err).replace("(timestamps='resample' or 'keep' in load_video)", "(--resample)")
        ) from None


def print_input(video: Video) -> None:
    """The human lines saying what :func:`open_input` did (resampling, region, calibration)."""
    if video.meta.get("timestamps"):
        print(f"  timestamps: read from the folder's {video.meta['timestamps']}")
    r = video.meta.get("resampled")
    if r:
        print(
            f"  resampled: {r['from_frames']} frames with non-uniform steps "
            f"{r['step_min']:.3g}-{r['step_max']:.3g} s "
            f"-> {video.frames.shape[0]} frames at dt = {r['dt']:.4g} s ({r['method']})"
        )
    if video.meta.get("roi"):
        print(f"  roi (x0, y0, width, height px): {video.meta['roi']}")
    given = {
        k: v for k, v in (video.meta.get("object_parameters") or {}).items() if v["source"] == "argument"
    }
    if given:
        shown = ", ".join(
            f"{k} {v['value']:g}{' ' + v['unit'] if v['unit'] else ''}" for k, v in given.items()
        )
        print(f"  object parameters set: {shown} (the others as stored in the file)")
    c = video.meta.get("calibration")
    if c:
        print(f"  calibrated with {c['table']} ({100 * c['outside_fraction']:.1f} % of values extrapolated)")


class UsageError(Exception):
    """A command-line mistake found by argparse (reported in one line, exit 2)."""


class Parser(argparse.ArgumentParser):
    """argparse that raises on a usage error instead of printing the usage block and exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(f"{message} (see '{self.prog} --help')")


# ----------------------------------------------------------------------------------- flag types
def device(text: str) -> torch.device:
    """A flag type: a torch device this machine has (``cpu``, ``cuda``, ``cuda:1``, ``mps``)."""
    try:
        chosen = torch.device(text)
    except (RuntimeError, ValueError) as err:
        raise argparse.ArgumentTypeError(f"must be a torch device such as cpu or cuda, got {text!r}") from err
    present = {
        "cpu": lambda: True,
        "cuda": lambda: torch.cuda.is_available() and (chosen.index or 0) < torch.cuda.device_count(),
        "mps": lambda: torch.backends.mps.is_available(),
    }.get(chosen.type, lambda: False)()
    if not present:
        raise argparse.ArgumentTypeError(f"{text!r} is not available on this machine; use --device cpu")
    return chosen


def number(unit: str, *, positive: bool, maximum: float = math.inf) -> Callable[[str], float]:
    """A flag type: a finite number in ``unit``, positive or non-negative, at most ``maximum``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or (value <= 0 if positive else value < 0) or value > maximum:
            need = "positive" if positive else "non-negative"
            most = f" up to {maximum:g}" if maximum < math.inf else ""
            raise argparse.ArgumentTypeError(f"must be a {need} number in {unit}{most}, got {text!r}")
        return value

    return parse


def integer(unit: str, *, minimum: int, odd: bool = False) -> Callable[[str], int]:
    """A flag type: an integer ``>= minimum`` (``unit`` for the message), odd when asked."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum or (odd and value % 2 == 0):
            kind = "an odd" if odd else "an"
            bound = f"{minimum} {unit}".strip()
            raise argparse.ArgumentTypeError(f"must be {kind} integer >= {bound}, got {text!r}")
        return value

    return parse


def relative(text: str) -> float:
    """``--precision``: a relative standard error as a percentage (``0.1%``) or a fraction (``0.001``), in
    (0, 1)."""
    value = text.strip()
    try:
        number = float(value[:-1]) / 100 if value.endswith("%") else float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be a relative standard error like 0.1% or 0.001, got {text!r}"
        ) from None
    if not 0 < number < 1:
        raise argparse.ArgumentTypeError(f"must be a relative standard error in (0, 100%), got {text!r}")
    return number


def clean_json(value: Any, nulled: list[str] | None = None, where: str = "") -> Any:
    """NaN and infinities -> None, recursively (JSON has no NaN); their keys (``a.b[2]``) go to ``nulled``."""
    if isinstance(value, dict):
        return {k: clean_json(v, nulled, f"{where}.{k}" if where else str(k)) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean_json(v, nulled, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, float) and not math.isfinite(value):
        if nulled is not None:
            nulled.append(where)
        return None
    return value


def json_line(record: dict[str, Any]) -> str:
    """``record`` as one line of strict JSON: a non-finite number becomes null and ``record["warnings"]``
    (created when missing) says which keys were nulled, so no NaN or inf ever reaches the output."""
    nulled: list[str] = []
    clean = clean_json(record, nulled)
    if nulled:
        shown = ", ".join(nulled[:8]) + (f" and {len(nulled) - 8} more" if len(nulled) > 8 else "")
        clean["warnings"] = [*clean.get("warnings", []), f"not finite, reported as null: {shown}"]
    return json.dumps(clean, allow_nan=False)
