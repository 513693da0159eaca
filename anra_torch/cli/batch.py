"""``anra batch``: estimate (and diagnose) many videos into one resumable CSV/Parquet table."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from anra_torch.batch import BatchOptions, run_batch, run_batch_dask
from anra_torch.cli.arguments import (
    PROG,
    add_device_argument,
    add_region_arguments,
    add_spacing_arguments,
    format_list,
    integer,
    relative,
)

__all__ = ["add_parser", "run"]


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``batch`` to the ``anra`` subcommands (``commands``: what ``add_subparsers`` returned)."""
    parser = commands.add_parser(
        "batch",
        help="estimate (and diagnose) many videos into one resumable CSV/Parquet table",
        description=f"Estimate the diffusivity of every video among INPUTS (files, folders, glob patterns; "
        f"{format_list()}) into one row each of OUT (.csv or .parquet). Same-shaped videos are estimated "
        "together; a bad file gets an error row and never stops the others; re-running skips inputs "
        "already ok with the same parameters and unchanged files (a changed file is recomputed; a row made "
        "with other parameters stops the run unless --rerun); OUT is replaced atomically after every "
        "batch. Warnings go to the 'message' column. Exit status 2 when an input failed (see its 'error' "
        "column).",
    )
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="video files, folders or glob patterns")
    parser.add_argument("--out", required=True, metavar="OUT", help="results table, .csv or .parquet")
    parser.add_argument(
        "--diagnose", action="store_true", help="also diagnose hidden effects (top_effect, gain, noise_floor)"
    )
    add_spacing_arguments(parser, "the files")
    add_region_arguments(parser)
    add_device_argument(parser)
    parser.add_argument(
        "--batch-size",
        type=integer("videos", minimum=1),
        default=8,
        metavar="N",
        help="videos read and estimated together (default 8)",
    )
    parser.add_argument("--float64", action="store_true", help="compute in float64 (default float32)")
    parser.add_argument(
        "--dask", action="store_true", help="run on Dask (embedded LocalCluster unless --scheduler)"
    )
    parser.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address (implies --dask)")
    parser.add_argument(
        "--workers",
        type=integer("workers", minimum=1),
        default=2,
        metavar="N",
        help="workers of the embedded LocalCluster (default 2)",
    )
    parser.add_argument(
        "--rerun",
        action="store_true",
        help="recompute and replace rows of OUT made with other parameters (--dt, --dx, --roi, ...) instead "
        "of stopping",
    )
    parser.add_argument(
        "--precision",
        type=relative,
        metavar="PCT",
        help="read each video in chunks and stop once its relative standard error reaches PCT (e.g. 0.1%%); "
        "the frames_used column says how many frames were read",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object: out, total, skipped, ok, failed, seconds"
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run ``anra batch`` with the parsed ``args``; returns the exit status (0 ok, 2 error)."""
    shared = BatchOptions(
        dt=args.dt,
        dx=args.dx,
        diagnose=args.diagnose,
        dtype="float64" if args.float64 else "float32",
        resample=args.resample,
        roi=args.roi,
        calibration=args.calibration,
        precision=args.precision,
        device=str(args.device),
    )
    options: dict[str, Any] = {
        "options": shared,
        "batch_size": args.batch_size,
        "progress": not args.no_progress,
        "rerun": args.rerun,
    }
    if args.dask or args.scheduler:
        summary = run_batch_dask(
            args.inputs, args.out, scheduler=args.scheduler, workers=args.workers, **options
        )
    else:
        summary = run_batch(args.inputs, args.out, **options)
    record = {
        "out": str(summary.out),
        "total": summary.total,
        "skipped": summary.skipped,
        "ok": summary.ok,
        "failed": summary.failed,
        "seconds": round(summary.seconds, 3),
    }
    if args.json:
        print(json.dumps(record))
    else:
        print(
            f"{summary.out}: {summary.ok} ok, {summary.failed} failed, {summary.skipped} already done "
            f"({summary.total} inputs) in {summary.seconds:.1f} s"
        )
    if summary.failed:
        print(
            f"{PROG}: error: {summary.failed} of {summary.total} inputs failed; see the 'error' column of "
            f"{summary.out}",
            file=sys.stderr,
        )
        return 2
    return 0
