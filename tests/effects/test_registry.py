"""The effect registry (:mod:`anra_torch.effects.registry`): fixed names and parameter names."""

from __future__ import annotations

from anra_torch.effects import (
    EFFECTS,
)

_DELAMINATION = ["x", "y", "radius", "strength", "depth_time", "t_heat", "plate_time", "T_ref", "reflected"]

PARAMS = {
    "linear_loss": ["b", "T_ref"],
    "source": ["x0", "y0", "x1", "y1", "rate", "width"],
    "advection": ["vx", "vy"],
    "anisotropy": ["a_x", "a_y", "a_xy"],
    "heterogeneity": ["x", "y", "radius", "a_inside", "a_outside"],
    "nonlinear_diffusion": ["a0", "beta", "T_ref"],
    "periodic_source": ["x", "y", "width", "rate", "frequency", "phase"],
    "depth_conduction": ["strength", "t_heat", "depth_time", "T_ref"],
    "delamination": _DELAMINATION,
    "delamination_2": _DELAMINATION,  # the same term under a second name
}
"""The fixed names of the truth records (a later JSON relies on them)."""


# --------------------------------------------------------------------------------------- registry
def test_registry_names_and_parameter_names_are_fixed() -> None:
    assert list(EFFECTS) == list(PARAMS)
    for name, keys in PARAMS.items():
        assert list(EFFECTS[name].params) == keys
        assert all(isinstance(unit, str) and unit for unit in EFFECTS[name].params.values())
    assert [n for n, s in EFFECTS.items() if s.replaces_diffusion] == [
        "anisotropy",
        "heterogeneity",
        "nonlinear_diffusion",
    ]
