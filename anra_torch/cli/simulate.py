"""``anra simulate``: a synthetic video of known diffusivity, optionally with hidden effects, as ``.npz``.

The file holds the truth too (``a_true``, ``noise_sd``, ``seed``, and with ``--effect`` the ``effects`` JSON),
which :func:`anra_torch.video.load_video` returns as :attr:`~anra_torch.video.Video.truth`.

A scene is a :class:`Preset` in :data:`PRESETS`: a new one is one more entry.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from anra_torch.checks import check_output
from anra_torch.cli.arguments import integer, number
from anra_torch.effects import EFFECTS, HiddenEffectVideo, Medium, Sensor, hidden_effect_video
from anra_torch.simulation import PaperSpot, SyntheticVideo, blobs_video, paper_video
from anra_torch.video import save_npz

__all__ = ["PRESETS", "Preset", "add_parser", "run"]


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
        min_size: the smallest ``--size`` in px the scene fits in, and why (for the message).
    """

    build: Callable[..., SyntheticVideo | HiddenEffectVideo]
    defaults: dict[str, float | int | None]
    help: str
    shown: dict[str, str] = field(default_factory=dict)
    effects: bool = False
    min_size: tuple[int, str] = (1, "")

    def default_text(self, key: str) -> str:
        value = self.defaults[key]
        return self.shown.get(key) or f"{value:.4g}"


def _paper(
    *, a: float, noise: float, seed: int, fps: float, frames: int, size: int, dx: float | None
) -> SyntheticVideo:
    extent = 10.0 if dx is None else dx * size  # the paper's 10 mm field of view unless dx is given
    spot = PaperSpot(extent=extent)
    return paper_video(
        seed=seed, noise_sd=noise, fps=fps, duration=(frames - 1) / fps, size=size, a=a, spot=spot
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
        medium=Medium(a=a),
        sensor=Sensor(noise_sd=noise),
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
        min_size=(49, "its blobs start with an sd of up to 12 px, and 4 sd must fit in the frame"),
    ),
    "hidden": Preset(
        _hidden,
        {"a": 0.15, "noise": None, "fps": 30.0, "frames": 91, "size": 96, "dx": 0.5},
        "one or two Gaussian hot spots (rise 5-20) on a background of 30, 96 px at 0.5 mm, 30 Hz for 3 s, "
        "plus the --effect terms (the scene of --effect)",
        {"noise": "0.01 x the peak rise"},
        effects=True,
        min_size=(16, "the scene's hot spots and effect regions need it"),
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
    least, why = preset.min_size
    if options["size"] < least:
        raise ValueError(
            f"--size must be at least {least} px for --preset {name} ({why}), got {options['size']}"
        )
    if args.duration is not None:
        options["frames"] = round(args.duration * options["fps"]) + 1
    video = preset.build(seed=args.seed, **options, **extra)
    return _crop(video, args.crop) if args.crop is not None else video


def run(args: argparse.Namespace) -> int:
    """Run ``anra simulate`` with the parsed ``args``; returns the exit status (0 ok, 2 error)."""
    out = check_output(args.out, name="-o")  # a folder or a device (-o /dev/null) is refused, not appended to
    check_output(out if out.suffix.lower() == ".npz" else out.with_name(out.name + ".npz"), name="-o")
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


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``simulate`` to the ``anra`` subcommands (``commands``: what ``add_subparsers`` returned)."""
    parser = commands.add_parser(
        "simulate",
        help="write a synthetic video of known diffusivity, optionally with hidden effects (.npz)",
        description="Write an exact solution of the heat equation plus Gaussian noise as .npz (keys "
        "frames, dt in s, dx in mm, t in s, a_true in mm^2/s), readable by 'anra estimate'. With --effect, "
        "simulate dT/dt = a Lap T + the named effects (method of lines, RK4) on the 'hidden' scene and store "
        "the truth too: 'effects' (a JSON list of {name, params, units}) and, for heterogeneity, 'a_map'. "
        "Parameters not set by --param are drawn at random from --seed, clearly visible yet physical. "
        "Presets: " + "; ".join(f"{name}: {p.help}" for name, p in PRESETS.items()),
    )
    parser.add_argument(
        "--preset",
        choices=list(PRESETS),
        default=None,
        help="the scene (default paper, or hidden with --effect)",
    )
    parser.add_argument(
        "--effect",
        type=_effect_list,
        action="append",
        metavar="NAME[,NAME...]",
        help="hidden effects to add (repeatable; at most one of anisotropy, heterogeneity, "
        "nonlinear_diffusion): "
        + "; ".join(f"{name} ({', '.join(spec.params)})" for name, spec in EFFECTS.items()),
    )
    parser.add_argument(
        "--param",
        type=_effect_param,
        action="append",
        metavar="NAME.KEY=VALUE",
        help="fix one effect parameter instead of drawing it (repeatable; units: mm, s, mm^2/s, K), "
        "e.g. advection.vx=0.5; the others are still drawn from --seed",
    )
    _add_scene_arguments(parser)
    parser.add_argument(
        "--seed",
        type=integer("", minimum=0),
        default=0,
        metavar="N",
        help="seed of the noise and, with --effect, of the scene and every parameter not set by --param "
        "(default 0)",
    )
    parser.add_argument(
        "--crop",
        type=integer("px", minimum=1),
        metavar="PX",
        help="keep the central PX x PX pixels (faster)",
    )
    parser.add_argument("-o", "--out", required=True, metavar="OUT.npz", help="output file (.npz)")
    parser.set_defaults(run=run)


def _add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """--a, --noise, --fps, --size, --dx, --frames | --duration, with the presets' defaults in their help."""

    def preset_default(key: str) -> str:
        text = "default " + ", ".join(f"{name} {p.default_text(key)}" for name, p in PRESETS.items())
        if key == "size":
            text += "; at least " + ", ".join(f"{n} {p.min_size[0]}" for n, p in PRESETS.items())
        return text

    length = parser.add_mutually_exclusive_group()
    for group, flag, kind, metavar, text in (
        (parser, "--a", number("mm^2/s", positive=False), "MM2S", "diffusivity in mm^2/s"),
        (
            parser,
            "--noise",
            number("temperature units", positive=False),
            "SD",
            "noise sd, temperature units",
        ),
        (parser, "--fps", number("Hz", positive=True), "HZ", "frame rate in Hz"),
        (parser, "--size", integer("px", minimum=1), "PX", "frame side in px"),
        (parser, "--dx", number("mm", positive=True), "MM", "pixel size in mm"),
        (length, "--frames", integer("frames", minimum=1), "N", "number of frames"),
    ):
        group.add_argument(flag, type=kind, metavar=metavar, help=f"{text} ({preset_default(flag[2:])})")
    length.add_argument(
        "--duration",
        type=number("s", positive=True),
        metavar="S",
        help="length in s: round(S * fps) + 1 frames",
    )
