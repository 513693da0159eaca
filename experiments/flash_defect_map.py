"""The flash defect map through the CLI on plates from the independent simulator, against TSR, PCT and PPT.

Each plate is :func:`anra_torch.simulation.reference_plate_video` (finite volumes on an irregular mesh,
Crank-Nicolson, nothing shared with :mod:`anra_torch.flash`): anisotropic (lateral 7.3 and 1.1 mm^2/s,
through-thickness 0.45 mm^2/s unless stated), a non-uniform flash, 20 mK noise, 48 x 48 px at 0.4 mm,
300 frames. The plates vary what the map assumes: 1-5 mm thick, defects at depth fractions 0.2-0.8 (an
ellipse, a rotated rectangle, polygons, two defects on one plate, defects running out of the frame),
recordings that end before the back wall shows (``duration < L^2 / (pi a_z)``) and long after it, intact
plates, one isotropic plate with another ``a_z``. ``anra diagnose PLATE --json --maps MAPS`` runs on each
file as a user would run it.

Per plate: the ROC AUC of ``defect_score`` against the truth's defect pixels, and of TSR's second
derivative, PCT's components and PPT's phases, each at its best frame / component / frequency and sign
chosen with hindsight; the IoU of ``defect_mask``; on intact plates the share of the frame it covers; the
plate's ``L^2 / a_z`` error; each true defect's depth fraction against the found defect that overlaps it
most; what the diagnosis names (``depth_conduction``, ``delamination`` and where, effects with a gain
``<= 0`` or centred outside the frame) and which defects the map lists.

Run: ``python -m experiments.flash_defect_map [--map-only] [--held-out | --probes] [--no-layered] [--out DIR]
[--plates 1,2,...] [--noise-sd K]``; ``--noise-sd`` gives every plate's camera that noise (a noisier camera
than the plates' own);
``--held-out`` runs :data:`HELD_OUT` (20 plates that break more of the map's assumptions) instead,
``--probes`` :data:`PROBES` (plates 1 and 2 taken apart, one defect at a time); ``--no-layered`` runs the
diagnosis with ``--no-layered`` (its forecasts by the surface alone; by default, as ``anra diagnose --maps``,
through the plate's thickness). With
``--map-only`` (the map that ``--maps`` writes, without the diagnosis) about 6 minutes on a loaded 2-core
machine; with the diagnosis 17-57 s a plate (two runs side by side on a 2-core machine). A plate whose
result is in ``DIR`` is not run again. It prints one line per plate and the Markdown table of
docs/results/flash.md.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from anra_torch.cli import main
from anra_torch.flash import flash_maps
from anra_torch.simulation.plate_reference import Defect, PlateSetup, reference_plate_video
from anra_torch.video import load_video

SHAPE, DX, FRAMES = (48, 48), 0.4, 300


def _ellipse(x: float, y: float, a: float, b: float, depth: float, angle: float = 0.0) -> Defect:
    return Defect("ellipse", centre=(x, y), size=(a, b), depth=depth, angle=angle)


def _rectangle(x: float, y: float, a: float, b: float, depth: float, angle: float = 0.0) -> Defect:
    return Defect("rectangle", centre=(x, y), size=(a, b), depth=depth, angle=angle)


def _polygon(depth: float, *vertices: tuple[float, float]) -> Defect:
    return Defect("polygon", vertices=vertices, depth=depth)


def _equal_area_disc(polygon: Defect) -> Defect:
    """The disc of ``polygon``'s area at its centroid, at its depth (shoelace formulas)."""
    x, y = np.array(polygon.vertices).T
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = 0.5 * cross.sum()
    cx, cy = (
        ((x + np.roll(x, -1)) * cross).sum() / (6 * area),
        ((y + np.roll(y, -1)) * cross).sum() / (6 * area),
    )
    radius = math.sqrt(abs(area) / math.pi)
    return _ellipse(float(cx), float(cy), radius, radius, polygon.depth)


_TRIANGLE = _polygon(0.2, (3.0, 3.0), (10.0, 4.0), (5.0, 10.0))  # plate 1's shallow defect
_DEEP_ELLIPSE = _ellipse(14.0, 13.5, 3.5, 3.0, 0.8)  # plate 1's deep defect
_PLATE2 = dict(thickness=1.3, duration=3.8)
_PLATE2_ELLIPSE = dict(a=5.0, b=3.0, depth=0.87, angle=20.0)

PLATES: dict[str, dict] = {
    "1.0 mm, triangle d/L 0.2 + ellipse 0.8, to 1.8 L^2/a_z": dict(
        thickness=1.0, duration=4.0, defects=(_TRIANGLE, _DEEP_ELLIPSE)
    ),
    "1.3 mm, ellipse d/L 0.67 out of the frame": dict(
        **_PLATE2, defects=(_ellipse(17.5, 8.0, **_PLATE2_ELLIPSE),)
    ),
    "2.0 mm, rotated rectangle d/L 0.5": dict(
        thickness=2.0, duration=8.0, defects=(_rectangle(10.0, 9.5, 4.0, 2.5, 1.0, 30.0),)
    ),
    "2.5 mm, intact": dict(thickness=2.5, duration=14.0),
    "3.0 mm, ellipse d/L 0.3, ends before the back wall": dict(
        thickness=3.0, duration=5.0, defects=(_ellipse(9.0, 10.0, 4.0, 3.0, 0.9),)
    ),
    "3.8 mm, rectangle d/L 0.35": dict(
        thickness=3.8, duration=32.0, defects=(_rectangle(9.5, 8.0, 3.5, 2.5, 1.33),)
    ),
    "4.0 mm, intact, ends before the back wall": dict(thickness=4.0, duration=9.0),
    "5.0 mm, ellipse d/L 0.8": dict(
        thickness=5.0, duration=45.0, defects=(_ellipse(10.0, 10.0, 5.0, 4.0, 4.0),)
    ),
    "2.0 mm, corner disc d/L 0.25 out of the frame + rectangle 0.6": dict(
        thickness=2.0,
        duration=9.0,
        defects=(_ellipse(1.0, 1.5, 3.0, 3.0, 0.5), _rectangle(13.0, 13.0, 4.5, 3.0, 1.2)),
    ),
    "4.6 mm, intact": dict(thickness=4.6, duration=47.0),
    "3.0 mm isotropic (2, 2, 0.6), polygon d/L 0.7": dict(
        thickness=3.0,
        duration=20.0,
        diffusivity=(2.0, 2.0, 0.6),
        defects=(_polygon(2.1, (6.0, 5.0), (14.0, 6.0), (15.0, 13.0), (8.0, 15.0)),),
    ),
    "1.5 mm, intact, to 2.4 L^2/a_z": dict(thickness=1.5, duration=12.0),
}
"""The plates: :class:`PlateSetup`'s fields (48 x 48 px at 0.4 mm, 300 frames)."""


def _spot(x: float, y: float, width: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A flash 0.6 + 0.9 of a Gaussian of sd ``width`` mm at ``(x, y)`` mm (on the frame's edge, a corner)."""
    return lambda xs, ys: 0.6 + 0.9 * np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * width**2))


HELD_OUT: dict[str, dict] = {
    "2.5 mm, corner disc d/L 0.4 out of the frame": dict(
        thickness=2.5, duration=12.0, defects=(_ellipse(18.0, 17.5, 4.0, 4.0, 1.0),)
    ),
    "1.5 mm, rectangle at 45 deg d/L 0.6": dict(
        thickness=1.5, duration=5.0, defects=(_rectangle(9.0, 10.0, 3.0, 2.0, 0.9, 45.0),)
    ),
    "3.5 mm, ellipse d/L 0.5, ends before the back wall": dict(
        thickness=3.5, duration=6.0, defects=(_ellipse(10.0, 9.0, 4.0, 3.5, 1.75),)
    ),
    "4.0 mm, intact, to 1.4 L^2/a_z": dict(thickness=4.0, duration=40.0),
    "2.0 mm, polygon d/L 0.3 + ellipse 0.7": dict(
        thickness=2.0,
        duration=9.0,
        defects=(
            _polygon(0.6, (2.0, 12.0), (8.0, 11.0), (7.0, 17.0)),
            _ellipse(14.0, 6.0, 3.5, 2.5, 1.4, 30.0),
        ),
    ),
    "4.5 mm, ellipse d/L 0.6": dict(
        thickness=4.5, duration=50.0, defects=(_ellipse(9.5, 10.5, 4.5, 3.5, 2.7),)
    ),
    "3.0 mm, intact, ends before the back wall": dict(thickness=3.0, duration=4.0),
    "3.5 mm, small rectangle d/L 0.4": dict(
        thickness=3.5, duration=30.0, defects=(_rectangle(10.0, 9.0, 3.0, 2.0, 1.4, 15.0),)
    ),
    "4.0 mm, disc r 3 mm d/L 0.5": dict(
        thickness=4.0, duration=40.0, defects=(_ellipse(9.0, 10.0, 3.0, 3.0, 2.0),)
    ),
    "2.5 mm, long rectangle d/L 0.3 at 20 deg": dict(
        thickness=2.5, duration=14.0, defects=(_rectangle(9.5, 9.5, 6.0, 1.8, 0.75, 20.0),)
    ),
    "2.5 mm, rectangle d/L 0.4, the flash's spot on the left edge": dict(
        thickness=2.5,
        duration=12.0,
        flash=_spot(0.0, 9.6, 4.8),
        defects=(_rectangle(11.0, 9.0, 3.0, 2.5, 1.0),),
    ),
    "3.0 mm, intact, the flash's spot in a corner": dict(
        thickness=3.0, duration=15.0, flash=_spot(19.2, 19.2, 5.76)
    ),
    "2.0 mm, ellipse d/L 0.5 passing 30 % of the heat": dict(
        thickness=2.0,
        duration=9.0,
        defects=(Defect("ellipse", centre=(9.0, 10.0), size=(4.0, 3.0), depth=1.0, transmission=0.3),),
    ),
    "3.0 mm, disc d/L 0.4; 40 x 64 px at 0.25 mm, 200 frames, 40 mK": dict(
        thickness=3.0,
        duration=15.0,
        shape=(40, 64),
        dx=0.25,
        n_frames=200,
        noise_sd=0.04,
        defects=(_ellipse(8.0, 5.0, 2.5, 2.5, 1.2),),
    ),
    "2.0 mm, rectangle d/L 0.5 over half the frame": dict(
        thickness=2.0, duration=9.0, defects=(_rectangle(9.0, 9.6, 7.5, 6.0, 1.0),)
    ),
    "3.0 mm isotropic (4, 4, 0.6), ellipse d/L 0.6; 64 x 64 px at 0.3 mm, 400 frames": dict(
        thickness=3.0,
        duration=18.0,
        shape=(64, 64),
        dx=0.3,
        n_frames=400,
        diffusivity=(4.0, 4.0, 0.6),
        defects=(_ellipse(9.0, 10.0, 4.0, 3.0, 1.8, 30.0),),
    ),
    "2.5 mm, rectangle d/L 0.4; 96 x 96 px at 0.2 mm": dict(
        thickness=2.5, duration=12.0, shape=(96, 96), dx=0.2, defects=(_rectangle(11.0, 9.0, 3.0, 2.5, 1.0),)
    ),
    "3.0 mm, intact; 96 x 96 px at 0.2 mm": dict(thickness=3.0, duration=15.0, shape=(96, 96), dx=0.2),
    "2.0 mm, ellipse d/L 0.5; 32 x 32 px at 0.6 mm": dict(
        thickness=2.0, duration=9.0, shape=(32, 32), dx=0.6, defects=(_ellipse(9.0, 10.0, 4.0, 3.0, 1.0),)
    ),
    "0.6 mm, ellipse d/L 0.5, recorded for 3 s": dict(
        thickness=0.6, duration=3.0, defects=(_ellipse(9.0, 10.0, 4.0, 3.0, 0.3),)
    ),
}
"""Plates not used to tune the map before they were added (``--held-out``; seeds 21-40): a flash whose
bright spot lies on the frame's edge or corner, a defect that passes some heat, a defect over half the
frame, other cameras (pixel size 0.2-0.6 mm, frame count, noise), an isotropic plate at another ``a_z``,
a plate thinner than any tuned one (0.6 mm: the back wall shows by 0.25 s)."""


_PLATE1 = dict(thickness=1.0, duration=4.0, seed=1)

PROBES: dict[str, dict] = {
    "1.0 mm, intact (plate 1 without its defects)": dict(_PLATE1),
    "1.0 mm, plate 1's triangle d/L 0.2 alone": dict(_PLATE1, defects=(_TRIANGLE,)),
    "1.0 mm, a disc of the triangle's area at its centroid, d/L 0.2": dict(
        _PLATE1, defects=(_equal_area_disc(_TRIANGLE),)
    ),
    "1.0 mm, plate 1's ellipse d/L 0.8 alone": dict(_PLATE1, defects=(_DEEP_ELLIPSE,)),
    "1.3 mm, plate 2's ellipse d/L 0.67 inside the frame": dict(
        **_PLATE2, defects=(_ellipse(9.6, 9.6, **_PLATE2_ELLIPSE),), seed=2
    ),
}
"""Plates 1 and 2 taken apart (``--probes``; each simulated with its parent plate's seed): which of their
defects breaks the diagnosis, and whether a defect running out of the frame is what gives plate 2's
delamination a negative gain."""


def auc(scores: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """ROC AUC of each row of ``scores`` ``(K, P)`` against ``truth`` ``(P,)`` (ties share their rank)."""
    positives, negatives = int(truth.sum()), int((~truth).sum())
    out = np.empty(len(scores))
    for k, row in enumerate(scores):  # a few dozen maps
        _, inverse, counts = np.unique(row, return_inverse=True, return_counts=True)
        ranks = (np.cumsum(counts) - (counts - 1) / 2)[inverse]  # average rank of ties, from 1
        out[k] = (ranks[truth].sum() - positives * (positives + 1) / 2) / (positives * negatives)
    return out


def _run(argv: list[str]) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        status = main(argv)
    text = out.getvalue().strip().splitlines()
    return json.loads(text[-1]) if status == 0 and text else {"error": f"exit {status}: {text[-1:]}"}


def _depths(
    truth_fraction: np.ndarray, found_mask: np.ndarray, found: list[dict], dx: float
) -> list[list[float]]:
    """Per true defect (distinct depth fraction): [truth, found d/L of the found defect overlapping it
    most (NaN: none)], the found defects' outlines recovered from their centroids' nearest pixels."""
    rows = []
    for value in np.unique(truth_fraction[np.isfinite(truth_fraction)]):
        region = np.isclose(truth_fraction, value)
        overlap = found_mask & region
        got = math.nan
        if overlap.any() and found:
            ys, xs = np.nonzero(overlap)
            centre = np.array([(xs.mean() + 0.5) * dx, (ys.mean() + 0.5) * dx])
            nearest = min(found, key=lambda d: float(np.hypot(d["x"] - centre[0], d["y"] - centre[1])))
            got = nearest["depth_fraction"]
        rows.append([float(value), got])
    return rows


def _named(diagnosis: dict, truth: np.ndarray, dx: float, fraction: np.ndarray | None = None) -> dict:
    """What the diagnosis names: depth_conduction, delaminations (every one, ``delamination`` and
    ``delamination_2``: centre over a true defect or not, and the true d/L under it, ``fraction`` ``(H, W)``
    NaN off the defects, which tells the defects apart), effects with a gain <= 0 or centred outside the
    frame."""
    effects = diagnosis.get("effects", [])
    if effects is None:
        return {
            "gain": None,
            "depth_conduction": None,
            "delamination_over_defect": [],
            "delamination_defects": [],
            "bad_effects": [],
            "names": ["(not run)"],
        }
    height, width = truth.shape
    bad, delaminations, under = [], [], []
    for e in effects:
        params, gain = e.get("params", {}), e.get("gain")
        if gain is None or gain <= 0:
            bad.append(f"{e['name']} gain {gain}")
        if "x" in params and "y" in params:
            col, row = int(params["x"] // dx), int(params["y"] // dx)
            inside = 0 <= col < width and 0 <= row < height
            if not inside:
                bad.append(f"{e['name']} centred outside the frame")
            if e["name"].startswith("delamination"):
                delaminations.append(bool(inside and truth[row, col]))
                value = float(fraction[row, col]) if inside and fraction is not None else math.nan
                under.append(value if math.isfinite(value) else None)
    return {
        "gain": diagnosis.get("gain"),
        "depth_conduction": any(e["name"] == "depth_conduction" for e in effects),
        "delamination_over_defect": delaminations,
        "delamination_defects": under,
        "bad_effects": bad,
        "names": [e["name"] for e in effects],
    }


def _maps_only(path: Path, maps_path: Path) -> dict:
    """What ``anra diagnose --maps`` writes of the map (the same :func:`flash_maps` on the same frames),
    without the diagnosis: ``{"defect_map": record}``."""
    video = load_video(path)
    maps = flash_maps(torch.as_tensor(video.frames), video.dt, video.dx)
    np.savez_compressed(maps_path, **maps.arrays())
    return {"defect_map": maps.record(), "effects": None}


def evaluate(
    name: str,
    case: dict,
    out: Path,
    seed: int,
    *,
    diagnose: bool = True,
    layered: bool = True,
    noise_sd: float | None = None,
) -> dict:
    """Simulate one plate (its camera's noise ``noise_sd`` K where given), run ``anra diagnose --maps`` (or
    only its map), score the maps."""
    path, maps_path = out / f"plate{seed}.npz", out / f"plate{seed}_maps.npz"
    case = dict(case) if noise_sd is None else {**case, "noise_sd": noise_sd}
    simulated = case.pop("seed", seed)  # a probe is simulated with its parent plate's seed
    plate = reference_plate_video(
        PlateSetup(**{"shape": SHAPE, "dx": DX, "n_frames": FRAMES, **case}, seed=simulated)
    )
    np.savez(path, frames=plate.frames.numpy(), dt=plate.dt, dx=plate.dx)
    start = time.perf_counter()
    if diagnose:
        argv = ["diagnose", str(path), "--json", "--maps", str(maps_path)]
        diagnosis = _run(argv + ([] if layered else ["--no-layered"]))
    else:
        diagnosis = _maps_only(path, maps_path)
    seconds = time.perf_counter() - start
    result: dict = {"name": name, "seconds": seconds, "plate_time": plate.plate_time}
    result["back_wall_in_recording"] = case["duration"] >= plate.plate_time / math.pi
    if "error" in diagnosis:
        return {**result, "error": diagnosis["error"]}
    record = diagnosis["defect_map"]
    truth = plate.defect_mask
    with np.load(maps_path) as maps:
        mask, score = maps["defect_mask"], maps["defect_score"]
        contrasts = {k: maps[k].reshape(len(maps[k]), -1) for k in ("tsr_d2", "pct", "ppt")}
    found = record["defects"]
    result.update(
        plate_time_found=record["plate_time"],
        plate_time_se=record["plate_time_std_error"],
        lateral=record["lateral_diffusivity"],
        diffusivity=list(case.get("diffusivity", (7.3, 1.1, 0.45))),
        back_wall_reached=record["back_wall_reached"],
        plate_time_error=(record["plate_time"] or math.nan) / plate.plate_time - 1,
        defects_found=len(found),
        false_defects=sum(
            not truth[
                min(int(d["y"] // plate.dx), truth.shape[0] - 1),
                min(int(d["x"] // plate.dx), truth.shape[1] - 1),
            ]
            for d in found
        ),
        diagnosis=_named(diagnosis, truth, plate.dx, plate.depth_fraction),
    )
    if truth.any():
        result["auc"] = float(auc(score.reshape(1, -1), truth.ravel())[0])
        for key, stack in contrasts.items():
            values = auc(np.nan_to_num(stack), truth.ravel())
            result[f"auc_{key}"] = float(np.max(np.maximum(values, 1 - values)))
        result["iou"] = float((mask & truth).sum() / (mask | truth).sum())
        result["depths"] = _depths(plate.depth_fraction, mask, found, plate.dx)
    else:
        result["coverage"] = float(mask.mean())
    return result


def _line(r: dict) -> str:
    if "error" in r:
        return f"| {r['name']} | error: {r['error']} |"
    d = r["diagnosis"]
    names = ", ".join(d["names"]) or "none"
    if d.get("gain") is not None:
        names += f" (gain {d['gain']:.2f})"
    bad = "; ".join(d["bad_effects"]) or "none"
    wall = "yes" if r["back_wall_in_recording"] else "no"
    plate = f"{100 * r['plate_time_error']:+.1f} % ({'reached' if r['back_wall_reached'] else 'not reached'})"
    if "auc" in r:
        best = max(r["auc_tsr_d2"], r["auc_pct"], r["auc_ppt"])
        aucs = f"**{r['auc']:.3f}** / {r['auc_tsr_d2']:.3f} / {r['auc_pct']:.3f} / {r['auc_ppt']:.3f}"
        aucs += " (>= best)" if r["auc"] >= best else " (< best)"
        mask = f"IoU {r['iou']:.2f}"
        depths = ", ".join(f"{t:.2f} -> {g:.2f}" for t, g in r["depths"])
    else:
        aucs, mask, depths = "-", f"covers {100 * r['coverage']:.2f} %", "-"
    lateral = "{:.2f}, {:.2f} ({:g}, {:g})".format(*r["lateral"][:2], *r["diffusivity"][:2])
    return (
        f"| {r['name']} | {wall} | {aucs} | {mask} | {plate} | {depths} | {r['defects_found']} "
        f"({r['false_defects']} false) | {lateral} | {names} | {bad} | {r['seconds']:.0f} |"
    )


HEADER = (
    "| plate | back wall in the recording | AUC defect_score / TSR / PCT / PPT | mask | L^2/a_z error | "
    "d/L truth -> found | map's defects | a_x, a_y taken off (truth) | diagnosis names | "
    "effects with gain <= 0 or outside | s |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|"
)


def run(
    out: Path,
    chosen: list[int],
    *,
    diagnose: bool = True,
    held_out: bool = False,
    probes: bool = False,
    layered: bool = True,
    noise_sd: float | None = None,
) -> list[dict]:
    """Evaluate the chosen plates (1-based) of :data:`PLATES`, :data:`HELD_OUT` or :data:`PROBES` (every
    camera's noise ``noise_sd`` K where given), reusing results already in ``out``; return every result."""
    results = []
    plates, first = (PROBES, 41) if probes else (HELD_OUT, 21) if held_out else (PLATES, 1)
    for index, (name, case) in enumerate(plates.items(), 1):
        cached = out / f"plate{index + first - 1}.json"
        if index in chosen and not cached.is_file():
            seed = index + first - 1
            result = evaluate(name, case, out, seed, diagnose=diagnose, layered=layered, noise_sd=noise_sd)
            cached.write_text(json.dumps(result))
            print(_line(result), flush=True)
        if cached.is_file():
            results.append(json.loads(cached.read_text()))
    return results


def summary(results: list[dict]) -> list[str]:
    """The table and the acceptance lines' aggregates."""
    lines = [HEADER, *(_line(r) for r in results)]
    defect = [r for r in results if "auc" in r]
    intact = [r for r in results if "coverage" in r]
    if defect:
        beats = sum(r["auc"] >= max(r["auc_tsr_d2"], r["auc_pct"], r["auc_ppt"]) for r in defect)
        lines.append(
            f"\nmean AUC {np.mean([r['auc'] for r in defect]):.3f} on {len(defect)} defect plates; >= best "
            f"contrast on {beats}; IoU >= 0.6 on {sum(r['iou'] >= 0.6 for r in defect)}"
        )
        errors = [abs(g - t) for r in defect for t, g in r["depths"] if r["back_wall_reached"]]
        found = [e for e in errors if math.isfinite(e)]
        lines.append(
            f"depth fraction error (back wall reached): max {max(found, default=math.nan):.3f} over "
            f"{len(found)} defects found ({len(errors) - len(found)} not found)"
        )
        every = [abs(g - t) for r in defect for t, g in r["depths"]]
        lines.append(
            f"depth fraction within 0.1 on {sum(e <= 0.1 for e in every)} of {len(every)} defects (the back "
            "wall reached or not; a defect not found is not within)"
        )
    reached = [
        abs(r["plate_time_error"]) for r in results if "error" not in r and r["back_wall_in_recording"]
    ]
    lines.append(
        f"|L^2/a_z error| where the back wall is in the recording: max {100 * max(reached, default=0):.1f} %"
    )
    if intact:
        lines.append(f"intact coverage: max {100 * max(r['coverage'] for r in intact):.2f} %")
    lines.extend(_diagnosis_summary([r for r in results if "error" not in r]))
    return lines


def _diagnosis_summary(results: list[dict]) -> list[str]:
    """The diagnosis' acceptance lines over the plates it ran on: depth_conduction named; a delamination
    centred over a true defect for each of the plate's defects (distinct depths) and none elsewhere, none
    on an intact plate; no effect with a gain <= 0 or centred outside the frame."""
    ran = [r for r in results if r["diagnosis"]["depth_conduction"] is not None]
    if not ran:
        return []

    def exact(r: dict) -> bool:
        over = r["diagnosis"]["delamination_over_defect"]
        if "delamination_defects" not in r["diagnosis"]:  # written before the defects were told apart
            return all(over) and len(over) >= len(r.get("depths", []))
        covered = {round(v, 6) for v in r["diagnosis"]["delamination_defects"] if v is not None}
        return all(over) and covered >= {round(t, 6) for t, _ in r.get("depths", [])}

    named = sum(r["diagnosis"]["depth_conduction"] for r in ran)
    clean = sum(not r["diagnosis"]["bad_effects"] for r in ran)
    return [
        f"diagnosis on {len(ran)} plates: depth_conduction named on {named}; a delamination over each defect "
        f"and none elsewhere on {sum(exact(r) for r in ran)}; no gain <= 0 or outside on {clean}"
    ]


def cli() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=Path, default=None, help="folder for plates and results (default: temporary)"
    )
    parser.add_argument(
        "--plates", default=None, help="comma-separated plate numbers, 1-based (default: all)"
    )
    parser.add_argument(
        "--map-only",
        action="store_true",
        help="only the map (flash_maps, what --maps writes), not the diagnosis",
    )
    sets = parser.add_mutually_exclusive_group()
    sets.add_argument(
        "--held-out",
        action="store_true",
        help="the plates of HELD_OUT (seeds 21-40: other cameras, flashes and defects) instead of PLATES",
    )
    sets.add_argument(
        "--probes",
        action="store_true",
        help="the plates of PROBES (plates 1 and 2 taken apart, one defect at a time) instead of PLATES",
    )
    parser.add_argument(
        "--layered",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="run anra diagnose with --layered (the default: the plate forecast through its thickness) or "
        "--no-layered (by its surface alone)",
    )
    parser.add_argument(
        "--noise-sd",
        type=float,
        default=None,
        help="every plate's camera noise sd in K (default: each plate's own, 20 mK on most)",
    )
    args = parser.parse_args()
    if args.noise_sd is not None and not args.noise_sd >= 0:
        parser.error(f"--noise-sd must be a noise sd in K, at least 0, got {args.noise_sd}")
    count = len(PROBES if args.probes else HELD_OUT if args.held_out else PLATES)
    chosen = list(range(1, count + 1)) if args.plates is None else [int(p) for p in args.plates.split(",")]
    with contextlib.ExitStack() as stack:
        out = args.out or Path(stack.enter_context(tempfile.TemporaryDirectory()))
        out.mkdir(parents=True, exist_ok=True)
        results = run(
            out,
            chosen,
            diagnose=not args.map_only,
            held_out=args.held_out,
            probes=args.probes,
            layered=args.layered,
            noise_sd=args.noise_sd,
        )
        print("\n".join(summary(results)))


if __name__ == "__main__":
    cli()
