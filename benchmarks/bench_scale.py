"""Throughput, memory and accuracy of ANRA against its peers, measured in one run on one machine.

For 224 x 224 (the paper's case) and 382 x 288 (an Optris Xi 400 frame) videos of 28 frames (27 Hz, 1 s),
float32, batches of 1, 8 and 32 videos:

- ``anra[auto]``: the default estimator (smoothing chosen per video among 1, 2, 4, 8 px, standard error);
- ``anra[sigma=4]``: the estimator with one fixed smoothing, 4 px;
- ``numpy[sigma=4]``: the SAME configuration as ``anra[sigma=4]`` in plain NumPy/SciPy, one video at a time
  (Gaussian taps, Holoborodko 5-frame time pair, central 5-point Laplacian, noise from the median absolute
  fourth difference, errors-in-variables correction; it skips the standard error, which ANRA computes);
  its diffusivity is checked against ANRA's;
- ``read``: one read pass ``x.sum()`` over the same batch, the memory-bound limit;

and on one video of each size: PySINDy's tuned weak form (``experiments/peers.weak_sindy_estimate``: time,
its traced peak memory, its diffusivity) and the exact spectral Problem-1 fit (``spectral_fit``: time to its
optimum and its error against ANRA's). Also: the streaming estimator's time per 382 x 288 frame on one
thread, and the peak RSS of :func:`anra_torch.estimation.estimate_long` on a 1k- and a 10k-frame ``.npy``
video (128 x 128 px, float32, read chunk by chunk).

Every measurement runs in its own subprocess: peak memory is the rise of the process's peak resident set
(``VmHWM`` after resetting it through ``/proc/self/clear_refs``) over its resident set before the run, on
the first (cold) run; time is the best of ``--repeats`` further runs. The machine may be shared: ratios
measured in the same run are what count, absolute numbers move with the load.

Run::

    .venv/bin/python -m benchmarks.bench_scale --out results/bench          # ~10-20 min, one thread
    .venv/bin/python -m benchmarks.bench_scale --quick --out results/bench  # sizes 1, 8; no 10k video

Writes ``bench.json`` (every measurement) and ``bench.md`` (tables and ratios) to ``--out``.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments.peers import spectral_fit, weak_sindy_estimate

FPS, FRAMES, NOISE, A_TRUE = 27.0, 28, 0.01, 0.2
SIZES = {"224x224": (224, 224), "382x288": (288, 382)}


# ----------------------------------------------------------------------------------------- memory
def _status(key: str) -> float:
    """A /proc/self/status entry in MiB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    return math.nan


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


class _Peak:
    """Peak resident memory (MiB) above the resident set at entry."""

    def __enter__(self) -> _Peak:
        gc.collect()
        self.reset = _reset_peak()
        self.before = _status("VmRSS")
        self.mb = math.nan
        return self

    def __exit__(self, *exc: object) -> None:
        if self.reset:
            self.mb = _status("VmHWM") - self.before


# ------------------------------------------------------------------------------------------- data
def make_videos(size: str, batch: int, seed: int = 0) -> tuple[np.ndarray, float, float]:
    """``batch`` noisy videos ``(B, 28, H, W)`` float32 of the paper's Gaussian (a = 0.2 mm^2/s, 27 Hz).

    224 x 224: :func:`anra_torch.simulation.paper_video`; 382 x 288: the same Gaussian (peak 3.8, FWHM 50 px,
    dx = 10/224 mm) at the centre of the wider frame, exact solution plus noise sd 0.01.
    """
    import torch

    from anra_torch.simulation import gaussian_blob
    from anra_torch.simulation.synthetic import paper_video

    h, w = SIZES[size]
    if size == "224x224":
        video = paper_video(n_videos=batch, seed=seed)
        return video.frames.numpy().astype(np.float32), video.dt, video.dx
    dx = 10.0 / 224
    times = torch.arange(FRAMES, dtype=torch.float64) / FPS
    sigma = 50 / (2 * math.sqrt(2 * math.log(2))) * dx
    clean = gaussian_blob(times, shape=(h, w), dx=dx, a=A_TRUE, peak=3.8, sigma=sigma)
    rng = torch.Generator().manual_seed(seed)
    noise = torch.randn((batch, FRAMES, h, w), generator=rng, dtype=torch.float64) * NOISE
    return (clean + noise).numpy().astype(np.float32), 1 / FPS, dx


# --------------------------------------------------------------------------- NumPy, same estimator
def same_estimate_taps(sigma: float = 4.0) -> dict[str, np.ndarray]:
    """The filters of ``ANRAEstimator(smoothing=sigma)`` as NumPy arrays: time derivative ``taps`` and its
    average ``pair``, Gaussian ``g``, one arm ``d2`` of the 5-point Laplacian cross (unit spacing)."""
    from anra_torch.layers.stencils import gaussian_taps, laplacian_kernel, time_stencil

    stencil = time_stencil("smooth", 5)
    d2 = laplacian_kernel(5, "central").numpy()[2].copy()  # the cross's horizontal arm
    d2[2] /= 2  # its centre holds both arms' centre taps
    taps, pair, g = stencil.taps.numpy(), stencil.pair.numpy(), gaussian_taps(sigma).numpy()
    return {"taps": taps, "pair": pair, "g": g, "d2": d2}


def numpy_same_estimate(
    frames: np.ndarray, dt: float, dx: float, sigma: float = 4.0, filters: dict[str, np.ndarray] | None = None
) -> float:
    """``ANRAEstimator(smoothing=sigma)``'s diffusivity in NumPy/SciPy for one video ``(T, H, W)``.

    Same filters and errors-in-variables correction; no standard error, no masking (finite input).
    ``filters``: :func:`same_estimate_taps` made beforehand (then NumPy and SciPy are all it imports).
    """
    import scipy.ndimage as ndi

    filters = same_estimate_taps(sigma) if filters is None else filters
    taps, pair, g, d2 = (filters[k] for k in ("taps", "pair", "g", "d2"))
    r = (g.size - 1) // 2
    x = frames - frames.mean(dtype=np.float64).astype(frames.dtype)
    # noise: median absolute fourth difference along t, y, x; median of the three (anra_torch.balance.noise)
    fourth = np.array([1.0, -4.0, 6.0, -4.0, 1.0], dtype=x.dtype)
    sds = []
    for axis in range(3):
        n = x.shape[axis] - 4
        diff = sum(c * np.take(x, range(i, i + n), axis=axis) for i, c in enumerate(fourth))
        sds.append(np.median(np.abs(diff)) / 0.6744897501960817 / math.sqrt(70.0))
    noise = float(np.median(sds))
    k = x.shape[0] - 4
    rate = sum(t * x[i : i + k] for i, t in enumerate(taps) if t != 0) / np.float32(dt)
    avg = sum(p * x[i : i + k] for i, p in enumerate(pair) if p != 0)

    def smooth(u: np.ndarray) -> np.ndarray:
        u = ndi.correlate1d(u, g, axis=1, mode="constant")[:, r:-r]
        return ndi.correlate1d(u, g, axis=2, mode="constant")[:, :, r:-r]

    rate_s, avg_s = smooth(rate)[:, 2:-2, 2:-2], smooth(avg)
    lap = ndi.correlate1d(avg_s, d2, axis=1, mode="constant") + ndi.correlate1d(
        avg_s, d2, axis=2, mode="constant"
    )
    lap = lap[:, 2:-2, 2:-2] / np.float32(dx * dx)
    m_ul = np.einsum("kij,kij->k", rate_s, lap, dtype=np.float64) / lap[0].size
    m_ll = np.einsum("kij,kij->k", lap, lap, dtype=np.float64) / lap[0].size
    # noise gains of the composite filters (unit spacing), as the estimator computes them
    g2 = np.outer(g, g)
    lap2 = np.zeros((5, 5))
    lap2[2] += d2
    lap2[:, 2] += d2
    from scipy.signal import convolve2d

    lap_g = convolve2d(g2, lap2[::-1, ::-1])
    part_g = convolve2d(g2, np.pad([[1.0]], 2)[::-1, ::-1])
    var = noise**2 * float((pair**2).sum()) * float((lap_g**2).sum()) / dx**4
    cov = noise**2 * float((taps * pair).sum()) * float((lap_g * part_g).sum()) / (dt * dx**2)
    return float((m_ul.sum() - k * cov) / (m_ll.sum() - k * var))


# ------------------------------------------------------------------------------------ one measurement
def _timed(fn, repeats: int) -> tuple[float, object, float]:
    with _Peak() as peak:
        out = fn()
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out, peak.mb


def measure(spec: dict) -> dict:
    """Run one measurement (in this process) and return its record."""
    import torch

    torch.set_num_threads(spec["threads"])
    kind, repeats = spec["kind"], spec["repeats"]
    if kind == "long":
        return _measure_long(spec)
    if kind == "stream":
        return _measure_stream(spec)
    frames, dt, dx = make_videos(spec["size"], spec["batch"])
    record = dict(spec)
    if kind.startswith("anra"):
        from anra_torch.estimation.estimator import ANRAEstimator

        est = ANRAEstimator(smoothing=4.0) if kind == "anra[sigma=4]" else ANRAEstimator()
        x = torch.from_numpy(frames)
        seconds, result, peak = _timed(lambda: est(x, dt, dx), repeats)
        values = result.diffusivity.double().numpy()
    elif kind == "numpy[sigma=4]":
        seconds, values, peak = _timed(
            lambda: np.array([numpy_same_estimate(f, dt, dx) for f in frames]), repeats
        )
        from anra_torch.estimation.estimator import ANRAEstimator

        anra = ANRAEstimator(smoothing=4.0)(torch.from_numpy(frames), dt, dx).diffusivity.double().numpy()
        record["max_rel_diff_vs_anra"] = float(np.max(np.abs(values - anra) / np.abs(anra)))
    elif kind == "read":
        x = torch.from_numpy(frames)
        seconds, total, peak = _timed(lambda: x.sum(), max(repeats, 5))
        values = np.array([math.nan])
    elif kind in ("weak_sindy", "spectral"):
        video = frames[0].astype(np.float64)
        fit = (
            (lambda: weak_sindy_estimate(video, dt, dx))
            if kind == "weak_sindy"
            else (lambda: spectral_fit(video, dt, dx))
        )
        result = fit()  # the peer times itself (fit only) and traces its own peak memory
        seconds, peak, values = result.seconds, result.peak_mb, np.array([result.diffusivity])
        record["note"] = result.note
        from anra_torch.estimation.estimator import ANRAEstimator

        record["anra_diffusivity"] = float(ANRAEstimator()(torch.from_numpy(frames[0]), dt, dx).diffusivity)
    else:
        raise ValueError(f"unknown kind {kind!r}")
    n_frames = (
        frames.shape[0] * frames.shape[1] if kind not in ("weak_sindy", "spectral") else frames.shape[1]
    )
    record.update(
        seconds=seconds,
        frames_per_s=n_frames / seconds,
        peak_mb=peak,
        diffusivity_mean=float(np.mean(values)),
        abs_error_mean=float(np.mean(np.abs(values - A_TRUE))),
    )
    return record


def _measure_stream(spec: dict) -> dict:
    import torch

    from anra_torch.estimation.streaming import StreamingEstimator

    h, w = SIZES["382x288"]
    frames = torch.randn(spec["frames"], h, w, generator=torch.Generator().manual_seed(0))
    stream = StreamingEstimator(dt=1 / FPS, dx=10 / 224, noise_sd=NOISE)
    for frame in frames[:20]:  # warm-up (ring buffer full, kernels cached)
        stream.push(frame)
    times = []
    for frame in frames[20:]:
        t0 = time.perf_counter()
        stream.push(frame)
        times.append(time.perf_counter() - t0)
    ms = np.array(times) * 1e3
    return dict(
        spec, ms_median=float(np.median(ms)), ms_p95=float(np.percentile(ms, 95)), ms_mean=float(ms.mean())
    )


def write_long_video(path: Path, n_frames: int, *, size: int = 128, chunk: int = 500) -> tuple[float, float]:
    """A diffusing Gaussian (a = 0.02 mm^2/s, dx 0.1 mm, 27 Hz) plus noise 0.01 as a float32 .npy, chunked."""
    import torch

    from anra_torch.simulation import gaussian_blob

    dt, dx = 1 / FPS, 0.1
    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(n_frames, size, size))
    rng = torch.Generator().manual_seed(1)
    for start in range(0, n_frames, chunk):
        times = torch.arange(start, min(start + chunk, n_frames), dtype=torch.float64) * dt
        clean = gaussian_blob(times, shape=(size, size), dx=dx, a=0.02, peak=5.0, sigma=1.0)
        out[start : start + len(times)] = (
            clean + NOISE * torch.randn(clean.shape, generator=rng, dtype=torch.float64)
        ).numpy()
    out.flush()
    del out
    return dt, dx


def _measure_long(spec: dict) -> dict:
    from anra_torch.estimation.streaming import NpyFrames, estimate_long

    frames = NpyFrames(spec["path"])
    baseline = _status("VmRSS")
    t0 = time.perf_counter()
    with _Peak() as peak_run:
        est = estimate_long(frames, spec["dt"], spec["dx"], chunk=spec["chunk"])
    seconds = time.perf_counter() - t0
    peak = _status("VmHWM")  # peak resident set since the reset at the start of the run
    return dict(
        spec,
        seconds=seconds,
        frames_per_s=frames.shape[0] / seconds,
        peak_rss_mb=peak,
        rss_before_mb=baseline,
        peak_above_start_mb=peak_run.mb,
        diffusivity=est.diffusivity,
    )


def _spawn(spec: dict) -> dict:
    done = subprocess.run(
        [sys.executable, __file__, "--worker", json.dumps(spec)], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        return dict(spec, failed=done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "failed")
    return json.loads(done.stdout.strip().splitlines()[-1])


# -------------------------------------------------------------------------------------------- report
def _fmt(value: float, digits: int = 3) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}g}"


def report(records: list[dict], args: argparse.Namespace) -> str:
    lines = [
        "# Throughput and memory benchmark",
        "",
        f"`{' '.join(['python', *sys.argv])}`; torch threads {args.threads}; float32; 28-frame videos "
        f"(27 Hz, a = {A_TRUE} mm^2/s, noise 0.01). The machine was shared with other jobs: ratios "
        "measured in "
        "this same run are what count.",
        "",
        "| size | batch | method | frames/s | s per call | peak MB | mean a | mean abs error |",
        "|---|---|---|---|---|---|---|---|",
    ]
    table = [
        r
        for r in records
        if r["kind"] in ("anra[auto]", "anra[sigma=4]", "numpy[sigma=4]", "read", "weak_sindy", "spectral")
    ]
    for r in table:
        if "failed" in r:
            lines.append(
                f"| {r['size']} | {r.get('batch', 1)} | {r['kind']} | failed: {r['failed']} | | | | |"
            )
            continue
        lines.append(
            f"| {r['size']} | {r.get('batch', 1)} | {r['kind']} | {_fmt(r['frames_per_s'], 4)} | "
            f"{_fmt(r['seconds'])} | "
            f"{_fmt(r['peak_mb'])} | {_fmt(r['diffusivity_mean'], 5)} | {_fmt(r['abs_error_mean'])} |"
        )
    lines += ["", "## Ratios (frames/s of ANRA over the other, same size; ANRA at its largest batch)", ""]
    lines += ["| size | ratio | value |", "|---|---|---|"]
    for size in SIZES:
        get = {
            (r["kind"], r.get("batch", 1)): r for r in records if r.get("size") == size and "failed" not in r
        }
        batches = sorted(b for k, b in get if k == "anra[auto]")
        if not batches:
            continue
        big = batches[-1]
        auto, fixed = get[("anra[auto]", big)], get.get(("anra[sigma=4]", big))
        pairs = [
            (
                f"anra[sigma=4] B={big} / numpy[sigma=4] (same estimator)",
                fixed,
                get.get(("numpy[sigma=4]", big)),
            ),
            (f"anra[auto] B={big} / numpy[sigma=4]", auto, get.get(("numpy[sigma=4]", big))),
            (f"anra[auto] B={big} / spectral fit", auto, get.get(("spectral", 1))),
            (f"anra[auto] B={big} / weak SINDy (tuned)", auto, get.get(("weak_sindy", 1))),
            (f"read pass x.sum() / anra[auto] B={big}", get.get(("read", big)), auto),
            (f"read pass x.sum() / anra[sigma=4] B={big}", get.get(("read", big)), fixed),
        ]
        for name, top, bottom in pairs:
            if top and bottom:
                lines.append(f"| {size} | {name} | {top['frames_per_s'] / bottom['frames_per_s']:.3g} |")
        numpy_rec = get.get(("numpy[sigma=4]", big))
        if numpy_rec:
            lines.append(
                f"| {size} | max relative difference numpy vs anra a (sigma=4) | "
                f"{numpy_rec['max_rel_diff_vs_anra']:.2g} |"
            )
        for peer in ("spectral", "weak_sindy"):
            rec = get.get((peer, 1))
            if rec:
                lines.append(
                    f"| {size} | {peer}: a = {_fmt(rec['diffusivity_mean'], 5)} "
                    f"(error {_fmt(rec['abs_error_mean'])}) vs anra[auto] a = "
                    f"{_fmt(rec['anra_diffusivity'], 5)} "
                    f"(error {_fmt(abs(rec['anra_diffusivity'] - A_TRUE))}) "
                    "on the same video | |"
                )
    stream = [r for r in records if r["kind"] == "stream"]
    if stream:
        s = stream[0]
        lines += ["", "## Streaming (one thread, 382 x 288 float32, sigma 4 px)", ""]
        lines.append(
            f"{_fmt(s.get('ms_median'))} ms per frame median, {_fmt(s.get('ms_p95'))} ms 95th percentile, "
            f"over {s['frames'] - 20} frames (target <= 5 ms)."
        )
    long = [r for r in records if r["kind"] == "long"]
    if long:
        lines += ["", "## Long videos (estimate_long, chunks of 64 frames, 128 x 128 float32 .npy)", ""]
        lines += [
            "| frames | peak RSS MB | RSS before MB | peak above start MB | s | a |",
            "|---|---|---|---|---|---|",
        ]
        for r in long:
            lines.append(
                f"| {r['frames']} | {_fmt(r.get('peak_rss_mb'), 4)} | {_fmt(r.get('rss_before_mb'), 4)} | "
                f"{_fmt(r.get('peak_above_start_mb'), 3)} | {_fmt(r.get('seconds'))} | "
                f"{_fmt(r.get('diffusivity'), 4)} |"
            )
        if len(long) == 2 and all("peak_rss_mb" in r for r in long):
            lines.append("")
            lines.append(
                f"Peak RSS ratio {long[1]['frames']} / {long[0]['frames']} frames: "
                f"{long[1]['peak_rss_mb'] / long[0]['peak_rss_mb']:.3f} (target <= 1.5)."
            )
    return "\n".join(lines) + "\n"


def _diagnose_seconds(path: Path, threads: list[str], busy: bool) -> float:
    """Wall time of ``anra diagnose PATH`` in a fresh process, beside a CPU-bound spinner when ``busy``."""
    spinner = None
    if busy:  # one other CPU-bound process, started first so it is running when the command starts
        spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        time.sleep(2.0)
    try:
        tick = time.perf_counter()
        anra = [sys.executable, "-c", "import sys; from anra_torch.cli import main; sys.exit(main())"]
        subprocess.run([*anra, *threads, "diagnose", str(path)], check=True, capture_output=True)
        return time.perf_counter() - tick
    finally:
        if spinner is not None:
            spinner.kill()
            spinner.wait()


def shared_machine(out: Path, repeats: int) -> dict:
    """``anra diagnose`` of a 128 x 128 x 81 video (one hidden advection): idle with the default threads,
    and beside one CPU-bound process with the default threads and with every core (the old default).
    Each the median of ``repeats`` runs; the ratios to the idle time are what count."""
    import os

    from anra_torch.effects import hidden_effect_video

    path = hidden_effect_video(["advection"], seed=0, size=128, duration=81 / 30).to_npz(out / "shared.npz")
    cores = ["--threads", str(os.cpu_count() or 1)]
    cases = {"idle, default": ([], False), "busy, default": ([], True), "busy, all cores": (cores, True)}
    seconds = {
        name: float(np.median([_diagnose_seconds(path, threads, busy) for _ in range(repeats)]))
        for name, (threads, busy) in cases.items()
    }
    path.unlink()
    idle = seconds["idle, default"]
    return {"seconds": seconds, "ratio_to_idle": {k: v / idle for k, v in seconds.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="results/bench", help="output folder (bench.json, bench.md)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per measurement (default 1)")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs after the cold one (best kept)")
    parser.add_argument(
        "--quick", action="store_true", help="batches 1 and 8 only, long video 1k and 2k frames"
    )
    parser.add_argument(
        "--shared",
        action="store_true",
        help="only the shared-machine case: anra diagnose idle and beside one CPU-bound process",
    )
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(measure(json.loads(args.worker))))
        return
    if args.shared:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        result = shared_machine(out, max(args.repeats, 1))
        (out / "shared.json").write_text(json.dumps(result, indent=1))
        for name, secs in result["seconds"].items():
            print(f"anra diagnose, {name}: {secs:.1f} s ({result['ratio_to_idle'][name]:.2f}x idle)")
        return
    from tqdm.auto import tqdm

    batches = (1, 8) if args.quick else (1, 8, 32)
    specs = []
    for size in SIZES:
        for batch in batches:
            for kind in ("anra[auto]", "anra[sigma=4]", "numpy[sigma=4]", "read"):
                repeats = args.repeats if batch < 32 else 1
                specs.append(
                    {"kind": kind, "size": size, "batch": batch, "threads": args.threads, "repeats": repeats}
                )
        for kind in ("spectral", "weak_sindy"):
            specs.append({"kind": kind, "size": size, "batch": 1, "threads": args.threads, "repeats": 0})
    specs.append({"kind": "stream", "frames": 220, "threads": 1, "repeats": 0})
    records = []
    with tempfile.TemporaryDirectory() as scratch:
        lengths = (1000, 2000) if args.quick else (1000, 10000)
        for n in lengths:
            path = Path(scratch) / f"long_{n}.npy"
            dt, dx = write_long_video(path, n)
            specs.append(
                {
                    "kind": "long",
                    "frames": n,
                    "path": str(path),
                    "dt": dt,
                    "dx": dx,
                    "chunk": 64,
                    "threads": args.threads,
                    "repeats": 0,
                }
            )
        for spec in tqdm(specs, desc="bench", unit="measurement"):
            records.append(_spawn(spec))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps(records, indent=1))
    (out / "bench.md").write_text(report(records, args))
    print((out / "bench.md").read_text())


if __name__ == "__main__":
    main()
