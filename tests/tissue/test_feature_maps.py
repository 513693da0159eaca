"""What the tissue features return and write: the maps stacked, the ``.npz`` of one video, the dose record."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch.tissue import SKIN, TissueFeatures
from anra_torch.tissue.feature_maps import DOSE_MAPS, MAP_UNITS, dose_record, save_feature_maps


def test_the_npz_holds_every_map_with_its_unit(tmp_path: Path) -> None:
    trace = torch.linspace(37.0, 60.0, 31, dtype=torch.float64).view(-1, 1, 1).expand(31, 2, 3).clone()
    trace[4, 1, 2] = float("nan")
    maps = TissueFeatures()(trace, dt=0.5)  # no pixel size: the dose maps only
    assert list(maps.maps) == list(DOSE_MAPS) and maps.stack().shape == (len(DOSE_MAPS), 2, 3)
    with pytest.raises(ValueError, match="unknown feature map 'source' \\(no pixel size"):
        maps.stack(["source"])
    path = save_feature_maps(str(tmp_path / "maps"), maps, dt=0.5, dx=None)
    assert path.endswith("maps.npz")
    with np.load(path) as saved:
        for name in DOSE_MAPS:
            np.testing.assert_array_equal(saved[name], maps.maps[name].numpy())
            assert str(saved[f"units_{name}"]) == MAP_UNITS.get(name, "s")
        assert int(saved["masked"][1, 2]) == 1 and float(saved["dt"]) == 0.5 and "dx" not in saved


def test_the_dose_record_names_the_span_of_each_rule() -> None:
    linear = dose_record(("linear", SKIN, (43.0,)), 11, 0.5, 1.0)
    hold = dose_record(("hold", SKIN, (43.0,)), 11, 0.5, 1.0)
    assert linear["span_s"] == 5.0 and hold["span_s"] == 5.5
    assert linear["arrhenius"]["A_per_s"] == SKIN.frequency and linear["thresholds_C"] == [43.0]
