"""``anra batch`` and ``ANRAEstimator`` against the plain NumPy/SciPy peer, same files, same run.

The peer is ``../shared/bench/plain_scipy.py`` (one fixed binomial smoothing of 4 px, the 5-tap smooth time
derivative, a 3-point Laplacian, RTC weights; about 30 lines), imported as it is from ``--peer``. The files:
``--files`` videos of 224 x 224 px x 120 frames (float32 ``.npz``: the paper's Gaussian spot, peak 3.8, FWHM
50 px, a = 0.2 mm^2/s, 27 Hz, dx = 10/224 mm, white noise sd 0.01, one seed per file), written once (or
taken from ``--data``). Every measurement runs in its own child process and is timed inside it, after its
imports (start-up excluded), in pairs A B A B ... after one warm-up pair that is not counted:

- **batch**: A = ``anra batch DIR --out rows.csv --no-progress`` (default settings: phases, the chunked route,
  automatic smoothing, standard error, artefact search, measured noise) on one thread (``OMP_NUM_THREADS=1``),
  through ``anra_torch.cli.main``; B = the peer over the same files (``np.load`` + ``estimate`` each),
  one thread (SciPy's filters have one). Ratio: A's frames/s over B's (target >= 1.2). **batch_threads**:
  the same A on the torch threads it chooses (its recordings side by side), against the same one-thread B.
- **estimator**: one thread (``OMP_NUM_THREADS=1``, ``torch.set_num_threads(1)``), every file read into
  memory first; A = ``ANRAEstimator()`` (default: ``smoothing="auto"``) called on each video, B = the peer's
  ``estimate`` on each. Ratio: A's values/s over B's (target >= 1). The same on the videos' first
  ``--short`` frames (default 28: the paper's second of video), **estimator_short**.

Each pair's ratio is printed; the table gives medians and the ratios' range. ``--profile`` adds a
``torch.profiler`` table of one ``ANRAEstimator`` call (one thread) on one file: where the time goes.
Writes ``bench_batch.json`` and ``bench_batch.md`` to ``--out``. Usage::

    .venv/bin/python -m benchmarks.bench_batch --out results/bench_batch            # ~8 min, 2 cores
    .venv/bin/python -m benchmarks.bench_batch --runs 5 --profile --out results/bench_batch
"""

from __future__ import annotations

import argparse
import importlib.util
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

ROOT = Path(__file__).resolve().parents[1]
PEER = ROOT.parent / "shared" / "bench" / "plain_scipy.py"
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


def _peer(path: Path):  # noqa: ANN202 - the peer's module
    spec = importlib.util.spec_from_file_location("plain_scipy", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"--peer {path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _files(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.npz"))


def _load(path: Path) -> tuple[np.ndarray, float, float]:
    with np.load(path) as z:
        return z["frames"], float(z["dt"]), float(z["dx"])


# ----------------------------------------------------------------------------------------- children
def child_anra_batch(folder: Path, rows: Path) -> dict:
    """A of the batch pair: ``anra batch`` through the CLI's own entry point, after its imports."""
    from anra_torch.cli import main

    rows.unlink(missing_ok=True)
    start, cpu = time.perf_counter(), time.process_time()
    code = main(["batch", str(folder), "--out", str(rows), "--no-progress"])
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    if code not in (0, None):
        raise SystemExit(f"anra batch exited with {code}")
    import csv

    with rows.open() as f:
        values = [float(r["diffusivity"]) for r in csv.DictReader(f)]
    return {"wall_s": wall, "cpu_s": cpu, "a": values}


def child_peer_files(folder: Path, peer: Path) -> dict:
    """B of the batch pair: the peer over the files, reading each."""
    estimate = _peer(peer).estimate
    start, cpu = time.perf_counter(), time.process_time()
    values = []
    for path in _files(folder):
        frames, dt, dx = _load(path)
        values.append(float(estimate(frames, dt, dx)))
    return {"wall_s": time.perf_counter() - start, "cpu_s": time.process_time() - cpu, "a": values}


def _videos(folder: Path, frames: int | None) -> list[tuple[np.ndarray, float, float]]:
    """Every file's ``(frames, dt, dx)``, its first ``frames`` frames only where given."""
    return [(f[:frames], dt, dx) for f, dt, dx in map(_load, _files(folder))]


def child_estimator(folder: Path, frames: int | None = None) -> dict:
    """A of the estimator pair: ``ANRAEstimator()`` on every video in memory, one thread."""
    import torch

    from anra_torch import ANRAEstimator

    torch.set_num_threads(1)
    videos = _videos(folder, frames)
    tensors = [(torch.from_numpy(f), dt, dx) for f, dt, dx in videos]
    est = ANRAEstimator(strict=False)
    start, cpu = time.perf_counter(), time.process_time()
    values = [float(est(f, dt, dx).diffusivity) for f, dt, dx in tensors]
    return {"wall_s": time.perf_counter() - start, "cpu_s": time.process_time() - cpu, "a": values}


def child_peer_memory(folder: Path, peer: Path, frames: int | None = None) -> dict:
    """B of the estimator pair: the peer's ``estimate`` on every video in memory."""
    estimate = _peer(peer).estimate
    videos = _videos(folder, frames)
    start, cpu = time.perf_counter(), time.process_time()
    values = [float(estimate(f, dt, dx)) for f, dt, dx in videos]
    return {"wall_s": time.perf_counter() - start, "cpu_s": time.process_time() - cpu, "a": values}


def child_profile(folder: Path, rows: int) -> dict:
    """A ``torch.profiler`` table of one ``ANRAEstimator()`` call on the first file, one thread."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    from anra_torch import ANRAEstimator

    torch.set_num_threads(1)
    frames, dt, dx = _load(_files(folder)[0])
    video = torch.from_numpy(frames)
    est = ANRAEstimator(strict=False)
    est(video, dt, dx)  # warm: transfer functions, impulse responses
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        est(video, dt, dx)
    return {"table": prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=rows)}


# ------------------------------------------------------------------------------------------- parent
def _child(args: list[str], *, one_thread: bool) -> dict:
    env = os.environ | ({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"} if one_thread else {})
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks.bench_batch", "--child", *args],
        cwd=ROOT, env=env, capture_output=True, text=True,
    )  # fmt: skip
    if done.returncode != 0:
        raise SystemExit(f"child {args[0]} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _pairs(kind: str, folder: Path, out: Path, peer: Path, runs: int, short: int) -> list[dict]:
    """``runs`` counted pairs (after a warm-up pair) of one comparison."""
    if kind in ("batch", "batch_threads"):
        a_args, b_args, one = (
            ["batch", str(folder), str(out / "rows.csv")],
            ["peer_files", str(folder)],
            kind == "batch",
        )
    else:
        frames = str(short) if kind == "estimator_short" else "0"
        a_args, b_args, one = ["estimator", str(folder), frames], ["peer_memory", str(folder)], 1
        b_args = [*b_args, "PEER", frames]
    pairs = []
    for run in range(runs + 1):
        a = _child(a_args, one_thread=bool(one))
        b_full = [str(peer) if x == "PEER" else x for x in b_args]
        b = _child(b_full if "PEER" in b_args else [*b_args, str(peer)], one_thread=True)
        ratio = b["wall_s"] / a["wall_s"]
        print(f"{kind} pair {run}{' (warm-up)' if not run else ''}: anra {a['wall_s']:.2f} s, "
              f"peer {b['wall_s']:.2f} s, ratio {ratio:.2f}", flush=True)  # fmt: skip
        if run:
            pairs.append({"anra": a, "peer": b, "ratio": ratio})
    return pairs


def _error(values: list[float]) -> float:
    return statistics.median(abs(a - A_TRUE) / A_TRUE for a in values)


def _summary(pairs: list[dict], files: int, length: int = FRAMES) -> dict:
    frames = files * length
    ratios = [p["ratio"] for p in pairs]
    anra, peer = (statistics.median(p[k]["wall_s"] for p in pairs) for k in ("anra", "peer"))
    return {
        "anra_s": anra,
        "peer_s": peer,
        "anra_frames_per_s": frames / anra,
        "peer_frames_per_s": frames / peer,
        "anra_values_per_s": frames * SIDE * SIDE / anra,
        "peer_values_per_s": frames * SIDE * SIDE / peer,
        "ratio_median": statistics.median(ratios),
        "ratio_min": min(ratios),
        "ratio_max": max(ratios),
        "anra_error": _error(pairs[-1]["anra"]["a"]),
        "peer_error": _error(pairs[-1]["peer"]["a"]),
        "pairs": pairs,
    }


def report(result: dict) -> str:
    files, b, e, es = result["files"], result["batch"], result["estimator"], result.get("estimator_short")
    lines = [
        f"{files} files of {SIDE} x {SIDE} x {FRAMES} float32; {len(b['pairs'])} pairs A B per comparison, "
        "start-up excluded (medians; ratio range in brackets)",
        "",
        "| comparison | anra (s) | peer (s) | anra | peer | ratio anra/peer | target | "
        "median abs(a - 0.2)/0.2 anra, peer |",
        "|---|---|---|---|---|---|---|---|",
        f"| `anra batch` (default, one thread) vs peer over the files | {b['anra_s']:.2f} | "
        f"{b['peer_s']:.2f} | "
        f"{b['anra_frames_per_s']:.0f} frames/s | {b['peer_frames_per_s']:.0f} frames/s | "
        f"{b['ratio_median']:.2f} ({b['ratio_min']:.2f}-{b['ratio_max']:.2f}) | >= 1.2 | "
        f"{b['anra_error']:.2e}, {b['peer_error']:.2e} |",
        f"| `ANRAEstimator()` in process, one thread, vs peer's `estimate` | {e['anra_s']:.2f} | "
        f"{e['peer_s']:.2f} | {e['anra_values_per_s'] / 1e6:.1f} M values/s | "
        f"{e['peer_values_per_s'] / 1e6:.1f} M values/s | "
        f"{e['ratio_median']:.2f} ({e['ratio_min']:.2f}-{e['ratio_max']:.2f}) | >= 1 | "
        f"{e['anra_error']:.2e}, {e['peer_error']:.2e} |",
    ]
    if bt := result.get("batch_threads"):
        lines.insert(5, f"| `anra batch` (default, the threads it chooses) vs the same | "
                     f"{bt['anra_s']:.2f} | {bt['peer_s']:.2f} | {bt['anra_frames_per_s']:.0f} frames/s | "
                     f"{bt['peer_frames_per_s']:.0f} frames/s | {bt['ratio_median']:.2f} "
                     f"({bt['ratio_min']:.2f}-{bt['ratio_max']:.2f}) | - | "
                     f"{bt['anra_error']:.2e}, {bt['peer_error']:.2e} |")  # fmt: skip
    if es:
        lines.append(
            f"| the same on the first {result['short']} frames | {es['anra_s']:.2f} | {es['peer_s']:.2f} | "
            f"{es['anra_values_per_s'] / 1e6:.1f} M values/s | "
            f"{es['peer_values_per_s'] / 1e6:.1f} M values/s | "
            f"{es['ratio_median']:.2f} ({es['ratio_min']:.2f}-{es['ratio_max']:.2f}) | >= 1 | "
            f"{es['anra_error']:.2e}, {es['peer_error']:.2e} |"
        )
    if result.get("profile"):
        lines += ["", "One `ANRAEstimator()` call on one file, one thread (torch.profiler):", "", "```",
                  result["profile"], "```"]  # fmt: skip
    return "\n".join(lines)


def _run_child(argv: list[str]) -> None:
    kind, *rest = argv
    if kind == "batch":
        result = child_anra_batch(Path(rest[0]), Path(rest[1]))
    elif kind == "peer_files":
        result = child_peer_files(Path(rest[0]), Path(rest[1]))
    elif kind == "estimator":
        result = child_estimator(Path(rest[0]), int(rest[1]) or None)
    elif kind == "peer_memory":
        result = child_peer_memory(Path(rest[0]), Path(rest[1]), int(rest[2]) or None)
    else:
        result = child_profile(Path(rest[0]), int(rest[1]))
    print(json.dumps(result))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="results/bench_batch", help="output folder")
    parser.add_argument("--runs", type=int, default=3, help="counted pairs per comparison, after a warm-up")
    parser.add_argument("--files", type=int, default=12, help="videos in the folder")
    parser.add_argument("--data", help="folder of the videos (default: a temporary one)")
    parser.add_argument("--peer", default=str(PEER), help="the plain estimator (plain_scipy.py)")
    parser.add_argument("--profile", action="store_true", help="add a torch.profiler table")
    parser.add_argument("--short", type=int, default=28, help="frames of the short estimator comparison")
    parser.add_argument(
        "--skip", choices=["batch", "batch_threads", "estimator", "estimator_short"], action="append",
        default=[],
        help="leave a comparison out (repeatable)",
    )  # fmt: skip
    parser.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _run_child(args.child)
        return
    if args.runs < 1 or args.files < 1:
        parser.error(f"--runs and --files must be >= 1, got {args.runs} and {args.files}")
    peer = Path(args.peer)
    if not peer.is_file():
        parser.error(f"--peer must be the plain estimator's file, got {peer} (not found)")
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.data).resolve() if args.data else Path(tmp) / "videos"
        if not _files(folder):
            write_videos(folder, args.files)
        files = len(_files(folder))
        result: dict = {"files": files, "shape": [FRAMES, SIDE, SIDE], "short": args.short}
        for kind in ("batch", "batch_threads", "estimator", "estimator_short"):
            pairs = [] if kind in args.skip else _pairs(kind, folder, out, peer, args.runs, args.short)
            length = args.short if kind == "estimator_short" else FRAMES
            result[kind] = _summary(pairs, files, length) if pairs else None
        if args.profile:
            result["profile"] = _child(["profile", str(folder), "25"], one_thread=True)["table"]
    (out / "bench_batch.json").write_text(json.dumps(result, indent=2))
    if result["batch"] and result["estimator"]:  # the short comparison is optional
        text = report(result)
        (out / "bench_batch.md").write_text(text + "\n")
        print(text)


if __name__ == "__main__":
    main()
