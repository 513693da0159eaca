"""Folders of text-matrix frames taken 5-60 s apart: what ``anra diagnose`` and ``anra estimate`` say, by
default, on recordings made by an independent 3-D simulation.

The kind of recording: a laser heats a spot on a silicone composite block for 2.5-5 minutes, then it
cools; a hand-triggered camera takes a 96 x 128 px frame every 5-60 s (steps drawn from 5, 10, 15, 20,
30, 45 and 60 s) for 10 minutes; each frame is saved as a CSV matrix whose file name states its time
(``composite_0045.0s.csv``). The simulation shares no code with the package: explicit 3-D conduction
(``depth_references.conduct``; 0.5 mm cells, 24 layers, zero-flux sides and bottom) with the beam's
Gaussian flux into the top surface, convection (10 W/m^2/K) and radiation (emissivity 0.95) from it,
diffusivity drawn in the PDMS range 0.10-0.15 mm^2/s, beam power 0.3-0.8 W and sigma 1.5-3 mm, and 0.1 K
white camera noise.

Each recording goes through the CLI exactly as a user would run it, with only the pixel size:
``anra diagnose FOLDER --dx 0.5 --json --report OUT/report_caseN`` (its phase timeline and forecasts) and
``anra estimate FOLDER --dx 0.5 --json``. The table says per
phase: frames, causes named, held-out gain, and for the cooling the estimate's plain and depth-aware
diffusivities against the simulation's.

    python -m experiments.sparse_recordings --cases 8                     # about 7 minutes
    python -m experiments.sparse_recordings --cases 8 --schedule issue    # the issue's times, about 3 minutes
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from anra_torch.cli import main
from tests.depth_references import conduct  # the same explicit 3-D solver

H, W, DEPTH = 96, 128, 24
DX = 0.5  # mm, lateral and depth cells
CONVECTION = 10e-6  # W/(mm^2 K)
STEFAN = 5.67e-14  # W/(mm^2 K^4)
STEPS = (5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0)  # s between frames


SCHEDULES = ("random", "issue")
"""``random``: steps drawn from :data:`STEPS` over 10 minutes, the beam off after 150-300 s. ``issue``: the
times the issue names, 0, 5, 15, 20, 30 s and then every 30 s to 300 s, the beam off after 90-200 s."""


def simulate(seed: int, folder: Path, schedule: str = "random") -> dict[str, float]:
    """Write one recording into ``folder`` sampled on ``schedule``; returns what it was made with."""
    rng = np.random.default_rng(seed)
    a, off = rng.uniform(0.10, 0.15), rng.uniform(150.0, 300.0)
    if schedule == "issue":
        off = rng.uniform(90.0, 200.0)
    power, width = rng.uniform(0.3, 0.8), rng.uniform(1.5, 3.0)
    cy, cx = rng.uniform(35, 60), rng.uniform(45, 80)
    y, x = np.mgrid[:H, :W]
    r2 = ((x - cx) * DX) ** 2 + ((y - cy) * DX) ** 2
    flux = power / (2 * np.pi * width**2) * np.exp(-r2 / (2 * width**2))  # W/mm^2
    times = np.cumsum(np.concatenate([[0.0], rng.choice(STEPS, 60)]))
    times = times[times <= 600.0]
    if schedule == "issue":
        times = np.concatenate([[0.0, 5.0, 15.0, 20.0], np.arange(30.0, 301.0, 30.0)])

    def surface(top: np.ndarray, t: float) -> np.ndarray:  # W/mm^2 into the block
        radiated = 0.95 * STEFAN * ((top + 273.15) ** 4 - 295.15**4)
        return (flux if t < off else 0.0) - CONVECTION * (top - 22.0) - radiated

    u, now = np.full((DEPTH, H, W), 22.0), 0.0
    folder.mkdir(parents=True, exist_ok=True)
    for target in times:
        u, now = conduct(u, now, target, a, DX, surface), target
        frame = u[0] + rng.normal(0.0, 0.1, (H, W))
        np.savetxt(folder / f"composite_{target:06.1f}s.csv", frame, delimiter=",", fmt="%.3f")
    made = {"a": a, "off_s": off, "power_W": power, "width_mm": width}
    return {**made, "frames": len(times), "times": [float(x) for x in times]}


def run_cli(*argv: str) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = main(list(argv))
    return json.loads(out.getvalue()) if code == 0 else {"error": code}


def case(seed: int, root: Path, schedule: str = "random", report: Path | None = None) -> dict:
    """Simulate recording ``seed`` under ``root`` and run the CLI on it (its report into ``report``)."""
    folder = root / f"case{seed}"
    truth = simulate(seed, folder, schedule)
    start = time.perf_counter()
    extra = ("--report", str(report)) if report is not None else ()
    diagnosis = run_cli("diagnose", str(folder), "--dx", str(DX), "--json", *extra)
    estimate = run_cli("estimate", str(folder), "--dx", str(DX), "--json")
    phases = []
    for p in diagnosis.get("phases", []):
        candidates = p.get("candidates") or {}
        phases.append(
            {
                "kind": p["kind"],
                "frames": p["stop_frame"] - p["start_frame"],
                "samples": sum(p["t_start"] - 1e-6 <= t <= p["t_stop"] + 1e-6 for t in truth["times"]),
                "analysed": p.get("analysed"),
                "causes": [e["name"] for e in p.get("effects", [])],
                "model": p.get("model"),
                "gain": p.get("gain"),
                "others": {k: c["gain"] for k, c in candidates.items() if k != p.get("model")},
            }
        )
    depth = estimate.get("depth_aware") or {}
    return {
        "seed": seed,
        "truth": truth,
        "timestamps": (diagnosis.get("input") or {}).get("timestamps"),
        "phases": phases,
        "estimate": {
            "phase": estimate.get("phase"),
            "plain": estimate.get("diffusivity"),
            "explained": estimate.get("explained"),
            "depth_aware": depth.get("diffusivity"),
            "consistent": depth.get("consistent"),
        },
        "seconds": round(time.perf_counter() - start, 1),
    }


def _signed(gain: float | None) -> str:
    """A gain to 2 decimals; a candidate that could not be simulated has none (null in the JSON)."""
    return "not simulable" if gain is None else f"{gain:+.2f}"


def table(results: list[dict]) -> str:
    rows = [
        "| case | a (mm^2/s) | phase | frames (measured) | causes named | model | held-out gain | "
        "other candidates' gains | estimate: plain a | explained | depth-aware a |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        e = r["estimate"]
        for p in r["phases"]:
            gain = "-" if p["gain"] is None else f"{p['gain']:+.2f}"
            cooling = p["kind"] == e["phase"]
            plain = f"{e['plain']:.3g}" if cooling and e["plain"] is not None else ""
            explained = f"{100 * e['explained']:.0f} %" if cooling and e["explained"] is not None else ""
            depth = ""
            if cooling and e["depth_aware"] is not None:
                depth = f"{e['depth_aware']:.3g}" + ("" if e["consistent"] else " (inconsistent)")
            others = ", ".join(f"{k} {_signed(g)}" for k, g in p["others"].items()) or "-"
            rows.append(
                f"| {r['seed']} | {r['truth']['a']:.3f} | {p['kind']} | {p['frames']} ({p['samples']}) | "
                f"{', '.join(p['causes']) or '-'} | {p['model'] or '-'} | {gain} | {others} | {plain} | "
                f"{explained} | {depth} |"
            )
    return "\n".join(rows) + "\n"


SCHEDULES_HELP = "when frames are taken: random 5-60 s steps, or the issue's 0, 5, 15, 20, 30, 60 ... 300 s"


def main_experiment() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=6, help="recordings (seeds 0 .. cases - 1)")
    parser.add_argument("--out", type=Path, default=Path("results/sparse_recordings"))
    parser.add_argument("--schedule", choices=SCHEDULES, default="random", help=SCHEDULES_HELP)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    with tempfile.TemporaryDirectory() as root:
        for seed in range(args.cases):
            results.append(case(seed, Path(root), args.schedule, args.out / f"report_case{seed}"))
            print(json.dumps(results[-1]), flush=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    (args.out / "table.md").write_text(table(results))
    print(table(results))


if __name__ == "__main__":
    main_experiment()
