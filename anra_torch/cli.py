"""Command line: ``anra estimate``, ``diagnose``, ``simulate``, ``demo`` (also ``python -m anra_torch``).

Units everywhere: lengths in mm, times in s, diffusivity in mm^2/s, temperatures in the data's own unit.
Every failure the user can cause (bad file, bad flag, a video without thermal activity) ends in one line
``anra: error: <message>`` on stderr and exit status 2, never a traceback.

``anra estimate --json`` prints one object on one line:

- ``path``; ``diffusivity`` and ``std_error`` (mm^2/s, null when no estimate); ``valid`` (bool) and
  ``message`` (the reason when not valid, a warning for a significantly negative diffusivity, else "");
- ``frames``, ``height``, ``width`` (px); ``dt`` (s); ``dx`` (mm); ``mode``;
- ``smoothing_px`` (the Gaussian sigma chosen from the data); ``noise_sd`` (data units); ``reliability``
  (signal fraction of the regressor energy, 1 is noiseless); ``n_masked`` (non-finite pixel values);
- ``window_px``, ``field_median`` (mm^2/s), ``field_coverage`` (pixel fraction) with ``--window``, else null;
- ``a_true`` (mm^2/s) when the file records the truth, else null; ``elapsed_s``; ``units`` (key -> unit).

A video without measurable thermal activity still prints its flagged object with ``--json`` (``valid``
false) and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from anra_torch.checks import one_line
from anra_torch.effects import EFFECTS, HiddenEffectVideo, hidden_effect_video
from anra_torch.layers.estimator import MODES, ANRAEstimator, ANRAResult
from anra_torch.report import format_pm, write_estimate_report
from anra_torch.synthetic import SyntheticVideo, blobs_video, paper_video
from anra_torch.video import REGISTRY, Video, load_video, prepare_video, save_npz

__all__ = ["PRESETS", "main", "build_parser"]

PROG = "anra"
DEMO_TRUTH = 0.2  # mm^2/s, the paper's simulation
DEMO_PAPER_ESTIMATE = 0.189  # mm^2/s, what El-Kebir et al. report for it
DEMO_WINDOW = 15  # px, windowed field in the demo report


def _add_spacing_arguments(parser: argparse.ArgumentParser, source: str) -> None:
    """--dt, --dx and --resample, shared by every command that reads videos (``source``: "the file(s)")."""
    parser.add_argument(
        "--dt", type=_number("s", positive=True), metavar="S", help=f"frame period in s (overrides {source})"
    )
    parser.add_argument(
        "--dx", type=_number("mm", positive=True), metavar="MM", help=f"pixel size in mm (overrides {source})"
    )
    parser.add_argument(
        "--resample",
        action="store_true",
        help="interpolate non-uniform timestamps (e.g. FLIR EXIF times) linearly onto their median step; "
        "the output states it",
    )


def _add_video_arguments(parser: argparse.ArgumentParser, formats: str) -> None:
    """VIDEO, --dt, --dx, --resample, --roi and --calibration, shared by the commands that read a video."""
    parser.add_argument(
        "video",
        metavar="VIDEO",
        help=f"video file ({formats}) or a folder with one file per frame (FLIR .jpg, .csv/.txt matrices); "
        "frames (T, H, W)",
    )
    _add_spacing_arguments(parser, "the file")
    _add_region_arguments(parser)


def _add_region_arguments(parser: argparse.ArgumentParser) -> None:
    """--roi and --calibration: what :func:`prepare_video` does after loading."""
    parser.add_argument(
        "--roi",
        metavar="X0,Y0,W,H",
        help="analyse only this region (px: first column, first row, width, height)",
    )
    parser.add_argument(
        "--calibration",
        metavar="CSV",
        help="map apparent to true temperature with a table of 'true,apparent' rows "
        "(e.g. calibration_og.csv)",
    )


def _load_input(args: argparse.Namespace) -> Video:
    """The video of VIDEO prepared by :func:`prepare_video` with --dt, --dx, --resample, --roi and
    --calibration; ``meta`` says what was done."""
    try:
        return prepare_video(
            args.video,
            dt=args.dt,
            dx=args.dx,
            timestamps="resample" if args.resample else "uniform",
            roi=args.roi,
            calibration=args.calibration,
        )
    except ValueError as err:  # the library's hint names its argument; here the flag is the fix
        raise ValueError(
            str(err).replace("(timestamps='resample' or 'keep' in load_video)", "(--resample)")
        ) from None


def _input_record(video: Video) -> dict[str, Any]:
    """What the loading did: ``resampled`` (from what), ``roi`` (px), ``calibration``; null when not done."""
    return {key: video.meta.get(key) for key in ("resampled", "roi", "calibration")}


def _print_input(video: Video) -> None:
    r = video.meta.get("resampled")
    if r:
        print(
            f"  resampled: {r['from_frames']} frames with non-uniform steps "
            f"{r['step_min']:.3g}-{r['step_max']:.3g} s "
            f"-> {video.frames.shape[0]} frames at dt = {r['dt']:.4g} s ({r['method']})"
        )
    if video.meta.get("roi"):
        print(f"  roi (x0, y0, width, height px): {video.meta['roi']}")
    c = video.meta.get("calibration")
    if c:
        print(f"  calibrated with {c['table']} ({100 * c['outside_fraction']:.1f} % of values extrapolated)")


class _UsageError(Exception):
    """A command-line mistake found by argparse (reported in one line, exit 2)."""


class _Parser(argparse.ArgumentParser):
    """argparse that raises on a usage error instead of printing the usage block and exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(f"{message} (see '{self.prog} --help')")


# ----------------------------------------------------------------------------------- flag types
def _number(unit: str, *, positive: bool) -> Callable[[str], float]:
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or (value <= 0 if positive else value < 0):
            need = "positive" if positive else "non-negative"
            raise argparse.ArgumentTypeError(f"must be a {need} number in {unit}, got {text!r}")
        return value

    return parse


def _integer(unit: str, *, minimum: int, odd: bool = False) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum or (odd and value % 2 == 0):
            kind = "an odd" if odd else "an"
            bound = f"{minimum} {unit}".strip()
            raise argparse.ArgumentTypeError(f"must be {kind} integer >= {bound}, got {text!r}")
        return value

    return parse


# ------------------------------------------------------------------------------------- estimate
def _summary(video: Video, result: ANRAResult, est: ANRAEstimator, elapsed: float) -> dict[str, Any]:
    """The ``estimate --json`` object (also the source of the human summary): the result's
    :meth:`~ANRAResult.to_record` with the video's shape and spacing, the estimator's settings and timing."""
    t, h, w = video.frames.shape
    record = result.to_record(unit=video.unit)
    units = record["units"]
    summary: dict[str, Any] = {
        "path": str(video.source),
        **{key: record[key] for key in ("diffusivity", "std_error", "valid", "message")},
        "frames": t,
        "height": h,
        "width": w,
        "dt": video.dt,
        "dx": video.dx,
        "mode": est.mode,
        **{key: record[key] for key in ("smoothing_px", "noise_sd", "reliability", "n_masked")},
        "window_px": est.window,
        "field_median": None,
        "field_coverage": None,
        "a_true": video.truth.a if video.truth is not None else None,
        "elapsed_s": round(elapsed, 3),
        "units": {
            **{key: units[key] for key in ("diffusivity", "std_error")},
            "dt": "s",
            "dx": "mm",
            **{key: units[key] for key in ("smoothing_px", "noise_sd")},
            "elapsed_s": "s",
        },
    }
    if result.field is not None:
        finite = result.field[result.field.isfinite()]
        summary["field_coverage"] = float(finite.numel() / result.field.numel())
        if finite.numel():
            summary["field_median"] = float(finite.median())
    return summary


def _print_summary(s: dict[str, Any]) -> None:
    a = s["diffusivity"]
    print(f"{s['path']}")
    print(f"  diffusivity a = {format_pm(a, s['std_error'], 'mm^2/s')} ({s['mode']}, ± 1 standard error)")
    print(
        f"  video: {s['frames']} frames of {s['height']} x {s['width']} px, "
        f"dt = {s['dt']:.6g} s ({1 / s['dt']:.4g} Hz), dx = {s['dx']:.6g} mm"
    )
    print(
        f"  smoothing {s['smoothing_px']:g} px (chosen from the data), noise sd {s['noise_sd']:.4g} "
        f"{s['units']['noise_sd']}, reliability {s['reliability']:.3f}"
    )
    if s["n_masked"]:
        print(f"  masked {s['n_masked']} non-finite pixel values")
    if s["message"]:
        print(f"  {s['message']}")
    if s["window_px"] is not None:
        median = f"median {s['field_median']:.4g} mm^2/s" if s["field_median"] is not None else "no estimate"
        print(
            f"  field ({s['window_px']} px windows): {median} on {100 * s['field_coverage']:.1f} % of pixels"
        )
    if s["a_true"] is not None:
        truth = float(s["a_true"])
        error = f" (error {100 * (a - truth) / truth:+.3g} %)" if truth else ""
        print(f"  file's a_true = {truth:g} mm^2/s{error}")
    print(f"  took {s['elapsed_s']:.2f} s")


def _run_estimate(args: argparse.Namespace) -> int:
    est = ANRAEstimator(mode=args.mode, window=args.window, strict=False)
    video = _load_input(args)
    start = time.perf_counter()
    try:
        result = est(video.frames, video.dt, video.dx)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{video.source}: {err}") from err
    summary = _summary(video, result, est, time.perf_counter() - start)
    if any(_input_record(video).values()):
        summary["input"] = _input_record(video)
    if args.json:
        print(json.dumps(summary, allow_nan=False))
    if not summary["valid"]:
        # No diffusivity: exit 2 in both modes; --json still printed its flagged record above.
        print(f"{PROG}: error: {video.source}: {summary['message']}", file=sys.stderr)
        return 2
    if not args.json:
        _print_summary(summary)
        _print_input(video)
    return 0


# ------------------------------------------------------------------------------------- simulate
@dataclass(frozen=True)
class Preset:
    """A synthetic video recipe for ``anra simulate``.

    Attributes:
        build: makes the video from the resolved flags (keyword arguments named after the flags:
            ``a`` mm^2/s, ``noise`` sd, ``seed``, ``fps`` Hz, ``frames``, ``size`` px, ``dx`` mm; plus
            ``effects`` (names) and ``params`` (``{effect: {key: value}}``) when ``effects`` is set).
        defaults: flag values used when the flag is absent (None: the builder decides, see ``shown``).
        help: one line for ``--help``.
        shown: how ``--help`` states a default that is not a plain number.
        effects: whether the scene takes ``--effect`` / ``--param`` (hidden effects with their truth).
    """

    build: Callable[..., SyntheticVideo | HiddenEffectVideo]
    defaults: dict[str, float | int | None]
    help: str
    shown: dict[str, str] = field(default_factory=dict)
    effects: bool = False

    def default_text(self, key: str) -> str:
        value = self.defaults[key]
        return self.shown.get(key) or f"{value:.4g}"


def _paper(
    *, a: float, noise: float, seed: int, fps: float, frames: int, size: int, dx: float | None
) -> SyntheticVideo:
    extent = 10.0 if dx is None else dx * size  # the paper's 10 mm field of view unless dx is given
    return paper_video(
        seed=seed, noise_sd=noise, fps=fps, duration=(frames - 1) / fps, size=size, extent=extent, a=a
    )


def _blobs(
    *, a: float, noise: float, seed: int, fps: float, frames: int, size: int, dx: float
) -> SyntheticVideo:
    return blobs_video(seed=seed, noise_sd=noise, fps=fps, n_frames=frames, size=size, dx=dx, a=a)


def _hidden(
    *,
    a: float,
    noise: float | None,
    seed: int,
    fps: float,
    frames: int,
    size: int,
    dx: float,
    effects: Sequence[str] = (),
    params: dict[str, dict[str, float]] | None = None,
) -> HiddenEffectVideo:
    if frames < 2:
        raise ValueError(f"the hidden scene needs at least 2 frames (--frames or --duration), got {frames}")
    return hidden_effect_video(
        effects,
        seed=seed,
        size=size,
        dx=dx,
        fps=fps,
        duration=(frames - 1) / fps,
        a=a,
        noise_sd=noise,
        params=params,
    )


PRESETS: dict[str, Preset] = {
    "paper": Preset(
        _paper,
        {"a": 0.2, "noise": 0.01, "fps": 27.0, "frames": 28, "size": 224, "dx": None},
        "El-Kebir et al.'s case: one Gaussian (peak 3.8, 50 px FWHM), 224 px over 10 mm, 27 Hz for 1 s",
        {"dx": "10 mm / size"},
    ),
    "blobs": Preset(
        _blobs,
        {"a": 0.15, "noise": 0.02, "fps": 30.0, "frames": 40, "size": 96, "dx": 0.5},
        "three Gaussian hot spots at random places on a warm background, 96 px at 0.5 mm, 30 Hz",
    ),
    "hidden": Preset(
        _hidden,
        {"a": 0.15, "noise": None, "fps": 30.0, "frames": 91, "size": 96, "dx": 0.5},
        "one or two Gaussian hot spots (rise 5-20) on a background of 30, 96 px at 0.5 mm, 30 Hz for 3 s, "
        "plus the --effect terms (the scene of --effect)",
        {"noise": "0.01 x the peak rise"},
        effects=True,
    ),
}
"""``anra simulate --preset NAME``: a new preset is one more entry."""


def _crop(video: SyntheticVideo | HiddenEffectVideo, crop: int) -> SyntheticVideo | HiddenEffectVideo:
    size = video.frames.shape[-1]
    if crop > size:
        raise ValueError(f"--crop must be at most the frame size {size} px, got {crop}")
    start = (size - crop) // 2
    if isinstance(video, HiddenEffectVideo):  # also shifts the positions in the truth to the window
        return video.crop(start, start, crop, crop)
    window = (..., slice(start, start + crop), slice(start, start + crop))
    return replace(video, frames=video.frames[window].contiguous(), clean=video.clean[window].contiguous())


def _effect_list(text: str) -> list[str]:
    """``--effect NAME[,NAME...]``."""
    names = [name.strip() for name in text.split(",")]
    for name in names:
        if name not in EFFECTS:
            raise argparse.ArgumentTypeError(
                f"unknown effect {name!r}; expected one of: {', '.join(EFFECTS)}"
            )
    return names


def _effect_param(text: str) -> tuple[str, str, float]:
    """``--param NAME.KEY=VALUE``."""
    target, _, value = text.partition("=")
    name, _, key = target.strip().partition(".")
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not (name and key and math.isfinite(number)):
        raise argparse.ArgumentTypeError(
            f"must be NAME.KEY=VALUE with a finite number, e.g. source.rate=2.5, got {text!r}"
        )
    if name not in EFFECTS:
        raise argparse.ArgumentTypeError(f"unknown effect {name!r}; expected one of: {', '.join(EFFECTS)}")
    return name, key, number


def _preset_name(args: argparse.Namespace) -> str:
    """``--preset``, by default ``hidden`` with ``--effect`` and ``paper`` without."""
    if args.preset is not None:
        return args.preset
    return "hidden" if args.effect else "paper"


def _effect_options(args: argparse.Namespace) -> tuple[list[str], dict[str, dict[str, float]]]:
    """The ``--effect`` names and the ``--param`` values grouped by effect."""
    names = [name for group in args.effect or [] for name in group]
    params: dict[str, dict[str, float]] = {}
    for name, key, value in args.param or []:
        if name not in names:
            raise ValueError(
                f"--param {name}.{key}={value:g}: effect {name!r} is not simulated; add it to --effect"
            )
        params.setdefault(name, {})[key] = value
    return names, params


def _synthesize(args: argparse.Namespace) -> SyntheticVideo | HiddenEffectVideo:
    """Preset with the flags (and for a scene with effects, ``--effect`` / ``--param``), then the crop."""
    name = _preset_name(args)
    preset = PRESETS[name]
    names, params = _effect_options(args)
    extra: dict[str, Any] = {}
    if preset.effects:
        extra = {"effects": names, "params": params}
    elif names:
        scenes = ", ".join(k for k, p in PRESETS.items() if p.effects)
        raise ValueError(f"--effect needs a scene with effects (--preset {scenes}), got --preset {name}")
    options = dict(preset.defaults)
    options.update({k: getattr(args, k) for k in preset.defaults if getattr(args, k) is not None})
    if args.duration is not None:
        options["frames"] = round(args.duration * options["fps"]) + 1
    video = preset.build(seed=args.seed, **options, **extra)
    return _crop(video, args.crop) if args.crop is not None else video


def _run_simulate(args: argparse.Namespace) -> int:
    video = _synthesize(args)
    name = _preset_name(args)
    if isinstance(video, HiddenEffectVideo):
        path = video.to_npz(args.out, preset=name)
        noise = video.noise_sd
        t, h, w = video.frames.shape
        truth = "; ".join(
            f"{e.name} " + ", ".join(f"{k}={v:.4g}" for k, v in e.to_dict()["params"].items())
            for e in video.effects
        )
        effects = f", effects: {truth or 'none'}"
    else:
        noise = args.noise if args.noise is not None else PRESETS[name].defaults["noise"]
        path = save_npz(
            args.out,
            video.frames[0],
            dt=video.dt,
            dx=video.dx,
            t=video.times,
            a_true=video.a,
            noise_sd=noise,
            seed=args.seed,
            preset=name,
        )
        t, h, w = video.frames.shape[1:]
        effects = ""
    print(
        f"wrote {path}: {t} frames of {h} x {w} px, dt = {video.dt:.6g} s, dx = {video.dx:.6g} mm, "
        f"a = {video.a:g} mm^2/s, noise sd {noise:g}, seed {args.seed}{effects}"
    )
    return 0


# ------------------------------------------------------------------------------------- diagnose
def _signed(value: float, spec: str) -> str:
    """``+ 0.20`` or ``- 0.20``: a term joined to the previous one."""
    return f"{'-' if value < 0 else '+'} {abs(value):{spec}}"


def _equation(a: float, effects: Sequence[Any]) -> str:
    """A human-readable ``dT/dt = ...`` of the extended model (``effects``: :class:`Effect` s)."""
    byname = {e.name: e.params for e in effects}
    if "anisotropy" in byname:
        p = byname["anisotropy"]
        diffusion = f"{p['a_x']:.3f} T_xx + {p['a_y']:.3f} T_yy {_signed(2 * p['a_xy'], '.3f')} T_xy"
    elif "heterogeneity" in byname:
        p = byname["heterogeneity"]
        diffusion = (
            f"div(a grad T) [a = {p['a_inside']:.3f} in the disc r < {p['radius']:.2f} mm around "
            f"({p['x']:.2f}, {p['y']:.2f}) mm, {p['a_outside']:.3f} outside]"
        )
    elif "nonlinear_diffusion" in byname:
        p = byname["nonlinear_diffusion"]
        diffusion = f"div({p['a0']:.3f} (1 + {p['beta']:.3g} (T - {p['T_ref']:.1f})) grad T)"
    else:
        diffusion = f"{a:.3f} Lap T"
    terms = [diffusion]
    if "linear_loss" in byname:
        p = byname["linear_loss"]
        terms.append(f"{_signed(-p['b'], '.2f')} (T - {p['T_ref']:.1f})")
    if "advection" in byname:
        p = byname["advection"]
        terms.append(f"- ({p['vx']:.2f} dT/dx {_signed(p['vy'], '.2f')} dT/dy)")
    if "source" in byname:
        p = byname["source"]
        terms.append(
            f"+ {p['rate']:.2f} G(width {p['width']:.2f} mm, ({p['x0']:.2f}, {p['y0']:.2f}) -> "
            f"({p['x1']:.2f}, {p['y1']:.2f}) mm)"
        )
    return "dT/dt = " + " ".join(terms)


def _clean_json(value: Any) -> Any:
    """NaN and infinities -> None, recursively (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _clean_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean_json(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _diagnose_summary(video: Video, args: argparse.Namespace) -> tuple[dict[str, Any], Any, Any]:
    """The ``diagnose --json`` object, the :class:`GainResult` it was made from, and the
    :class:`SourceMapGain` with ``--source-map`` (else None)."""
    from anra_torch.prediction import assess_gain, extended_effects

    frames = video.frames
    try:
        result = assess_gain(
            frames, video.dt, video.dx, fit_fraction=args.fit_fraction, assimilate=args.assimilate
        )
    except (ValueError, TypeError) as err:
        raise ValueError(f"{video.source}: {err}") from err
    diagnosis = result.diagnosis
    per_effect = [
        {"name": record["name"], "params": dict(record["params"]), "gain": gain}
        for record, gain in zip(diagnosis.effects, result.effect_gains, strict=True)
    ]
    diagnosed = extended_effects(diagnosis)  # timed from the first frame (result.effects: from the split)
    params: dict[str, Any] = {"a": diagnosis.base}
    params.update({e.name: dict(e.params) for e in diagnosed})
    summary = {
        "base": {"diffusivity": diagnosis.a_plain, "prediction_rmse": result.base_rmse},
        "effects": per_effect,
        "extended": {
            "equation": _equation(diagnosis.base, diagnosed),
            "params": params,
            "prediction_rmse": result.extended_rmse,
        },
        "gain": result.gain,
        "noise_floor": result.noise_floor,
        "scale_px": result.scale_px,
        "time_window": result.time_window,
        "assimilated": result.assimilated,
        "gain_above_floor": result.gain_above_floor,
        "raw": {
            "base_rmse": result.base_rmse_raw,
            "extended_rmse": result.extended_rmse_raw,
            "gain": result.gain_raw,
            "noise_floor": result.noise_floor_raw,
        },
    }
    mapped = None
    if args.source_map:
        from anra_torch.source_map import source_map_gain

        try:
            mapped = source_map_gain(frames, video.dt, video.dx, result)
        except ValueError as err:
            raise ValueError(f"{video.source}: --source-map: {err}") from err
        summary["source_map"] = {
            "equation": "dT/dt = a Lap T - b T + q(x, y)",
            "a": mapped.model.a,
            "b": mapped.model.b,
            "q_max": float(mapped.model.forcing.max()),
            "q_min": float(mapped.model.forcing.min()),
            "prediction_rmse": mapped.rmse,
            "gain": mapped.gain,
        }
    if any(_input_record(video).values()):
        summary["input"] = _input_record(video)
    return _clean_json(summary), result, mapped


def _run_diagnose(args: argparse.Namespace) -> int:
    try:
        if not 0 < args.fit_fraction < 1:
            raise ValueError(f"--fit-fraction must be in (0, 1), got {args.fit_fraction:g}")
        video = _load_input(args)
        summary, result, mapped = _diagnose_summary(video, args)
    except (ValueError, TypeError, OSError) as err:
        if args.json:  # batch users keep a row
            print(json.dumps({"path": str(args.video), "error": one_line(err)}))
        raise
    if args.json:
        print(json.dumps(summary, allow_nan=False))
    else:
        base, ext = summary["base"], summary["extended"]
        print(f"{video.source}")
        _print_input(video)
        print(
            f"  plain heat equation: a = {base['diffusivity']:.4g} mm^2/s, forecast RMSE "
            f"{base['prediction_rmse']:.4g} (noise floor {summary['noise_floor']:.4g} {video.unit}, frames "
            f"smoothed by a {summary['scale_px']:g} px Gaussian and averaged over {summary['time_window']} "
            f"frames; forecasts from the state of the last {summary['assimilated']} fit frames)"
        )
        if summary["effects"]:
            found = ", ".join(f"{e['name']} (gain {e['gain']:.2f})" for e in summary["effects"])
            print(f"  effects: {found}")
            print(f"  extended: {ext['equation']}")
            print(f"  extended forecast RMSE {ext['prediction_rmse']:.4g}, gain {summary['gain']:.3f}")
        else:
            print("  no effect beyond heat diffusion found (gain 0)")
        if "source_map" in summary:
            sm = summary["source_map"]
            print(
                f"  source map: a = {sm['a']:.4g} mm^2/s, b = {sm['b']:.4g} 1/s, q {sm['q_min']:.4g} to "
                f"{sm['q_max']:.4g} {video.unit}/s; forecast RMSE {sm['prediction_rmse']:.4g}, "
                f"gain {sm['gain']:.3f}"
            )
        print(
            f"  diagnosed frames 0-{result.split}, forecast {result.held_out} held-out frames "
            f"in {result.elapsed:.1f} s"
        )
    if args.report is not None:
        from anra_torch.report import write_diagnosis_report

        path = write_diagnosis_report(args.report, video, result.diagnosis, result, source_map=mapped)
        if not args.json:
            print(f"  report: {path}")
    return 0


# ------------------------------------------------------------------------------------- features
def _run_features(args: argparse.Namespace) -> int:
    from anra_torch.features import feature_summary, save_feature_maps

    video = _load_input(args)
    try:
        record, maps = feature_summary(video.frames, video.dt, video.dx, units=args.units)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{video.source}: {err}") from err
    record = {"path": str(video.source), **record, "out": None}
    if any(_input_record(video).values()):
        record["input"] = _input_record(video)
    if args.out is not None:
        record["out"] = save_feature_maps(args.out, maps, dt=video.dt, dx=video.dx)
    if args.json:
        print(json.dumps(_clean_json(record), allow_nan=False))
        return 0
    print(f"{video.source}: {record['frames']} frames of {record['height']} x {record['width']} px")
    _print_input(video)
    for key in (
        "peak_temperature_max",
        "cem43_minutes_max",
        "omega_max",
        "damaged_fraction",
        "diffusivity_global",
    ):
        value = record[key]
        shown = "n/a" if value is None else f"{value:.4g}"
        print(f"  {key}: {shown} {record['units'][key]}")
    if record["message"]:
        print(f"  note: {record['message']}")
    if record["out"]:
        print(f"  maps: {record['out']}")
    return 0


# ---------------------------------------------------------------------------------------- batch
def _run_batch(args: argparse.Namespace) -> int:
    from anra_torch.batch import run_batch

    options = {
        "dt": args.dt,
        "dx": args.dx,
        "diagnose": args.diagnose,
        "batch_size": args.batch_size,
        "dtype": "float64" if args.float64 else "float32",
        "progress": not args.no_progress,
        "resample": args.resample,
        "roi": args.roi,
        "calibration": args.calibration,
    }
    if args.dask or args.scheduler:
        from anra_torch.distributed import run_batch_dask

        summary = run_batch_dask(
            args.inputs, args.out, scheduler=args.scheduler, workers=args.workers, **options
        )
    else:
        summary = run_batch(args.inputs, args.out, **options)
    record = {
        "out": str(summary.out),
        "total": summary.total,
        "skipped": summary.skipped,
        "ok": summary.ok,
        "failed": summary.failed,
        "seconds": round(summary.seconds, 3),
    }
    if args.json:
        print(json.dumps(record))
    else:
        print(
            f"{summary.out}: {summary.ok} ok, {summary.failed} failed, {summary.skipped} already done "
            f"({summary.total} inputs) in {summary.seconds:.1f} s"
        )
    if summary.failed:
        print(
            f"{PROG}: error: {summary.failed} of {summary.total} inputs failed; see the 'error' column of "
            f"{summary.out}",
            file=sys.stderr,
        )
        return 2
    return 0


# ----------------------------------------------------------------------------------------- demo
def _run_demo(args: argparse.Namespace) -> int:
    if importlib.util.find_spec("matplotlib") is None:
        raise ImportError(
            "anra demo writes a report with matplotlib, which is not installed: pip install anra_torch[plot]"
        )
    out = Path(args.out)
    start = time.perf_counter()
    synthetic = paper_video(noise_sd=0.01, seed=0)
    path = save_npz(
        out / "paper_simulation.npz",
        synthetic.frames[0],
        dt=synthetic.dt,
        dx=synthetic.dx,
        t=synthetic.times,
        a_true=synthetic.a,
        noise_sd=0.01,
        seed=0,
        preset="paper",
    )
    video = load_video(path)
    est = ANRAEstimator(window=DEMO_WINDOW)
    tick = time.perf_counter()
    result = est(video.frames, video.dt, video.dx)
    estimated = time.perf_counter() - tick
    report = write_estimate_report(out, video, result, truth=DEMO_TRUTH, estimator=est)
    total = time.perf_counter() - start
    a, error = float(result.diffusivity), float(result.std_error)
    t, h, w = video.frames.shape
    print(
        f"anra demo: the simulation of El-Kebir et al. (arXiv 2203.13148): {t} frames of {h} x {w} px at "
        f"{1 / video.dt:g} Hz, dx = {video.dx:.4g} mm, a = {DEMO_TRUTH} mm^2/s, noise sd 0.01"
    )
    print(
        f"  estimate a = {format_pm(a, error, 'mm^2/s')}, error {100 * (a - DEMO_TRUTH) / DEMO_TRUTH:+.3g} % "
        f"against {DEMO_TRUTH} (the paper reports {DEMO_PAPER_ESTIMATE})"
    )
    print(
        f"  smoothing {float(result.smoothing):g} px chosen from the data, noise sd "
        f"{float(result.noise_sd):.4g}, reliability {float(result.reliability):.3f}"
    )
    print(f"  estimated in {estimated:.2f} s ({total:.1f} s with simulation and report)")
    print(f"  video:  {path}")
    print(f"  report: {report}")
    return 0


# --------------------------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    """The ``anra`` argument parser (usage errors raise instead of exiting; :func:`main` reports them)."""
    from anra_torch import __version__

    parser = _Parser(
        prog=PROG,
        description="Estimate the thermal diffusivity a of dT/dt = a (d11 + d22) T directly from thermal "
        "video (ANRA, El-Kebir et al., arXiv 2203.13148). Units: mm, s, mm^2/s; temperatures in any "
        "linear unit.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument(
        "--threads",
        type=_integer("threads", minimum=1),
        default=None,
        metavar="N",
        help="torch CPU threads (default: torch's choice, all cores); 1 is fastest when other processes "
        "share the cores, e.g. several 'anra batch' runs side by side",
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    formats = ", ".join(REGISTRY)
    estimate = commands.add_parser(
        "estimate",
        help="estimate the diffusivity (mm^2/s) of a video file",
        description=f"Estimate the diffusivity a (mm^2/s) of one video ({formats}). The spatial smoothing is "
        "chosen from the data; exit status 2 when no diffusivity can be estimated.",
    )
    _add_video_arguments(estimate, formats)
    estimate.add_argument(
        "--mode",
        choices=MODES,
        default="lsq",
        help="lsq: weighted least squares with errors-in-variables correction (default); "
        "ratio: the paper's attention-weighted average of dT/dt / Laplacian",
    )
    estimate.add_argument(
        "--window",
        type=_integer("px", minimum=1, odd=True),
        metavar="PX",
        help="also estimate a windowed field a(x, y) in mm^2/s over PX x PX pixel windows (odd)",
    )
    estimate.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (diffusivity and std_error in mm^2/s, dt in s, dx in mm, ...)",
    )
    estimate.set_defaults(run=_run_estimate)

    simulate = commands.add_parser(
        "simulate",
        help="write a synthetic video of known diffusivity, optionally with hidden effects (.npz)",
        description="Write an exact solution of the heat equation plus Gaussian noise as .npz (keys "
        "frames, dt in s, dx in mm, t in s, a_true in mm^2/s), readable by 'anra estimate'. With --effect, "
        "simulate dT/dt = a Lap T + the named effects (method of lines, RK4) on the 'hidden' scene and store "
        "the truth too: 'effects' (a JSON list of {name, params, units}) and, for heterogeneity, 'a_map'. "
        "Parameters not set by --param are drawn at random from --seed, clearly visible yet physical. "
        "Presets: " + "; ".join(f"{name}: {p.help}" for name, p in PRESETS.items()),
    )
    simulate.add_argument(
        "--preset",
        choices=list(PRESETS),
        default=None,
        help="the scene (default paper, or hidden with --effect)",
    )
    simulate.add_argument(
        "--effect",
        type=_effect_list,
        action="append",
        metavar="NAME[,NAME...]",
        help="hidden effects to add (repeatable; at most one of anisotropy, heterogeneity, "
        "nonlinear_diffusion): "
        + "; ".join(f"{name} ({', '.join(spec.params)})" for name, spec in EFFECTS.items()),
    )
    simulate.add_argument(
        "--param",
        type=_effect_param,
        action="append",
        metavar="NAME.KEY=VALUE",
        help="fix one effect parameter instead of drawing it (repeatable; units: mm, s, mm^2/s, K), "
        "e.g. advection.vx=0.5; the others are still drawn from --seed",
    )

    def preset_default(key: str) -> str:
        return "default " + ", ".join(f"{name} {p.default_text(key)}" for name, p in PRESETS.items())

    length = simulate.add_mutually_exclusive_group()
    for group, flag, kind, metavar, text in (
        (simulate, "--a", _number("mm^2/s", positive=False), "MM2S", "diffusivity in mm^2/s"),
        (
            simulate,
            "--noise",
            _number("temperature units", positive=False),
            "SD",
            "noise sd, temperature units",
        ),
        (simulate, "--fps", _number("Hz", positive=True), "HZ", "frame rate in Hz"),
        (simulate, "--size", _integer("px", minimum=1), "PX", "frame side in px"),
        (simulate, "--dx", _number("mm", positive=True), "MM", "pixel size in mm"),
        (length, "--frames", _integer("frames", minimum=1), "N", "number of frames"),
    ):
        group.add_argument(flag, type=kind, metavar=metavar, help=f"{text} ({preset_default(flag[2:])})")
    length.add_argument(
        "--duration",
        type=_number("s", positive=True),
        metavar="S",
        help="length in s: round(S * fps) + 1 frames",
    )
    simulate.add_argument(
        "--seed",
        type=_integer("", minimum=0),
        default=0,
        metavar="N",
        help="seed of the noise and, with --effect, of the scene and every parameter not set by --param "
        "(default 0)",
    )
    simulate.add_argument(
        "--crop",
        type=_integer("px", minimum=1),
        metavar="PX",
        help="keep the central PX x PX pixels (faster)",
    )
    simulate.add_argument("-o", "--out", required=True, metavar="OUT.npz", help="output file (.npz)")
    simulate.set_defaults(run=_run_simulate)

    diagnose = commands.add_parser(
        "diagnose",
        help="find hidden effects and test whether they forecast held-out frames better",
        description="Diagnose which effects beyond heat diffusion (linear_loss, source, advection, "
        "anisotropy, heterogeneity, nonlinear_diffusion) act in the first part of a video, then forecast "
        "the rest with the plain heat equation and with the extended model (RK4, zero-flux edges), each "
        "from its own state assimilated from the fit frames, and compare their RMSE on the interior at "
        "the evaluation scale (forecasts and held-out frames smoothed alike by the diagnosis' Gaussian "
        "and a 9-frame moving average in time). gain = 1 - RMSE_extended / "
        "RMSE_plain; the noise floor is a perfect model's RMSE at that scale; 'raw' holds the same against "
        "unsmoothed frames. Exit status 2 on bad input.",
    )
    _add_video_arguments(diagnose, formats)
    diagnose.add_argument(
        "--fit-fraction",
        type=_number("fraction of the frames", positive=True),
        default=0.6,
        metavar="F",
        help="fraction of the frames diagnosed, in (0, 1); the rest is forecast (default 0.6)",
    )
    diagnose.add_argument(
        "--assimilate",
        type=_integer("frames", minimum=1),
        default=None,
        metavar="N",
        help="fit frames (the last N) assimilated into each model's starting state; 1 starts from the "
        "measured split frame (default: all the fit frames)",
    )
    diagnose.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object: base, effects (with per-effect gain), extended, gain, noise_floor "
        "(an object with 'error' on failure)",
    )
    diagnose.add_argument(
        "--report", metavar="DIR", help="write report.md with figures (forecasts, residual, RMSE) to DIR"
    )
    diagnose.add_argument(
        "--source-map",
        action="store_true",
        help="also fit a stationary source map dT/dt = a Lap T - b T + q(x, y) on the same frames (a "
        "measured beam that is not a Gaussian spot) and report its forecast RMSE and gain ('source_map')",
    )
    diagnose.set_defaults(run=_run_diagnose)

    batch = commands.add_parser(
        "batch",
        help="estimate (and diagnose) many videos into one resumable CSV/Parquet table",
        description=f"Estimate the diffusivity of every video among INPUTS (files, folders, glob patterns; "
        f"{formats}) into one row each of OUT (.csv or .parquet). Same-shaped videos are estimated "
        "together; a bad file gets an error row and never stops the others; re-running skips inputs "
        "already ok; OUT is replaced atomically after every batch. Exit status 2 when an input failed "
        "(see its 'error' column).",
    )
    batch.add_argument("inputs", nargs="+", metavar="INPUT", help="video files, folders or glob patterns")
    batch.add_argument("--out", required=True, metavar="OUT", help="results table, .csv or .parquet")
    batch.add_argument(
        "--diagnose", action="store_true", help="also diagnose hidden effects (top_effect, gain, noise_floor)"
    )
    _add_spacing_arguments(batch, "the files")
    _add_region_arguments(batch)
    batch.add_argument(
        "--batch-size",
        type=_integer("videos", minimum=1),
        default=8,
        metavar="N",
        help="videos read and estimated together (default 8)",
    )
    batch.add_argument("--float64", action="store_true", help="compute in float64 (default float32)")
    batch.add_argument(
        "--dask", action="store_true", help="run on Dask (embedded LocalCluster unless --scheduler)"
    )
    batch.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address (implies --dask)")
    batch.add_argument(
        "--workers",
        type=_integer("workers", minimum=1),
        default=2,
        metavar="N",
        help="workers of the embedded LocalCluster (default 2)",
    )
    batch.add_argument("--no-progress", action="store_true", help="no progress bar")
    batch.add_argument(
        "--json", action="store_true", help="print one JSON object: out, total, skipped, ok, failed, seconds"
    )
    batch.set_defaults(run=_run_batch)

    demo = commands.add_parser(
        "demo",
        help="simulate the paper's case, estimate a (mm^2/s) and write a report",
        description="Simulate El-Kebir et al.'s case (a = 0.2 mm^2/s, 224 px over 10 mm, 27 Hz for 1 s, "
        "noise sd 0.01), estimate a with the default estimator and write report.md with figures.",
    )
    demo.add_argument(
        "--out", default="results/demo", metavar="DIR", help="output directory (default results/demo)"
    )
    demo.set_defaults(run=_run_demo)

    features = commands.add_parser(
        "features",
        help="tissue features of a video: thermal dose (CEM43, Omega), peak, rates, ANRA maps",
        description="Per-pixel tissue features of one video: peak temperature, time above 43/50/60 C, "
        "CEM43 (min), Arrhenius Omega (skin constants), heating and cooling rates (K/s), RTC attention, "
        "local diffusivity (mm^2/s) and its confidence, loss rate (1/s) and source (K) maps. "
        "Temperatures are reported in Celsius. Non-finite values are masked and counted.",
    )
    _add_video_arguments(features, formats)
    features.add_argument(
        "--units", choices=("C", "K"), default="C", help="temperature unit of the frames (default C)"
    )
    features.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object: cem43_minutes_max, omega_max, peak_temperature_max, ... with units",
    )
    features.add_argument(
        "--out", metavar="MAPS.npz", help="save the maps (one (H, W) array each) to MAPS.npz"
    )
    features.set_defaults(run=_run_features)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``anra`` command line; returns the exit status (0 ok, 2 error).

    Args:
        argv: arguments without the program name; default ``sys.argv[1:]``.
    """
    try:
        args = build_parser().parse_args(argv)
        if args.threads is not None:
            import torch

            torch.set_num_threads(args.threads)
        return args.run(args)
    except SystemExit as done:  # --help, --version
        return done.code if isinstance(done.code, int) else 0 if done.code is None else 2
    except _UsageError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    except (ValueError, TypeError, OSError, ImportError) as err:
        print(f"{PROG}: error: {one_line(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
