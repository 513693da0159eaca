"""Thermal videos of three tissues heated by a moving spot, each tissue with its own published Arrhenius
constants and its own ranges of diffusivity and perfusion: the scenes of :mod:`experiments.learning_pipeline`.

Tissues (:data:`TISSUES`; ``b`` is the loss rate of the bioheat model, ``b = w rho_b c_b / (rho c)`` for a
blood flow ``w``):

* skin: ``A = 3.1e98 1/s``, ``Ea = 6.28e5 J/mol`` (Henriques & Moritz 1947, Am J Pathol 23:531; Henriques
  1947, Arch Pathol 43:489); ``a`` 0.08-0.11 mm^2/s, ``b`` 0.001-0.006 1/s;
* liver: ``A = 7.39e39 1/s``, ``Ea = 2.577e5 J/mol`` (Jacques & Gaeeni 1989, pig liver coagulation, Lasers
  Surg Med Suppl 1; the constants of most liver ablation models); ``a`` 0.12-0.15 mm^2/s, ``b`` 0.01-0.03 1/s;
* arterial wall: ``A = 5.6e63 1/s``, ``Ea = 4.3e5 J/mol`` (Agah, Pearce, Welch & Motamedi 1994, Lasers Surg
  Med 15:176, rate process model of arterial tissue); ``a`` 0.11-0.14 mm^2/s, ``b`` 0.001-0.005 1/s.

The diffusivities are ``k / (rho c)`` of the IT'IS tissue database (Hasgall et al., v4: skin 0.098, liver
0.136, blood-vessel wall 0.126 mm^2/s) with a spread of about 15 %; the perfusions span its blood flows (skin
106, liver 860, vessel wall about 150 ml/min/kg), skin's up to the vasodilated flow of heated skin. The
ranges are our reading of those sources; muscle is left out for want of Arrhenius constants we could check.
The tissues differ where it matters: the temperature that damages in one minute (``T60``, rate 1/60 1/s)
is 54.0 C for skin, 50.1 C for liver and 69.6 C for arterial wall, and liver's small ``Ea`` makes it the most
sensitive to long exposures.

A scene: ``size`` x ``size`` px of 0.3 mm at 37 C; one tissue, or (a ``mixed`` share of the scenes) two
tissues meeting along a curved boundary (a vessel on an organ, an incision's edge), each with a smooth random
texture of its ranges. A broad Gaussian spot (sigma ``width`` mm) sweeps 0-2 mm for an exposure drawn
log-uniformly from ``exposure`` s, then the tissue cools until ``duration`` s; the power gives a surface peak
drawn uniformly from ``peak`` C (default 50-85: the span of the three tissues' thresholds at these
exposures). :class:`anra_torch.simulation.TissueRHS` integrates 32 scenes at a time at ``fine_dt``; truth:
``Omega >= 1`` with each pixel's own tissue constants (piecewise-linear rule) of the noiseless temperature.
Camera: every ``stride``-th frame (2 Hz by default) plus white noise of ``noise`` K.

Assumptions (each a way a clinic's scenes may differ): a surface layer (2-D bioheat; heat lost to depth
only through the loss rate), constant tissue properties (none changes as the tissue coagulates), one
Arrhenius process per tissue, white camera noise, a spot absorbed alike everywhere.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from anra_torch.simulation import TissueRHS, integrate, stable_substeps
from anra_torch.tissue import GAS_CONSTANT, SKIN, ArrheniusConstants, arrhenius_omega
from anra_torch.video import save_npz
from experiments.tissue_damage import camera, smooth_field

F64 = torch.float64
DX = 0.3  # mm


@dataclass(frozen=True)
class Tissue:
    """A tissue's Arrhenius constants and its ranges of diffusivity (mm^2/s) and perfusion (1/s)."""

    name: str
    constants: ArrheniusConstants
    diffusivity: tuple[float, float]
    perfusion: tuple[float, float]

    @property
    def t60(self) -> float:
        """The temperature (C) at which the damage rate is 1/60 1/s (Omega = 1 in one minute)."""
        c = self.constants
        return c.activation_energy / (GAS_CONSTANT * (math.log(c.frequency) + math.log(60))) - 273.15


TISSUES = (
    Tissue("skin", SKIN, (0.08, 0.11), (0.001, 0.006)),
    Tissue("liver", ArrheniusConstants(7.39e39, 2.577e5), (0.12, 0.15), (0.01, 0.03)),
    Tissue("arterial wall", ArrheniusConstants(5.6e63, 4.3e5), (0.11, 0.14), (0.001, 0.005)),
)
"""The scenes' tissues (sources in the module docstring)."""


@dataclass(frozen=True)
class SceneSettings:
    """What the scenes are (units: px, s, K, C): frame size, record, camera noise, spot, tissue mixing."""

    size: int = 32
    duration: float = 45.0
    noise: float = 0.2
    peak: tuple[float, float] = (50.0, 85.0)
    exposure: tuple[float, float] = (2.0, 30.0)
    width: tuple[float, float] = (1.5, 3.0)
    mixed: float = 1 / 3
    fine_dt: float = 0.1
    stride: int = 5

    def __post_init__(self) -> None:
        if not 20 <= self.size <= 48:
            raise ValueError(
                f"size must be 20-48 px (the layer's filters; the texture's grid), got {self.size}"
            )

    def key(self) -> dict:
        """What decides the scenes (a folder written with the same key is reused)."""
        keys = ("size", "duration", "noise", "peak", "exposure", "width", "mixed", "fine_dt", "stride")
        return {k: getattr(self, k) for k in keys} | {"tissues": [asdict(t) for t in TISSUES]}


def omega_of_tissues(history: Tensor, dt: float | Tensor, tissue: Tensor) -> Tensor:
    """Arrhenius Omega of each pixel with its own tissue's constants (piecewise-linear rule).

    Shape:
        ``history`` ``(B, T, H, W)`` (C) and ``tissue`` ``(B, H, W)`` (indices into :data:`TISSUES`) ->
        ``(B, H, W)``.
    """
    omega = torch.zeros_like(history[:, 0], dtype=F64)
    for k, t in enumerate(TISSUES):
        dose = arrhenius_omega(history, dt, constants=t.constants, rule="linear")
        omega = torch.where(tissue == k, dose, omega)
    return omega


# ------------------------------------------------------------------------------------------- scenes
def tissue_map(rng: np.random.Generator, settings: SceneSettings) -> Tensor:
    """Which tissue each pixel is, ``(H, W)`` (indices into :data:`TISSUES`)."""
    n, first = settings.size, int(rng.integers(len(TISSUES)))
    other = (first + 1 + int(rng.integers(len(TISSUES) - 1))) % len(TISSUES)
    angle, offset = rng.uniform(0, 2 * math.pi), rng.uniform(-0.25, 0.25) * n * DX
    wavelength, mixed = rng.uniform(6.0, 15.0), rng.uniform() < settings.mixed
    centre = (torch.arange(n, dtype=F64) + 0.5) * DX - n * DX / 2
    y, x = torch.meshgrid(centre, centre, indexing="ij")
    along = -x * math.sin(angle) + y * math.cos(angle)
    across = (
        x * math.cos(angle) + y * math.sin(angle) - offset + 0.6 * torch.sin(2 * math.pi * along / wavelength)
    )
    return torch.where((across > 0) & mixed, other, first)


def scene_setup(seed: int, settings: SceneSettings) -> dict:
    """A scene's tissue map, fields and spot (the same seed always gives the same scene)."""
    rng = np.random.default_rng(seed)
    tissue = tissue_map(rng, settings)
    n = settings.size
    a, b = torch.zeros(n, n, dtype=F64), torch.zeros(n, n, dtype=F64)
    for k, t in enumerate(TISSUES):  # every tissue's texture is drawn, so the stream never depends on the map
        a = torch.where(tissue == k, smooth_field(rng, *t.diffusivity)[:n, :n], a)
        b = torch.where(tissue == k, smooth_field(rng, *np.log(t.perfusion))[:n, :n].exp(), b)
    length, angle = rng.uniform(0.0, 2.0), rng.uniform(0, 2 * math.pi)
    mid = rng.uniform(0.35 * n * DX, 0.65 * n * DX, size=2)
    half = 0.5 * length * np.array([math.cos(angle), math.sin(angle)])
    exposure = math.exp(rng.uniform(*np.log(settings.exposure)))
    return {
        "tissue": tissue,
        "a": a,
        "b": b,
        "start": mid - half,
        "end": mid + half,
        "width": rng.uniform(*settings.width),
        "t_off": max(1, round(exposure / settings.fine_dt)) * settings.fine_dt,
        "peak": rng.uniform(*settings.peak),
    }


class _Spots(nn.Module):
    """:class:`anra_torch.simulation.TissueRHS` plus one moving Gaussian spot per scene (unit power, K/s)."""

    def __init__(self, rhs: TissueRHS, scenes: list[dict], size: int) -> None:
        super().__init__()
        self.rhs = rhs
        self.start = torch.tensor(np.array([s["start"] for s in scenes]), dtype=F64)
        self.end = torch.tensor(np.array([s["end"] for s in scenes]), dtype=F64)
        self.width = torch.tensor([s["width"] for s in scenes], dtype=F64)
        self.t_off = torch.tensor([s["t_off"] for s in scenes], dtype=F64)
        self.x = (torch.arange(size, dtype=F64) + 0.5) * DX

    def forward(self, t: Tensor, u: Tensor) -> Tensor:
        seconds = t * self.rhs.time_scale
        on = (seconds < self.t_off).to(F64).view(-1, 1, 1)
        where = self.start + (self.end - self.start) * (seconds / self.t_off).clamp(0, 1).unsqueeze(1)
        inverse = (0.5 / self.width**2).view(-1, 1)
        gx = torch.exp(-((self.x - where[:, :1]) ** 2) * inverse)
        gy = torch.exp(-((self.x - where[:, 1:]) ** 2) * inverse)
        return self.rhs(t, u) + on * gy.unsqueeze(2) * gx.unsqueeze(1) * self.rhs.time_scale


def simulate(seeds: list[int], settings: SceneSettings) -> dict:
    """Noiseless camera frames ``(B, T, H, W)``, true damage and tissue maps of the scenes ``seeds``.

    The heat equation with perfusion is linear in the source: each scene runs at unit power and is scaled
    to its peak. The batch's largest fields set the RK4 step (stable for every scene).
    """
    scenes = [scene_setup(s, settings) for s in seeds]
    a, b = torch.stack([s["a"] for s in scenes]), torch.stack([s["b"] for s in scenes])
    rhs = TissueRHS(a, b, dx=DX, body_temperature=37.0)
    count = stable_substeps(
        settings.fine_dt, DX, diffusivity=float(a.max()), decay=float(b.max()), policy="stable"
    )
    rhs.time_scale = settings.fine_dt / count.automatic
    n = settings.size
    frames = round(settings.duration / settings.fine_dt) + 1
    start = torch.full((len(seeds), n, n), 37.0, dtype=F64)
    rise = integrate(_Spots(rhs, scenes, n), start, n_frames=frames, substeps=count.automatic, perturb=True)
    rise = rise.transpose(0, 1) - 37.0  # (B, T, H, W)
    peaks = torch.tensor([s["peak"] for s in scenes], dtype=F64).view(-1, 1, 1, 1)
    truth = 37.0 + (peaks - 37.0) / rise.flatten(1).amax(1).view(-1, 1, 1, 1) * rise
    tissue = torch.stack([s["tissue"] for s in scenes])
    omega = omega_of_tissues(truth, settings.fine_dt, tissue)
    facts = [
        {
            "exposure_s": s["t_off"],
            "peak_c": s["peak"],
            "tissues": sorted({TISSUES[k].name for k in s["tissue"].unique().tolist()}),
        }
        for s in scenes
    ]
    return {"clean": truth[:, :: settings.stride], "damage": omega >= 1.0, "tissue": tissue, "facts": facts}


def write_scenes(folder: Path, seeds: range, settings: SceneSettings, *, chunk: int = 32) -> list[dict]:
    """Simulate the scenes of ``seeds`` and write each camera video (with its damage and tissue maps) to
    ``folder``; reuse the folder when it holds them for the same settings."""
    record = folder / "scenes.json"
    key = {"seeds": [seeds.start, seeds.stop], **settings.key()}
    if record.is_file() and json.loads(record.read_text())["key"] == json.loads(json.dumps(key)):
        return json.loads(record.read_text())["facts"]
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("scene_*.npz"):  # another set's videos would be read with these
        old.unlink()
    facts = []
    dt = settings.fine_dt * settings.stride
    for first in range(seeds.start, seeds.stop, chunk):
        batch = list(range(first, min(first + chunk, seeds.stop)))
        made = simulate(batch, settings)
        for k, seed in enumerate(batch):
            frames = camera(made["clean"][k], settings.noise, seed).float()
            damage, tissue = made["damage"][k], made["tissue"][k]
            save_npz(folder / f"scene_{seed:04d}.npz", frames, dt=dt, dx=DX, damage=damage, tissue=tissue)
            facts.append(made["facts"][k] | {"damaged_fraction": float(damage.double().mean())})
    record.write_text(json.dumps({"key": key, "facts": facts}))
    return facts
