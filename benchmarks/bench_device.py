"""Frames per second of the estimator and the tissue features on the CPU and, where there is one, a GPU.

``ANRAEstimator()`` (default settings) on ``--videos`` paper videos (``paper_video``: 28 x 224 x 224, float32)
in one call, and ``TissueFeatures()`` on as many heated-spot videos (37 C plus a 25 K Gaussian spot, 28 frames
of 224 x 224 px, 2 Hz); each timed ``--repeats`` times after one call that builds the kernels (median, wall;
on a GPU synchronised before the clock is read). The inputs are made on the CPU and moved to each device:
the computation follows them. Without a GPU the table says "no GPU" and shows the CPU alone.

Usage::

    .venv/bin/python -m benchmarks.bench_device --out results/bench_device
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

from anra_torch import ANRAEstimator, TissueFeatures, paper_video
from anra_torch.simulation import gaussian_blob


def devices() -> list[torch.device]:
    """The CPU and every GPU torch sees (CUDA, or Apple's MPS)."""
    found = [torch.device("cpu")]
    found += [torch.device("cuda", i) for i in range(torch.cuda.device_count())]
    if torch.backends.mps.is_available():
        found.append(torch.device("mps"))
    return found


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    elif device.type == "mps":
        torch.mps.synchronize()


def timed(run: Callable[[], object], device: torch.device, repeats: int) -> float:
    """Median wall seconds of ``run()`` after one untimed call."""
    run()
    _sync(device)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        _sync(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def inputs(videos: int) -> dict[str, tuple[torch.Tensor, float, float]]:
    """The two workloads' frames ``(B, 28, 224, 224)`` float32 on the CPU, with dt (s) and dx (mm)."""
    paper = paper_video(n_videos=videos, seed=0, dtype=torch.float32)
    t = torch.arange(28, dtype=torch.float64) * 0.5
    spot = 37.0 + gaussian_blob(t, shape=(224, 224), dx=0.05, a=0.13, peak=25.0, sigma=1.0)
    draws = torch.randn(videos, *spot.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    noise = 0.05 * draws
    return {
        "estimator": (paper.frames, paper.dt, paper.dx),
        "features": ((spot + noise).float(), 0.5, 0.05),
    }


def measure(videos: int, repeats: int) -> dict:
    work = inputs(videos)
    estimator, features = ANRAEstimator(strict=False), TissueFeatures()
    models = {"estimator": estimator, "features": features}
    rows = []
    for device in devices():
        for name, (frames, dt, dx) in work.items():
            model, moved = models[name].to(device), frames.to(device)
            seconds = timed(lambda m=model, f=moved, a=dt, b=dx: m(f, a, b), device, repeats)
            rows.append({"device": str(device), "workload": name, "seconds": seconds,
                         "frames_per_s": frames.shape[0] * frames.shape[1] / seconds})  # fmt: skip
    return {"videos": videos, "repeats": repeats, "torch": torch.__version__, "rows": rows,
            "gpu": [str(d) for d in devices() if d.type != "cpu"]}  # fmt: skip


def report(result: dict) -> str:
    lines = [
        f"{result['videos']} videos of 28 x 224 x 224 float32 per call, median of {result['repeats']} calls "
        f"(torch {result['torch']})",
        "",
        "| workload | device | s per call | frames/s |",
        "|---|---|---|---|",
    ]
    lines += [f"| {r['workload']} | {r['device']} | {r['seconds']:.3f} | {r['frames_per_s']:.0f} |"
              for r in result["rows"]]  # fmt: skip
    if not result["gpu"]:
        lines += ["", "no GPU: torch sees neither CUDA nor MPS on this machine; the CPU alone is shown"]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--videos", type=int, default=4, help="videos per call (default 4)")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per row (default 3)")
    parser.add_argument("--out", default="results/bench_device", help="folder for bench.md and bench.json")
    args = parser.parse_args()
    if args.videos < 1 or args.repeats < 1:
        parser.error(f"--videos and --repeats must be >= 1, got {args.videos} and {args.repeats}")
    result = measure(args.videos, args.repeats)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = report(result)
    (out / "bench.json").write_text(json.dumps(result, indent=2))
    (out / "bench.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
