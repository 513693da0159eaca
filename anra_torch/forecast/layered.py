"""A flash plate's forecast resolved in depth: the diagnosed model on layers through the plate's thickness.

The balance describes a flash plate by its surface: ``- r(t) (T - T_ref)`` for the heat flowing into depth
(:mod:`~anra_torch.effects.depth_conduction`) and, over a defect, a thinner layer's rate
(:mod:`~anra_torch.effects.delamination`). The rate is the plate's at the time since the flash, so heat
that arrives at a pixel later (sideways from the warm layer over a defect) is cooled as if it had been
there since the flash, far too slowly: on a 1.3 mm plate of experiments.flash_defect_map every positive
strength of a correctly placed delamination made the surface forecast worse. Here the same model runs on
layers through the thickness, in the depth ``zeta = z / L`` where the diffusion into depth is
``(1 / (L^2 / a_z)) d^2 T / d zeta^2`` (front-face data fix only ``L^2 / a_z``, and nothing else is
needed): the layers graded from the surface (:data:`LAYERS`), the diffusion into depth stepped exactly
(the layers' propagator), each layer taking the lateral diffusion (the anisotropy when named, else the
isotropic ``a``) and the other named terms; a delamination is a face at its ``d / L`` over its disc, passing
a share of the intact conductance that the layers fit themselves (:func:`fitted_face`: the share of
:data:`PASSED` whose run forecasts the last frames before the split best; the balance's strength, a share of
the plate's rate, said 0.5-0.83 of a rate for defects that pass no heat).

The run starts from a frame :data:`SETTLED` times as long after the flash as the first, each pixel at the
plate's (over a defect the layer's) profile through the thickness at that time, scaled to the measured
surface; it follows the measured frame edge (each layer at that profile), and at the split each pixel's
layers are scaled by the mean ratio of the measured surface to the model's over the last
:data:`ASSIMILATED` frames. The surface is the top two layers extrapolated to it.

:func:`layered_plate` says whether a diagnosis asks for it and is a flash plate's (a defect map's plate
among its hints, from :func:`~anra_torch.recording.flash_hints` with ``layered``, and ``depth_conduction``
named; no effect that replaces the diffusion but the anisotropy); :func:`layered_forecast` makes the
forecast. ``anra diagnose --maps FILE --layered`` uses it; docs/results/flash.md measures it.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as nnf
from torch import Tensor

from anra_torch.effects import Effect, Grid, step_rates
from anra_torch.forecast.core import extended_effects
from anra_torch.selection import Diagnosis

__all__ = [
    "ASSIMILATED",
    "LAYERS",
    "SETTLED",
    "LayeredPlate",
    "FACE_SPLIT",
    "PASSED",
    "depth_faces",
    "fitted_face",
    "layered_forecast",
    "layered_plate",
    "surface",
]

LAYERS = (0.004, 1.2, 0.08)
"""The layers through the thickness, as shares of it: the top one's, the growth from one to the next, the
thickest (24 layers, :func:`depth_faces`; the profile 0.07 s after the flash on a 1 mm plate at 0.45 mm^2/s
spans about 10)."""

_F64 = torch.float64
PASSED = (0.0, 0.03, 0.1, 0.3)
"""The shares of the intact conductance a defect's face may pass (:func:`fitted_face`), graded towards none: a
delamination's gap passes little heat, and the forecast's error grows fastest as the face begins to pass
some. The balance's ``strength`` is a share of the plate's rate, not of the face's conductance, and is not
used."""
FACE_SPLIT = 0.8
"""The share of the frames before the split from which :func:`fitted_face` forecasts the rest."""
_STABLE = 0.8  # an explicit lateral step's share of its stability limit
_LEVELS = 16  # a defect face's share of the heat it stops, in steps of 1/16 (one propagator a step)
SETTLED = 4.0
"""The run starts at the first frame this many times as long after the flash as the first: the earliest
frames, where the profile through the thickness is steepest, are the least like the plate's model (a camera's
flash and afterglow; the independent plate's top cells, whose extrapolated surface is far above the plate's
profile in its first frames)."""
ASSIMILATED = 10
"""The most frames before the split assimilated: the run from the flash is scaled at the split by each pixel's
mean ratio of the measured surface to the model's over them (the white noise averaged, the profile through the
thickness kept; scaling the layers at every frame to the measured surface, as a surface model assimilates it,
put the lateral flow's misfit into the heat below the surface and lost a 1.3 mm plate's delamination)."""


@dataclass(frozen=True)
class LayeredPlate:
    """A diagnosed flash plate's model through its thickness.

    Attributes:
        lateral: ``(a_x, a_y, a_xy)`` in mm^2/s.
        plate_time: ``L^2 / a_z`` in s.
        t_heat: the flash's time relative to the first frame in s (< 0).
        t_ref: the temperature before the flash (data units).
        defect: the delamination's ``(x, y, radius, d / L, strength)`` (mm, mm, mm, 1, 1; ``strength`` the
            share of the intact conductance its face stops), or None.
        others: the model's other effects, each acting on every layer.
    """

    lateral: tuple[float, float, float]
    plate_time: float
    t_heat: float
    t_ref: float
    defect: tuple[float, float, float, float, float] | None
    others: tuple[Effect, ...]


def layered_plate(diagnosis: Diagnosis, names: Collection[str]) -> LayeredPlate | None:
    """The model of ``diagnosis``' effects ``names`` (timed from its first frame) through the thickness, or
    None where it is not asked for or not a flash plate's: no defect map's plate among the diagnosis' hints
    or one without ``"layered"`` (:func:`~anra_torch.recording.flash_hints`' option), ``depth_conduction``
    not among them, or an effect that replaces the diffusion other than the anisotropy.

    Raises:
        ValueError: asked for, with effects that cannot be simulated
            (:func:`~anra_torch.forecast.core.extended_effects`).
    """
    held = diagnosis.hints.get("depth_conduction")
    if not held or not held[0].get("layered"):
        return None
    chosen = [e for e in extended_effects(diagnosis) if e.name in names]
    rest = {e.name: e for e in chosen}  # what the layers do not model themselves acts on each layer
    depth = rest.pop("depth_conduction", None)
    delamination, anisotropy = rest.pop("delamination", None), rest.pop("anisotropy", None)
    if depth is None or any(e.replaces_diffusion for e in rest.values()):
        return None
    lateral = (diagnosis.base, diagnosis.base, 0.0)
    if anisotropy is not None:
        lateral = (anisotropy.params["a_x"], anisotropy.params["a_y"], anisotropy.params["a_xy"])
    defect = None
    plate_time = depth.params["depth_time"]
    if delamination is not None:
        p = delamination.params
        fraction = math.sqrt(min(p["depth_time"] / plate_time, 1.0))
        defect = (p["x"], p["y"], p["radius"], fraction, min(max(p["strength"], 0.0), 1.0))
    others = tuple(e for e in chosen if e.name in rest)
    return LayeredPlate(lateral, plate_time, depth.params["t_heat"], depth.params["T_ref"], defect, others)


def layered_forecast(
    video: Tensor,
    split: int,
    dt: float,
    dx: float,
    plate: LayeredPlate,
    *,
    assimilated: int = 1,
    forcing: Tensor | None = None,
) -> Tensor:
    """Forecast frames ``split + 1 ..`` of ``video`` with ``plate`` (module text).

    Args:
        video: the measured frames, the first ``-plate.t_heat`` s after the flash, ``(T, H, W)``.
        split: the last frame the forecast knows.
        dt: frame period in s.
        dx: pixel size in mm.
        plate: from :func:`layered_plate`; a defect's face as :func:`fitted_face` fits it to the frames up to
            the split.
        assimilated: the last frames up to the split assimilated into the state (at most
            :data:`ASSIMILATED`): each pixel's layers are scaled at the split by the mean ratio of the
            measured surface to the model's over them.
        forcing: a stationary heat input in data units per s on every layer, ``(H, W)``, or None.

    Returns:
        The surface ``(T - split - 1, H, W)``, float64 on ``video``'s device.

    Raises:
        ValueError: lateral diffusivities that are not positive (definite): the model cannot be simulated.
    """
    return _run(video, split, dt, dx, fitted_face(video[: split + 1], dt, dx, plate), assimilated, forcing)


def fitted_face(frames: Tensor, dt: float, dx: float, plate: LayeredPlate) -> LayeredPlate:
    """``plate`` with its defect's face passing the share of :data:`PASSED` whose run forecasts best the
    last ``1 -`` :data:`FACE_SPLIT` of ``frames`` ``(T, H, W)`` from the frames before them (RMSE over the
    defect's neighbourhood: its disc and the lateral diffusion length over the frames around it, the ring
    following the frames; no stationary heat input); ``plate`` itself where it has no defect or too few
    frames."""
    if plate.defect is None:
        return plate
    split = frames.shape[0] - 1
    inner = round(FACE_SPLIT * split)
    if inner - _begin(-plate.t_heat, dt, inner) < 2:
        return plate
    x, y, radius, fraction, _ = plate.defect
    reach = radius + math.sqrt(max(plate.lateral[:2]) * split * dt) + 2 * dx
    # the other terms are placed on the whole frame: only a plate without them is forecast on a crop
    rows, cols = (slice(0, None), slice(0, None)) if plate.others else _around(x, y, reach, frames.shape, dx)
    part = frames[:, rows, cols]
    moved = (x - (cols.start or 0) * dx, y - (rows.start or 0) * dx, radius, fraction)
    truth = part[inner + 1 :, 1:-1, 1:-1].to(_F64)

    def misfit(passed: float) -> float:
        model = replace(plate, defect=(*moved, 1.0 - passed))
        run = _run(part, inner, dt, dx, model, ASSIMILATED, None)[:, 1:-1, 1:-1]
        return float((run - truth).pow(2).mean())

    best = min(PASSED, key=misfit)
    return replace(plate, defect=(x, y, radius, fraction, 1.0 - best))


def _around(x: float, y: float, reach: float, shape: torch.Size, dx: float) -> tuple[slice, slice]:
    """The rows and columns of frames ``shape`` ``(T, H, W)`` within ``reach`` mm of ``(x, y)`` mm (at least 5
    px each way where the frame has them)."""

    def span(centre: float, size: int) -> slice:
        low = max(0, math.floor((centre - reach) / dx))
        high = min(size, math.ceil((centre + reach) / dx))
        if high - low < 5:
            low, high = max(0, min(low, size - 5)), min(size, max(high, low + 5))
        return slice(low, high)

    return span(y, int(shape[1])), span(x, int(shape[2]))


def _run(
    video: Tensor,
    split: int,
    dt: float,
    dx: float,
    plate: LayeredPlate,
    assimilated: int,
    forcing: Tensor | None,
) -> Tensor:
    """:func:`layered_forecast` with ``plate``'s face as it is."""
    a_x, a_y, a_xy = plate.lateral
    if not (a_x > 0 and a_y > 0 and a_x * a_y > a_xy**2):
        raise ValueError(
            f"the layered plate's lateral diffusivities must be positive definite, got a_x={a_x:.4g}, "
            f"a_y={a_y:.4g}, a_xy={a_xy:.4g} mm^2/s"
        )
    frames = video.to(_F64) - plate.t_ref
    layers = _Layers(plate, frames, dt, dx, forcing)
    begin = _begin(-plate.t_heat, dt, split)
    state = layers.profiles(-plate.t_heat + begin * dt) * frames[begin][None]
    first = max(begin, split + 1 - min(assimilated, ASSIMILATED))  # the first frame assimilated
    ratio = (
        torch.zeros_like(frames[0]) if first > begin else _ratio(frames[begin], surface(state, layers.faces))
    )
    out = []
    for k in range(begin, frames.shape[0] - 1):  # sequential by nature: each frame starts from the last
        state = layers.advance(state, k)
        if first <= k + 1 <= split:
            ratio = ratio + _ratio(frames[k + 1], surface(state, layers.faces))
        if k + 1 == split:
            state = state * (ratio / (split + 1 - first)).clamp(0.2, 5.0)[None]
        if k + 1 > split:
            out.append(surface(state, layers.faces) + plate.t_ref)
    return torch.stack(out) if out else frames.new_zeros((0, *frames.shape[1:]))


def _begin(elapsed: float, dt: float, split: int) -> int:
    """The frame the run starts from: the first seen :data:`SETTLED` times as long after the flash as the
    first frame (at most :data:`ASSIMILATED` frames before the split)."""
    settled = math.ceil((SETTLED - 1) * elapsed / dt - 1e-9)
    return max(0, min(settled, split - ASSIMILATED))


class _Layers:
    """The layered model of ``plate`` on the frames' grid, one frame ahead at a time: each step the exact
    diffusion into depth (the layers' propagator), then an explicit lateral step with the other terms."""

    def __init__(self, plate: LayeredPlate, frames: Tensor, dt: float, dx: float, forcing: Tensor | None):
        self.plate, self.frames, self.dt, self.dx, self.forcing = plate, frames, dt, dx, forcing
        height, width = frames.shape[1:]
        self.block, self.fraction = _block(plate, (height, width), dx, frames.device)
        self.faces = depth_faces(self.fraction).to(frames.device)
        grid = Grid((height, width), dx)
        self.terms = [e.spec.build(e.params, grid) for e in plate.others]
        low, high = float(frames.min()) + plate.t_ref, float(frames.max()) + plate.t_ref
        _, speed, decay = step_rates(0.0, plate.others, low, high, frames.shape[0] * dt)
        a_x, a_y, a_xy = plate.lateral
        fastest = 2 * (a_x + a_y + abs(a_xy)) / dx**2 + speed / dx + decay
        self.substeps = max(1, math.ceil(dt * fastest / _STABLE))
        h = dt / self.substeps
        self.intact = torch.linalg.matrix_exp(_depth_operator(self.faces, plate.plate_time, None) * h)
        self.last: tuple[int, Tensor] | None = None
        self.over, self.cut = _face_steps(self.faces, plate.plate_time, self.fraction, self.block, h)

    def profiles(self, elapsed: float) -> Tensor:
        """Each pixel's temperature through the thickness ``elapsed`` s after the flash over its surface's,
        ``(layers, H, W)``: the plate's, blended over a defect (the share its face stops) with the layer's
        above the face (nothing below it)."""
        plate, block = self.plate, self.block
        profile = _profile(self.faces, elapsed, plate.plate_time)[:, None, None] * (1 - block)[None]
        if self.fraction is None:
            return profile
        f = self.fraction
        upper = self.faces[self.faces <= f + 1e-12] / f
        shallow = torch.zeros_like(self.faces[1:])
        shallow[: len(upper) - 1] = _profile(upper, elapsed, plate.plate_time * f**2)
        return profile + shallow[:, None, None] * block[None]

    def advance(self, state: Tensor, k: int) -> Tensor:
        """The layers at frame ``k + 1`` from those at frame ``k``; the edge ring follows the frames."""
        h = self.dt / self.substeps
        elapsed = -self.plate.t_heat + k * self.dt
        start = self._ring(k, elapsed)  # the ring's layers at both frames
        end = self._ring(k + 1, elapsed + self.dt)
        t_ref = self.plate.t_ref
        for s in range(self.substeps):
            t = torch.tensor(k * self.dt + s * h, dtype=_F64, device="cpu")
            state = self.into_depth(state, torch.einsum("ij,jhw->ihw", self.intact, state))
            rhs = _lateral(state, self.plate.lateral, self.dx)
            for term in self.terms:
                rhs = rhs + term(t, state + t_ref)
            if self.forcing is not None:
                rhs = rhs + self.forcing
            w = (s + 1) / self.substeps
            state = _edges(state + h * rhs, (1 - w) * start + w * end)
        return state

    def _ring(self, k: int, elapsed: float) -> Tensor:
        """Frame ``k``'s surface times the profiles at ``elapsed`` s, ``(layers, H, W)``; the last one kept
        (a frame's end is the next frame's start)."""
        if self.last is None or self.last[0] != k:
            self.last = (k, self.profiles(elapsed) * self.frames[k][None])
        return self.last[1]

    def into_depth(self, state: Tensor, intact: Tensor) -> Tensor:
        """One step of the diffusion into depth: ``intact``, the intact plate's, with the pixels over a defect
        stepped through their own face (:func:`_face_steps`)."""
        if self.cut is None:
            return intact
        out = intact.clone()
        out[:, self.over] = torch.bmm(self.cut, state[:, self.over].T[:, :, None])[:, :, 0].T
        return out


def _face_steps(
    faces: Tensor, plate_time: float, fraction: float | None, block: Tensor, h: float
) -> tuple[Tensor, Tensor | None]:
    """The pixels over a defect ``(H, W)`` bool and each one's propagator of the diffusion into depth over
    ``h`` s ``(pixels, n, n)``: its face at ``fraction`` passing ``1 - block`` of the intact conductance
    (``block`` in steps of :data:`_LEVELS`; one matrix exponential per step present)."""
    level = (block * _LEVELS).round()
    over = level > 0
    if fraction is None or not bool(over.any()):
        return over, None
    steps, which = torch.unique(level[over], return_inverse=True)
    device = block.device
    propagators = torch.stack(
        [
            torch.linalg.matrix_exp(_depth_operator(faces, plate_time, fraction, 1 - float(s) / _LEVELS) * h)
            for s in steps.cpu()
        ]
    ).to(device)
    return over, propagators[which]


def depth_faces(cut: float | None = None) -> Tensor:
    """The layers' faces through the thickness as shares of it, 0 to 1, graded (:data:`LAYERS`), with a face
    at ``cut`` (a defect's ``d / L``) where given (moved there from the nearest, as a mesher puts a node on a
    crack), ``(layers + 1,)`` float64 on the CPU."""
    first, growth, thickest = LAYERS
    faces, size = [0.0], first
    while faces[-1] + 0.5 * size < 1.0:
        faces.append(faces[-1] + size)
        size = min(size * growth, thickest)
    faces[-1] = 1.0
    grid = torch.tensor(faces, dtype=_F64, device="cpu")
    if cut is not None:
        nearest = int((grid[1:-1] - cut).abs().argmin()) + 1
        grid[nearest] = cut
    return grid


def _depth_operator(faces: Tensor, plate_time: float, cut: float | None, passed: float = 0.0) -> Tensor:
    """The finite-volume operator of ``dT/dt = (1 / (L^2 / a_z)) d^2 T / d zeta^2`` on the layers between
    ``faces`` ``(n + 1,)``, both faces insulated, the face at ``cut`` passing ``passed`` of its conductance
    (0: no heat), ``(n, n)``."""
    size = faces.diff()
    centres = (faces[1:] + faces[:-1]) / 2
    g = 1 / (plate_time * centres.diff())  # the conductance between neighbouring centres
    if cut is not None:
        g = torch.where((faces[1:-1] - cut).abs() < 1e-12, g * passed, g)
    n = len(size)
    k = torch.arange(n - 1, device=faces.device)
    operator = torch.zeros(n, n, dtype=faces.dtype, device=faces.device)
    operator[k, k + 1] += g / size[:-1]
    operator[k, k] -= g / size[:-1]
    operator[k + 1, k] += g / size[1:]
    operator[k + 1, k + 1] -= g / size[1:]
    return operator


def _block(
    plate: LayeredPlate, shape: tuple[int, int], dx: float, device: torch.device
) -> tuple[Tensor, float | None]:
    """The share of the heat the defect's face stops per pixel ``(H, W)`` and the face's ``d / L``."""
    height, width = shape
    if plate.defect is None:
        return torch.zeros(shape, dtype=_F64, device=device), None
    x, y, radius, fraction, strength = plate.defect
    xs = (torch.arange(width, dtype=_F64, device=device) + 0.5) * dx
    ys = (torch.arange(height, dtype=_F64, device=device) + 0.5) * dx
    r = torch.sqrt((xs[None, :] - x) ** 2 + (ys[:, None] - y) ** 2)
    disc = 0.5 * (1 + torch.tanh((radius - r) / dx))  # the delamination's disc, its tanh edge 1 px wide
    return strength * disc, min(max(fraction, 0.02), 0.98)


def _profile(faces: Tensor, elapsed: float, plate_time: float) -> Tensor:
    """An insulated plate's temperature through its thickness ``elapsed`` s after a flash at its surface,
    averaged over each layer between ``faces`` (shares of the thickness, 0 to 1), over its surface value,
    ``(len(faces) - 1,)``."""
    s = max(elapsed, 1e-9) * math.pi**2 / plate_time
    terms = min(4000, max(8, math.ceil(math.sqrt(40 / s))))
    n = torch.arange(1, terms + 1, dtype=faces.dtype, device=faces.device)[:, None]
    sines = torch.sin(n * math.pi * faces)
    decay = torch.exp(-(n**2) * s)
    average = 1 + 2 * (decay * (sines[:, 1:] - sines[:, :-1]) / (n * math.pi * faces.diff())).sum(0)
    return average / (1 + 2 * decay.sum())


def surface(state: Tensor, faces: Tensor) -> Tensor:
    """The surface temperature of layers ``(n, ...)`` between ``faces``: the top two layers' values
    extrapolated linearly to the surface (as a camera sees a plate's top cells)."""
    c0, c1 = float(faces[1]) / 2, float(faces[1] + faces[2]) / 2
    return state[0] - c0 * (state[1] - state[0]) / (c1 - c0)


def _lateral(state: Tensor, lateral: tuple[float, float, float], dx: float) -> Tensor:
    """``a_x T_xx + a_y T_yy + 2 a_xy T_xy`` on every layer (central differences; the ring is reset after)."""
    a_x, a_y, a_xy = lateral
    p = nnf.pad(state[None], (1, 1, 1, 1), mode="replicate")[0]
    t_xx = p[:, 1:-1, 2:] - 2 * state + p[:, 1:-1, :-2]
    t_yy = p[:, 2:, 1:-1] - 2 * state + p[:, :-2, 1:-1]
    out = a_x * t_xx + a_y * t_yy
    if a_xy != 0.0:
        t_xy = (p[:, 2:, 2:] - p[:, 2:, :-2] - p[:, :-2, 2:] + p[:, :-2, :-2]) / 4
        out = out + 2 * a_xy * t_xy
    return out / dx**2


def _edges(state: Tensor, ring: Tensor) -> Tensor:
    """The frame's outermost pixel ring of every layer set to ``ring``'s (the measured surface times its
    profile through the thickness), ``(layers, H, W)``."""
    state = state.clone()
    state[:, 0], state[:, -1] = ring[:, 0], ring[:, -1]
    state[:, :, 0], state[:, :, -1] = ring[:, :, 0], ring[:, :, -1]
    return state


def _ratio(measured: Tensor, model: Tensor) -> Tensor:
    """``measured / model`` per pixel (1 where the model's surface is 0)."""
    zero = model == 0
    return torch.where(
        zero, torch.ones_like(model), measured / torch.where(zero, torch.ones_like(model), model)
    )
