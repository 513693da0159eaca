"""Command line: ``anra estimate``, ``simulate``, ``diagnose``, ``batch``, ``demo``, ``features``,
``convert`` (also ``python -m anra_torch``).

One module per command (:mod:`~anra_torch.cli.estimate`, :mod:`~anra_torch.cli.simulate`, ...), each adding
its own subparser (``add_parser``) and running it (``run``); the flags and helpers they share are in
:mod:`~anra_torch.cli.arguments`. A new command is one module and one entry in :data:`COMMANDS`.

Units everywhere: lengths in mm, times in s, diffusivity in mm^2/s, temperatures in the data's own unit.
Every failure the user can cause (bad file, bad flag, a video without thermal activity) ends in one line
``anra: error: <message>`` on stderr and exit status 2, never a traceback. Anything else is a bug: one line
``anra: internal error: <type>: <message> ...`` and exit status 1; set ``ANRA_TRACEBACK=1`` to see where.
"""

from __future__ import annotations

import argparse
import ctypes
import functools
import gc
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

from anra_torch import __version__
from anra_torch.checks import one_line
from anra_torch.cli import batch, convert, demo, diagnose, estimate, features, simulate
from anra_torch.cli.arguments import PROG, Parser, UsageError, integer
from anra_torch.cli.simulate import PRESETS

__all__ = ["COMMANDS", "PRESETS", "build_parser", "free_cores", "main"]

COMMANDS = (estimate, simulate, diagnose, batch, demo, features, convert)
"""The command modules, in the order ``anra --help`` lists them."""


def free_cores(cores: int, loadavg: Path = Path("/proc/loadavg")) -> int:
    """``cores`` less the processes other than this one that are running right now (``/proc/loadavg``'s
    runnable count, this process included), at least 1; ``cores`` where that count is unavailable.

    A thread pool wider than the free cores stalls at every parallel step while a neighbour holds a core;
    measured in ``docs/results/scale.md``, "Threads on a shared machine".
    """
    try:
        running = int(loadavg.read_text().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return cores
    return max(1, min(cores, cores - (running - 1)))


def build_parser() -> argparse.ArgumentParser:
    """The ``anra`` argument parser (usage errors raise instead of exiting; :func:`main` reports them)."""
    parser = Parser(
        prog=PROG,
        description="Estimate the thermal diffusivity a of dT/dt = a (d11 + d22) T directly from thermal "
        "video (ANRA, El-Kebir et al., arXiv 2203.13148). Units: mm, s, mm^2/s; temperatures in any "
        "linear unit.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument(
        "--threads",
        type=integer("threads", minimum=1),
        default=None,
        metavar="N",
        help="torch CPU threads (default: the cores no other process is running on when the command starts, "
        "at least 1; on a shared machine more threads than free cores make every step wait for the slowest)",
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.add_parser(commands)
    return parser


@functools.cache
def _parser() -> argparse.ArgumentParser:
    """The parser :func:`main` parses with, built once per process: parsing leaves it unchanged (each call
    fills a new namespace; appended options copy their default)."""
    return build_parser()


@functools.cache
def _process_threads() -> int:
    """torch's thread count when this process first ran a command: the base of the free-core default, so a
    process that calls :func:`main` again and again does not shrink it call after call."""

    return torch.get_num_threads()


_MALLOPT = {-3: 32 * 2**20, -1: 256 * 2**20, -2: 16 * 2**20}
"""glibc's ``mallopt`` settings of a process running ``anra``: ``M_MMAP_THRESHOLD`` 32 MiB (blocks below it
from the heap, not each mapped and unmapped anew), ``M_TRIM_THRESHOLD`` 256 MiB (freed heap kept for the
next frames' tensors, not returned and faulted in again), ``M_TOP_PAD`` 16 MiB. The same numbers, fewer page
faults: ``anra features --depth`` on the 150-frame benchmark 0.88 -> 0.40 s of system time; the 1,668-frame
one's peak 1.65 GiB (1.54-1.58 without; 1.68-1.83 with 1 GiB kept)."""


def _keep_freed_memory() -> None:
    """Apply :data:`_MALLOPT` where the C library is glibc (elsewhere nothing changes)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        for option, value in _MALLOPT.items():
            libc.mallopt(option, value)
    except (OSError, AttributeError):
        return


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``anra`` command line; returns the exit status (0 ok, 2 error, 1 internal error).

    Args:
        argv: arguments without the program name; default ``sys.argv[1:]``: the process is the command,
            and what its imports built (~170,000 objects of torch's and the package's modules, alive until
            it exits) is frozen out of the garbage collector's passes (:func:`gc.freeze`), which otherwise
            walk it at every full collection and when the interpreter ends (0.4-0.5 s CPU of every run).
    """
    if argv is None:
        gc.freeze()
        _keep_freed_memory()
    try:
        args = _parser().parse_args(argv)

        torch.set_num_threads(args.threads if args.threads is not None else free_cores(_process_threads()))
        return args.run(args)
    except SystemExit as done:  # --help, --version
        return done.code if isinstance(done.code, int) else 0 if done.code is None else 2
    except UsageError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    except (ValueError, TypeError, OSError, ImportError) as err:
        print(f"{PROG}: error: {one_line(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # a bug, not the user's mistake: still one line, unless asked for the traceback
        if os.environ.get("ANRA_TRACEBACK"):
            raise
        print(
            f"{PROG}: internal error: {one_line(err, kind=True)} (a bug: please report it with the input; "
            "ANRA_TRACEBACK=1 shows where)",
            file=sys.stderr,
        )
        return 1
