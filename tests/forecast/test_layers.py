"""The layers through a flash plate's thickness against closed forms: the insulated plate's cooling through
its thickness, a defect's layer, the anisotropic spread of a Gaussian; the graded faces."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.forecast.layered import LayeredPlate, layered_forecast
from anra_torch.forecast.layers import depth_faces

T_REF = 20.0


def flash_surface(elapsed: np.ndarray, plate_time: float, share: float = 1.0) -> np.ndarray:
    """The surface of an insulated plate ``share`` of the thickness thick after a unit flash (its excess over
    the whole thickness' mean): ``(1 + 2 sum_n exp(-n^2 pi^2 t / (share^2 tau))) / share``."""
    n = np.arange(1, 4000)[:, None]
    terms = np.exp(-(n**2) * math.pi**2 * elapsed[None, :] / (plate_time * share**2))
    return (1 + 2 * terms.sum(0)) / share


def plate(**changes: object) -> LayeredPlate:
    fields = dict(lateral=(2.0, 2.0, 0.0), plate_time=4.0, t_heat=-0.2, t_ref=T_REF, defects=(), others=())
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
    defects = () if share == 1.0 else ((1.5, 1.5, 100.0, share, 1.0),)
    got = layered_forecast(video, split, dt, 0.25, plate(defects=defects, plate_time=16.0))
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


def test_the_layers_are_graded_from_the_surface_with_a_face_at_the_defect() -> None:
    plain, cut = depth_faces(), depth_faces(0.669)
    for faces in (plain, cut):
        assert faces[0] == 0 and faces[-1] == 1 and bool((faces.diff() > 0).all())
        assert faces[1] == pytest.approx(0.004) and float(faces.diff().max()) <= 0.08 * 1.5
    assert bool((cut == 0.669).any()) and len(cut) == len(plain)


def test_two_defects_at_different_depths_each_cool_their_half_as_the_layer_above_them() -> None:
    """A flash uniform over each half of the frame, each half over a defect that stops all heat (a disc so
    large its edge is straight down the middle) at its own depth, 0.5 and 0.3 of the thickness: each half
    follows the closed form of the layer above its defect (lateral diffusion too slow to mix the halves
    where they are compared); with one face, or both at the first's depth, the second half does not."""
    dt, frames, split, dx = 0.05, 60, 10, 0.25
    elapsed = 0.2 + dt * np.arange(frames)
    halves = {0.5: flash_surface(elapsed, 16.0, 0.5), 0.3: flash_surface(elapsed, 16.0, 0.3)}
    video = torch.empty(frames, 12, 16, dtype=torch.float64)
    video[:, :, :8] = torch.tensor(T_REF + halves[0.5])[:, None, None]
    video[:, :, 8:] = torch.tensor(T_REF + halves[0.3])[:, None, None]
    left, right = (2.0 - 1000.0, 1.5, 1000.0, 0.5, 1.0), (2.0 + 1000.0, 1.5, 1000.0, 0.3, 1.0)
    lateral = (0.01, 0.01, 0.0)

    def errors(defects: tuple) -> tuple[float, float]:
        got = layered_forecast(video, split, dt, dx, plate(lateral=lateral, defects=defects, plate_time=16.0))
        return tuple(  # type: ignore[return-value]
            float(np.abs((got[:, 6, col].numpy() - T_REF) / halves[share][split + 1 :] - 1).max())
            for col, share in ((3, 0.5), (12, 0.3))
        )

    both = errors((left, right))
    assert max(both) < 2e-3, both
    assert errors((left,))[1] > 0.04 and errors((left, (*right[:3], 0.5, 1.0)))[1] > 0.04


def test_each_defect_has_its_face_and_two_nearest_the_same_face_share_the_first() -> None:
    plain, two, near = depth_faces(), depth_faces(0.3, 0.669), depth_faces(0.5, 0.501)
    assert bool((two == 0.3).any()) and bool((two == 0.669).any()) and bool((two.diff() > 0).all())
    assert bool((near == 0.5).any()) and not bool((near == 0.501).any())
    assert len(two) == len(near) == len(plain)
