"""A flash plate's forecast resolved in depth: the diagnosed model on layers through the plate's thickness.

The balance describes a flash plate by its surface: ``- r(t) (T - T_ref)`` for the heat flowing into depth
(:mod:`~anra_torch.effects.depth_conduction`) and, over a defect, a thinner layer's rate
(:mod:`~anra_torch.effects.delamination`). The rate is the plate's at the time since the flash, so heat
that arrives at a pixel later (sideways from the warm layer over a defect) is cooled as if it had been
there since the flash, far too slowly: on a 1.3 mm plate of experiments.flash_defect_map every positive
strength of a correctly placed delamination made the surface forecast worse. Here the same model runs on
the layers of :mod:`~anra_torch.forecast.layers`: the lateral diffusion (the anisotropy when named, else
the isotropic ``a``) and the other named terms on every layer, a delamination a face at its ``d / L`` over
its disc.

What the surface balance cannot say, the layers fit themselves on the frames before the split
(:func:`fitted_plate`): the share of the intact conductance the face passes (:data:`PASSED`; the
balance's strength is a share of the plate's rate, 0.5-0.83 for defects that pass no heat), and the
lateral tensor, the balance's or the defect map's, whichever forecasts those frames better.

The run starts from a frame :data:`SETTLED` times as long after the flash as the first, each pixel at the
plate's (over a defect the layer's) profile through the thickness at that time, scaled to the measured
surface; it follows the measured frame edge (each layer at that profile), and at the split each pixel's
layers are scaled by the mean ratio of the measured surface to the model's over the last
:data:`ASSIMILATED` frames. The surface is the top two layers extrapolated to it.

:func:`layered_plate` says whether a diagnosis asks for it and is a flash plate's (a defect map's plate
among its hints, from :func:`~anra_torch.recording.flash_hints` with ``layered``, and ``depth_conduction``
named; no effect that replaces the diffusion but the anisotropy); :func:`layered_forecast` makes the
forecast; :func:`within_layered` bounds a refit as the layers run it (the earned diagnosis' inner splits).
``anra diagnose --maps FILE`` uses it (``--no-layered``: the surface forecasts); docs/results/flash.md
measures it.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import replace

import torch
from torch import Tensor

from anra_torch.effects import EFFECTS
from anra_torch.forecast.core import extended_effects
from anra_torch.forecast.layers import Defect, LayeredPlate, Layers, definite, surface
from anra_torch.selection import Diagnosis

__all__ = [
    "ASSIMILATED",
    "FACE_SPLIT",
    "PASSED",
    "SETTLED",
    "LayeredPlate",
    "fitted_face",
    "fitted_plate",
    "layered_forecast",
    "layered_plate",
    "within_layered",
]

_F64 = torch.float64

PASSED = (0.0, 0.03, 0.1, 0.3)
"""The shares of the intact conductance a defect's face may pass (:func:`fitted_face`), graded towards none: a
delamination's gap passes little heat, and the forecast's error grows fastest as the face begins to pass
some; tried in order until the forecast's error rises. The balance's ``strength`` is a share of the plate's
rate, not of the face's conductance, and is not used."""
FACE_SPLIT = 0.8
"""The share of the frames before the split from which :func:`fitted_face` forecasts the rest."""
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


def layered_plate(diagnosis: Diagnosis, names: Collection[str]) -> LayeredPlate | None:
    """The model of ``diagnosis``' effects ``names`` (timed from its first frame) through the thickness, or
    None where it is not asked for or not a flash plate's: no defect map's plate among the diagnosis' hints
    or one without ``"layered"`` (:func:`~anra_torch.recording.flash_hints`' option), ``depth_conduction``
    not among them, or an effect that replaces the diffusion other than the anisotropy. Each delamination
    (the first, then ``delamination_2``) is a face at its own depth over its disc. Without the anisotropy,
    an isotropic ``a`` that is not positive takes the mean of the map's ``a_x`` and ``a_y``, as in
    :func:`within_layered` (held-out plate 30 of experiments.flash_defect_map: its balance's ``a`` was
    negative, and the layers stopped on it, the whole extension with them).

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
    delaminations = [rest.pop("delamination", None), rest.pop("delamination_2", None)]
    anisotropy = rest.pop("anisotropy", None)
    if depth is None or any(e.replaces_diffusion for e in rest.values()):
        return None
    base, hint = diagnosis.base, held[0]
    if base <= 0 and "a_x" in hint:  # as within_layered: an isotropic a not positive takes the map's mean
        base = (hint["a_x"] + hint["a_y"]) / 2
    lateral = (base, base, 0.0)
    measured = None
    if anisotropy is not None:
        lateral = (anisotropy.params["a_x"], anisotropy.params["a_y"], anisotropy.params["a_xy"])
        measured = (hint["a_x"], hint["a_y"], hint["a_xy"]) if "a_x" in hint else None
    plate_time = depth.params["depth_time"]
    defects = tuple(
        (p["x"], p["y"], p["radius"], math.sqrt(min(p["depth_time"] / plate_time, 1.0)), 1.0 - PASSED[0])
        for p in (e.params for e in delaminations if e is not None)
    )  # each passing no heat until fitted_face fits it
    others = tuple(e for e in chosen if e.name in rest)
    t_heat, t_ref = depth.params["t_heat"], depth.params["T_ref"]
    return LayeredPlate(lateral, plate_time, t_heat, t_ref, defects, others, measured)


def within_layered(diagnosis: Diagnosis) -> Diagnosis:
    """``diagnosis`` with what the layered forecast does not need from the balance bounded, where the
    layered forecast is asked for (:func:`layered_plate`'s conditions for all its effects); else
    ``diagnosis`` itself, for the other forecasts to refuse what cannot be simulated.

    - an anisotropy whose tensor is not positive definite takes the defect map's (the layered plate's
      other candidate, :func:`fitted_plate`, which leaves out one not positive definite);
    - a linear loss whose rate ``b`` (1/s) is negative, a heat gain, is no loss (``b = 0``);
    - without the anisotropy, an isotropic ``a`` (``base``, mm^2/s) that is not positive takes the mean of the
      map's ``a_x`` and ``a_y`` (the layers' lateral diffusivity).

    All three come from a balance that cools every pixel at the plate's rate since the flash: fitted on fewer
    frames (:func:`~anra_torch.forecast.earned_diagnosis`' inner splits, plate 3 of
    experiments.flash_defect_map), they took up its misfit (``a_x`` -0.94 mm^2/s, ``b`` -0.028 1/s; plate 11
    without its delamination ``a`` -0.56 mm^2/s), which the layers, resolving the depth themselves, do not
    have.
    """
    held = diagnosis.hints.get("depth_conduction")
    effects = {record["name"]: dict(record) for record in diagnosis.effects}
    if not held or not held[0].get("layered") or "depth_conduction" not in effects:
        return diagnosis
    anisotropy, loss = effects.pop("anisotropy", None), effects.get("linear_loss")
    if any(EFFECTS[name].replaces_diffusion for name in effects):
        return diagnosis
    measured: dict[str, float] = {k: held[0][k] for k in ("a_x", "a_y", "a_xy") if k in held[0]}
    if anisotropy is not None and len(measured) == 3:
        params = anisotropy["params"]
        if not definite((params["a_x"], params["a_y"], params["a_xy"])):
            derived = EFFECTS[anisotropy["name"]].derived
            anisotropy["params"] = {**params, **measured, **(derived(measured) if derived else {})}
    if loss is not None and loss["params"]["b"] < 0:
        loss["params"] = {**loss["params"], "b": 0.0}
    chosen = {**effects, **({} if anisotropy is None else {anisotropy["name"]: anisotropy})}
    base = diagnosis.base
    if anisotropy is None and base <= 0 and len(measured) == 3:  # the isotropic lateral a: the map's mean
        base = (measured["a_x"] + measured["a_y"]) / 2
    return replace(diagnosis, effects=[chosen[record["name"]] for record in diagnosis.effects], base=base)


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
        plate: from :func:`layered_plate`; its lateral tensor and its defect's face as :func:`fitted_plate`
            fits them to the frames up to the split.
        assimilated: the last frames up to the split assimilated into the state (at most
            :data:`ASSIMILATED`): each pixel's layers are scaled at the split by the mean ratio of the
            measured surface to the model's over them.
        forcing: a stationary heat input in data units per s on every layer, ``(H, W)``, or None.

    Returns:
        The surface ``(T - split - 1, H, W)``, float64 on ``video``'s device.

    Raises:
        ValueError: lateral diffusivities that are not positive (definite): the model cannot be simulated.
    """
    return _run(video, split, dt, dx, fitted_plate(video[: split + 1], dt, dx, plate), assimilated, forcing)


def fitted_plate(frames: Tensor, dt: float, dx: float, plate: LayeredPlate) -> LayeredPlate:
    """``plate`` with the lateral tensor of the anisotropy's candidates (the balance's, the defect map's)
    whose run forecasts best the last ``1 -`` :data:`FACE_SPLIT` of ``frames`` ``(T, H, W)`` from the
    frames before them (RMSE over the frame's interior), those not positive definite left out, and its
    defect's face fitted (:func:`fitted_face`).

    Raises:
        ValueError: no candidate positive definite (the model cannot be simulated).
    """
    candidates = [c for c in (plate.lateral, plate.measured) if c is not None and definite(c)]
    if len(candidates) > 1 and _inner(frames, dt, plate) is not None:
        candidates = [min(candidates, key=lambda c: _misfit(frames, dt, dx, replace(plate, lateral=c)))]
    return fitted_face(frames, dt, dx, replace(plate, lateral=candidates[0]) if candidates else plate)


def _inner(frames: Tensor, dt: float, plate: LayeredPlate) -> int | None:
    """The frame from which the fits forecast the rest of ``frames`` (:data:`FACE_SPLIT` of them), or None
    where the run would start less than 2 frames before it."""
    inner = round(FACE_SPLIT * (frames.shape[0] - 1))
    return inner if inner - _begin(-plate.t_heat, dt, inner) >= 2 else None


def _misfit(frames: Tensor, dt: float, dx: float, plate: LayeredPlate) -> float:
    """The mean squared error of ``plate``'s run forecasting ``frames`` ``(T, H, W)`` after :func:`_inner`'s
    frame from those before it, inside the outermost pixel ring (which follows the frames)."""
    inner = _inner(frames, dt, plate)
    assert inner is not None
    run = _run(frames, inner, dt, dx, plate, ASSIMILATED, None)
    return float((run - frames[inner + 1 :].to(_F64))[:, 1:-1, 1:-1].pow(2).mean())


def fitted_face(frames: Tensor, dt: float, dx: float, plate: LayeredPlate) -> LayeredPlate:
    """``plate`` with each defect's face in turn passing the share of :data:`PASSED` whose run forecasts best
    the last ``1 -`` :data:`FACE_SPLIT` of ``frames`` ``(T, H, W)`` from the frames before them (RMSE over the
    defect's neighbourhood: its disc and the lateral diffusion length over the frames around it, the ring
    following the frames; no stationary heat input; the other defects as fitted so far); ``plate`` itself
    where it has no defect or too few frames."""
    if _inner(frames, dt, plate) is None:
        return plate
    for j in range(len(plate.defects)):
        plate = replace(plate, defects=_fitted_share(frames, dt, dx, plate, j))
    return plate


def _fitted_share(frames: Tensor, dt: float, dx: float, plate: LayeredPlate, j: int) -> tuple[Defect, ...]:
    """``plate``'s defects with the ``j``-th one's face passing the share :func:`fitted_face` fits."""
    x, y, radius, fraction, _ = plate.defects[j]
    reach = radius + math.sqrt(max(*plate.lateral[:2], 0.0) * (frames.shape[0] - 1) * dt) + 2 * dx
    # the other terms are placed on the whole frame: only a plate without them is forecast on a crop
    rows, cols = (slice(0, None), slice(0, None)) if plate.others else _around(x, y, reach, frames.shape, dx)
    part = frames[:, rows, cols]
    left, top = (cols.start or 0) * dx, (rows.start or 0) * dx
    moved = [(d[0] - left, d[1] - top, *d[2:]) for d in plate.defects]  # in the crop's coordinates

    def misfit(passed: float) -> float:
        defects = tuple((*d[:4], 1.0 - passed) if i == j else d for i, d in enumerate(moved))
        return _misfit(part, dt, dx, replace(plate, defects=defects))

    best, lowest = PASSED[0], misfit(PASSED[0])
    for passed in PASSED[1:]:  # in order until the misfit rises (one minimum along the shares)
        error = misfit(passed)
        if error >= lowest:
            break
        best, lowest = passed, error
    return tuple((x, y, radius, fraction, 1.0 - best) if i == j else d for i, d in enumerate(plate.defects))


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
    if not definite(plate.lateral):
        raise ValueError(
            f"the layered plate's lateral diffusivities must be positive definite, got a_x={a_x:.4g}, "
            f"a_y={a_y:.4g}, a_xy={a_xy:.4g} mm^2/s"
        )
    frames = video.to(_F64) - plate.t_ref
    layers = Layers(plate, frames, dt, dx, forcing)
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


def _ratio(measured: Tensor, model: Tensor) -> Tensor:
    """``measured / model`` per pixel (1 where the model's surface is 0)."""
    zero = model == 0
    return torch.where(
        zero, torch.ones_like(model), measured / torch.where(zero, torch.ones_like(model), model)
    )
