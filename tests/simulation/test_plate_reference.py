"""The independent flash plate (finite volumes on an irregular mesh, solved in one piece): an insulated
plate's cosine series, the package's other plate simulator on a case both can do, and its defects' outlines
and truth (its solver against a dense solve: tests/simulation/test_plate_solver.py)."""

from __future__ import annotations

import ast
import inspect
import math

import numpy as np
import pytest
import torch

import anra_torch.simulation.plate_reference as plate_reference
import anra_torch.simulation.plate_solver as plate_solver
from anra_torch.simulation.plate_reference import Defect, PlateSetup, reference_plate_video


def _uniform(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.ones(np.broadcast(x, y).shape)


def _cosine_series(t: np.ndarray, thickness: float, a_z: float, energy: float) -> np.ndarray:
    """Surface excess of an insulated plate after an instantaneous surface flash of ``energy`` K mm."""
    n = np.arange(1, 400)
    return energy / thickness * (1 + 2 * np.exp(-np.outer(t, n**2) * math.pi**2 * a_z / thickness**2).sum(1))


def test_a_uniform_flash_follows_the_insulated_plates_cosine_series() -> None:
    """Every column is then a 1-D plate. Measured: 0.15 % from the 20th frame (t = 0.4 s, ~0.1 L^2/a_z),
    0.6 % from the 10th; the first frames carry the mesh's error (35 % at the first: the heat has not
    crossed the top cells yet), as the earliest frames of a finite-element plate do."""
    plate = reference_plate_video(PlateSetup(
        thickness=1.3, duration=2.0, shape=(6, 6), n_frames=100, flash=_uniform, noise_sd=0.0,
        mesh_noise=0.0, energy=1.0,
    ))  # fmt: skip
    t = np.arange(1, 101) * plate.dt
    exact = _cosine_series(t, 1.3, 0.45, 1.0)
    surface = plate.frames[:, 3, 3].double().numpy() - 20.0
    np.testing.assert_allclose(surface[19:], exact[19:], rtol=4e-3)
    np.testing.assert_allclose(surface[9:], exact[9:], rtol=1.5e-2)
    assert abs(surface[0] / exact[0] - 1) > 0.1  # the mesh's error at the first frame is there
    assert plate.plate_time == pytest.approx(1.3**2 / 0.45)
    np.testing.assert_allclose(plate.frames[-1].double().numpy(), plate.frames[-1, 0, 0].item(), rtol=1e-6)


@pytest.mark.slow
def test_agrees_with_the_packages_spectral_plate_on_a_disc_defect() -> None:
    """The same plate, flash and disc in both simulators (plate.py: lateral flow exact per Fourier mode on a
    periodic domain, equal layers, Strang splitting): frames normalised by their mean agree within 2 %
    (measured 1.6 %) and the defect's contrast within 6 % (measured 4 %) from the 10th frame on."""
    from anra_torch.simulation.plate import FlashPlate, flash_plate_video

    size, dx, rate, count = 32, 0.2, 40.0, 40
    spectral, _, _ = flash_plate_video(
        size=size, dx=dx, n_frames=count, rate=rate, t_heat=-1 / rate, noise_sd=0.0, pad=32,
        plate=FlashPlate(thickness=1.5, layers=60, defect=(3.2, 3.2, 1.4, 0.5)),
    )  # fmt: skip

    def flash(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # plate.py's flash
        return 0.6 + 0.4 * np.exp(-((x - 0.35 * size * dx) ** 2 + (y - 0.45 * size * dx) ** 2) / (2 * 3.0**2))

    mine = reference_plate_video(PlateSetup(
        thickness=1.5, duration=count / rate, shape=(size, size), dx=dx, n_frames=count, flash=flash,
        defects=[Defect("ellipse", centre=(3.2, 3.2), size=(1.4, 1.4), depth=0.5)], noise_sd=0.0,
        mesh_noise=0.0,
    ))  # fmt: skip
    a, b = spectral.double().numpy()[9:] - 20.0, mine.frames.double().numpy()[9:] - 20.0
    a, b = a / a.mean((1, 2), keepdims=True), b / b.mean((1, 2), keepdims=True)
    np.testing.assert_allclose(b, a, atol=0.02)
    contrast_a, contrast_b = a[:, 16, 16] - a[:, 3, 28], b[:, 16, 16] - b[:, 3, 28]
    assert float(contrast_a.min()) > 0.1
    np.testing.assert_allclose(contrast_b, contrast_a, rtol=0.06)


def test_defect_outlines_and_truth() -> None:
    ellipse = Defect("ellipse", centre=(0.0, 0.0), size=(2.0, 1.0), depth=0.5, angle=90.0)
    assert ellipse.inside(np.array([0.0, 0.9, 0.0]), np.array([1.9, 0.0, 2.1])).tolist() == [
        True,
        True,
        False,
    ]
    rectangle = Defect("rectangle", centre=(1.0, 1.0), size=(1.0, 0.5), depth=0.5)
    assert rectangle.inside(np.array([1.9, 1.9, 1.0]), np.array([1.4, 1.6, 1.0])).tolist() == [
        True,
        False,
        True,
    ]
    triangle = Defect("polygon", vertices=((0.0, 0.0), (4.0, 0.0), (0.0, 4.0)), depth=1.0)
    assert triangle.inside(np.array([1.0, 3.0, 2.1]), np.array([1.0, 0.5, 2.1])).tolist() == [
        True,
        True,
        False,
    ]
    plate = reference_plate_video(PlateSetup(
        thickness=2.0, duration=0.5, shape=(20, 20), dx=0.5, n_frames=20,
        defects=[Defect("ellipse", centre=(9.0, 5.0), size=(3.0, 2.0), depth=1.0),
                 Defect("rectangle", centre=(3.0, 3.0), size=(1.0, 1.0), depth=0.4)],
    ))  # fmt: skip
    y, x = np.mgrid[0:20, 0:20] * 0.5 + 0.25
    over_ellipse = ((x - 9.0) / 3.0) ** 2 + ((y - 5.0) / 2.0) ** 2 <= 1
    over_square = (abs(x - 3.0) <= 1.0) & (abs(y - 3.0) <= 1.0)
    np.testing.assert_array_equal(plate.defect_mask, over_ellipse | over_square)
    assert plate.defect_mask[:, -1].any()  # the ellipse runs out of the frame
    np.testing.assert_allclose(plate.depth_fraction[over_square], 0.2)
    np.testing.assert_allclose(plate.depth_fraction[over_ellipse & ~over_square], 0.5)
    assert np.isnan(plate.depth_fraction[~(over_ellipse | over_square)]).all()
    assert plate.frames.shape == (20, 20, 20) and plate.frames.dtype == torch.float32


def test_errors() -> None:
    with pytest.raises(ValueError, match="kind must be one of"):
        Defect("circle")
    with pytest.raises(ValueError, match="at least 3 vertices"):
        Defect("polygon", vertices=((0.0, 0.0), (1.0, 1.0)))
    with pytest.raises(ValueError, match="transmission must be in"):
        Defect("ellipse", transmission=1.0)
    with pytest.raises(ValueError, match="a defect's depth must be below 1.0 mm"):
        PlateSetup(thickness=1.0, duration=1.0, defects=[Defect("ellipse", depth=1.5)])
    with pytest.raises(ValueError, match="must be positive"):
        PlateSetup(thickness=0.0, duration=1.0)


def test_shares_no_code_with_the_other_plate_or_the_effects() -> None:
    imported = {
        node.module
        for module in (plate_reference, plate_solver)
        for node in ast.walk(ast.parse(inspect.getsource(module)))
        if isinstance(node, ast.ImportFrom) and node.module
    }
    own = {"anra_torch.simulation.plate_solver"}  # the simulator's own solver
    assert not {m for m in imported if m.startswith("anra_torch") and m not in own}, imported
