"""``anra batch`` against a plain NumPy/SciPy estimator on the same folder, as whole processes in turn.

Writes ``--files`` videos of 224 x 224 px x 120 frames (float32 ``.npz``: the paper's Gaussian spot, peak
3.8, FWHM 50 px, a = 0.2 mm^2/s, 27 Hz, dx = 10/224 mm, white noise sd 0.01, one seed per file), then runs
``--runs`` pairs, A B A B ...:

- A: ``anra batch DIR --out rows.csv --no-progress`` with default settings (automatic smoothing, standard
  error, camera-artefact search, measured noise model);
- B: ``python -m experiments.bench_batch --plain DIR FILTERS``: the same estimator with one fixed smoothing
  (4 px) in NumPy/SciPy (``bench_scale.numpy_same_estimate``: no standard error, no artefact search), file
  by file; its filters are written beforehand, so it imports NumPy and SciPy only, not torch.

Each run is its own process (start-up included in both); wall time from the parent, peak RSS from the
kernel's accounting of the finished child (``os.wait4``). The ratio B / A of wall times, pair by pair: at
least 1 means ``anra batch`` is at least as fast. Writes ``bench_batch.json`` and ``bench_batch.md`` to
``--out``. Usage::

    .venv/bin/python -m experiments.bench_batch --out results/bench_batch        # ~4 min, 2 cores
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments.bench_scale import numpy_same_estimate, same_estimate_taps

A_TRUE, FPS, NOISE, FRAMES, SIDE = 0.2, 27.0, 0.01, 120, 224


def write_videos(folder: Path, files: int) -> None:
    """``files`` noisy videos of the Gaussian spot (see the module docs) as ``v00.npz`` ...."""
    import torch

    from anra_torch.simulation import gaussian_blob

    folder.mkdir(parents=True, exist_ok=True)
    dx, dt = 10.0 / SIDE, 1.0 / FPS
    times = torch.arange(FRAMES, dtype=torch.float64) * dt
    sigma = 50 / (2 * math.sqrt(2 * math.log(2))) * dx
    clean = gaussian_blob(times, shape=(SIDE, SIDE), dx=dx, a=A_TRUE, peak=3.8, sigma=sigma).numpy()
    for i in range(files):
        noisy = clean + NOISE * np.random.default_rng(i).standard_normal(clean.shape)
        np.savez(folder / f"v{i:02d}.npz", frames=noisy.astype(np.float32), dt=dt, dx=dx)


def plain(folder: Path, filters: Path) -> None:
    """B: the plain NumPy/SciPy estimate of every file, one ``name,a`` line each; the filters come from the
    ``filters`` file, so this process imports NumPy and SciPy only (no torch)."""
    with np.load(filters) as z:
        taps = {k: z[k] for k in z.files}
    for path in sorted(folder.glob("*.npz")):
        with np.load(path) as z:
            a = numpy_same_estimate(z["frames"], float(z["dt"]), float(z["dx"]), filters=taps)
        print(f"{path.name},{a!r}", flush=True)


def _run(command: list[str], log: Path) -> tuple[float, float]:
    """Wall seconds and peak RSS (MiB) of one child process; its output goes to ``log``."""
    with log.open("ab") as out:
        start = time.perf_counter()
        child = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode not in (0,):
        raise RuntimeError(f"{command[0]} ... exited with {child.returncode}; see {log}")
    return wall, usage.ru_maxrss / 1024


def _errors(rows: Path, log: Path) -> tuple[float, float]:
    """Median |a - 0.2| / 0.2 of ``anra batch``'s rows and of the plain estimator's last run."""
    with rows.open() as f:
        anra = [float(r["diffusivity"]) for r in csv.DictReader(f)]
    lines = [line.split(",") for line in log.read_text().splitlines() if line.startswith("v") and "," in line]
    plain_a = [float(a) for _, a in lines[-len(anra) :]]
    return (
        statistics.median(abs(a - A_TRUE) / A_TRUE for a in anra),
        statistics.median(abs(a - A_TRUE) / A_TRUE for a in plain_a),
    )


def measure(folder: Path, out: Path, runs: int) -> dict:
    anra = Path(sys.executable).with_name("anra")
    rows = out / "rows.csv"
    a_cmd = [str(anra), "batch", str(folder), "--out", str(rows), "--no-progress"]
    np.savez(out / "filters.npz", **same_estimate_taps(4.0))
    filters = str(out / "filters.npz")
    b_cmd = [sys.executable, "-m", "experiments.bench_batch", "--plain", str(folder), filters]
    logs = {"anra": out / "anra.log", "plain": out / "plain.log"}
    for log in logs.values():
        log.unlink(missing_ok=True)
    pairs = []
    for i in range(runs + 1):  # the first pair warms the file cache and is not counted
        rows.unlink(missing_ok=True)
        a = _run(a_cmd, logs["anra"])
        b = _run(b_cmd, logs["plain"])
        if i:
            pairs.append({"anra_s": a[0], "anra_mib": a[1], "plain_s": b[0], "plain_mib": b[1]})
    anra_error, plain_error = _errors(rows, logs["plain"])
    ratios = [p["plain_s"] / p["anra_s"] for p in pairs]
    return {
        "files": len(list(folder.glob("*.npz"))),
        "shape": [FRAMES, SIDE, SIDE],
        "pairs": pairs,
        "ratio_median": statistics.median(ratios),
        "ratio_min": min(ratios),
        "ratio_max": max(ratios),
        "anra_median_error": anra_error,
        "plain_median_error": plain_error,
    }


def report(result: dict) -> str:
    pairs = result["pairs"]

    def med(key: str) -> float:
        return statistics.median(p[key] for p in pairs)

    frames = result["files"] * FRAMES
    return "\n".join(
        [
            f"{result['files']} files of {SIDE} x {SIDE} x {FRAMES} float32, {len(pairs)} pairs (median):",
            "",
            "| command | wall (s) | frames/s | peak RSS (MiB) | median abs(a - 0.2) / 0.2 |",
            "|---|---|---|---|---|",
            f"| `anra batch` (default) | {med('anra_s'):.2f} | {frames / med('anra_s'):.0f} | "
            f"{med('anra_mib'):.0f} | {result['anra_median_error']:.2e} |",
            f"| plain NumPy/SciPy, 4 px | {med('plain_s'):.2f} | {frames / med('plain_s'):.0f} | "
            f"{med('plain_mib'):.0f} | {result['plain_median_error']:.2e} |",
            "",
            f"ratio plain / anra (wall, pair by pair): median {result['ratio_median']:.2f} "
            f"(min {result['ratio_min']:.2f}, max {result['ratio_max']:.2f}); target >= 1",
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="results/bench_batch", help="output folder")
    parser.add_argument("--runs", type=int, default=5, help="counted pairs after one warm-up pair")
    parser.add_argument("--files", type=int, default=12, help="videos in the folder")
    parser.add_argument("--data", help="folder of the videos (default: a temporary one)")
    parser.add_argument("--plain", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.plain:
        plain(Path(args.plain[0]), Path(args.plain[1]))
        return
    if args.runs < 1 or args.files < 1:
        parser.error(f"--runs and --files must be >= 1, got {args.runs} and {args.files}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.data) if args.data else Path(tmp) / "videos"
        if not list(folder.glob("*.npz")):
            write_videos(folder, args.files)
        result = measure(folder, out, args.runs)
    (out / "bench_batch.json").write_text(json.dumps(result, indent=2))
    text = report(result)
    (out / "bench_batch.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
