"""What every video of a batch shares (:mod:`anra_torch.batch.options`): the resume key's parameters."""

from __future__ import annotations

import hashlib
import json
import pickle

import numpy as np
import pytest

from anra_torch.batch.options import BatchOptions
from anra_torch.video import CalibrationTable


def test_the_parameters_are_every_result_changing_option_as_json() -> None:
    options = BatchOptions(
        dt=0.1, dx=0.05, diagnose=True, dtype="float64", roi=(1, 2, 30, 20), precision=0.01
    )
    parameters = options.parameters()
    assert parameters == {
        "dt": 0.1,
        "dx": 0.05,
        "dtype": "float64",
        "resample": False,
        "roi": [1, 2, 30, 20],
        "calibration": None,
        "fit_fraction": 0.6,
        "precision": 0.01,
    }  # diagnose is not one: a row without a diagnosis is simply not done for a run that asks for it
    assert json.loads(json.dumps(parameters)) == parameters
    assert BatchOptions().parameters()["roi"] is None


def test_a_calibration_counts_by_its_values_not_its_file() -> None:
    table = CalibrationTable(
        true=np.array([0.0, 50.0, 200.0]), apparent=np.array([0.0, 40.0, 60.0]), source="a"
    )
    renamed = CalibrationTable(true=table.true.copy(), apparent=table.apparent.copy(), source="b.csv")
    changed = CalibrationTable(true=np.array([0.0, 50.0, 201.0]), apparent=table.apparent, source="a")
    digest = BatchOptions(calibration=table).parameters()["calibration"]
    values = np.concatenate([table.true, table.apparent]).astype(np.float64).tobytes()
    assert digest == f"sha256:{hashlib.sha256(values).hexdigest()[:16]}"
    assert BatchOptions(calibration=renamed).parameters()["calibration"] == digest
    assert BatchOptions(calibration=changed).parameters()["calibration"] != digest


def test_options_travel_to_workers_unchanged() -> None:
    table = CalibrationTable(true=np.array([0.0, 100.0]), apparent=np.array([0.0, 90.0]), source="t")
    options = BatchOptions(dt=0.2, roi=(0, 0, 8, 8), calibration=table, precision=0.001)
    copy = pickle.loads(pickle.dumps(options))
    assert copy.parameters() == options.parameters() and copy.roi == (0, 0, 8, 8)


def test_checked_options_parse_the_region_and_read_the_calibration_once(tmp_path) -> None:  # noqa: ANN001
    path = tmp_path / "table.csv"
    path.write_text("true,apparent\n0,0\n100,90\n")
    given = BatchOptions(roi="1,2,30,20", calibration=path, precision=0.01)
    checked = given.checked()
    assert tuple(checked.roi) == (1, 2, 30, 20) and isinstance(checked.calibration, CalibrationTable)
    assert checked.checked() == checked and given.parameters() == checked.parameters()
    with pytest.raises(ValueError, match=r"precision must be a relative standard error in \(0, 1\), got 2"):
        BatchOptions(precision=2).checked()
