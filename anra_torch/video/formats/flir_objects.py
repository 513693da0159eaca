"""The object parameters of a FLIR radiometric recording a user may set after capture, and the record of
which values the temperatures used.

Emissivity, reflected apparent temperature, object distance, atmospheric temperature and relative humidity
are stored in each frame's CameraInfo record (:mod:`~anra_torch.video.formats.flir_fff`); the camera set
them at capture, and they can be replaced before the counts become temperatures (:class:`ObjectParameters`).
:func:`object_record` states the values used and where each came from (``meta["object_parameters"]``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import Any

from anra_torch.checks import number
from anra_torch.video.formats.flir_fff import CameraInfo

__all__ = ["ObjectParameters", "object_record"]

_KELVIN = 273.15
_OBJECT_FIELDS = {
    # name: (CameraInfo field, unit, to the CameraInfo unit)
    "emissivity": ("emissivity", "", 1.0),
    "reflected_temp": ("reflected_temp", "degC", 1.0),
    "distance": ("object_distance", "m", 1.0),
    "atmospheric_temp": ("atmospheric_temp", "degC", 1.0),
    "humidity": ("relative_humidity", "%", 0.01),
}


_OBJECT_LIMITS: dict[str, tuple[str, Callable[[float], bool]]] = {
    "emissivity": ("in (0, 1]", lambda v: 0 < v <= 1),
    "reflected_temp": ("above -273.15", lambda v: v > -_KELVIN),
    "distance": (">= 0", lambda v: v >= 0),
    "atmospheric_temp": ("above -273.15", lambda v: v > -_KELVIN),
    "humidity": ("in [0, 100]", lambda v: 0 <= v <= 100),
}


@dataclass(frozen=True)
class ObjectParameters:
    """The object parameters a user may set after capture; None keeps the file's value.

    Attributes:
        emissivity: in (0, 1].
        reflected_temp: reflected apparent temperature in degC.
        distance: object distance in m, >= 0.
        atmospheric_temp: degC.
        humidity: relative humidity in % (0-100).

    Shape:
        Scalars.

    Raises:
        ValueError: a value outside its range (checked on construction).
        TypeError: a value that is not a number.
    """

    emissivity: float | None = None
    reflected_temp: float | None = None
    distance: float | None = None
    atmospheric_temp: float | None = None
    humidity: float | None = None

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if value is None:
                continue
            unit = _OBJECT_FIELDS[item.name][1]
            value = number(value, item.name, unit or "(a fraction)")
            need, ok = _OBJECT_LIMITS[item.name]
            if not ok(value):
                raise ValueError(f"{item.name} must be {need}{' ' + unit if unit else ''}, got {value:g}")
            object.__setattr__(self, item.name, value)

    @property
    def given(self) -> bool:
        """Whether any parameter is set."""
        return any(getattr(self, item.name) is not None for item in fields(self))

    def changes(self) -> dict[str, float]:
        """The set parameters as :data:`PLANCK_KEYS` entries (temperatures degC, humidity a fraction)."""
        return {
            field: getattr(self, name) * scale
            for name, (field, _, scale) in _OBJECT_FIELDS.items()
            if getattr(self, name) is not None
        }

    def apply(self, camera: CameraInfo) -> CameraInfo:
        """``camera`` with the set parameters in place of the file's."""
        return replace(camera, planck={**camera.planck, **self.changes()})


def object_record(
    camera: CameraInfo, objects: ObjectParameters | None, *, varies: frozenset[str] = frozenset()
) -> dict[str, dict[str, Any]]:
    """Which object parameters the temperatures used and where each came from.

    Args:
        camera: the file's CameraInfo (of the first frame).
        objects: the user's overrides, or None.
        varies: names whose file value changes between frames (the first frame's is shown).

    Returns:
        ``{name: {"value", "unit", "source"}}`` for emissivity, reflected_temp (degC), distance (m),
        atmospheric_temp (degC), humidity (%); ``source`` is ``"argument"`` or ``"file"`` (``"file (varies
        by frame; first frame shown)"`` when it changes), and an overridden entry keeps the ``"file"`` value.

    Shape:
        No tensors.
    """
    record = {}
    for name, (field, unit, scale) in _OBJECT_FIELDS.items():
        value = camera.planck[field] / scale  # float32 in the file: K to 3e-5, so degC to 4 decimals
        stored = round(value, 4) if unit == "degC" else float(f"{value:.6g}")
        given = getattr(objects, name) if objects is not None else None
        entry: dict[str, Any] = {"value": stored if given is None else given, "unit": unit or None}
        if given is None:
            entry["source"] = "file (varies by frame; first frame shown)" if field in varies else "file"
        else:
            entry.update(source="argument", file=stored)
        record[name] = entry
    return record
