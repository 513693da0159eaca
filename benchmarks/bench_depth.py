"""Time and peak memory of ``anra features --depth`` on one thread: 64 x 64 x 150 and 64 x 64 x 1,668 frames,
and the memory with ``--thickness 10`` against ``--thickness 1000`` (the command's largest: a thicker layer
is refused) and ``--thickness 1e300`` (the same command with that refusal lifted in the child, so that the
depth model itself gets the layer of 1e300 mm; ``tests/tissue/test_depth.py -k deeper``)

The recordings: a Gaussian spot (s = 1.5 mm, slightly off the frame's centre) on skin-like tissue (a = 0.15
mm^2/s, b = 0.003 1/s, a loss to the air) from the Green's-function reference
(:func:`anra_torch.simulation.simulate_spot`), surface peak 75 C, switched off 10 s before the end and
between two frames; 64 x 64 px of 0.1 mm with 0.3 K white noise; 150 frames at 10 frames/s (an exposure of
3.9 s) and 1,668 at 30 frames/s (45.6 s: a minute-long recording). Written once to ``--out`` as ``.npz``.

Each case runs ``anra features VIDEO --depth --json`` (the whole command: reading, the surface features, the
depth fit and maps, the JSON; on 150 frames also without ``--depth``: the surface features' share) in a child
process with ``OMP_NUM_THREADS=1`` from the working tree (or ``--tree``: another revision's ``anra_torch/``,
e.g. exported with ``git archive``), ``--runs`` times after ``--warmup`` runs (the tree's bytecode compiled
first, as an installation has it); the child's wall seconds and its CPU seconds (user + system: on a shared
machine the one thread's own work, which wall time overstates by the machine's load; medians) and peak
resident memory (the largest, from the operating system's accounting of the finished child) are reported.
``--profile`` also times the stages of the depth maps in process (the fit, the march, the doses) for the table
of where the time goes.

Usage::

    .venv/bin/python -m benchmarks.bench_depth --runs 3 --out results/bench_depth
"""

from __future__ import annotations

import argparse
import compileall
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from anra_torch.simulation import GreenScene, simulate_spot
from anra_torch.video import save_npz

ROOT = Path(__file__).resolve().parents[1]
CASES = {"150": (150, 10.0), "1668": (1668, 30.0)}  # frames, frames/s
LIMITS = {"150": {"seconds": 5.0}, "1668": {"seconds": 60.0, "gigabytes": 2.0}}


def recording(frames: int, rate: float, folder: Path) -> Path:
    """The case's ``.npz`` (made once)."""
    path = folder / f"spot_{frames}.npz"
    if path.exists():
        return path
    duration = (frames - 1) / rate
    scene = GreenScene(0.15, 0.003, 0.02, (3.3, 3.1), 1.5, 75.0, 1.0, duration - 9.987, duration, rate)
    result = simulate_spot(scene, damage=False)
    noise = 0.3 * np.random.default_rng(0).standard_normal(result.frames.shape)
    return save_npz(path, result.frames + noise, dt=result.dt, dx=result.dx)


def run(tree: Path, video: Path, extra: list[str]) -> tuple[float, float, float, dict]:
    """``anra features VIDEO --json EXTRA`` from ``tree``: wall and CPU seconds, peak memory (GB), JSON."""
    env = os.environ | {"PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    code = "import sys; from anra_torch.cli import main; sys.exit(main())"
    if "1e300" in extra:  # the command's refusal of layers over MAX_THICKNESS lifted (looked up per parse)
        code = "import anra_torch.cli.features as f; f.MAX_THICKNESS = float('inf'); " + code
    start = time.perf_counter()
    child = subprocess.Popen(  # in the tree: `python -c` imports from the working directory before PYTHONPATH
        [sys.executable, "-c", code, "features", str(Path(video).resolve()), "--json", *extra],
        env=env,
        cwd=tree,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    out = child.stdout.read() if child.stdout else b""
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"anra features {video} {' '.join(extra)} failed")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 2**20, json.loads(out)


def profile(video: Path) -> dict[str, float]:
    """Inclusive CPU seconds of the depth maps' stages, in process (one thread: the process's CPU time is
    the thread's own work, which a loaded machine's wall time overstates)."""
    import importlib

    import torch

    from anra_torch.video import load_video

    # the modules (the package's face exports functions of the same names)
    depth, doses, features = (
        importlib.import_module(f"anra_torch.tissue.{name}")
        for name in ("depth_damage", "depth_doses", "depth_features")
    )

    torch.set_num_threads(1)
    stages: dict[str, float] = {}

    def timed(module: object, name: str, label: str) -> None:
        original = getattr(module, name)

        def wrapper(*args: object, **kwargs: object) -> object:
            start = time.process_time()
            try:
                return original(*args, **kwargs)
            finally:
                stages[label] = stages.get(label, 0.0) + time.process_time() - start

        setattr(module, name, wrapper)

    timed(features, "fit_depth_parameters", "fit of a, b (forecast of the cooling)")
    timed(depth, "_reach", "coarse pass (how deep the heat goes)")
    timed(depth, "node_temperatures", "temperatures at the nodes (modes to pixels)")
    timed(depth, "window_temperatures", "temperatures at the nodes (modes to pixels)")
    timed(depth, "window_problem", "the window's modes (the frames continued, split)")
    timed(depth, "march", "march of the modal states")
    timed(doses.DoseAccumulator, "add", "doses (peak, Omega, CEM43, noise)")
    video = load_video(video)
    start = time.process_time()
    features.depth_features(torch.as_tensor(video.frames), video.dt, video.dx)
    stages["depth maps in all"] = time.process_time() - start
    return stages


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--warmup", type=int, default=1, help="runs before the counted ones (files cached)")
    parser.add_argument("--tree", default=str(ROOT), help="folder holding the anra_torch/ to time")
    parser.add_argument("--cases", default="150,1668")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--out", default="results/bench_depth")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {"tree": args.tree, "runs": args.runs, "cases": {}}
    # The package's bytecode written once, as installing it does: the command then reads it instead of
    # compiling its ~140 modules on every run (a shell with PYTHONDONTWRITEBYTECODE never caches them)
    compileall.compile_dir(str(Path(args.tree) / "anra_torch"), quiet=1)
    for name in args.cases.split(","):
        frames, rate = CASES[name]
        video = recording(frames, rate, out)
        variants = {"without --depth": [], "--depth (half-space)": ["--depth"]}
        if name == "1668":
            variants = {
                "--depth (half-space)": ["--depth"],
                "--depth --thickness 10": ["--depth", "--thickness", "10"],
                "--depth --thickness 1000": ["--depth", "--thickness", "1000"],
                "--depth --thickness 1e300": ["--depth", "--thickness", "1e300"],
            }
        case: dict = {"frames": frames, "rate": rate, "limits": LIMITS[name]}
        for label, extra in variants.items():
            for _ in range(args.warmup):  # files cached, not counted
                run(Path(args.tree), video, extra)
            walls, cpus, peaks = [], [], []
            for _ in range(args.runs):
                wall, cpu, peak, record = run(Path(args.tree), video, extra)
                walls.append(wall)
                cpus.append(cpu)
                peaks.append(peak)
            depth = record.get("depth") or {}
            case[label] = {
                "wall_s_median": statistics.median(walls),
                "wall_s": walls,
                "cpu_s_median": statistics.median(cpus),
                "cpu_s": cpus,
                "peak_gb_max": max(peaks),
                "diffusivity_mm2_s": depth.get("diffusivity_mm2_s"),
                "damage_depth_mm_max": record.get("damage_depth_mm_max"),
                "nodes": depth.get("nodes"),
            }
            print(f"{name} frames {label}: {case[label]}", flush=True)
        if args.profile:
            case["stages_s"] = profile(video)
            print(f"{name} frames stages: {case['stages_s']}", flush=True)
        results["cases"][name] = case
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {out / 'results.json'}")


if __name__ == "__main__":
    main()
