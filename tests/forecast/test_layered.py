"""The depth-resolved forecast of a flash plate against closed forms: the insulated plate's cooling through
its thickness, a defect's layer, the anisotropic spread of a Gaussian."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import torch

from anra_torch.effects import Effect
from anra_torch.forecast.layered import (
    LayeredPlate,
    depth_faces,
    fitted_face,
    layered_forecast,
    layered_plate,
)

T_REF = 20.0


def flash_surface(elapsed: np.ndarray, plate_time: float, share: float = 1.0) -> np.ndarray:
    """The surface of an insulated plate ``share`` of the thickness thick after a unit flash (its excess over
    the whole thickness' mean): ``(1 + 2 sum_n exp(-n^2 pi^2 t / (share^2 tau))) / share``."""
    n = np.arange(1, 4000)[:, None]
    terms = np.exp(-(n**2) * math.pi**2 * elapsed[None, :] / (plate_time * share**2))
    return (1 + 2 * terms.sum(0)) / share


def plate(**changes: object) -> LayeredPlate:
    fields = dict(lateral=(2.0, 2.0, 0.0), plate_time=4.0, t_heat=-0.2, t_ref=T_REF, defect=None, others=())
    return LayeredPlate(**{**fields, **changes})  # type: ignore[arg-type]


@pytest.mark.parametrize("share", [1.0, 0.5])
def test_a_uniform_flash_cools_as_the_insulated_plate_or_the_layer_over_a_defect(share: float) -> None:
    """A flash uniform over the frame: the surface follows the closed form of the plate (``share`` 1) or, over
    a defect that stops all heat at half the thickness and covers the frame, of the layer above it (the
    face's time ``(d / L)^2 L^2 / a_z``), to 0.8 of the layer's time (the layers' second-order error)."""
    dt, frames, split = 0.05, 60, 10
    elapsed = 0.2 + dt * np.arange(frames)
    surface = flash_surface(elapsed, 16.0, share)
    video = torch.tensor(T_REF + surface)[:, None, None].expand(frames, 12, 12).clone()
    defect = None if share == 1.0 else (1.5, 1.5, 100.0, share, 1.0)
    got = layered_forecast(video, split, dt, 0.25, plate(defect=defect, plate_time=16.0))
    error = (got[:, 6, 6].numpy() - T_REF) / surface[split + 1 :] - 1
    assert got.shape == (frames - split - 1, 12, 12)
    assert np.abs(error).max() < 2e-3, np.abs(error).max()
    # the forecast of a plate without the defect differs by far more
    if share != 1.0:
        plain = layered_forecast(video, split, dt, 0.25, plate(plate_time=16.0))
        assert np.abs((plain[:, 6, 6].numpy() - T_REF) / surface[split + 1 :] - 1).max() > 0.04


def test_a_gaussian_spreads_with_the_anisotropic_lateral_diffusivities() -> None:
    """Long after the flash (flat through the thickness) a Gaussian spreads with covariance
    ``S0 + 2 t A`` for the lateral tensor ``A`` (a_xy included); the frame's edge follows the frames."""
    a = np.array([[3.0, 0.8], [0.8, 1.0]])
    dx, dt, frames, split = 0.25, 0.02, 40, 10
    n = 40
    coords = (np.arange(n) + 0.5 - n / 2) * dx
    xs, ys = np.meshgrid(coords, coords)  # (row = y, column = x)
    points = np.stack([xs, ys], -1)

    def gaussian(t: float) -> np.ndarray:
        cov = np.diag([1.2, 0.9]) + 2 * t * a
        inv = np.linalg.inv(cov)
        quad = np.einsum("...i,ij,...j->...", points, inv, points)
        return np.exp(-0.5 * quad) / (2 * math.pi * math.sqrt(np.linalg.det(cov)))

    video = torch.tensor(np.stack([T_REF + 5 * gaussian(k * dt) for k in range(frames)]))
    model = plate(lateral=(3.0, 1.0, 0.8), plate_time=1.0, t_heat=-20.0)
    got = layered_forecast(video, split, dt, dx, model)
    truth = video[split + 1 :]
    error = (got - truth)[:, 3:-3, 3:-3].abs().max() / (truth - T_REF).max()
    assert error < 3e-3, float(error)
    isotropic = layered_forecast(
        video, split, dt, dx, plate(lateral=(2.0, 2.0, 0.0), plate_time=1.0, t_heat=-20.0)
    )
    assert (isotropic - truth)[:, 3:-3, 3:-3].abs().max() / (truth - T_REF).max() > 5 * error


def test_the_model_of_a_flash_plate_is_read_from_the_chosen_effects() -> None:
    """Only a diagnosis with a defect map's plate asked to be layered among its hints and the depth term
    chosen is a layered plate's; the anisotropy sets the lateral tensor, the delamination the face (its
    ``d / L``, strength at most 1), the other effects act on every layer; an effect that replaces the
    diffusion otherwise: not layered."""
    depth = Effect("depth_conduction", {"strength": 1.0, "t_heat": -0.1, "depth_time": 4.0, "T_ref": T_REF})
    anisotropy = Effect("anisotropy", {"a_x": 6.0, "a_y": 1.0, "a_xy": 0.5})
    delamination = Effect(
        "delamination",
        {"x": 2.0, "y": 3.0, "radius": 1.5, "strength": 1.3, "depth_time": 1.0, "t_heat": -0.1,
         "plate_time": 4.0, "T_ref": T_REF},
    )  # fmt: skip
    loss = Effect("linear_loss", {"b": 0.01, "T_ref": T_REF})
    heterogeneity = Effect(
        "heterogeneity", {"x": 2.0, "y": 2.0, "radius": 1.0, "a_inside": 1.0, "a_outside": 2.0}
    )
    effects = [e.to_dict() for e in (depth, anisotropy, delamination, loss, heterogeneity)]
    held = {"T_ref": T_REF, "plate_time": 4.0, "t_heat": -0.1}

    def diagnosis(layered: bool) -> Any:
        plate = {**held, "layered": 1.0} if layered else held
        return SimpleNamespace(hints={"depth_conduction": (plate,)}, base=3.0, effects=effects)

    assert layered_plate(diagnosis(False), {"depth_conduction"}) is None
    assert layered_plate(diagnosis(True), {"depth_conduction"}) == plate(lateral=(3.0, 3.0, 0.0), t_heat=-0.1)
    assert layered_plate(SimpleNamespace(hints={}, base=3.0, effects=effects), {"depth_conduction"}) is None
    assert layered_plate(diagnosis(True), {"anisotropy"}) is None
    model = layered_plate(diagnosis(True), {"depth_conduction", "anisotropy", "delamination", "linear_loss"})
    assert model is not None
    assert model.lateral == (6.0, 1.0, 0.5) and model.defect == (2.0, 3.0, 1.5, 0.5, 1.0)
    assert model.others == (loss,)
    assert layered_plate(diagnosis(True), {"depth_conduction", "heterogeneity"}) is None


def test_the_forecast_computes_where_its_frames_are() -> None:
    """With the default device switched to ``meta`` and the frames on the CPU, the same numbers, on the CPU
    (a defect's face and another effect's term included)."""
    rng = np.random.default_rng(0)
    video = torch.tensor(T_REF + 1 + rng.random((12, 10, 14)), device="cpu")
    loss = Effect("linear_loss", {"b": 0.05, "T_ref": T_REF})
    model = plate(defect=(1.5, 1.2, 0.8, 0.5, 0.9), others=(loss,))
    want = layered_forecast(video, 6, 0.05, 0.25, model, assimilated=3)
    with torch.device("meta"):
        got = layered_forecast(video, 6, 0.05, 0.25, model, assimilated=3)
    assert got.device.type == "cpu"
    torch.testing.assert_close(got, want, rtol=0, atol=0)


def test_the_layers_are_graded_from_the_surface_with_a_face_at_the_defect() -> None:
    plain, cut = depth_faces(), depth_faces(0.669)
    for faces in (plain, cut):
        assert faces[0] == 0 and faces[-1] == 1 and bool((faces.diff() > 0).all())
        assert faces[1] == pytest.approx(0.004) and float(faces.diff().max()) <= 0.08 * 1.5
    assert bool((cut == 0.669).any()) and len(cut) == len(plain)


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
    for defect in ((4.8, 4.8, math.sqrt(3.0 * 2.0), 0.87 / 1.3, 1.0), None):
        model = plate(lateral=(7.3, 1.1, 0.0), plate_time=video.plate_time, t_heat=-dt, defect=defect)
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
        lateral=(7.3, 1.1, 0.0), plate_time=video.plate_time, t_heat=-dt, defect=(4.8, 4.8, 2.4, 0.5, 0.5)
    )
    fitted = fitted_face(frames, dt, 0.4, model)
    assert fitted.defect is not None and fitted.defect[4] == pytest.approx(1 - transmission)
    assert fitted.defect[:4] == model.defect[:4] and fitted.lateral == model.lateral
