"""The whole pipeline on measured thermography (../shared/data), through the library's defaults.

A thin loop: every recording is read the way ``anra diagnose`` reads it (``prepare_video``: non-uniform
timestamps resampled onto their median step and stated; the CSV exports calibrated with their
``calibration_og.csv``, as ``--calibration`` would), then :func:`anra_torch.forecast.diagnose_recording`,
the CLI's own default, does everything else: the phases (baseline / heating / cooling from the data), the
model family per phase (the balance where its filters fit; the small-box models in 9-15 px boxes), the
extension chosen on splits inside the fit frames, the held-out gain. No rule here depends on the recording
or the phase. The diffusivity per phase is ``anra estimate``'s (ANRA where the filters fit; the small-box
plain fit, or "unresolved" with its bound, elsewhere). Beside it, for the balance family: the plain
balance fit of ``anra diagnose`` over the phase's fit frames (its phase ``base.diffusivity``), and where
effects were named the extended model's own coefficient of ``Lap T`` (``a_extended``; outside a named
disc, ``a_outside``), which says whether the extended model still describes lateral conduction.

Unknown spacings are passed as a user would pass ``--dx``/``--dt``: laser runs 0.55 mm/px (interval
0.5-0.6 mm from the C3-X field of view at ~10 cm, carried into an interval on ``a``, which scales as
``dx^2``); CSV exports 0.1 s and 0.25 mm (the source's assumptions: every diffusivity from them is
conditional on them).

Outputs in --out (default results/real_data): table.md, results.json, one Fig.-3-style PNG per recording
and phase (measured, plain forecast and its deviation, extended forecast and its deviation, at the last
held-out frame) and the hot-spot signal with its phases per recording.

    python -m experiments.real_data                      # all recordings (a few minutes on 2 cores)
    python -m experiments.real_data --quick              # one laser run and one CSV file
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import torch

from anra_torch.estimation.estimator import ANRAEstimator
from anra_torch.recording import PhaseDiagnosis, diagnose_recording
from anra_torch.report.phases import forecast_figure, timeline_figure
from anra_torch.video import Video
from tests.shared_data import CSV_DT, CSV_DX, DATA, LASER_DX, load  # the tests read the files the same way

PDMS = (0.10, 0.15)  # mm^2/s, literature

CAUSES = {
    "source": "heat source while it is on (laser / heated spot)",
    "linear_loss": "heat loss into the deep liquid / sample and to the air",
    "advection": "flow or drift of the hot region",
    "anisotropy": "direction-dependent spreading",
    "heterogeneity": "a region that conducts differently",
    "nonlinear_diffusion": "temperature-dependent diffusivity",
}


# ------------------------------------------------------------------------------------------------ main
def recordings(quick: bool) -> list[tuple[str, Path]]:
    laser = DATA / "laser_silicone"
    runs = [("Nov19", laser / "Nov19"), ("Nov19_2", laser / "Nov19_2")]
    runs += [(p.stem, p) for p in sorted((DATA / "flir_csv").glob("* *.csv"))]
    return [runs[0], runs[2]] if quick else runs


def phase_row(video: Video, found: PhaseDiagnosis) -> dict[str, Any]:
    """One phase: the library's record, plus ``anra estimate``'s diffusivity where the filters fit."""
    record = found.to_record()
    record["frames"] = found.phase.frames
    if found.family == "balance":
        part = video.frames[found.phase.start : found.phase.stop]
        est = ANRAEstimator(strict=False)(part, video.dt, video.dx)
        a = float(est.diffusivity)
        record["a_anra"] = a if math.isfinite(a) else None
        record["a_anra_interval"] = list(LASER_DX.diffusivity_interval(a)) if math.isfinite(a) else None
        if found.result is not None and found.effects:
            record["a_extended"] = float(found.result.diagnosis.base)
    names = [e["name"] for e in record["effects"]]
    record["cause"] = CAUSES.get(names[0], names[0]) if names else "none found"
    return record


def run(out: Path, quick: bool) -> dict[str, Any]:
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = {"pixel_size_laser_mm": vars(LASER_DX), "csv_dt_s": CSV_DT, "csv_dx_mm": CSV_DX}
    rows = []
    for name, path in tqdm(recordings(quick), desc="recordings", file=sys.stderr):
        record: dict[str, Any] = {"path": str(path)}
        results[name] = record
        tick = time.perf_counter()
        try:
            video = load(path)
        except (ValueError, OSError) as err:  # a bad recording never stops the others
            record["error"] = str(err)
            continue
        record.update(
            frames=int(video.frames.shape[0]),
            shape=list(video.frames.shape[1:]),
            dt_s=video.dt,
            dx_mm=video.dx,
            resampled=video.meta.get("resampled"),
            calibration=video.meta.get("calibration"),
        )
        found = diagnose_recording(
            video.frames, video.dt, video.dx, video.t, measured_t=video.meta.get("measured_t")
        )
        timeline_figure(out / f"{name}_phases.png".replace(" ", "_"), name, video, [f.phase for f in found])
        record["phases"] = []
        for phase in found:
            row = phase_row(video, phase)
            record["phases"].append(row)
            if phase.forecasts is not None:
                f = phase.forecasts
                figure = tuple(f[k].numpy() for k in ("measured", "plain", "extended"))
                after = f["measured"].shape[0] * video.dt
                png = out / f"{name}_{phase.phase.name}.png".replace(" ", "_")
                title = (
                    f"{name} {phase.phase.name} ({phase.family}; {phase.model}): {after:.1f} s after split"
                )
                forecast_figure(png, title, figure, video.unit)
            rows.append((name, row))
        record["seconds"] = time.perf_counter() - tick
    (out / "results.json").write_text(json.dumps(results, indent=1, default=float))
    (out / "table.md").write_text(table(rows))
    return results


def _f(x: Any, spec: str = ".3g") -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def _diffusivity(row: dict[str, Any]) -> str:
    base = row["base"]
    if "a_anra" in row:
        lo, hi = row["a_anra_interval"] or (None, None)
        plain = f"ANRA {_f(row['a_anra'])} [{_f(lo)}, {_f(hi)}] for dx 0.5-0.6 mm"
        if base.get("diffusivity") is not None:
            plain += f"; diagnose's plain fit {_f(base['diffusivity'])}"
        if row.get("a_extended") is not None:
            plain += f"; extended model {_f(row['a_extended'])}"
        return plain
    if base.get("diffusivity_lower_bound") is not None:
        return f"unresolved: > {_f(base['diffusivity_lower_bound'])}"
    se = f" +- {_f(base['std_error'], '.2g')}" if base.get("std_error") is not None else ""
    flags = f" ({', '.join(base['flags'])})" if base.get("flags") else ""
    return f"small box {_f(base['diffusivity'])}{se}{flags}"


def table(rows: list) -> str:
    lines = [
        "| recording | phase | frames (t) | family; extension chosen | a (mm^2/s) | causes named "
        "| RMSE plain | RMSE extended | gain | other candidate's gain | noise floor |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows:
        where = f"{r['frames']} ({r['t_start']:.0f}-{r['t_stop']:.0f} s)"
        if not r["analysed"]:
            lines.append(f"| {name} | {r['kind']} | {where} | not analysed: {r['reason']} | | | | | | | |")
            continue
        others = ", ".join(
            f"{k} {_f(c['gain'], '+.2f')}" for k, c in r["candidates"].items() if k != r["model"]
        )
        lines.append(
            f"| {name} | {r['kind']} | {where} | {r['family']}; {r['model']} | {_diffusivity(r)} | "
            f"{', '.join(e['name'] for e in r['effects']) or 'none'} | {_f(r['base']['prediction_rmse'])} | "
            f"{_f(r['extended_rmse'])} | {_f(r['gain'], '+.2f')} | {others or 'n/a'} | "
            f"{_f(r['noise_floor'])} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/real_data", help="output directory")
    parser.add_argument("--quick", action="store_true", help="one laser run and one CSV file")
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        print(f"real_data: {DATA} not found (the measured data live beside the checkout)", file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    run(Path(args.out), args.quick)
    print((Path(args.out) / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
