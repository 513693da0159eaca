"""Pieces the diagnosis benchmarks share (``diagnosis_benchmark.py`` and its ``--artefacts`` mode).

The effect groups, the two simulators of a case, the parameter errors of a found effect, the PySINDy weak
form peer (:func:`sindy_case`, its term-to-effect rule in ``diagnosis_benchmark.py``'s docs), what a
:class:`anra_torch.selection.Diagnosis` says as a JSON-ready record (names, parameters, scores, and any
keys the diagnosis may grow, e.g. ``negligible`` or ``artefacts``, read without assuming them), and
whether an exception is a clean refusal of the input or an internal error.

Also how the benchmarks run their cases: spawned processes of one thread each (:func:`run_jobs`), records
kept as they come, results written as ``table.md`` and ``results.json`` (:func:`write_results`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import multiprocessing as mp
import os
import re
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

EFFECT_NAMES = ("linear_loss", "source", "advection", "anisotropy", "heterogeneity", "nonlinear_diffusion")
PURE = "pure"
GROUPS = (*EFFECT_NAMES, PURE)
SIMULATORS = ("library", "independent")


def make_video(simulator: str, names: Sequence[str], *, noise_frac: float = 0.01, **kwargs: object):
    """The hidden-effect video of a case from ``"library"`` (:func:`anra_torch.effects.hidden_effect_video`)
    or ``"independent"`` (:func:`anra_torch.effects.independent_effect_video`): the same
    scene and effect parameters for a seed, white noise ``noise_frac`` of the peak initial rise."""
    from anra_torch.effects import Sensor

    if simulator == "library":
        from anra_torch.effects import hidden_effect_video as simulate
    elif simulator == "independent":
        from anra_torch.effects import independent_effect_video as simulate
    else:
        raise ValueError(f"unknown simulator {simulator!r}; expected one of: {', '.join(SIMULATORS)}")
    return simulate(tuple(names), sensor=Sensor(noise_frac=noise_frac), **kwargs)


def _rel(est: float, true: float) -> float:
    return abs(est - true) / abs(true) if true != 0 else math.nan


def param_errors(name: str, true: dict, est: dict, dx: float) -> dict[str, float]:
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


def sindy_outcome(found: list[str], group: str) -> str:
    """``false_positive`` / ``none`` on pure videos; ``correct`` (exactly the truth), ``contains``,
    ``wrong`` or ``none`` on effect videos."""
    if group == PURE:
        return "false_positive" if found else "none"
    if not found:
        return "none"
    return "correct" if found == [group] else ("contains" if group in found else "wrong")


# ---------------------------------------------------------------------------------------- records
_KNOWN_FIELDS = {
    "base", "base_std_error", "effects", "a_plain", "scores", "thresholds", "coefficients", "std_errors",
    "noise_sd", "smoothing", "mean", "fit_ratio", "residual_map", "margin",
}  # fmt: skip
_EXTRA_NAMES = ("negligible", "artefacts", "artifacts", "noise_model", "masked", "mask", "warnings")


def jsonable(value: object, depth: int = 0) -> object:
    """``value`` as JSON-ready data: tensors and arrays of up to 64 values as lists, larger ones as a
    summary (shape, mean, count of non-zeros), a noise model as its ``describe()``, dataclasses and mappings
    recursively, the rest as text."""
    if depth > 6:
        return str(value)
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    if hasattr(value, "describe"):  # a noise model: its JSON object
        return jsonable(value.describe(), depth + 1)
    if isinstance(value, np.generic):
        return jsonable(value.item(), depth + 1)
    if isinstance(value, np.ndarray):
        if value.size <= 64:
            return jsonable(value.tolist(), depth + 1)
        numeric = value.dtype.kind in "biuf"
        return {
            "shape": list(value.shape),
            "mean": float(value.mean()) if numeric else None,
            "nonzero": int(np.count_nonzero(value)),
        }
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name), depth + 1) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): jsonable(v, depth + 1) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [jsonable(v, depth + 1) for v in value]
    return str(value)


def diagnosis_record(diag: object) -> dict:
    """What a diagnosis named: ``found`` (names, best first), ``params`` and ``scores`` by name, each
    effect's other keys, and the diagnosis' fields beyond today's (``negligible``, ``artefacts``, ...)."""
    effects = list(getattr(diag, "effects", []) or [])
    names = [e["name"] for e in effects] if effects else list(getattr(diag, "names", []) or [])
    record = {
        "found": names,
        "params": {e["name"]: jsonable(e.get("params", {})) for e in effects},
        "scores": {e["name"]: jsonable(e.get("score")) for e in effects},
        "effect_extras": {
            e["name"]: jsonable({k: v for k, v in e.items() if k not in ("name", "params", "score")})
            for e in effects
            if set(e) - {"name", "params", "score"}
        },
        "base": jsonable(getattr(diag, "base", None)),
    }
    fields = {f.name for f in dataclasses.fields(diag)} if dataclasses.is_dataclass(diag) else set()
    extras = {name: getattr(diag, name) for name in sorted(fields - _KNOWN_FIELDS)}
    extras.update({n: getattr(diag, n) for n in _EXTRA_NAMES if n not in extras and hasattr(diag, n)})
    record["extras"] = {k: jsonable(v) for k, v in extras.items() if not callable(v)}
    return record


_INTERNAL_VALUE_ERRORS = (
    re.compile(r"\b(" + "|".join((*EFFECT_NAMES, "periodic_source")) + r")[.:]"),  # a parameter check
    re.compile(r"anisotropy tensor"),
    re.compile(r"^effect '\w+' (has no|is missing)"),
)


def classify_error(err: BaseException) -> str:
    """``"input"`` for a clean ``ValueError`` about the input (the diagnosis refused the video),
    ``"internal"`` for any other exception or a ``ValueError`` from an internal parameter check (e.g.
    ``heterogeneity.a_inside must be non-negative``)."""
    if type(err) is not ValueError:
        return "internal"
    text = str(err)
    return "internal" if any(p.search(text) for p in _INTERNAL_VALUE_ERRORS) else "input"


def diagnose(frames: object, dt: float, dx: float) -> tuple[object, object]:
    """What the library names in a video: :func:`anra_torch.selection.diagnose_terms` (the stepwise
    selection) and the model whose effects earn their place by their own forecast inside the frames
    (:func:`anra_torch.forecast.earned_diagnosis`, what ``anra diagnose`` reports)."""
    from anra_torch.forecast import earned_diagnosis
    from anra_torch.selection import diagnose_terms

    stepwise = diagnose_terms(frames, dt, dx)
    return stepwise, earned_diagnosis(frames, dt, dx, stepwise)


def measure_gain(frames: object, dt: float, dx: float) -> dict:
    """The forecast gain of :func:`anra_torch.forecast.assess_gain` as record fields (``gain_error``
    instead when it fails): the earned model of the fit part (:func:`diagnose` of its frames) against
    the plain one on the held-out frames."""
    try:
        from anra_torch.forecast import assess_gain, earned_diagnosis, split_index

        t0 = time.perf_counter()
        fit = frames[: split_index(frames.shape[0], 0.6) + 1]
        g = assess_gain(frames, dt, dx, diagnosis=earned_diagnosis(fit, dt, dx))
        return {
            "gain_seconds": time.perf_counter() - t0,
            "gain": float(g.gain),
            "gain_raw": float(g.gain_raw),
            "gain_above_floor": float(g.gain_above_floor),
            "base_over_floor": float(g.base_rmse / g.noise_floor) if g.noise_floor > 0 else None,
            "gain_effects": [e.name for e in g.effects],
            "gain_result": {
                k: (float(v) if isinstance(v, (int, float)) else str(v))
                for k, v in getattr(g, "__dict__", {}).items()
                if isinstance(v, (int, float, str))
            },
        }
    except Exception as err:  # noqa: BLE001 - a failed gain is a result
        return {"gain_error": f"{type(err).__name__}: {err}"}


# ---------------------------------------------------------------------------------- running cases
def _setup_worker() -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)


def gain_available(no_gain: bool) -> bool:
    """Whether ``anra_torch.forecast.assess_gain`` imports (and is wanted)."""
    if no_gain:
        return False
    try:
        from anra_torch.forecast import assess_gain  # noqa: F401

        return True
    except Exception as err:  # noqa: BLE001
        print(f"gain: not measured (anra_torch.forecast.assess_gain does not import: {err})", file=sys.stderr)
        return False


def run_jobs(
    function: Callable[[tuple], dict | list[dict]], jobs: list[tuple], workers: int, out: Path
) -> tuple[list[dict], float]:
    """Run ``function`` on every job (``workers`` spawned processes of one thread each), keeping each
    record in ``out/records.partial.jsonl`` as it comes; returns the records and the wall time (s)."""
    start = time.perf_counter()
    records: list[dict] = []
    out.mkdir(parents=True, exist_ok=True)
    with (out / "records.partial.jsonl").open("w") as partial:

        def keep(result: dict | list[dict]) -> None:
            for rec in result if isinstance(result, list) else [result]:
                records.append(rec)
                partial.write(json.dumps(rec, default=str) + "\n")
            partial.flush()

        if workers > 1:
            ctx = mp.get_context("spawn")
            with ctx.Pool(workers, initializer=_setup_worker) as pool:
                for result in tqdm(pool.imap_unordered(function, jobs), total=len(jobs), desc="cases"):
                    keep(result)
        else:
            _setup_worker()
            for job in tqdm(jobs, desc="cases"):
                keep(function(job))
    return records, time.perf_counter() - start


def write_results(out: Path, text: str, results: dict) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(text)
    (out / "results.json").write_text(json.dumps(results, indent=1, default=str))
    print(text)
