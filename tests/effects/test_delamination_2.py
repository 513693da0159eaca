"""The second delamination: tried only with two candidate regions or more, held at a region the first does
not cover, and named beside the first over each defect of a plate with two."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from anra_torch.effects import EFFECTS, Effect, simulate_effects
from anra_torch.effects.delamination import REGRESSORS, _uncovered
from anra_torch.selection import diagnose_terms
from anra_torch.selection.stepwise import tried

F64 = torch.float64

PLATE = {"strength": 1.0, "t_heat": -0.08, "depth_time": 5.0, "T_ref": 30.0}
FIRST = {"x": 8.0, "y": 9.0, "radius": 2.0, "strength": 1.0, "depth_time": 0.3, "t_heat": -0.08}
FIRST = {**FIRST, "plate_time": 5.0, "T_ref": 30.0, "reflected": 1.0}  # d / L 0.245
SECOND = {**FIRST, "x": 15.0, "y": 15.0, "depth_time": 1.2}  # d / L 0.49
REGIONS = [  # a defect map's outlines about them, off by a fraction of a pixel
    {"x": 8.2, "y": 8.9, "radius": 1.8, "depth_fraction": 0.25},
    {"x": 15.0, "y": 15.1, "radius": 2.1, "depth_fraction": 0.5},
]
NAMES = ["depth_conduction", "delamination", "delamination_2"]


@pytest.fixture(scope="module")
def two_defects() -> tuple[torch.Tensor, float, float]:
    """A flash spot (2 K, 5 mm sd) on a plate with two discs at different depths, the library's own
    simulator (the independent 3-D plate holds one defect), 48 px of 0.5 mm, 60 frames of 0.05 s, white
    noise 0.01 K."""
    dx = 0.5
    centres = (torch.arange(48, dtype=F64) + 0.5) * dx
    y, x = torch.meshgrid(centres, centres, indexing="ij")
    u0 = 30.0 + 2.0 * torch.exp(-((x - 11.0) ** 2 + (y - 12.0) ** 2) / (2 * 5.0**2))
    effects = [Effect(n, p) for n, p in zip(NAMES, (PLATE, FIRST, SECOND), strict=True)]
    video = simulate_effects(u0, a=0.5, dx=dx, dt=0.05, n_frames=60, effects=effects)
    noise = torch.randn(video.shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    return video + 0.01 * noise, 0.05, dx


def test_tried_only_with_two_candidate_regions_or_more() -> None:
    spec = EFFECTS["delamination_2"]
    assert spec.requires == ("depth_conduction", "delamination") and spec.regressors == ("Y2",)
    assert not spec.tried({}) and not spec.tried({"delamination": (REGIONS[0],)})
    assert spec.tried({"delamination": tuple(REGIONS)})
    plate = {"T_ref": 30.0, "plate_time": 5.0, "t_heat": -0.08}
    assert spec.tried({"delamination": tuple(REGIONS), "depth_conduction": (plate,)})
    # also where the plate is forecast on layers, which hold a face for each delamination
    assert spec.tried({"delamination": tuple(REGIONS), "depth_conduction": ({**plate, "layered": 1.0},)})
    assert all(EFFECTS[n].tried({}) for n in EFFECTS if n != "delamination_2")
    assert tried(NAMES, {}) == NAMES[:2] and tried(NAMES, {"delamination": tuple(REGIONS)}) == NAMES


def test_a_delamination_is_held_at_the_regions_the_others_in_the_model_do_not_cover() -> None:
    regions = [(10.0, 10.0, 4.0, 0.2, 1.0), (30.0, 30.0, 5.0, 0.5, 1.0), (30.0, 10.0, 3.0, 0.4, 1.0)]
    shapes = {"delamination": {"x": 5.5, "y": 5.0}, "delamination_2": {"x": 14.0, "y": 6.0}}
    system = SimpleNamespace(dx=0.5, shapes=shapes)  # px: the first at (11, 10), the second at (28, 12)
    with_first = SimpleNamespace(columns=("L", "Z", REGRESSORS["delamination"]))
    assert _uncovered(system, with_first, "delamination_2", regions) == regions[1:]  # type: ignore[arg-type]
    # a delamination's own shape, or another's outside the fit's model, covers nothing
    assert _uncovered(system, with_first, "delamination", regions) == regions  # type: ignore[arg-type]
    alone = SimpleNamespace(columns=("L", "Z"))
    assert _uncovered(system, alone, "delamination_2", regions) == regions  # type: ignore[arg-type]
    # the first refitted beside the second: the second's region (nearest in its radii) left out
    with_second = SimpleNamespace(columns=("L", "Z", REGRESSORS["delamination_2"]))
    kept = _uncovered(system, with_second, "delamination", regions)  # type: ignore[arg-type]
    assert kept == [regions[0], regions[1]]


def test_both_defects_named_where_the_map_gives_both(two_defects) -> None:
    d = diagnose_terms(*two_defects, effects=NAMES, hints={"delamination": REGIONS})
    assert sorted(d.names) == sorted(NAMES), (d.names, d.scores)
    found = {e["name"]: e["params"] for e in d.effects}
    for name, truth in (("delamination", FIRST), ("delamination_2", SECOND)):
        p = found[name]
        assert math.hypot(p["x"] - truth["x"], p["y"] - truth["y"]) < 0.5, (name, p)  # mm (1 px)
        truth_fraction = math.sqrt(truth["depth_time"] / truth["plate_time"])
        assert p["depth_fraction"] == pytest.approx(truth_fraction, abs=0.05), (name, p)
        assert p["strength"] == pytest.approx(1.0, abs=0.2), (name, p)


def test_one_region_or_none_leaves_the_second_untried(two_defects) -> None:
    for hints in ({"delamination": REGIONS[:1]}, None):
        d = diagnose_terms(*two_defects, effects=NAMES, hints=hints)
        assert "delamination_2" not in d.scores and d.names == NAMES[:2], (d.names, d.scores)


def test_the_layered_forecast_holds_a_face_for_each_delamination() -> None:
    """The layers hold each delamination's face at its own depth (the first's, then the second's), not the
    surface balance's term on every layer."""
    from anra_torch.forecast.layered import layered_plate

    held = {"T_ref": 30.0, "plate_time": 5.0, "t_heat": -0.08, "layered": 1.0}
    effects = [Effect(n, p).to_dict() for n, p in zip(NAMES, (PLATE, FIRST, SECOND), strict=True)]
    diagnosis = SimpleNamespace(hints={"depth_conduction": (held,)}, base=0.5, effects=effects)
    model = layered_plate(diagnosis, set(NAMES))  # type: ignore[arg-type]
    assert model is not None and model.others == ()
    assert [d[:3] for d in model.defects] == [(p["x"], p["y"], p["radius"]) for p in (FIRST, SECOND)]
    depths = [math.sqrt(p["depth_time"] / p["plate_time"]) for p in (FIRST, SECOND)]
    assert [d[3] for d in model.defects] == pytest.approx(depths)
