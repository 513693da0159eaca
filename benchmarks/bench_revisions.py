"""Whole-process speed of ``anra estimate``, ``anra batch`` and ``anra diagnose`` at two git revisions,
timed in the same run.

Each revision's ``anra_torch/`` is exported (``git archive``) to a temporary folder and run with this
interpreter (so both see the same torch), one torch thread per process (``OMP_NUM_THREADS=1``), on the
same inputs, made first by the newer revision's ``anra simulate``: the paper's 224 px video, 6 blobs videos of
128 x 128 px x 60 frames, and a 96 px advection video. Runs alternate (before, after, before, ...), so a
drift in the machine's speed falls on both; each pair gives a ratio after / before of the child's CPU
time (user + system, from ``os.wait4``) and of its wall time, and the table shows their median and range.

Usage::

    python -m benchmarks.bench_revisions --before ':/^One checks module' --after HEAD --runs 7 \
        --out results/bench_revisions

(``:/TEXT`` is git's name for the youngest commit whose message matches: the one before the PDE-balance core.)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = {
    "estimate": ["estimate", "paper.npz", "--json"],
    "batch": ["batch", "videos", "--out", "{out}"],
    "diagnose": ["diagnose", "adv.npz", "--json"],
}
INPUTS = [
    ["simulate", "--preset", "paper", "--noise", "0.01", "-o", "paper.npz"],
    *(
        ["simulate", "--preset", "blobs", "--size", "128", "--frames", "60", "--seed", str(s), "-o",
         f"videos/blobs{s}.npz"]
        for s in range(6)
    ),
    ["simulate", "--effect", "advection", "--size", "96", "--seed", "0", "-o", "adv.npz"],
]  # fmt: skip


def export(revision: str, folder: Path) -> Path:
    """``anra_torch/`` of ``revision`` in ``folder``, for ``PYTHONPATH``."""
    folder.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", revision, "anra_torch"], check=True,
                             capture_output=True).stdout  # fmt: skip
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def anra(tree: Path, args: list[str], cwd: Path) -> tuple[float, float, int]:
    """Run ``anra ARGS`` from ``tree``: (CPU seconds, wall seconds, exit status) of the child."""
    env = os.environ | {"PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    code = "import sys; from anra_torch.cli import main; sys.exit(main())"
    start = time.perf_counter()
    child = subprocess.Popen([sys.executable, "-c", code, *args], cwd=cwd, env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_utime + usage.ru_stime, wall, child.returncode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", required=True, help="the earlier git revision")
    parser.add_argument("--after", default="HEAD", help="the later git revision (default HEAD)")
    parser.add_argument("--runs", type=int, default=7, help="timed pairs per command (default 7)")
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--out", default="results/bench_revisions", help="folder for bench.md and bench.json")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        trees = {"before": export(args.before, work / "before"), "after": export(args.after, work / "after")}
        data = work / "data"
        (data / "videos").mkdir(parents=True)
        for argv in INPUTS:
            cpu, wall, code = anra(trees["after"], argv, data)
            if code != 0:
                raise SystemExit(f"making the inputs failed: anra {' '.join(argv)}")
        records = {case: time_case(case, trees, data, work, args.runs) for case in args.cases}
    header = "| command | runs | CPU s before | CPU s after | CPU ratio after/before | wall ratio |"
    lines = [f"# `anra` at {args.after} against {args.before}: whole process, one torch thread, paired runs"]
    lines += ["", header, "|---|---|---|---|---|---|"]
    for r in records.values():
        command = " ".join(r["args"]).replace("{out}", "OUT.csv")
        c, w = r["cpu_ratio"], r["wall_ratio"]
        lines.append(
            f"| `anra {command}` | {r['runs']} | {r['cpu_before_s']:.2f} | {r['cpu_after_s']:.2f} | "
            f"{c['median']:.2f} ({c['min']:.2f}-{c['max']:.2f}) | "
            f"{w['median']:.2f} ({w['min']:.2f}-{w['max']:.2f}) |"
        )
    lines += [
        "",
        "Ratios: median over the pairs (min-max in brackets); below 1 the later revision is faster.",
    ]
    (out / "bench.md").write_text("\n".join(lines) + "\n")
    summary = {"before": args.before, "after": args.after, **records}
    (out / "bench.json").write_text(json.dumps(summary, indent=2))
    print("\n".join(lines))


def spread(values: list[float]) -> dict[str, float]:
    """Median, min and max."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def time_case(case: str, trees: dict[str, Path], data: Path, work: Path, runs: int) -> dict:
    """``runs`` timed pairs of one command (after a first pair that warms the caches)."""
    pairs = []
    for run in range(runs + 1):
        timed = {}
        for side in ("before", "after"):
            argv = [a.format(out=str(work / f"{case}-{side}-{run}.csv")) for a in CASES[case]]
            cpu, wall, code = anra(trees[side], argv, data)
            if code not in (0, 2):
                raise SystemExit(f"{side} failed (exit {code}): anra {' '.join(argv)}")
            timed[side] = (cpu, wall)
        if run:
            pairs.append(timed)
        said = ", ".join(f"{side} cpu {c:.2f} s wall {w:.2f} s" for side, (c, w) in timed.items())
        print(f"{case} run {run}: {said}", flush=True)
    return {
        "args": CASES[case],
        "runs": len(pairs),
        "cpu_before_s": statistics.median(p["before"][0] for p in pairs),
        "cpu_after_s": statistics.median(p["after"][0] for p in pairs),
        "cpu_ratio": spread([p["after"][0] / p["before"][0] for p in pairs]),
        "wall_ratio": spread([p["after"][1] / p["before"][1] for p in pairs]),
    }


if __name__ == "__main__":
    main()
