"""FLIR counts to temperatures (:mod:`anra_torch.video.formats.flir_planck`): Thermimage's raw2temp in plain
floats as the reference, per-frame constants, counts outside the formula's range."""

from __future__ import annotations

import numpy as np
import pytest
from fff_writer import CONSTANTS, Camera, planck_celsius

from anra_torch.video.formats.flir_fff import PLANCK_KEYS
from anra_torch.video.formats.flir_planck import celsius


def planck(cam: Camera, **changes: float) -> dict[str, float]:
    """The :data:`PLANCK_KEYS` values of ``cam`` (degC, m, a fraction), float32 as a camera stores them."""
    f32 = lambda v: float(np.float32(v))  # noqa: E731
    values = {
        "emissivity": f32(cam.emissivity),
        "object_distance": f32(cam.distance),
        "reflected_temp": f32(cam.reflected_k) - 273.15,
        "atmospheric_temp": f32(cam.atmospheric_k) - 273.15,
        "ir_window_temp": f32(cam.window_k) - 273.15,
        "ir_window_transmission": f32(cam.window_transmission),
        "relative_humidity": f32(cam.humidity),
        **{f"planck_{k}": f32(CONSTANTS[k]) for k in ("r1", "b", "f", "r2")},
        "planck_o": CONSTANTS["o"],
        **{name: f32(CONSTANTS[k]) for name, k in (("alpha1", "a1"), ("alpha2", "a2"), ("beta1", "b1"))},
        "beta2": f32(CONSTANTS["b2"]),
        "x": f32(CONSTANTS["x"]),
    }
    values.update(changes)
    return {key: values[key] for key in PLANCK_KEYS}


@pytest.mark.parametrize("emissivity", [0.95, 0.5])
def test_celsius_is_thermimages_raw2temp(emissivity: float) -> None:
    cam = Camera(emissivity=emissivity, distance=2.0, humidity=0.4)
    counts = np.array([[12000, 15000], [18000, 21000]], dtype=np.uint16)
    expected = [[planck_celsius(float(v), cam) for v in row] for row in counts]
    np.testing.assert_allclose(celsius(counts, planck(cam)), expected, atol=2e-4)


def test_per_frame_constants_apply_to_their_own_frame() -> None:
    cam, warm = Camera(), Camera(reflected_k=320.0)
    counts = np.full((2, 1, 1), 15000, dtype=np.uint16)
    both = {key: np.array([planck(cam)[key], planck(warm)[key]]) for key in PLANCK_KEYS}
    out = celsius(counts, both)
    assert out[0, 0, 0] == pytest.approx(planck_celsius(15000.0, cam), abs=2e-4)
    assert out[1, 0, 0] == pytest.approx(planck_celsius(15000.0, warm), abs=2e-4)


def test_counts_without_object_radiance_are_nan_not_an_error() -> None:
    out = celsius(np.array([[0, 15000]], dtype=np.uint16), planck(Camera(), emissivity=0.0))
    assert np.isnan(out).all()
    assert np.isfinite(celsius(np.array([[15000]]), planck(Camera()))).all()
