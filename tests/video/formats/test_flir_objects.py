"""The object parameters of a FLIR recording (:mod:`anra_torch.video.formats.flir_objects`): their ranges,
what they replace in a frame's CameraInfo, and the record of which values were used and where each came
from."""

from __future__ import annotations

import numpy as np
import pytest
from fff_writer import Camera, simple_frame

from anra_torch.video.formats.flir_fff import read_frame
from anra_torch.video.formats.flir_objects import ObjectParameters, object_record


def camera_info(cam: Camera):
    data = simple_frame(np.full((4, 4), 17000, np.uint16), cam)
    return read_frame(lambda o, n: data[o : o + n], 0).camera


def test_set_parameters_replace_the_files_in_the_formulas_units() -> None:
    camera = camera_info(Camera(emissivity=0.95, distance=2.0, reflected_k=293.15, humidity=0.5))
    objects = ObjectParameters(emissivity=0.5, humidity=80.0, reflected_temp=35.0)
    assert objects.given and not ObjectParameters().given
    assert objects.changes() == {"emissivity": 0.5, "reflected_temp": 35.0, "relative_humidity": 0.8}
    applied = objects.apply(camera).planck
    assert applied["relative_humidity"] == 0.8 and applied["object_distance"] == pytest.approx(2.0)
    assert camera.planck["emissivity"] == pytest.approx(0.95)  # the file's record is left as read
    record = object_record(camera, objects, varies=frozenset({"object_distance"}))
    assert record["emissivity"] == {"value": 0.5, "unit": None, "source": "argument", "file": 0.95}
    assert record["humidity"] == {"value": 80.0, "unit": "%", "source": "argument", "file": 50.0}
    assert record["distance"]["source"] == "file (varies by frame; first frame shown)"
    assert record["reflected_temp"] == {"value": 35.0, "unit": "degC", "source": "argument", "file": 20.0}


@pytest.mark.parametrize(
    ("given", "pattern"),
    [
        ({"emissivity": 0.0}, r"^emissivity must be in \(0, 1\], got 0$"),
        ({"humidity": 100.5}, r"^humidity must be in \[0, 100\] %, got 100\.5$"),
        ({"distance": -0.1}, r"^distance must be >= 0 m, got -0\.1$"),
        ({"atmospheric_temp": -274.0}, r"^atmospheric_temp must be above -273\.15 degC, got -274$"),
    ],
)
def test_values_out_of_range_are_one_line_errors(given: dict, pattern: str) -> None:
    with pytest.raises(ValueError, match=pattern):
        ObjectParameters(**given)
