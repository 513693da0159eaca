"""What an effect is (:mod:`anra_torch.effects.base`): the grid it acts on, the scene geometry it is drawn
for, and the contract's small helpers, with their one-line errors."""

from __future__ import annotations

import pytest
import torch

from anra_torch.effects import EFFECTS, Geometry, Grid
from anra_torch.effects.base import EffectSpec, require, same_bounds, signed

F64 = torch.float64


def test_a_grid_has_pixel_centres_in_mm_and_ghost_pixels_from_its_boundary() -> None:
    grid = Grid((3, 4), 0.5, duration=2.0)
    torch.testing.assert_close(grid.x, torch.tensor([0.25, 0.75, 1.25, 1.75], dtype=F64))
    torch.testing.assert_close(grid.y, torch.tensor([0.25, 0.75, 1.25], dtype=F64))
    u = torch.arange(12, dtype=F64).reshape(3, 4)
    padded = grid.pad(u)  # zero flux: the ghost mirrors the edge pixel
    assert padded.shape == (5, 6)
    torch.testing.assert_close(padded[1:-1, 1:-1], u)
    torch.testing.assert_close(padded[0, 1:-1], u[0])
    torch.testing.assert_close(padded[1:-1, -1], u[:, -1])
    held = Grid((3, 4), 0.5, boundary="dirichlet", boundary_value=7.0).pad(u)
    assert bool((held[0] == 7.0).all()) and bool((held[:, 0] == 7.0).all())
    wrapped = Grid((3, 4), 0.5, boundary="periodic").pad(u)
    torch.testing.assert_close(wrapped[1:-1, 0], u[:, -1])
    assert Grid([5, 6], 1).shape == (5, 6) and isinstance(Grid((5, 6), 1).dx, float)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (
            {"shape": (3,), "dx": 0.5},
            ValueError,
            r"shape must be \(H, W\) with positive integers, got \(3,\)",
        ),
        ({"shape": (0, 4), "dx": 0.5}, ValueError, r"shape must be \(H, W\) with positive integers"),
        ({"shape": (3.0, 4), "dx": 0.5}, ValueError, r"shape must be \(H, W\)"),
        ({"shape": (3, 4), "dx": 0.0}, ValueError, r"dx must be a positive finite number in mm, got 0.0"),
        ({"shape": (3, 4), "dx": "a"}, TypeError, r"dx must be a number in mm, got 'a'"),
        (
            {"shape": (3, 4), "dx": 1.0, "duration": -1.0},
            ValueError,
            r"duration must be a finite number >= 0",
        ),
        ({"shape": (3, 4), "dx": 1.0, "boundary": "open"}, ValueError, r"unknown boundary 'open'; expected"),
        (
            {"shape": (3, 4), "dx": 1.0, "boundary_value": 2.0},
            ValueError,
            r"boundary_value applies to boundary='dirichlet' only, got boundary='neumann'",
        ),
    ],
)
def test_a_bad_grid_is_a_one_line_error(kwargs: dict, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match) as info:
        Grid(**kwargs)
    assert "\n" not in str(info.value)


def test_the_geometry_of_a_scene_in_mm() -> None:
    geometry = Geometry((40, 60), 0.25, 3.0, 0.15, rise=10.0, hotspots=((5.0, 4.0, 1.0),))
    assert (geometry.width_mm, geometry.height_mm) == (15.0, 10.0)
    assert geometry.background == 0.0


def test_the_contracts_helpers() -> None:
    with pytest.raises(ValueError, match=r"^linear_loss\.b must be >= 0, got -1\.0$"):
        require(False, "linear_loss", "b", ">= 0", {"b": -1.0})
    require(True, "linear_loss", "b", ">= 0", {"b": 1.0})
    assert signed(-0.2, ".2f") == "- 0.20" and signed(0.125, ".3f") == "+ 0.125"
    assert same_bounds({}, 20.0, 30.0, 5.0) == (20.0, 30.0)
    assert all(isinstance(spec, EffectSpec) and spec.params for spec in EFFECTS.values())
