"""A second independent bioheat reference: a Gaussian laser spot on a half-space, by its Green's function.

:func:`simulate_spot` gives a camera's frames of the spot, the surface temperature averaged over each
pixel, and the Arrhenius damage depth under every pixel as the truth. The tissue is a laterally unbounded
half-space that obeys Pennes' equation, heated through its surface by a Gaussian flux while the laser is on
and losing heat to the air; the frame is a window onto it. Nothing is discretised in space, so its scenes
share no error with :mod:`anra_torch.tissue.depth` nor with :mod:`anra_torch.simulation.bioheat_reference`.
The solution: ``docs/architecture.md``, "The bioheat references".

Units: mm, s, C, mm^2/s, 1/s. Computed in NumPy float64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

__all__ = ["GreenScene", "GreenResult", "simulate_spot", "spot_peak"]

_A_SKIN, _EA_SKIN, _R_GAS = 3.1e98, 6.28e5, 8.314462618  # Henriques-Moritz skin
_V_STEPS = 4000  # trapezoid steps in v = sqrt(u) over the record
_DZ = 0.005  # mm between the truth's depths
_DT = 0.005  # s: the truth's largest time step


@dataclass(frozen=True)
class GreenScene:
    """A Gaussian spot on skin-like tissue seen by a camera.

    Attributes:
        diffusivity: ``a`` in mm^2/s.
        perfusion: ``b`` in 1/s.
        air: the loss to the air ``beta = h / k`` in 1/mm.
        centre: the spot's centre ``(x, y)`` in mm from the frame's top-left corner; anywhere, even outside.
        radius: the Gaussian's ``s`` in mm: the flux falls to ``e^-1/2`` of its peak there.
        peak: the surface's largest temperature in C, reached at the centre at the switch-off.
        t_on, t_off: the laser's switch-on and switch-off in s; any times.
        duration: the record in s, with frames at ``0, 1 / rate, ...``.
        rate: frames per second.
        shape: the frame ``(H, W)``.
        dx: pixel size in mm.
        body_temperature: in C.
        label: the scene's name.
    """

    diffusivity: float
    perfusion: float
    air: float
    centre: tuple[float, float]
    radius: float
    peak: float
    t_on: float
    t_off: float
    duration: float
    rate: float
    shape: tuple[int, int] = (64, 64)
    dx: float = 0.1
    body_temperature: float = 37.0
    label: str = "green spot"


@dataclass(frozen=True)
class GreenResult:
    """Output of :func:`simulate_spot`.

    Attributes:
        frames: noiseless frames in C, ``(T, H, W)``.
        dt: frame period in s.
        dx: pixel size in mm.
        damage_depth: deepest point with ``Omega >= 1`` under each pixel in mm, 0 without damage, ``(H, W)``.
        scene: the :class:`GreenScene`.
        power: the flux's peak ``P`` in K mm/s.
        info: ``radii`` in mm and the damage depth at each radius, ``depth_of_radius``.
    """

    frames: np.ndarray
    dt: float
    dx: float
    damage_depth: np.ndarray
    scene: GreenScene
    power: float
    info: dict = field(default_factory=dict)


def _erfcx(x: np.ndarray) -> np.ndarray:
    return torch.special.erfcx(torch.from_numpy(np.ascontiguousarray(x))).numpy()


def _cumulative(scene: GreenScene, radii: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray]:
    """``F(r, z, tau)``, the response to a unit flux switched on ``tau`` ago, on the grid ``v = sqrt(tau)``
    at ``radii`` ``(R,)``: ``v`` ``(V,)`` and ``F`` ``(R, V)``."""
    a, b, beta, s2 = scene.diffusivity, scene.perfusion, scene.air, scene.radius**2
    v = np.linspace(0.0, math.sqrt(scene.duration) * 1.0001, _V_STEPS + 1)
    u = np.maximum(v**2, 1e-300)
    spread = s2 + 2 * a * u
    lateral = s2 / spread * np.exp(-(radii[:, None] ** 2) / (2 * spread))  # (R, V)
    root = np.sqrt(a * u)
    depth = np.exp(-(z**2) / (4 * a * u)) * (
        1 / math.sqrt(math.pi) - beta * root * _erfcx(z / (2 * root) + beta * root)
    )
    # G(z, u) du = depth / root * 2 v dv: the u^(-1/2) singularity becomes 2 / sqrt(a) at v = 0.
    integrand = lateral * (depth * 2 / math.sqrt(a) * np.exp(-b * u))[None, :]
    steps = 0.5 * (integrand[:, 1:] + integrand[:, :-1]) * np.diff(v)[None, :]
    return v, np.concatenate([np.zeros((len(radii), 1)), np.cumsum(steps, 1)], 1)


def _response(v: np.ndarray, cumulative: np.ndarray, scene: GreenScene, times: np.ndarray) -> np.ndarray:
    """``theta / P`` at ``times`` ``(N,)`` for each row of ``cumulative`` ``(R, V)``: ``(R, N)``."""
    out = np.zeros((cumulative.shape[0], len(times)))
    for start, sign in ((scene.t_on, 1.0), (scene.t_off, -1.0)):
        elapsed = np.sqrt(np.clip(times - start, 0.0, None))
        index = np.clip(np.searchsorted(v, elapsed) - 1, 0, len(v) - 2)
        weight = (elapsed - v[index]) / (v[index + 1] - v[index])
        out += sign * (cumulative[:, index] * (1 - weight) + cumulative[:, index + 1] * weight)
    return out


def spot_peak(scene: GreenScene) -> float:
    """The largest surface rise per unit flux: ``theta / P`` at the spot's centre at the switch-off, in K
    per K mm/s."""
    v, cumulative = _cumulative(scene, np.zeros(1), 0.0)
    return float(_response(v, cumulative, scene, np.array([scene.t_off]))[0, 0])


def _points(scene: GreenScene, subpixel: int) -> np.ndarray:
    """Distances in mm from the spot's centre of every pixel's ``subpixel^2`` points, ``(H, W, S)``."""
    h, w = scene.shape
    offsets = (np.arange(subpixel) + 0.5) / subpixel
    ys = (np.arange(h)[:, None] + offsets[None, :]) * scene.dx  # (H, S)
    xs = (np.arange(w)[:, None] + offsets[None, :]) * scene.dx
    dy = ys[:, None, :, None] - scene.centre[1]
    dx = xs[None, :, None, :] - scene.centre[0]
    return np.sqrt(dy**2 + dx**2).reshape(h, w, -1)


def simulate_spot(
    scene: GreenScene, *, subpixel: int = 3, max_depth: float = 2.5, damage: bool = True
) -> GreenResult:
    """The camera's frames and the damage depth under every pixel of ``scene``.

    The flux's peak is set so that the surface reaches ``scene.peak``. Frames and truth are means over
    ``subpixel^2`` points of each pixel; the truth is the deepest point with ``Omega >= 1`` for
    Henriques-Moritz skin constants.

    Args:
        scene: :class:`GreenScene`.
        subpixel: points per pixel side of the frames' and the truth's pixel means.
        max_depth: deepest depth in mm the truth looks at.
        damage: False skips the truth, whose damage depth is then all zeros: frames only.

    Returns:
        :class:`GreenResult`.

    Raises:
        ValueError: ``t_on`` negative or not before ``t_off``, or a duration, rate or radius that is not
            positive.

    Shape:
        ``frames`` ``(T, H, W)``; ``damage_depth`` ``(H, W)``.
    """
    if not (0 <= scene.t_on < scene.t_off and scene.duration > 0 and scene.rate > 0 and scene.radius > 0):
        raise ValueError(
            f"a scene needs 0 <= t_on < t_off, a positive duration, rate and radius, got {scene}"
        )
    power = (scene.peak - scene.body_temperature) / spot_peak(scene)
    points = _points(scene, subpixel)
    radii = np.linspace(0.0, float(points.max()) + 1e-9, max(64, int(points.max() / (0.25 * scene.dx)) + 2))
    frame_times = np.arange(round(scene.duration * scene.rate) + 1) / scene.rate
    v, surface = _cumulative(scene, radii, 0.0)
    rise = power * _response(v, surface, scene, frame_times)  # (R, T)
    frames = scene.body_temperature + _at(radii, rise, points).mean(2)  # (H, W, T)
    depth = _damage(scene, power, radii, max_depth) if damage else np.zeros(len(radii))
    truth = np.interp(points.reshape(-1), radii, depth).reshape(points.shape).mean(2)
    return GreenResult(
        frames=np.moveaxis(frames, -1, 0),
        dt=1.0 / scene.rate,
        dx=scene.dx,
        damage_depth=truth,
        scene=scene,
        power=power,
        info={"radii": radii, "depth_of_radius": depth},
    )


def _at(radii: np.ndarray, values: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``values`` ``(R, T)`` interpolated linearly in the radius at ``points`` ``(H, W, S)``:
    ``(H, W, S, T)``."""
    flat = points.reshape(-1)
    index = np.clip(np.searchsorted(radii, flat) - 1, 0, len(radii) - 2)
    weight = ((flat - radii[index]) / (radii[index + 1] - radii[index]))[:, None]
    out = values[index] * (1 - weight) + values[index + 1] * weight
    return out.reshape(*points.shape, values.shape[1])


def _damage(scene: GreenScene, power: float, radii: np.ndarray, max_depth: float) -> np.ndarray:
    """The damage depth in mm at every radius: ``Omega`` on depths ``_DZ`` apart, by the trapezoid rule in
    time, steps of at most ``_DT`` with the switch-on and -off on the grid; ``ln Omega`` interpolated to 1."""
    steps = max(1, math.ceil(scene.duration / _DT))
    times = np.unique(
        np.concatenate([np.linspace(0.0, scene.duration, steps + 1), [scene.t_on, scene.t_off]])
    )
    times = times[times <= scene.duration]
    weights = np.zeros_like(times)
    weights[1:] += 0.5 * np.diff(times)
    weights[:-1] += 0.5 * np.diff(times)
    depth = np.zeros(len(radii))
    previous = None
    for z in np.arange(0.0, max_depth + 1e-9, _DZ):
        v, cumulative = _cumulative(scene, radii, float(z))
        kelvin = scene.body_temperature + 273.15 + power * _response(v, cumulative, scene, times)
        hot = kelvin.max(1) > 315.15  # 42 C: the rate below adds nothing
        omega = np.zeros(len(radii))
        omega[hot] = (_A_SKIN * np.exp(-_EA_SKIN / (_R_GAS * kelvin[hot])) * weights).sum(1)
        if previous is not None:
            crossing = (previous >= 1.0) & (omega < 1.0)
            low, high = np.log(previous[crossing]), np.log(np.maximum(omega[crossing], 1e-300))
            depth[crossing] = z - _DZ + _DZ * low / (low - high)
        damaged = omega >= 1.0
        if not damaged.any():
            break
        depth[damaged] = z  # still damaged here: deeper than z
        previous = omega
    return depth
