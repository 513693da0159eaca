"""The depth maps of ``TissueFeatures(depth=True)``: the textbook prior without a cooling, the other
maps kept."""

from __future__ import annotations

import pytest
import torch
from depth_scenes import (
    burn_video,
)

from anra_torch.tissue import (
    DEPTH_MAPS,
    StandardErrors,
    TissueFeatures,
    damage_in_depth,
    depth_features,
)
from anra_torch.tissue.depth_features import MAP_SETTINGS, PRIOR


@pytest.fixture(scope="module")
def burn() -> tuple[torch.Tensor, float, float]:
    """A Gaussian spot held at up to 85 C for 4 s, then cooling: ``(frames, dt, dx)``."""
    return burn_video()


def test_without_cooling_the_maps_use_the_stated_prior(burn: tuple[torch.Tensor, float, float]) -> None:
    frames, dt, dx = burn
    found = depth_features(frames[:18], dt, dx)
    assert bool(found.used[0]) and not bool(found.parameters.valid[0])
    assert "textbook prior used instead" in found.messages[0]
    record = found.record(0)
    assert record["parameters_from"].startswith("textbook prior")
    assert (record["diffusivity_mm2_s"], record["diffusivity_std_mm2_s"]) == PRIOR["diffusivity"]
    maps = damage_in_depth(
        frames[:18].float(),  # the maps' settings: float32, the MAP_GROWTH grid
        dt,
        dx,
        diffusivity=0.14,
        loss_rate=0.005,
        errors=StandardErrors(0.03, 0.005, found.parameters.noise_sd),
        settings=MAP_SETTINGS,
    )
    torch.testing.assert_close(found.maps["damage_depth_std_mm"][0], maps.damage_depth_std)
    assert float(maps.damage_depth_std[10, 10]) > 0.02  # a wide prior, a wide band


def test_tissue_features_gain_the_depth_maps_and_keep_the_others(
    burn: tuple[torch.Tensor, float, float],
) -> None:
    frames, dt, dx = burn
    plain = TissueFeatures()(frames, dt, dx)
    deep = TissueFeatures(depth=True)(frames, dt, dx)
    for name, m in plain.maps.items():
        torch.testing.assert_close(deep.maps[name], m, rtol=0, atol=0)
    assert set(DEPTH_MAPS) <= set(deep.maps) and all(deep.units[name] == "mm" for name in DEPTH_MAPS)
    assert deep.depth is not None and deep.depth.parameters.diffusivity.shape == (1,)
    assert "damage_depth_mm" in TissueFeatures(depth=True)(frames, dt).absent  # no pixel size
    assert isinstance(TissueFeatures(depth=True), torch.nn.Module)
