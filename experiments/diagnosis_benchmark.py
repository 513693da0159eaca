"""Benchmark :func:`anra_torch.selection.diagnose_terms` on random hidden-effect videos, against weak SINDy.

Cases: ``--cases`` random videos per effect (linear_loss, source, advection, anisotropy, heterogeneity,
nonlinear_diffusion) plus ``--cases`` pure heat-transfer videos, from
:func:`anra_torch.effects.hidden_effect_video`. Each case draws (seeded by effect index and case index)
white noise 0.5-3 % of the peak temperature rise, 27-50 fps, a 64-128 px square frame, 2-4 s, and a pixel
size of 0.1-0.2 mm (log-uniform; ``--dx-range``): a 6-26 mm field of view, a close-up like the paper's
(10 mm). The pixel size sets how far heat moves during the forecast: at a = 0.15 mm^2/s the diffusion
length over a 1.2 s forecast is 0.6 mm, a few pixels here but one pixel at 0.5 mm/px, where anisotropy,
heterogeneity and nonlinear diffusion change the forecast little (``tests/test_prediction.py`` compares
the same scene at 0.5 and 0.1 mm/px; ``--dx-range 0.5 0.5`` runs the whole benchmark there).

Per case, ANRA's ``diagnose_terms``: the top effect against the truth (correct / wrong / none), the extra
effects, a false positive on pure videos (anything reported), parameter errors of the true effect when it
was found (relative for magnitudes; heterogeneity: centroid distance over the radius, radius and
``a_inside / a_outside`` relative errors; source: distance in px between the midpoints of the true and
fitted paths, rate relative error; anisotropy: eigenvalue ratio relative error and principal-axis angle
error in degrees; advection: ``|v_est - v_true| / |v_true|``), the wall time; and the prediction gain of
``anra_torch.forecast.assess_gain`` when that module imports (otherwise "not measured"): the gain at the
diagnosis' spatial scale (the headline), the part of the plain model's error above the noise floor
that the extension removes, and the gain against the raw frames (capped by the noise).

Peer: PySINDy 2.1 weak form (``ps.WeakPDELibrary``) on the same videos, in pixel units and seconds, on the
excess temperature ``u = T - background`` (median of the first frame's border) divided by the peak rise
of the first frame. Settings follow ``experiments/peers.py::weak_sindy_estimate`` (tuned): K=200
subdomains of half-width 22 px, 22 px, 7 frames (clipped to 0.4 of the extent), p=4, one BLAS thread;
library ``PolynomialLibrary(degree=2, include_bias=False)`` functions (u, u^2), a constant, derivatives up to
second order (u_1, u_2, u_11, u_12, u_22) and their products with u and u^2; ``STLSQ(threshold, alpha=0.05,
normalize_columns=True)`` (``--sindy-threshold``, default 0.2, from a 5-video look at 0.2, 0.5,
1 and 2: from 0.5 up the Laplacian itself is dropped on pure videos; normalised columns make one threshold
meaningful across terms whose scales differ by orders of magnitude). Kept terms map to our names by
this rule:

- a product of u or u^2 with a derivative (u u_11, u u_1, u^2 u_22, ...) -> nonlinear_diffusion;
- u_1 or u_2 alone -> advection;
- 1, u or u^2 alone -> linear_loss (a reaction term);
- u_12 kept, or ``|c_11 - c_22| > 0.1 (|c_11| + |c_22|) / 2`` -> anisotropy;
- nothing else -> no effect (u_11 = u_22 is plain diffusion).

The library has no term for a moving Gaussian source or a disc of different diffusivity, so SINDy can
only name them wrong or not at all: it is reported as it is. SINDy has no ranking of terms into a "top
effect"; we count it correct when the mapped set is exactly the truth, and also report when the truth
is among the mapped set.

    python experiments/diagnosis_benchmark.py                  # 20 cases per effect and pure
    python experiments/diagnosis_benchmark.py --cases 2        # quick timing estimate

Writes ``results.json`` and ``table.md`` to ``--out`` (default results/diagnosis_benchmark) and prints
the table and an acceptance block.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import re
import sys
import time
import traceback
from pathlib import Path

import numpy as np

EFFECT_NAMES = ("linear_loss", "source", "advection", "anisotropy", "heterogeneity", "nonlinear_diffusion")
PURE = "pure"
GROUPS = (*EFFECT_NAMES, PURE)

# Acceptance targets (from the brief).
TOP_TARGET = 0.95
FP_TARGET = 0.05
PARAM_TARGET = 0.10
HET_CENTRE_TARGET = 0.5  # centroid distance / radius
HET_RATIO_TARGET = 0.20
GAIN_TARGET = 0.50

# The parameter errors that the acceptance uses per effect (all must have median within target).
PRIMARY = {
    "linear_loss": ("b",),
    "source": ("rate",),
    "advection": ("v",),
    "anisotropy": ("ratio",),
    "heterogeneity": ("ratio_in_out",),  # plus centre_over_radius <= 0.5
    "nonlinear_diffusion": ("a0", "beta"),
}


def _setup_worker() -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)


DX_RANGE = (0.1, 0.2)  # mm/px, drawn log-uniformly


def _draw_case(group_index: int, index: int, dx_range: tuple[float, float] = DX_RANGE) -> dict:
    rng = np.random.default_rng([20261121, group_index, index])
    return {
        "seed": int(rng.integers(0, 2**31 - 1)),
        "noise_frac": float(rng.uniform(0.005, 0.03)),
        "fps": float(rng.uniform(27.0, 50.0)),
        "size": int(rng.integers(64, 129)),
        "duration": float(rng.uniform(2.0, 4.0)),
        "dx": float(np.exp(rng.uniform(math.log(dx_range[0]), math.log(dx_range[1])))),
    }


def _rel(est: float, true: float) -> float:
    return abs(est - true) / abs(true) if true != 0 else math.nan


def _param_errors(name: str, true: dict, est: dict, dx: float) -> dict[str, float]:
    if name == "linear_loss":
        return {"b": _rel(est["b"], true["b"])}
    if name == "advection":
        v_true = math.hypot(true["vx"], true["vy"])
        return {"v": math.hypot(est["vx"] - true["vx"], est["vy"] - true["vy"]) / v_true}
    if name == "anisotropy":

        def eig(p: dict) -> tuple[float, float, float]:
            mean = 0.5 * (p["a_x"] + p["a_y"])
            half = math.hypot(0.5 * (p["a_x"] - p["a_y"]), p["a_xy"])
            angle = 0.5 * math.degrees(math.atan2(2.0 * p["a_xy"], p["a_x"] - p["a_y"]))
            return mean + half, mean - half, angle

        lt, st, at = eig(true)
        le, se, ae = eig(est)
        d_angle = abs((ae - at + 90.0) % 180.0 - 90.0)
        return {
            "ratio": _rel(le / se if se > 0 else math.inf, lt / st),
            "large": _rel(le, lt),
            "small": _rel(se, st),
            "angle_deg": d_angle,
        }
    if name == "nonlinear_diffusion":
        return {"a0": _rel(est["a0"], true["a0"]), "beta": _rel(est["beta"], true["beta"])}
    if name == "source":
        mid_t = (0.5 * (true["x0"] + true["x1"]), 0.5 * (true["y0"] + true["y1"]))
        mid_e = (0.5 * (est["x0"] + est["x1"]), 0.5 * (est["y0"] + est["y1"]))
        return {
            "rate": _rel(est["rate"], true["rate"]),
            "centre_px": math.hypot(mid_e[0] - mid_t[0], mid_e[1] - mid_t[1]) / dx,
            "width": _rel(est["width"], true["width"]),
        }
    if name == "heterogeneity":
        ratio_t = true["a_inside"] / true["a_outside"]
        ratio_e = est["a_inside"] / est["a_outside"] if est["a_outside"] != 0 else math.inf
        return {
            "centre_over_radius": math.hypot(est["x"] - true["x"], est["y"] - true["y"]) / true["radius"],
            "radius": _rel(est["radius"], true["radius"]),
            "ratio_in_out": _rel(ratio_e, ratio_t),
        }
    raise ValueError(name)


# ---------------------------------------------------------------------------------------- SINDy peer
SINDY_K = 200
SINDY_HALF = (22.0, 22.0, 7.0)
SINDY_MAX_FRACTION = 0.4


def _sindy_map(names: list[str], coef: np.ndarray) -> tuple[list[str], list[str]]:
    """Kept terms -> our effect names (rule in the module docs)."""
    kept = {n: float(c) for n, c in zip(names, coef, strict=True) if c != 0.0}
    found: set[str] = set()
    for term in kept:
        product = re.fullmatch(r"(x0|x0\^2|1 ?)(x0_\d+)", term.replace(" ", ""))
        if product and product.group(1).startswith("x0"):
            found.add("nonlinear_diffusion")
        elif term in ("x0_1", "x0_2"):
            found.add("advection")
        elif term in ("1", "x0", "x0^2"):
            found.add("linear_loss")
        elif term == "x0_12":
            found.add("anisotropy")
    c11, c22 = kept.get("x0_11", 0.0), kept.get("x0_22", 0.0)
    if abs(c11 - c22) > 0.1 * 0.5 * (abs(c11) + abs(c22)):
        found.add("anisotropy")
    return sorted(found), [f"{c:+.4g} {n}" for n, c in kept.items()]


def sindy_case(frames: np.ndarray, dt: float, threshold: float, seed: int) -> dict:
    import pysindy as ps
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    n_t, n_y, n_x = frames.shape
    first = frames[0]
    border = np.concatenate(
        [first[:2].ravel(), first[-2:].ravel(), first[:, :2].ravel(), first[:, -2:].ravel()]
    )
    background = float(np.median(border))
    rise = float(first.max() - background)
    u = np.moveaxis((frames - background) / rise, 0, -1)[..., None]
    extent = np.array([n_y - 1, n_x - 1, n_t - 1], dtype=np.float64)
    half = np.minimum(np.array(SINDY_HALF), SINDY_MAX_FRACTION * extent) * np.array([1.0, 1.0, dt])  # t in s
    axes = (np.arange(n_y, dtype=float), np.arange(n_x, dtype=float), np.arange(n_t) * dt)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    saved = np.random.get_state()  # noqa: NPY002 - PySINDy samples subdomains from the global generator
    np.random.seed(seed % (2**32))  # noqa: NPY002
    try:
        library = ps.WeakPDELibrary(
            function_library=ps.PolynomialLibrary(degree=2, include_bias=False),
            derivative_order=2,
            include_bias=True,
            spatiotemporal_grid=grid,
            include_interaction=True,
            K=SINDY_K,
            H_xt=half,
        )
        model = ps.SINDy(
            feature_library=library,
            optimizer=ps.STLSQ(threshold=threshold, alpha=0.05, normalize_columns=True),
        )
        with threadpool_limits(limits=1, user_api="blas"):
            model.fit(u, t=grid[0, 0, :, 2])
        names = list(model.get_feature_names())
        coef = np.asarray(model.coefficients(), dtype=np.float64).reshape(-1)
        found, kept = _sindy_map(names, coef)
        error = None
    except Exception as err:  # noqa: BLE001 - a failed peer fit is a result, not a crash
        found, kept, error = [], [], f"{type(err).__name__}: {err}"
    finally:
        np.random.set_state(saved)  # noqa: NPY002
    return {"found": found, "kept": kept, "error": error, "seconds": time.perf_counter() - t0}


# ---------------------------------------------------------------------------------------- one case
def run_case(job: tuple) -> dict:
    group, index, gi, options = job
    import torch

    from anra_torch.effects import hidden_effect_video
    from anra_torch.selection import diagnose_terms

    case = _draw_case(gi, index, options["dx_range"])
    names = () if group == PURE else (group,)
    rec: dict = {"group": group, "index": index, **case}
    try:
        t0 = time.perf_counter()
        video = hidden_effect_video(
            names,
            seed=case["seed"],
            size=case["size"],
            fps=case["fps"],
            duration=case["duration"],
            noise_frac=case["noise_frac"],
            dx=case["dx"],
        )
        rec["simulate_seconds"] = time.perf_counter() - t0
        rec["truth"] = [e.to_dict() for e in video.effects]
        frames = video.frames
        t0 = time.perf_counter()
        diag = diagnose_terms(frames, video.dt, video.dx)
        rec["seconds"] = time.perf_counter() - t0
        found = diag.names
        rec["found"] = found
        rec["scores"] = [float(e["score"]) for e in diag.effects]
        rec["top"] = found[0] if found else None
        if group == PURE:
            rec["outcome"] = "false_positive" if found else "none"
            rec["extra"] = list(found)
        else:
            rec["outcome"] = "none" if not found else ("correct" if found[0] == group else "wrong")
            rec["extra"] = [n for n in found if n != group]
            match = [e for e in diag.effects if e["name"] == group]
            if match:
                rec["errors"] = _param_errors(group, video.effects[0].params, match[0]["params"], video.dx)
                rec["estimate"] = {k: float(v) for k, v in match[0]["params"].items()}
        rec["gain"] = None
        if options["gain"]:
            try:
                from anra_torch.forecast import assess_gain

                t0 = time.perf_counter()
                g = assess_gain(frames, video.dt, video.dx)
                rec["gain_seconds"] = time.perf_counter() - t0
                rec["gain"] = float(g.gain)
                rec["gain_raw"] = float(g.gain_raw)
                rec["gain_above_floor"] = float(g.gain_above_floor)
                rec["base_over_floor"] = float(g.base_rmse / g.noise_floor) if g.noise_floor > 0 else None
                rec["gain_effects"] = [e.name for e in g.effects]
                rec["gain_result"] = {
                    k: (float(v) if isinstance(v, (int, float)) else str(v))
                    for k, v in getattr(g, "__dict__", {}).items()
                    if isinstance(v, (int, float, str))
                }
            except Exception as err:  # noqa: BLE001
                rec["gain_error"] = f"{type(err).__name__}: {err}"
        if options["sindy"]:
            rec["sindy"] = sindy_case(
                frames.double().numpy(), video.dt, options["sindy_threshold"], case["seed"]
            )
            s = rec["sindy"]["found"]
            if group == PURE:
                rec["sindy"]["outcome"] = "false_positive" if s else "none"
            else:
                rec["sindy"]["outcome"] = (
                    "none"
                    if not s
                    else ("correct" if s == [group] else ("contains" if group in s else "wrong"))
                )
    except Exception as err:  # noqa: BLE001
        rec["outcome"] = "error"
        rec["error"] = f"{type(err).__name__}: {err}\n{traceback.format_exc()}"
    del torch
    return rec


# ---------------------------------------------------------------------------------------- summary
def _median(values: list[float]) -> float:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.median(vals)) if vals else math.nan


def summarise(records: list[dict], gain_measured: bool, sindy_ran: bool) -> dict:
    summary: dict = {}
    for group in GROUPS:
        recs = [r for r in records if r["group"] == group]
        if not recs:
            continue
        n = len(recs)
        s: dict = {"cases": n, "errors": sum(r["outcome"] == "error" for r in recs)}
        s["median_seconds"] = _median([r.get("seconds") for r in recs])
        if group == PURE:
            s["false_positive_rate"] = sum(r["outcome"] == "false_positive" for r in recs) / n
            s["false_positive_names"] = sorted({n_ for r in recs for n_ in r.get("found", [])})
        else:
            s["correct"] = sum(r["outcome"] == "correct" for r in recs) / n
            s["wrong"] = sum(r["outcome"] == "wrong" for r in recs) / n
            s["none"] = sum(r["outcome"] == "none" for r in recs) / n
            s["with_extra"] = sum(bool(r.get("extra")) for r in recs) / n
            s["extra_names"] = sorted({n_ for r in recs for n_ in r.get("extra", [])})
            keys = sorted({k for r in recs for k in r.get("errors", {})})
            s["median_errors"] = {
                k: _median([r["errors"].get(k) for r in recs if "errors" in r]) for k in keys
            }
            s["param_cases"] = sum("errors" in r for r in recs)
        s["median_gain"] = _median([r.get("gain") for r in recs]) if gain_measured else None
        for key in ("gain_raw", "gain_above_floor", "base_over_floor"):
            s[f"median_{key}"] = _median([r.get(key) for r in recs]) if gain_measured else None
        if sindy_ran:
            sr = [r["sindy"] for r in recs if "sindy" in r]
            m = len(sr)
            s["sindy_cases"] = m
            s["sindy_median_seconds"] = _median([x["seconds"] for x in sr])
            s["sindy_failed"] = sum(x["error"] is not None for x in sr)
            if m:
                if group == PURE:
                    s["sindy_false_positive_rate"] = sum(x["outcome"] == "false_positive" for x in sr) / m
                else:
                    s["sindy_exact"] = sum(x["outcome"] == "correct" for x in sr) / m
                    s["sindy_contains"] = sum(x["outcome"] in ("correct", "contains") for x in sr) / m
                    s["sindy_none"] = sum(x["outcome"] == "none" for x in sr) / m
                s["sindy_names"] = sorted({n_ for x in sr for n_ in x["found"]})
        summary[group] = s
    return summary


def _pct(x: float | None) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{100 * x:.0f} %"


def _fmt_err(group: str, errs: dict) -> str:
    parts = []
    for k, v in errs.items():
        if not math.isfinite(v):
            parts.append(f"{k} n/a")
        elif k == "angle_deg":
            parts.append(f"angle {v:.2f} deg")
        elif k == "centre_px":
            parts.append(f"centre {v:.2f} px")
        elif k == "centre_over_radius":
            parts.append(f"centre {v:.3f} R")
        else:
            parts.append(f"{k} {100 * v:.1f} %")
    return ", ".join(parts) or "n/a"


def table(summary: dict, gain_measured: bool, sindy_ran: bool) -> str:
    gain_head = "median gain" if gain_measured else "gain: not measured"
    head = [
        "effect",
        "cases",
        "top correct",
        "wrong / none",
        "with extra (names)",
        "median param errors",
        gain_head,
        "gain above floor / raw",
        "plain RMSE / floor",
        "median time",
    ]
    if sindy_ran:
        head += ["SINDy cases", "SINDy exact", "SINDy truth among", "SINDy names", "SINDy time"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for group, s in summary.items():
        gain = _pct(s["median_gain"]) if gain_measured else "not measured"
        more = (
            [
                f"{_pct(s['median_gain_above_floor'])} / {_pct(s['median_gain_raw'])}",
                f"{s['median_base_over_floor']:.2f}",
            ]
            if gain_measured
            else ["", ""]
        )
        if group == PURE:
            row = [
                group,
                str(s["cases"]),
                f"false positives {_pct(s['false_positive_rate'])}",
                "",
                ", ".join(s["false_positive_names"]) or "-",
                "",
                gain,
                *more,
                f"{s['median_seconds']:.2f} s",
            ]
        else:
            row = [
                group,
                str(s["cases"]),
                _pct(s["correct"]),
                f"{_pct(s['wrong'])} / {_pct(s['none'])}",
                f"{_pct(s['with_extra'])} ({', '.join(s['extra_names']) or '-'})",
                f"{_fmt_err(group, s['median_errors'])} (n={s['param_cases']})",
                gain,
                *more,
                f"{s['median_seconds']:.2f} s",
            ]
        if sindy_ran:
            if group == PURE:
                row += [
                    str(s["sindy_cases"]),
                    f"false positives {_pct(s.get('sindy_false_positive_rate'))}",
                    "",
                    ", ".join(s["sindy_names"]) or "-",
                    f"{s['sindy_median_seconds']:.2f} s",
                ]
            else:
                row += [
                    str(s["sindy_cases"]),
                    _pct(s.get("sindy_exact")),
                    _pct(s.get("sindy_contains")),
                    ", ".join(s["sindy_names"]) or "-",
                    f"{s['sindy_median_seconds']:.2f} s",
                ]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def acceptance(summary: dict, gain_measured: bool) -> tuple[str, bool]:
    lines, ok_all = [], True

    def check(label: str, ok: bool | None, value: str) -> None:
        nonlocal ok_all
        if ok is None:
            status = "NOT MEASURED"
            ok_all = False
        else:
            status = "PASS" if ok else "FAIL"
            ok_all = ok_all and ok
        lines.append(f"- {status}: {label}: {value}")

    for group in EFFECT_NAMES:
        if group not in summary:
            continue
        s = summary[group]
        check(f"{group} top effect correct >= 95 %", s["correct"] >= TOP_TARGET, _pct(s["correct"]))
        errs = s["median_errors"]
        for key in PRIMARY[group]:
            v = errs.get(key, math.nan)
            target = HET_RATIO_TARGET if key == "ratio_in_out" else PARAM_TARGET
            check(
                f"{group} median {key} error <= {100 * target:.0f} %",
                math.isfinite(v) and v <= target,
                f"{100 * v:.1f} %",
            )
        if group == "heterogeneity":
            v = errs.get("centre_over_radius", math.nan)
            check(
                "heterogeneity median centroid distance <= 0.5 radius",
                math.isfinite(v) and v <= HET_CENTRE_TARGET,
                f"{v:.3f} radius",
            )
        if gain_measured:
            g = s["median_gain"]
            check(f"{group} median gain >= 50 %", math.isfinite(g) and g >= GAIN_TARGET, _pct(g))
        else:
            check(f"{group} median gain >= 50 %", None, "assess_gain not available")
    if PURE in summary:
        fp = summary[PURE]["false_positive_rate"]
        check("pure false positives <= 5 %", fp <= FP_TARGET, _pct(fp))
    verdict = "OVERALL: PASS" if ok_all else "OVERALL: FAIL (or not fully measured)"
    return "\n".join(["## Acceptance", "", *lines, "", verdict]), ok_all


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--cases", type=int, default=20, help="random cases per effect and pure (default 20)")
    parser.add_argument("--out", type=Path, default=Path("results/diagnosis_benchmark"))
    parser.add_argument("--workers", type=int, default=2, help="processes, one thread each (default 2)")
    parser.add_argument(
        "--sindy-cases",
        type=int,
        default=None,
        help="run PySINDy on the first N cases of each group (default all)",
    )
    parser.add_argument("--sindy-threshold", type=float, default=0.2)
    parser.add_argument(
        "--dx-range",
        type=float,
        nargs=2,
        default=DX_RANGE,
        metavar=("LO", "HI"),
        help=f"pixel size range in mm, drawn log-uniformly (default {DX_RANGE[0]} {DX_RANGE[1]})",
    )
    parser.add_argument("--no-gain", action="store_true", help="skip assess_gain even if available")
    args = parser.parse_args()
    from tqdm import tqdm

    gain_available = False
    if not args.no_gain:
        try:
            from anra_torch.forecast import assess_gain  # noqa: F401

            gain_available = True
        except Exception as err:  # noqa: BLE001
            print(
                f"gain: not measured (anra_torch.forecast.assess_gain does not import: {err})",
                file=sys.stderr,
            )
    sindy_n = args.cases if args.sindy_cases is None else args.sindy_cases
    jobs = []
    for gi, group in enumerate(GROUPS):
        for i in range(args.cases):
            options = {
                "gain": gain_available,
                "sindy": i < sindy_n,
                "sindy_threshold": args.sindy_threshold,
                "dx_range": tuple(args.dx_range),
            }
            jobs.append((group, i, gi, options))
    start = time.perf_counter()
    records = []
    args.out.mkdir(parents=True, exist_ok=True)
    partial = (args.out / "records.partial.jsonl").open("w")

    def keep(rec: dict) -> None:
        records.append(rec)
        partial.write(json.dumps(rec, default=str) + "\n")
        partial.flush()

    if args.workers > 1:
        ctx = mp.get_context("spawn")
        with ctx.Pool(args.workers, initializer=_setup_worker) as pool:
            for rec in tqdm(pool.imap_unordered(run_case, jobs), total=len(jobs), desc="cases"):
                keep(rec)
    else:
        _setup_worker()
        for job in tqdm(jobs, desc="cases"):
            keep(run_case(job))
    partial.close()
    wall = time.perf_counter() - start
    records.sort(key=lambda r: (GROUPS.index(r["group"]), r["index"]))
    sindy_ran = sindy_n > 0
    summary = summarise(records, gain_available, sindy_ran)
    md = table(summary, gain_available, sindy_ran)
    acc, ok = acceptance(summary, gain_available)
    notes = [
        f"{args.cases} cases per group, {len(records)} in all; wall time {wall:.0f} s on {args.workers} "
        f"process(es) with one thread each; times are per case (one core).",
        f"PySINDy weak form on the first {min(sindy_n, args.cases)} cases of each group, "
        f"threshold {args.sindy_threshold} (normalised columns); mapping rule in the script's docs.",
        "gain: "
        + ("anra_torch.forecast.assess_gain" if gain_available else "not measured (assess_gain unavailable)"),
        f"errors (exceptions): {sum(r['outcome'] == 'error' for r in records)}",
    ]
    text = (
        "# Diagnosis benchmark\n\n" + md + "\n\n" + "\n".join(f"- {n}" for n in notes) + "\n\n" + acc + "\n"
    )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "table.md").write_text(text)
    (args.out / "results.json").write_text(
        json.dumps(
            {
                "args": {k: str(v) for k, v in vars(args).items()},
                "wall_seconds": wall,
                "gain_measured": gain_available,
                "summary": summary,
                "acceptance_pass": ok,
                "records": records,
            },
            indent=1,
            default=str,
        )
    )
    print(text)


if __name__ == "__main__":
    main()
