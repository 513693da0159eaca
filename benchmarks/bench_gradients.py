"""Forward and backward through ``ANRAEstimator`` at two git revisions, timed in the same run.

What a training loop pays per step: ``ANRAEstimator()(frames, dt, dx)`` on ``--videos`` paper videos
(``anra_torch.simulation.paper_video``: 28 x 224 x 224, noise 0.01) with ``frames.requires_grad_()``, then
``diffusivity.sum().backward()``. Each revision's ``anra_torch/`` is exported (``git archive``) and run with
this interpreter in its own child process, one torch thread (``OMP_NUM_THREADS=1``), in pairs before, after,
before, ... after one warm-up pair that is not counted; each child times one forward and one backward
(wall, after its imports and a first call that builds the kernels). The table gives the medians, the ratio
backward / forward of the later revision (target <= 2) and the ratio of the forward times before / after
(target >= 4), pair by pair.

``--compile`` adds, for the later revision, ``torch.compile`` of the estimator (default mode): its first
call (the compilation) and the median of the following forward and backward passes.

Usage::

    .venv/bin/python -m benchmarks.bench_gradients --before 5a863eb --runs 3 --out results/bench_gradients
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.bench_revisions import export

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import json, statistics, sys, time
import torch
from anra_torch import ANRAEstimator, paper_video
videos, dtype = int(sys.argv[1]), getattr(torch, sys.argv[2])
compiled, repeats = sys.argv[3] == "1", int(sys.argv[4])
torch.set_num_threads(1)
video = paper_video(n_videos=videos, seed=0, dtype=dtype)
est = ANRAEstimator(strict=False)
step = torch.compile(est) if compiled else est

def once():
    frames = video.frames.clone().requires_grad_(True)
    start = time.perf_counter()
    result = step(frames, video.dt, video.dx)
    forward = time.perf_counter() - start
    start = time.perf_counter()
    result.diffusivity.sum().backward()
    backward = time.perf_counter() - start
    assert frames.grad is not None and bool(torch.isfinite(frames.grad).all())
    return forward, backward, result.diffusivity.detach().tolist()

start = time.perf_counter()
once()  # kernels built (and, compiled, the graph)
first = time.perf_counter() - start
times = [once() for _ in range(repeats)]
forward = statistics.median(t[0] for t in times) if repeats else float("nan")
backward = statistics.median(t[1] for t in times) if repeats else float("nan")
print(json.dumps({"first_s": first, "forward_s": forward, "backward_s": backward, "a": times[-1][2]}))
"""


def run_child(tree: Path, videos: int, dtype: str, compiled: bool, repeats: int = 1) -> dict:
    """One child process on ``tree``'s ``anra_torch``: its first call and the median pass."""
    env = os.environ | {"PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    argv = [sys.executable, "-c", CHILD, str(videos), dtype, "1" if compiled else "0", str(repeats)]
    done = subprocess.run(argv, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"child on {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def spread(values: list[float]) -> dict[str, float]:
    """Median, min and max."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--before", default="5a863eb", help="the earlier git revision (default: issue 35's base)"
    )
    parser.add_argument("--after", default="HEAD", help="the later git revision (default HEAD)")
    parser.add_argument("--runs", type=int, default=3, help="counted pairs (default 3)")
    parser.add_argument("--videos", type=int, default=4, help="paper videos per batch (default 4)")
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    parser.add_argument(
        "--compile", action="store_true", help="also time torch.compile of the later revision"
    )
    parser.add_argument("--out", default="results/bench_gradients", help="folder for bench.md and bench.json")
    args = parser.parse_args()
    if args.runs < 1 or args.videos < 1:
        parser.error(f"--runs and --videos must be >= 1, got {args.runs} and {args.videos}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        trees = {"before": export(args.before, work / "before"), "after": export(args.after, work / "after")}
        pairs = []
        for run in range(args.runs + 1):
            pair = {
                side: run_child(trees[side], args.videos, args.dtype, False) for side in ("before", "after")
            }
            said = ", ".join(f"{s} forward {p['forward_s']:.2f} s backward {p['backward_s']:.2f} s"
                             for s, p in pair.items())  # fmt: skip
            print(f"pair {run}{' (warm-up)' if not run else ''}: {said}", flush=True)
            if run:
                pairs.append(pair)
        compiled = (
            run_child(trees["after"], args.videos, args.dtype, True, repeats=3) if args.compile else None
        )
    forward_gain = spread([p["before"]["forward_s"] / p["after"]["forward_s"] for p in pairs])
    backward_share = spread([p["after"]["backward_s"] / p["after"]["forward_s"] for p in pairs])
    med = {s: {k: statistics.median(p[s][k] for p in pairs) for k in ("forward_s", "backward_s")}
           for s in ("before", "after")}  # fmt: skip
    lines = [
        f"# Forward + backward through ANRAEstimator() on {args.videos} paper videos (28 x 224 x 224, "
        f"{args.dtype}), one thread: {args.after} against {args.before}, {len(pairs)} pairs",
        "",
        "| revision | forward (s) | backward (s) | backward / forward |",
        "|---|---|---|---|",
    ]
    for side in ("before", "after"):
        f, b = med[side]["forward_s"], med[side]["backward_s"]
        lines.append(f"| {side} ({getattr(args, side)}) | {f:.2f} | {b:.2f} | {b / f:.2f} |")
    lines += [
        "",
        f"forward before / after (pair by pair): median {forward_gain['median']:.2f} "
        f"(min {forward_gain['min']:.2f}, max {forward_gain['max']:.2f}); target >= 4",
        f"backward / forward after: median {backward_share['median']:.2f} "
        f"(min {backward_share['min']:.2f}, max {backward_share['max']:.2f}); target <= 2",
    ]
    if compiled is not None:
        lines += [
            "",
            f"torch.compile(ANRAEstimator()) at {args.after}: first call (compilation) "
            f"{compiled['first_s']:.1f} s, "
            f"then forward {compiled['forward_s']:.2f} s, backward {compiled['backward_s']:.2f} s "
            f"(eager in the same run: forward {med['after']['forward_s']:.2f} s, "
            f"backward {med['after']['backward_s']:.2f} s)",
        ]
    result = {"before": args.before, "after": args.after, "videos": args.videos, "dtype": args.dtype,
              "pairs": pairs, "forward_gain": forward_gain, "backward_share": backward_share,
              "compiled": compiled}  # fmt: skip
    (out / "bench.json").write_text(json.dumps(result, indent=2))
    (out / "bench.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
