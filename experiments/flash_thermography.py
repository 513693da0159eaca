"""Flash thermography of composite plates: what ``anra estimate`` and ``anra diagnose`` say, by default.

Each case is an independent 3-D simulation (:func:`anra_torch.simulation.flash_plate_video`: lateral
heat flow exact per Fourier mode, finite volumes through the thickness, nothing shared with the diagnosis):
an anisotropic plate (lateral 7.3 and 1.1 mm^2/s, through-thickness 0.45 mm^2/s, 3 mm thick), 100 x 100 px
at 0.2 mm, 380 frames at 31 Hz, 20 mK noise; 3 mm and 2 mm thick, intact and with a delamination.
Both CLI commands run in this process with default settings, as a user would run them on the files.

Run: ``python -m experiments.flash_thermography [--out DIR]`` (about 10 minutes on 2 cores). It prints, per
case, the effects named in the phase with their own held-out gains and the parameters of
``depth_conduction``, and the estimate's diffusivity, its share of dT/dt explained and its flags; each
case's ``anra diagnose --report`` goes to ``DIR/caseN_report`` (README's figure: case 1's ``maps.png``).
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
from anra_torch.simulation.plate import FlashPlate, flash_plate_video

CASES: dict[str, FlashPlate] = {
    "intact 3 mm": FlashPlate(defect=None),
    "delamination 0.6 mm deep": FlashPlate(defect=(12.0, 9.0, 2.0, 0.6)),  # x, y, radius, depth in mm
    "intact 2 mm": FlashPlate(defect=None, thickness=2.0),
    "delamination 1.0 mm deep, 2 mm plate": FlashPlate(defect=(7.0, 12.0, 3.0, 1.0), thickness=2.0),
}
"""The plates (3 mm thick unless stated), for flash_plate_video."""


def _run(argv: list[str]) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        status = main(argv)
    if status != 0:
        return {"error": f"exit {status}"}
    return json.loads(out.getvalue())


def _describe(name: str, diagnosis: dict, estimate: dict, seconds: float) -> list[str]:
    lines = [f"{name}: diagnose and estimate in {seconds:.0f} s"]
    if "error" in diagnosis:
        return [*lines, f"  diagnose failed: {diagnosis['error']}"]
    for phase in diagnosis["phases"]:
        effects = ", ".join(
            f"{e['name']} (gain {e['gain']:.2f})" if e["gain"] is not None else e["name"]
            for e in phase["effects"]
        )
        gain = f"{phase['gain']:.2f}" if phase["gain"] is not None else "none"
        lines.append(
            f"  {phase['kind']} frames {phase['start_frame']}-{phase['stop_frame']}: a = "
            f"{phase['base']['diffusivity']:.3g} mm^2/s; {effects or 'no effect'}; extended gain {gain}"
        )
        for effect in phase["effects"]:
            if effect["name"] in ("depth_conduction", "delamination", "anisotropy"):
                params = ", ".join(f"{k} {v:.3g}" for k, v in effect["params"].items())
                lines.append(f"    {effect['name']}: {params}")
    if "error" in estimate:
        lines.append(f"  estimate failed: {estimate['error']}")
    else:
        lines.append(
            f"  estimate: a = {estimate['diffusivity']:.3g} mm^2/s, plain model explains "
            f"{100 * estimate['explained']:.0f} % of dT/dt; flags: {len(estimate['warnings'])}"
        )
    return lines


def run(out: Path) -> list[str]:
    """Simulate every case into ``out``, run both commands, and return the printed lines."""
    lines = []
    for index, (name, case) in enumerate(CASES.items()):
        frames, dt, dx = flash_plate_video(plate=case, seed=index + 1)
        path = out / f"case{index}.npz"
        np.savez(path, frames=frames.numpy(), dt=dt, dx=dx)
        start, start_line = time.perf_counter(), len(lines)
        diagnosis = _run(["diagnose", str(path), "--json", "--report", str(out / f"case{index}_report")])
        estimate = _run(["estimate", str(path), "--json"])
        lines += _describe(name, diagnosis, estimate, time.perf_counter() - start)
        print("\n".join(lines[start_line:]), flush=True)
    return lines


def cli() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=Path, default=None, help="folder for the simulated videos (default: temporary)"
    )
    args = parser.parse_args()
    if args.out is None:
        with tempfile.TemporaryDirectory() as folder:
            run(Path(folder))
    else:
        args.out.mkdir(parents=True, exist_ok=True)
        run(args.out)


if __name__ == "__main__":
    cli()
