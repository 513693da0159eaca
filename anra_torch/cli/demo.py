"""``anra demo``: simulate the paper's case, estimate its diffusivity and write a report with figures."""

from __future__ import annotations

import argparse
import importlib.util
import time

from anra_torch.checks import check_output
from anra_torch.estimation import ANRAEstimator
from anra_torch.report import format_pm, write_estimate_report
from anra_torch.simulation import paper_video
from anra_torch.video import load_video, save_npz

__all__ = ["add_parser", "run"]

DEMO_TRUTH = 0.2  # mm^2/s, the paper's simulation
DEMO_PAPER_ESTIMATE = 0.189  # mm^2/s, what El-Kebir et al. report for it
DEMO_WINDOW = 15  # px, windowed field in the demo report


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``anra`` subcommands (``commands``: what ``add_subparsers`` returned)."""
    parser = commands.add_parser(
        "demo",
        help="simulate the paper's case, estimate a (mm^2/s) and write a report",
        description="Simulate El-Kebir et al.'s case (a = 0.2 mm^2/s, 224 px over 10 mm, 27 Hz for 1 s, "
        "noise sd 0.01), estimate a with the default estimator and write report.md with figures.",
    )
    parser.add_argument(
        "--out", default="results/demo", metavar="DIR", help="output directory (default results/demo)"
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run ``anra demo`` with the parsed ``args``; returns the exit status (0 ok, 2 error)."""
    if importlib.util.find_spec("matplotlib") is None:
        raise ImportError(
            "anra demo writes a report with matplotlib, which is not installed: pip install anra_torch[plot]"
        )
    out = check_output(args.out, name="--out", folder=True)
    start = time.perf_counter()
    synthetic = paper_video(noise_sd=0.01, seed=0)
    path = save_npz(
        out / "paper_simulation.npz",
        synthetic.frames[0],
        dt=synthetic.dt,
        dx=synthetic.dx,
        t=synthetic.times,
        a_true=synthetic.a,
        noise_sd=0.01,
        seed=0,
        preset="paper",
    )
    video = load_video(path)
    est = ANRAEstimator(window=DEMO_WINDOW)
    tick = time.perf_counter()
    result = est(video.frames, video.dt, video.dx)
    estimated = time.perf_counter() - tick
    report = write_estimate_report(out, video, result, truth=DEMO_TRUTH, estimator=est)
    total = time.perf_counter() - start
    a, error = float(result.diffusivity), float(result.std_error)
    t, h, w = video.frames.shape
    print(
        f"anra demo: the simulation of El-Kebir et al. (arXiv 2203.13148): {t} frames of {h} x {w} px at "
        f"{1 / video.dt:g} Hz, dx = {video.dx:.4g} mm, a = {DEMO_TRUTH} mm^2/s, noise sd 0.01"
    )
    print(
        f"  estimate a = {format_pm(a, error, 'mm^2/s')}, error {100 * (a - DEMO_TRUTH) / DEMO_TRUTH:+.3g} % "
        f"against {DEMO_TRUTH} (the paper reports {DEMO_PAPER_ESTIMATE})"
    )
    print(
        f"  smoothing {float(result.smoothing):g} px chosen from the data, noise sd "
        f"{float(result.noise_sd):.4g}, reliability {float(result.reliability):.3f}"
    )
    print(f"  estimated in {estimated:.2f} s ({total:.1f} s with simulation and report)")
    print(f"  video:  {path}")
    print(f"  report: {report}")
    return 0
