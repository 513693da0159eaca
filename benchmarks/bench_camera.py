"""Camera-scale recordings: time and peak memory of ``anra estimate`` and ``anra diagnose`` on 640 x 512 px
videos, from the CLI.

A Gaussian spot diffusing at a = 0.2 mm^2/s (dx = 0.1 mm, 30 Hz, noise sd 0.01 K), float32, written as
``.npy`` files of 900 frames (1.2 GB, 30 s of a 30 Hz camera) and, with ``--long``, 9000 frames (11.8 GB).
The spot diffuses with no other effect, so ``anra diagnose`` should name none.
Each command runs in its own process, started from a parent that stays small (Linux hands a forked child
its parent's peak); its wall time and peak resident set (``wait4``'s ``ru_maxrss``) are recorded. In the
same run, as the peer, the whole-video estimator (every frame and term in memory at once, what ``anra
estimate`` did before it read in chunks) on the first 120 frames of the same recording: its time and memory
per frame against the chunked run's.

Run::

    .venv/bin/python -m benchmarks.bench_camera --out results/camera          # ~2 min (+ ~6 min with --long)

Writes ``camera.json`` and ``camera.md`` to ``--out``; the recordings go to a temporary folder (or
``--data``) and are deleted unless ``--keep``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FPS, DX, NOISE, A_TRUE, SHAPE = 30.0, 0.1, 0.01, 0.2, (512, 640)


def write_recording(path: Path, frames: int, *, block: int = 100) -> None:
    """A ``(frames, 512, 640)`` float32 ``.npy`` written block by block (never whole in memory)."""
    import torch
    from numpy.lib.format import open_memmap

    from anra_torch.simulation import gaussian_blob

    out = open_memmap(path, mode="w+", dtype=np.float32, shape=(frames, *SHAPE))
    rng = np.random.default_rng(0)
    for start in range(0, frames, block):
        stop = min(frames, start + block)
        t = torch.arange(start, stop, dtype=torch.float64) / FPS
        clean = gaussian_blob(t, shape=SHAPE, dx=DX, a=A_TRUE, peak=3.8, sigma=2.0).numpy()
        out[start:stop] = clean + NOISE * rng.standard_normal(clean.shape)
    out.flush()
    del out


def run(argv: list[str]) -> dict:
    """Run a command; its wall time (s), peak resident set (MiB), exit code and stdout."""
    start = time.perf_counter()
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - start
    out, err = process.stdout.read(), process.stderr.read()
    return {
        "argv": argv[1:],
        "seconds": round(seconds, 2),
        "peak_mib": round(usage.ru_maxrss / 1024, 1),
        "code": os.waitstatus_to_exitcode(status),
        "stdout": out,
        "stderr": err[-2000:],
    }


_WHOLE = """
import sys, numpy as np, torch
from anra_torch.estimation.estimator import ANRAEstimator
frames = torch.from_numpy(np.load(sys.argv[1], mmap_mode="r")[: int(sys.argv[2])].copy())
result = ANRAEstimator()(frames, 1 / 30, 0.1)
print(float(result.diffusivity), float(result.std_error))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="results/camera", help="output folder (camera.json, camera.md)")
    parser.add_argument("--data", help="folder for the recordings (default a temporary one)")
    parser.add_argument("--long", action="store_true", help="also the 9000-frame (11.8 GB) recording")
    parser.add_argument("--keep", action="store_true", help="keep the recordings")
    parser.add_argument("--write", nargs=2, metavar=("PATH", "FRAMES"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.write:
        write_recording(Path(args.write[0]), int(args.write[1]))
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = Path(args.data) if args.data else Path(tempfile.mkdtemp(prefix="anra_camera_"))
    data.mkdir(parents=True, exist_ok=True)
    anra = str(Path(sys.executable).with_name("anra"))
    records = []
    try:
        for frames in (900, 9000) if args.long else (900,):
            path = data / f"camera_{frames}.npy"
            if not path.exists():  # in a child: a parent grown by the writing would hand its peak on
                print(f"writing {path} ...", flush=True)
                subprocess.run([sys.executable, __file__, "--write", str(path), str(frames)], check=True)
            spacing = ["--dt", repr(1 / FPS), "--dx", repr(DX), "--json"]
            for command in ("estimate", "diagnose"):
                record = run([anra, command, str(path), *spacing])
                summary = json.loads(record.pop("stdout")) if record["code"] == 0 else {}
                record.update(what=f"anra {command}, 640 x 512 x {frames}", frames=frames)
                if command == "estimate":
                    record.update(
                        diffusivity=summary.get("diffusivity"),
                        std_error=summary.get("std_error"),
                        chunked=summary.get("chunked"),
                    )
                else:
                    record.update(
                        diffusivity=summary.get("base", {}).get("diffusivity"),
                        std_error=None,
                        effects=[e["name"] for e in summary.get("effects", [])],
                        negligible=[e["name"] for e in summary.get("negligible", [])],
                        copy=summary.get("input", {}).get("decimated"),
                    )
                records.append(record)
                shown = ("what", "seconds", "peak_mib", "diffusivity")
                print(json.dumps({k: record[k] for k in shown}), flush=True)
        peer_frames = 120
        record = run([sys.executable, "-c", _WHOLE, str(data / "camera_900.npy"), str(peer_frames)])
        values = record.pop("stdout").split()
        record.update(
            what=f"whole-video estimator (in memory), 640 x 512 x {peer_frames}",
            frames=peer_frames,
            diffusivity=float(values[0]) if values else None,
            std_error=float(values[1]) if values else None,
        )
        records.append(record)
        print(json.dumps({k: record[k] for k in ("what", "seconds", "peak_mib", "diffusivity")}), flush=True)
    finally:
        if not args.keep and not args.data:
            shutil.rmtree(data, ignore_errors=True)
    (out / "camera.json").write_text(json.dumps(records, indent=1))
    (out / "camera.md").write_text(report(records))
    print(report(records))


def report(records: list[dict]) -> str:
    """The table, per-frame costs and the ratios against the whole-video peer."""
    lines = [
        "| what | time (s) | peak RSS (MiB) | ms per frame | a (mm^2/s) | std error |",
        "|---|---|---|---|---|---|",
    ]
    for r in records:
        a = "n/a" if r["diffusivity"] is None else f"{r['diffusivity']:.5f}"
        se = "n/a" if r["std_error"] is None else f"{r['std_error']:.2g}"
        per_frame = 1000 * r["seconds"] / r["frames"]
        lines.append(
            f"| {r['what']} | {r['seconds']:.1f} | {r['peak_mib']:.0f} | {per_frame:.1f} | {a} | {se} |"
        )
    chunked = [r for r in records if r["what"].startswith("anra estimate")]
    peer = records[-1]
    if chunked and peer["code"] == 0:
        first = chunked[0]
        speed = (peer["seconds"] / peer["frames"]) / (first["seconds"] / first["frames"])
        lines.append("")
        lines.append(
            f"Per frame, the chunked `anra estimate` is {speed:.1f}x as fast as the whole-video estimator "
            f"(same run), with {first['peak_mib'] / peer['peak_mib']:.2f}x its memory for "
            f"{first['frames'] / peer['frames']:.1f}x the frames."
        )
    if len(chunked) > 1:
        lines.append(
            f"10x the frames: {chunked[1]['seconds'] / chunked[0]['seconds']:.1f}x the time, "
            f"{chunked[1]['peak_mib'] / chunked[0]['peak_mib']:.2f}x the peak memory."
        )
    for r in records:
        if r["what"].startswith("anra diagnose") and r["code"] == 0 and r.get("copy"):
            c = r["copy"]
            where = (
                "the whole frame"
                if c["region"] is None
                else f"the region {c['region']} (x0, y0, width, height px)"
            )
            lines.append(
                f"{r['what']}: diagnosed on a copy averaged over {c['space_px']} x {c['space_px']} px and "
                f"{c['time_frames']} frames of {where}, {c['shape'][0]} frames of {c['shape'][1]} x "
                f"{c['shape'][2]} px; effects named: {', '.join(r['effects']) or 'none'} (truth: none); "
                f"negligible: {', '.join(r['negligible']) or 'none'}."
            )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
