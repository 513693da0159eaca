"""Values per second of ``TissueFeatures()`` (no depth) at two revisions, timed in the same run, and how far
the later revision's dose maps are from the earlier's.

The scene: a Gaussian source (0.8 mm, 15 K/s) crosses tissue at 37 C for 4 s, then the tissue cools
(``simulate_tissue``: a = 0.13 mm^2/s, b = 0.05 1/s), 100 frames of 128 x 128 px at dx = 0.1 mm and
dt = 0.1 s, white noise of 0.05 K, float32 frames; made once, by the later tree, and read by both. Each
revision's ``anra_torch/`` runs in its own child process with this interpreter, one torch thread
(``OMP_NUM_THREADS=1``): one untimed call (kernels built), then ``--repeats`` timed calls (median wall
time). Children alternate (before, after, before, ...) after one warm-up pair that is not counted; the ratio
after / before of values per second (``T H W`` per call) is taken pair by pair. The later revision is the
working tree by default (``--after worktree``); an earlier one is exported with ``git archive``.

The dose maps (``peak_temperature``, ``time_above_*``, ``cem43_minutes``, ``omega``) of the two
revisions are compared pixel by pixel: the largest ``|after - before| / |before|`` of each (over the
pixels where ``before`` is not 0) and the largest difference relative to the map's maximum. The other maps
and the loss rate's standard error are summarised by the median and range of their ratio.

With ``--profile`` each child also times its stages (inclusive wall seconds of the named functions, in the
last timed call), for the table of where the time goes.

Usage::

    .venv/bin/python -m benchmarks.bench_tissue --before ':/^Tests: the beam recording of the depth CLI' \\
        --runs 3 --profile --out results/bench_tissue
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

import numpy as np
import torch

from benchmarks.bench_revisions import export

ROOT = Path(__file__).resolve().parents[1]
SIZE, FRAMES, DX, DT, NOISE = 128, 100, 0.1, 0.1, 0.05
DOSE_MAPS = ("peak_temperature", "time_above_43", "time_above_50", "time_above_60", "cem43_minutes", "omega")

CHILD = r"""
import json, statistics, sys, time
import numpy as np
import torch
torch.set_num_threads(1)
from anra_torch.tissue import TissueFeatures
import anra_torch.tissue.features as features
import anra_torch.balance.loss as loss

scene, repeats, profile, out = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1", sys.argv[4]
data = np.load(scene)
frames, dt, dx = torch.from_numpy(data["frames"]), float(data["dt"]), float(data["dx"])
extractor = TissueFeatures()
stages = {}

def timed(owner, name, label):
    function = getattr(owner, name, None)
    if function is None:
        return
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            stages[label] = stages.get(label, 0.0) + time.perf_counter() - start
    setattr(owner, name, wrapper)

if profile:
    for name in ("to_celsius", "dose_maps", "time_above", "cem43", "arrhenius_omega", "estimate_noise_sd",
                 "fit_loss_windows", "rtc_attention", "_fill"):
        timed(features, name, name)
    timed(loss, "_loss_error", "loss rate's standard error (_loss_error)")
    timed(features.TissueFeatures, "_dose_maps", "dose maps (_dose_maps)")
    timed(features.TissueFeatures, "_spatial", "rate and ANRA maps (_spatial)")
    timed(type(extractor.estimator), "forward", "ANRAEstimator")
    timed(type(extractor.filters), "terms", "MatchedFilters.terms")
    timed(type(extractor.history_smoother), "forward", "GaussianSmoothing")

extractor(frames, dt, dx)
seconds, cpu = [], []
for _ in range(repeats):
    stages.clear()
    start, start_cpu = time.perf_counter(), time.process_time()
    result = extractor(frames, dt, dx)
    seconds.append(time.perf_counter() - start)
    cpu.append(time.process_time() - start_cpu)
maps = {k: v.double().numpy() for k, v in result.maps.items()}
maps["loss_rate_std_error"] = result.loss_rate_std_error.double().numpy()
np.savez(out, **maps)
print(json.dumps({"seconds": statistics.median(seconds), "cpu_s": statistics.median(cpu),
                  "values_per_s": frames.numel() / statistics.median(seconds), "stages": stages}))
"""


def make_scene(path: Path) -> None:
    """The benchmark video (see the module docstring) as ``.npz``: ``frames`` float32, ``dt``, ``dx``."""
    from anra_torch.simulation import MovingSource, simulate_tissue

    u0 = torch.full((SIZE, SIZE), 37.0, dtype=torch.float64)
    side = SIZE * DX
    source = MovingSource(
        start=(0.3 * side, 0.5 * side), end=(0.7 * side, 0.5 * side), width=0.8, power=15.0, t_off=4.0
    )
    clean = simulate_tissue(u0, 0.13, 0.05, dx=DX, dt=DT, n_frames=FRAMES, source=source)
    draws = torch.randn(clean.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    np.savez(path, frames=(clean + NOISE * draws).float().numpy(), dt=DT, dx=DX)


def run_child(tree: Path, scene: Path, repeats: int, profile: bool, out: Path) -> dict:
    """One child process on ``tree``'s ``anra_torch``: its median call and, with ``profile``, stages."""
    env = os.environ | {"PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    argv = [sys.executable, "-c", CHILD, str(scene), str(repeats), "1" if profile else "0", str(out)]
    # From the scene's folder: a child started in the repository would import its anra_torch first.
    done = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=scene.parent)
    if done.returncode != 0:
        raise SystemExit(f"child on {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def spread(values: list[float]) -> dict[str, float]:
    """Median, min and max."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def compare(before: Path, after: Path) -> dict[str, dict[str, float]]:
    """Per map: the largest pixel-relative and max-relative differences (dose maps), or the spread of the
    ratio after / before over the pixels where both are finite and non-zero (the others)."""
    old, new = np.load(before), np.load(after)
    rows = {}
    for name in old.files:
        if name not in new.files:
            continue
        a, b = new[name], old[name]
        both = np.isfinite(a) & np.isfinite(b)
        if name in DOSE_MAPS:
            nonzero = both & (b != 0)
            pixel = float(np.max(np.abs(a - b)[nonzero] / np.abs(b[nonzero]))) if nonzero.any() else 0.0
            scale = float(np.max(np.abs(b[both]))) if both.any() else 0.0
            whole = float(np.max(np.abs(a - b)[both])) / scale if scale > 0 else 0.0
            rows[name] = {"max_pixel_relative": pixel, "max_relative_to_max": whole,
                          "same_nonfinite": bool(np.array_equal(np.isfinite(a), np.isfinite(b)))}  # fmt: skip
        else:
            usable = both & (b != 0) & (a != 0)
            ratio = a[usable] / b[usable]
            quantiles = np.quantile(ratio, (0.05, 0.5, 0.95)) if ratio.size else np.full(3, np.nan)
            rows[name] = {"ratio_median": float(quantiles[1]), "ratio_p5": float(quantiles[0]),
                          "ratio_p95": float(quantiles[2])}  # fmt: skip
    return rows


def report(args: argparse.Namespace, pairs: list[dict], gain: dict, maps: dict) -> list[str]:
    """The markdown table of the run."""
    med = {s: {k: statistics.median(p[s][k] for p in pairs) for k in ("seconds", "cpu_s", "values_per_s")}
           for s in ("before", "after")}  # fmt: skip
    lines = [
        f"# TissueFeatures() on {FRAMES} x {SIZE} x {SIZE} float32 frames, one thread: {args.after} against "
        f"{args.before}, {len(pairs)} pairs of {args.repeats} calls",
        "",
        "| revision | s per call (wall) | CPU s per call | values/s |",
        "|---|---|---|---|",
    ]
    for side in ("before", "after"):
        m = med[side]
        lines.append(
            f"| {side} ({getattr(args, side)}) | {m['seconds']:.3f} | {m['cpu_s']:.3f} | "
            f"{m['values_per_s'] / 1e6:.2f} M |"
        )
    lines += [
        "",
        f"values/s after / before (pair by pair): median {gain['median']:.2f} "
        f"(min {gain['min']:.2f}, max {gain['max']:.2f}); target >= 5",
        "",
        "| dose map | max pixel-relative difference | max difference / map maximum |",
        "|---|---|---|",
    ]
    for name, row in maps.items():
        if "max_pixel_relative" in row:
            lines.append(f"| {name} | {row['max_pixel_relative']:.2e} | {row['max_relative_to_max']:.2e} |")
    lines += ["", "| other map | ratio after / before: median (5-95 %) |", "|---|---|"]
    for name, row in maps.items():
        if "ratio_median" in row:
            lines.append(
                f"| {name} | {row['ratio_median']:.4g} ({row['ratio_p5']:.4g}-{row['ratio_p95']:.4g}) |"
            )
    for side in ("before", "after") if args.profile else ():
        stages = pairs[-1][side]["stages"]
        total = pairs[-1][side]["seconds"]
        lines += ["", f"Stages of the last {side} call ({total:.3f} s; inclusive, nested):", ""]
        lines += ["| stage | s | share |", "|---|---|---|"]
        for name, value in sorted(stages.items(), key=lambda kv: -kv[1]):
            lines.append(f"| {name} | {value:.3f} | {100 * value / total:.0f} % |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", required=True, help="the earlier git revision")
    parser.add_argument("--after", default="worktree", help="a later git revision, or the working tree")
    parser.add_argument("--runs", type=int, default=3, help="counted pairs (default 3)")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per child (default 3)")
    parser.add_argument("--profile", action="store_true", help="also time the stages")
    parser.add_argument("--out", default="results/bench_tissue", help="folder for bench.md and bench.json")
    args = parser.parse_args()
    if args.runs < 1 or args.repeats < 1:
        parser.error(f"--runs and --repeats must be >= 1, got {args.runs} and {args.repeats}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        after = ROOT if args.after == "worktree" else export(args.after, work / "after")
        trees = {"before": export(args.before, work / "before"), "after": after}
        scene = work / "scene.npz"
        make_scene(scene)
        pairs = []
        for run in range(args.runs + 1):
            pair = {
                side: run_child(trees[side], scene, args.repeats, args.profile, work / f"{side}.npz")
                for side in ("before", "after")
            }
            said = ", ".join(f"{s} {p['seconds']:.3f} s" for s, p in pair.items())
            print(f"pair {run}{' (warm-up)' if not run else ''}: {said}", flush=True)
            if run:
                pairs.append(pair)
        maps = compare(work / "before.npz", work / "after.npz")
    gain = spread([p["after"]["values_per_s"] / p["before"]["values_per_s"] for p in pairs])
    lines = report(args, pairs, gain, maps)
    result = {"before": args.before, "after": args.after, "scene": {"size": SIZE, "frames": FRAMES, "dx": DX,
              "dt": DT, "noise": NOISE}, "pairs": pairs, "gain": gain, "maps": maps}  # fmt: skip
    (out / "bench.json").write_text(json.dumps(result, indent=2))
    (out / "bench.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
