"""The depth-resolved forecast of a flash plate: the model read from a diagnosis, the device it computes on,
and what the layers fit themselves (a defect's face, the lateral tensor) on the independent plate."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import torch

from anra_torch.effects import Effect
from anra_torch.forecast.layered import (
    LayeredPlate,
    fitted_face,
    fitted_plate,
    layered_forecast,
    layered_plate,
    within_layered,
)

T_REF = 20.0


def plate(**changes: object) -> LayeredPlate:
    fields = dict(lateral=(2.0, 2.0, 0.0), plate_time=4.0, t_heat=-0.2, t_ref=T_REF, defects=(), others=())
    return LayeredPlate(**{**fields, **changes})  # type: ignore[arg-type]


def test_the_model_of_a_flash_plate_is_read_from_the_chosen_effects() -> None:
    """Only a diagnosis with a defect map's plate asked to be layered among its hints and the depth term
    chosen is a layered plate's; the anisotropy sets the lateral tensor (the map's beside it), the
    delamination the face (its ``d / L``, passing no heat until fitted), the other effects act on every
    layer; an effect that replaces the diffusion otherwise: not layered."""
    depth = Effect("depth_conduction", {"strength": 1.0, "t_heat": -0.1, "depth_time": 4.0, "T_ref": T_REF})
    anisotropy = Effect("anisotropy", {"a_x": 6.0, "a_y": 1.0, "a_xy": 0.5})
    delamination = Effect(
        "delamination",
        {"x": 2.0, "y": 3.0, "radius": 1.5, "strength": 1.3, "depth_time": 1.0, "t_heat": -0.1,
         "plate_time": 4.0, "T_ref": T_REF, "reflected": 1.0},
    )  # fmt: skip
    loss = Effect("linear_loss", {"b": 0.01, "T_ref": T_REF})
    heterogeneity = Effect(
        "heterogeneity", {"x": 2.0, "y": 2.0, "radius": 1.0, "a_inside": 1.0, "a_outside": 2.0}
    )
    effects = [e.to_dict() for e in (depth, anisotropy, delamination, loss, heterogeneity)]
    held = {"T_ref": T_REF, "plate_time": 4.0, "t_heat": -0.1}
    lateral = {"a_x": 7.0, "a_y": 1.1, "a_xy": 0.2}  # the map's

    def diagnosis(layered: bool) -> Any:
        plate = {**held, "layered": 1.0, **lateral} if layered else held
        return SimpleNamespace(hints={"depth_conduction": (plate,)}, base=3.0, effects=effects)

    assert layered_plate(diagnosis(False), {"depth_conduction"}) is None
    assert layered_plate(diagnosis(True), {"depth_conduction"}) == plate(lateral=(3.0, 3.0, 0.0), t_heat=-0.1)
    assert layered_plate(SimpleNamespace(hints={}, base=3.0, effects=effects), {"depth_conduction"}) is None
    assert layered_plate(diagnosis(True), {"anisotropy"}) is None
    model = layered_plate(diagnosis(True), {"depth_conduction", "anisotropy", "delamination", "linear_loss"})
    assert model is not None
    assert model.lateral == (6.0, 1.0, 0.5) and model.measured == (7.0, 1.1, 0.2)
    assert model.defects == ((2.0, 3.0, 1.5, 0.5, 1.0),)
    assert model.others == (loss,)
    assert layered_plate(diagnosis(True), {"depth_conduction", "heterogeneity"}) is None


@dataclass(frozen=True)
class Fitted:
    """What :func:`within_layered` and :func:`layered_plate` read of a diagnosis."""

    effects: list[dict[str, Any]]
    hints: dict[str, Any] = field(default_factory=dict)
    base: float = 3.0

    @property
    def names(self) -> list[str]:
        return [e["name"] for e in self.effects]


def test_a_layered_plates_refit_takes_the_maps_tensor_and_no_heat_gain() -> None:
    """A refit of a layered plate (the earned diagnosis' inner splits) whose tensor is not positive definite
    takes the defect map's, and a negative loss rate is no loss; without the anisotropy, an isotropic ``a``
    that is not positive takes the mean of the map's. The layered plate can then be built and run, as it
    cannot from the refit itself. A PD tensor and a loss stay; a plate not asked to be layered, or a model the
    layers do not run (one that replaces the diffusion besides the anisotropy), is returned as it is."""
    depth = {"strength": 1.0, "t_heat": -0.1, "depth_time": 4.0, "T_ref": T_REF}
    held = {"T_ref": T_REF, "plate_time": 4.0, "t_heat": -0.1}
    layered = {"depth_conduction": ({**held, "layered": 1.0, "a_x": 7.0, "a_y": 1.1, "a_xy": 0.2},)}

    def refit(tensor: tuple[float, float, float], b: float, hints: dict, *more: dict) -> Fitted:
        a_x, a_y, a_xy = tensor
        effects = [
            {"name": "depth_conduction", "params": depth},
            {"name": "anisotropy", "params": {"a_x": a_x, "a_y": a_y, "a_xy": a_xy, "ratio": 2.0}},
            {"name": "linear_loss", "params": {"b": b, "T_ref": T_REF}},
            *more,
        ]
        return Fitted(effects, hints)

    names = {"depth_conduction", "anisotropy", "linear_loss"}
    unphysical = refit((-0.94, 0.38, 0.1), -0.028, layered)
    with pytest.raises(ValueError, match="positive definite"):
        layered_plate(unphysical, names)
    bounded = within_layered(unphysical)
    eigen = np.linalg.eigvalsh(np.array([[7.0, 0.2], [0.2, 1.1]]))
    tensor = {"a_x": 7.0, "a_y": 1.1, "a_xy": 0.2}  # with its derived values, the ratio and the axis' angle
    assert bounded.effects[1]["params"] == pytest.approx(
        {**tensor, "ratio": eigen[1] / eigen[0], "angle_deg": math.degrees(math.atan2(0.4, 5.9)) / 2}
    )
    assert bounded.effects[2]["params"] == {"b": 0.0, "T_ref": T_REF}
    model = layered_plate(bounded, names)
    assert model is not None and model.lateral == (7.0, 1.1, 0.2)
    assert [(e.name, e.params["b"]) for e in model.others] == [("linear_loss", 0.0)]
    assert unphysical.effects[1]["params"]["a_x"] == -0.94  # the refit itself untouched
    physical = refit((6.0, 1.0, 0.5), 0.01, layered)
    assert within_layered(physical) == physical
    assert bounded.base == unphysical.base  # the anisotropy sets the lateral tensor, not ``base``
    alone = Fitted([{"name": "depth_conduction", "params": depth}], layered, base=-0.56)  # no delamination
    frames = torch.full((6, 8, 8), T_REF + 1.0, dtype=torch.float64, device="cpu")
    for model in (within_layered(alone), alone):  # the final model's forecast as the inner refits'
        isotropic = layered_plate(model, {"depth_conduction"})
        assert isotropic is not None and isotropic.lateral == ((7.0 + 1.1) / 2, (7.0 + 1.1) / 2, 0.0)
        assert torch.isfinite(layered_forecast(frames, 3, 0.1, 0.25, isotropic)).all()
    with pytest.raises(ValueError, match="positive definite, got a_x=-0.56"):  # no map's tensor to take
        layered_forecast(frames, 3, 0.1, 0.25, replace(isotropic, lateral=(-0.56, -0.56, 0.0)))
    assert within_layered(replace(alone, base=0.3)).base == 0.3
    not_layered = refit((-0.94, 0.38, 0.1), -0.028, {"depth_conduction": (held,)})
    replaced = refit((-0.94, 0.38, 0.1), -0.028, layered, {"name": "heterogeneity", "params": {}})
    for other in (not_layered, replaced):
        assert within_layered(other) is other


def test_the_forecast_computes_where_its_frames_are() -> None:
    """With the default device switched to ``meta`` and the frames on the CPU, the same numbers, on the CPU
    (a defect's face and another effect's term included)."""
    rng = np.random.default_rng(0)
    video = torch.tensor(T_REF + 1 + rng.random((12, 10, 14)), device="cpu")
    loss = Effect("linear_loss", {"b": 0.05, "T_ref": T_REF})
    model = plate(defects=((1.5, 1.2, 0.8, 0.5, 0.9),), others=(loss,))
    want = layered_forecast(video, 6, 0.05, 0.25, model, assimilated=3)
    with torch.device("meta"):
        got = layered_forecast(video, 6, 0.05, 0.25, model, assimilated=3)
    assert got.device.type == "cpu"
    torch.testing.assert_close(got, want, rtol=0, atol=0)


def test_a_lateral_tensor_that_is_not_positive_definite_cannot_be_forecast() -> None:
    video = torch.full((6, 8, 8), T_REF + 1.0, dtype=torch.float64, device="cpu")
    with pytest.raises(ValueError, match="positive definite, got a_x=-1"):
        layered_forecast(video, 3, 0.1, 0.25, plate(lateral=(-1.0, -1.0, 0.0)))


def test_a_defects_face_forecasts_an_independent_plate_better() -> None:
    """On the independent finite-volume plate (:func:`~anra_torch.simulation.reference_plate_video`, no
    noise) of a 1.3 mm composite with an ellipse at ``d / L`` 0.67, the true plate with the defect's face (its
    equal-area disc) forecasts the frames after 0.6 of the recording a third closer than without it."""
    from anra_torch.simulation.plate_reference import Defect, PlateSetup, reference_plate_video

    ellipse = Defect("ellipse", centre=(4.8, 4.8), size=(3.0, 2.0), depth=0.87)
    setup = PlateSetup(thickness=1.3, duration=3.8, shape=(24, 24), dx=0.4, n_frames=80, defects=(ellipse,),
                       noise_sd=0.0, seed=3)  # fmt: skip
    video = reference_plate_video(setup)
    frames, dt, split = torch.as_tensor(video.frames).to(torch.float64), 3.8 / 80, 47
    truth = frames[split + 1 :, 3:-3, 3:-3]
    errors = []
    for defects in (((4.8, 4.8, math.sqrt(3.0 * 2.0), 0.87 / 1.3, 1.0),), ()):
        model = plate(lateral=(7.3, 1.1, 0.0), plate_time=video.plate_time, t_heat=-dt, defects=defects)
        forecast = layered_forecast(frames, split, dt, 0.4, model, assimilated=10)[:, 3:-3, 3:-3]
        errors.append(float((forecast - truth).pow(2).mean().sqrt()))
    assert errors[0] < 0.7 * errors[1], errors


@pytest.mark.parametrize("transmission", [0.0, 0.3])
def test_the_face_passes_the_share_of_heat_the_independent_plates_defect_passes(transmission: float) -> None:
    """On the independent finite-volume plate (no noise) with a disc at ``d / L`` 0.5 passing ``transmission``
    of the intact conductance, the face fitted to the frames up to the split passes that share (the nearest
    of :data:`PASSED`), whatever the strength the plate came with."""
    from anra_torch.simulation.plate_reference import Defect, PlateSetup, reference_plate_video

    disc = Defect("ellipse", centre=(4.8, 4.8), size=(2.4, 2.4), depth=0.5, transmission=transmission)
    setup = PlateSetup(thickness=1.0, duration=3.0, shape=(24, 24), dx=0.4, n_frames=60, defects=(disc,),
                       noise_sd=0.0, seed=3)  # fmt: skip
    video = reference_plate_video(setup)
    frames, dt = torch.as_tensor(video.frames).to(torch.float64)[:36], 3.0 / 60
    model = plate(
        lateral=(7.3, 1.1, 0.0), plate_time=video.plate_time, t_heat=-dt, defects=((4.8, 4.8, 2.4, 0.5, 0.5),)
    )
    fitted = fitted_face(frames, dt, 0.4, model)
    assert fitted.defects[0][4] == pytest.approx(1 - transmission)
    assert fitted.defects[0][:4] == model.defects[0][:4] and fitted.lateral == model.lateral


def test_the_lateral_tensor_is_the_candidate_that_forecasts_the_frames_before_the_split() -> None:
    """A Gaussian spreading with the lateral tensor ``A`` long after the flash: of the balance's tensor and
    the defect map's, the one equal to ``A`` is kept, whichever it is; one not positive definite is left out
    instead of failing the forecast."""
    truth, wrong = (3.0, 1.0, 0.8), (1.0, 3.0, -0.5)
    a = np.array([[truth[0], truth[2]], [truth[2], truth[1]]])
    coords = (np.arange(32) + 0.5 - 16) * 0.25
    points = np.stack(np.meshgrid(coords, coords), -1)

    def gaussian(t: float) -> np.ndarray:
        cov = np.diag([1.0, 0.8]) + 2 * t * a
        return np.exp(-0.5 * np.einsum("...i,ij,...j->...", points, np.linalg.inv(cov), points))

    frames = torch.tensor(np.stack([T_REF + gaussian(0.02 * k) for k in range(30)]))
    for lateral, measured in ((wrong, truth), (truth, wrong), ((-1.0, 1.0, 0.0), truth)):
        model = plate(lateral=lateral, measured=measured, plate_time=1.0, t_heat=-20.0)
        assert fitted_plate(frames, 0.02, 0.25, model).lateral == truth


def test_each_defects_face_is_fitted_in_turn() -> None:
    """Each half of the frame cooling as the layer above a face that stops all heat (the closed form of an
    insulated layer, 0.5 and 0.3 of the thickness, discs so large their edges meet down the middle): both
    faces, given passing half the heat, are fitted to pass none, each at its own depth and place."""
    dt, frames = 0.05, 40
    elapsed = 0.2 + dt * np.arange(frames)
    n = np.arange(1, 4000)[:, None]
    video = torch.empty(frames, 12, 16, dtype=torch.float64)
    for share, columns in ((0.5, slice(0, 8)), (0.3, slice(8, None))):
        layer = (1 + 2 * np.exp(-(n**2) * math.pi**2 * elapsed / (16.0 * share**2)).sum(0)) / share
        video[:, :, columns] = torch.tensor(T_REF + layer)[:, None, None]
    given = ((2.0 - 1000.0, 1.5, 1000.0, 0.5, 0.5), (2.0 + 1000.0, 1.5, 1000.0, 0.3, 0.5))
    model = plate(lateral=(0.01, 0.01, 0.0), plate_time=16.0, defects=given)
    fitted = fitted_face(video, dt, 0.25, model)
    assert [d[4] for d in fitted.defects] == [1.0, 1.0]
    assert [d[:4] for d in fitted.defects] == [d[:4] for d in given]
