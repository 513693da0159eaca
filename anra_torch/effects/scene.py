"""Hidden-effect scenes: random hot spots, effects drawn to be detectable, their simulation plus noise.

The ground truth that the diagnosis is tested against (:func:`hidden_effect_video`), with the true
effects recorded for every output (:class:`HiddenEffectVideo`, ``anra simulate --effect``).

A scene draws from ``numpy.random.default_rng(seed)``, in this order: one or two Gaussian hot spots on
the uniform background (rise 5-20, sigma 3-8 px, centres at least ``2.5 sigma + 10`` px inside the frame),
then each effect's parameters from its :attr:`~anra_torch.effects.EffectSpec.sample` in the order
given (ranges in each effect's module). The noise is white, sd ``noise_sd`` or else ``noise_frac`` times
the peak initial rise, from ``torch.Generator().manual_seed(seed)``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import check_dtype, check_int, number
from anra_torch.effects.base import Geometry, Grid
from anra_torch.effects.model import Effect, check_effects, effects_to_json
from anra_torch.effects.registry import EFFECTS, unknown_effect
from anra_torch.effects.simulate import simulate_effects
from anra_torch.simulation import gaussian_blobs
from anra_torch.video import save_npz

__all__ = ["HiddenEffectVideo", "Medium", "Scene", "Sensor", "draw_scene", "hidden_effect_video"]

_F64 = torch.float64


@dataclass(frozen=True)
class HiddenEffectVideo:
    """A synthetic thermal video with hidden effects and their true parameters.

    Attributes:
        frames: noisy temperatures.
        clean: the noise-free simulation.
        dt: frame period in s.
        dx: pixel size in mm.
        a: the reference diffusivity in mm^2/s: the base ``a``, or the effect's own when one replaces
            the diffusion term (``a_outside``, ``a0``, or ``sqrt(det A)`` for anisotropy).
        times: frame times ``k dt`` in s.
        effects: the effects with their true parameters.
        noise_sd: standard deviation of the added white noise in data units.
        seed: the seed everything was drawn from.
        a_map: the diffusivity field ``(H, W)`` in mm^2/s for ``heterogeneity``, else None.

    Shape:
        ``frames``, ``clean`` ``(T, H, W)``; ``times`` ``(T,)``; ``a_map`` ``(H, W)``.
    """

    frames: Tensor
    clean: Tensor
    dt: float
    dx: float
    a: float
    times: Tensor
    effects: tuple[Effect, ...]
    noise_sd: float
    seed: int
    a_map: Tensor | None = None

    @property
    def truth_json(self) -> str:
        """The true effects as JSON (:func:`effects_to_json`)."""
        return effects_to_json(self.effects)

    def crop(self, top: int, left: int, height: int, width: int) -> HiddenEffectVideo:
        """The window ``[top:top + height, left:left + width]`` with positions in the truth shifted to it.

        Heat then crosses the window's edges (the simulation ran on the full frame).

        Raises:
            ValueError: a window outside the frame.
        """
        rows, cols = self.frames.shape[-2:]
        if not (0 <= top and 0 <= left and 1 <= height and 1 <= width and top + height <= rows
                and left + width <= cols):  # fmt: skip
            raise ValueError(
                f"crop window (top={top}, left={left}, height={height}, width={width}) must lie inside the "
                f"{rows} x {cols} px frame"
            )
        window = (..., slice(top, top + height), slice(left, left + width))
        shift = {"x": left * self.dx, "y": top * self.dx}
        effects = []
        for effect in self.effects:
            params = dict(effect.params)
            for kx, ky in effect.spec.positions:
                params[kx] -= shift["x"]
                params[ky] -= shift["y"]
            effects.append(Effect(effect.name, params))
        return replace(
            self,
            frames=self.frames[window].contiguous(),
            clean=self.clean[window].contiguous(),
            effects=tuple(effects),
            a_map=None if self.a_map is None else self.a_map[window].contiguous(),
        )

    def to_npz(self, path: str | os.PathLike[str], **extra: Any) -> Path:
        """Save as ``.npz`` readable by ``anra estimate``.

        Keys: ``frames``, ``dt``, ``dx``, ``t``, ``a_true``, ``noise_sd``, ``seed``, ``effects`` (the JSON
        truth, a string) and ``a_map`` when there is one.

        Args:
            path: output file (``.npz`` appended when missing).
            **extra: more scalars or arrays to store.

        Returns:
            The path written.
        """
        if self.a_map is not None:
            extra = {"a_map": self.a_map, **extra}
        return save_npz(
            path,
            self.frames,
            dt=self.dt,
            dx=self.dx,
            t=self.times,
            a_true=np.float64(self.a),
            noise_sd=np.float64(self.noise_sd),
            seed=np.int64(self.seed),
            effects=self.truth_json,
            **extra,
        )


@dataclass(frozen=True)
class Medium:
    """The body a scene's hot spots lie on.

    Attributes:
        a: base diffusivity in mm^2/s, >= 0: the diffusivity unless an effect replaces the diffusion term.
        background: temperature of the uniform background in data units.
    """

    a: float = 0.15
    background: float = 30.0


@dataclass(frozen=True)
class Sensor:
    """What the camera adds to a simulated scene, and the dtype it records in.

    Attributes:
        noise_frac: white-noise sd as a fraction of the peak initial rise, >= 0.
        noise_sd: absolute white-noise sd in data units overriding ``noise_frac``, or None.
        dtype: float32 or float64.
    """

    noise_frac: float = 0.01
    noise_sd: float | None = None
    dtype: torch.dtype = torch.float64

    def checked(self) -> Sensor:
        """This sensor checked.

        Raises:
            ValueError: a negative or non-finite noise level, a dtype other than float32 and float64.
        """
        frac = number(self.noise_frac, "noise_frac", "fraction of the rise", minimum=0.0)
        sd = None if self.noise_sd is None else number(self.noise_sd, "noise_sd", "data units", minimum=0.0)
        check_dtype(self.dtype)
        return Sensor(frac, sd, self.dtype)


def hidden_effect_video(
    effect_names: Sequence[str] | str = (),
    *,
    seed: int,
    size: int = 96,
    dx: float = 0.5,
    fps: float = 30.0,
    duration: float = 3.0,
    medium: Medium | None = None,
    sensor: Sensor | None = None,
    params: Mapping[str, Mapping[str, float]] | None = None,
) -> HiddenEffectVideo:
    """A random scene with the named hidden effects, simulated by :func:`simulate_effects`, plus noise.

    The scene, the effects' parameters and the noise are drawn as the module docs say; ``params``
    overrides drawn values after the draw, so the other parameters do not depend on which were
    overridden. Simulated in float64 with zero-flux edges, then cast to the sensor's ``dtype``.

    Args:
        effect_names: keys of :data:`EFFECTS` (distinct); ``()`` gives pure heat transfer.
        seed: seed of the scene, the effect parameters and the noise, >= 0.
        size: frame side in px (>= 16).
        dx: pixel size in mm.
        fps: frame rate in Hz.
        duration: length in s: ``round(duration * fps) + 1`` frames.
        medium: base diffusivity and background temperature (:class:`Medium`); default ``Medium()``.
        sensor: the noise and dtype (:class:`Sensor`); default ``Sensor()``, noise 1 % of the rise.
        params: ``{effect: {parameter: value}}`` fixed instead of drawn.

    Returns:
        A :class:`HiddenEffectVideo` holding the true effects.

    Shape:
        ``frames`` ``(T, size, size)``.

    Raises:
        ValueError: unknown or repeated effects, two diffusion-replacing effects, ``params`` for an effect
            not named, bad sizes or rates.

    Example:
        >>> video = hidden_effect_video(["advection"], seed=1, size=32, duration=0.5)
        >>> tuple(video.frames.shape), [e.name for e in video.effects]
        ((16, 32, 32), ['advection'])
    """
    sensor = (Sensor() if sensor is None else sensor).checked()
    grid = {"size": size, "dx": dx, "fps": fps, "duration": duration}
    scene = draw_scene(effect_names, seed=seed, **grid, medium=medium, params=params)
    clean = simulate_effects(
        scene.initial, a=scene.a, dx=scene.dx, dt=scene.dt, n_frames=scene.n_frames, effects=scene.effects
    )
    return scene.video(clean, sensor=sensor)


@dataclass(frozen=True)
class Scene:
    """A drawn scene before simulation: its first frame, hot spots, geometry and effects.

    The one draw behind :func:`hidden_effect_video` and the independent simulator
    (:func:`anra_torch.effects.independent_effect_video`): same seed, same scene and
    effect parameters.

    Attributes:
        initial: the first frame sampled at the pixel centres (float64).
        spots: ``(rise, x, y, sigma)`` of each Gaussian hot spot (data units above ``background``, mm).
        geometry: what the effects drew their parameters for.
        effects: the checked effects with their drawn (or given) parameters.
        dt: frame period in s.
        n_frames: number of frames.
        a: base diffusivity in mm^2/s.
        seed: the seed everything was drawn from (the noise too).

    Shape:
        ``initial`` ``(H, W)``.
    """

    initial: Tensor
    spots: tuple[tuple[float, float, float, float], ...]
    geometry: Geometry
    effects: tuple[Effect, ...]
    dt: float
    n_frames: int
    a: float
    seed: int

    @property
    def dx(self) -> float:
        """Pixel size in mm."""
        return self.geometry.dx

    @property
    def background(self) -> float:
        """Temperature of the background."""
        return self.geometry.background

    def temperature(self, x: Tensor, y: Tensor) -> Tensor:
        """The initial temperature at points ``(x, y)`` in mm (the hot spots on the background).

        Shape:
            ``x``, ``y`` broadcastable float64 tensors; output their broadcast shape.
        """
        out = torch.full(
            torch.broadcast_shapes(x.shape, y.shape), self.background, dtype=_F64, device=x.device
        )
        for rise, cx, cy, sigma in self.spots:
            out = out + rise * torch.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2.0 * sigma**2))
        return out

    def video(self, clean: Tensor, *, sensor: Sensor | None = None) -> HiddenEffectVideo:
        """The :class:`HiddenEffectVideo` of a simulation of this scene: ``clean`` cast to the sensor's
        ``dtype`` plus the scene's white noise (``torch.Generator().manual_seed(seed)``).

        Args:
            clean: the simulated video of this scene.
            sensor: the noise and dtype (:class:`Sensor`); default ``Sensor()``.

        Shape:
            ``clean`` ``(T, H, W)`` with ``T = n_frames`` and ``(H, W)`` the initial frame's.

        Raises:
            ValueError: ``clean`` of another shape, bad noise levels.
        """
        sensor = (Sensor() if sensor is None else sensor).checked()
        noise_frac, noise_sd, dtype = sensor.noise_frac, sensor.noise_sd, sensor.dtype
        need = (self.n_frames, *self.initial.shape)
        if not isinstance(clean, Tensor) or tuple(clean.shape) != need:
            got = tuple(clean.shape) if isinstance(clean, Tensor) else type(clean).__name__
            raise ValueError(f"clean must be a tensor of shape {need} (the scene's frames), got {got}")
        sd = noise_sd if noise_sd is not None else noise_frac * self.geometry.rise
        clean = clean.to(dtype)
        generator = torch.Generator().manual_seed(self.seed)
        frames = clean + sd * torch.randn(clean.shape, generator=generator, dtype=dtype, device="cpu")
        size = tuple(self.initial.shape)
        reference, a_map = _reference(self.effects, Grid(size, self.dx, self.geometry.duration), self.a)
        return HiddenEffectVideo(
            frames=frames,
            clean=clean,
            dt=self.dt,
            dx=self.dx,
            a=reference,
            times=torch.arange(self.n_frames, dtype=dtype, device="cpu") * self.dt,
            effects=self.effects,
            noise_sd=sd,
            seed=self.seed,
            a_map=None if a_map is None else a_map.to(dtype),
        )


def draw_scene(
    effect_names: Sequence[str] | str = (),
    *,
    seed: int,
    size: int = 96,
    dx: float = 0.5,
    fps: float = 30.0,
    duration: float = 3.0,
    medium: Medium | None = None,
    params: Mapping[str, Mapping[str, float]] | None = None,
) -> Scene:
    """Draw the scene and effect parameters of :func:`hidden_effect_video` for ``seed``, unsimulated.

    Arguments as :func:`hidden_effect_video`.

    Returns:
        A :class:`Scene`.

    Shape:
        ``initial`` ``(size, size)``.

    Raises:
        ValueError: as :func:`hidden_effect_video`.

    Example:
        >>> scene = draw_scene(["linear_loss"], seed=1, size=32)
        >>> scene.n_frames, [e.name for e in scene.effects], len(scene.spots) >= 1
        (91, ['linear_loss'], True)
    """
    names = _check_names(effect_names, params)
    seed, size = check_int(seed, "seed", 0), check_int(size, "size", 16)
    dx, fps = number(dx, "dx", "mm", positive=True), number(fps, "fps", "Hz", positive=True)
    medium = Medium() if medium is None else medium
    a = number(medium.a, "a", "mm^2/s", minimum=0.0)
    background = number(medium.background, "background", "data units")
    n_frames = _frame_count(duration, fps)
    rng = np.random.default_rng(seed)
    initial, geometry, spots = _scene(rng, size, dx, (n_frames - 1) / fps, a, background)
    drawn = [{**EFFECTS[n].sample(rng, geometry), **(params or {}).get(n, {})} for n in names]
    checked = check_effects([Effect(n, p) for n, p in zip(names, drawn, strict=True)])
    return Scene(initial, spots, geometry, checked, 1.0 / fps, n_frames, a, seed)


def _check_names(effect_names: object, params: Mapping[str, Mapping[str, float]] | None) -> tuple[str, ...]:
    """Effect names as a tuple, each known, and ``params`` only for named effects."""
    names = (effect_names,) if isinstance(effect_names, str) else effect_names
    if not isinstance(names, Sequence) or not all(isinstance(n, str) for n in names):
        raise TypeError(f"effect_names must be a sequence of effect names, got {effect_names!r}")
    for name in names:
        if name not in EFFECTS:
            raise unknown_effect(name)
    for name in params or {}:
        if name not in names:
            raise ValueError(
                f"params given for effect {name!r}, which is not among the effects "
                f"({', '.join(names) or 'none'}); add it to effect_names"
            )
    return tuple(names)


def _reference(effects: Sequence[Effect], grid: Grid, a: float) -> tuple[float, Tensor | None]:
    """The diffusivity a fit should be compared with, and the diffusivity map when an effect has one."""
    reference, a_map = a, None
    for effect in effects:
        if effect.spec.reference_a is not None:
            reference = effect.spec.reference_a(effect.params)
        if effect.spec.diffusivity_map is not None:
            a_map = effect.spec.diffusivity_map(effect.params, grid)
    return reference, a_map


def _frame_count(duration: object, fps: float) -> int:
    """``round(duration * fps) + 1`` frames, at least 2."""
    duration = number(duration, "duration", "s", positive=True)
    n_frames = round(duration * fps) + 1
    if n_frames < 2:
        raise ValueError(f"duration * fps must give at least 2 frames, got duration={duration} s at {fps} Hz")
    return n_frames


def _scene(
    rng: np.random.Generator, size: int, dx: float, duration: float, a: float, background: float
) -> tuple[Tensor, Geometry, tuple[tuple[float, float, float, float], ...]]:
    """One or two Gaussian hot spots on the background (the first draws from ``rng``), the geometry
    the effects draw their parameters for, and the spots ``(rise, x, y, sigma)`` in mm.

    Shape:
        The initial frame ``(size, size)``.
    """
    spots = []
    for _ in range(int(rng.integers(1, 3))):
        rise, sigma = rng.uniform(5.0, 20.0), rng.uniform(3.0, 8.0)
        margin = min(2.5 * sigma + 10.0, size / 2.0)
        spots.append((rise, sigma, rng.uniform(margin, size - margin), rng.uniform(margin, size - margin)))
    initial = gaussian_blobs(
        [0.0],
        shape=(size, size),
        dx=dx,
        a=0.0,
        peaks=[s[0] for s in spots],
        sigmas=[s[1] * dx for s in spots],
        centres=[[s[2] * dx, s[3] * dx] for s in spots],
        background=background,
    )[0]
    geometry = Geometry(
        shape=(size, size),
        dx=dx,
        duration=duration,
        a=a,
        rise=float(initial.max()) - background,
        background=background,
        hotspots=tuple((s[2] * dx, s[3] * dx, s[1] * dx) for s in spots),
    )
    return initial, geometry, tuple((s[0], s[2] * dx, s[3] * dx, s[1] * dx) for s in spots)
