"""One recording's estimate (:mod:`anra_torch.recording.estimate`): ``anra estimate``, ``anra diagnose`` and
``anra batch`` agree, on a still box and on every recording in ``../shared/data``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from scenes import DT, DX, still_box
from shared_data import DATA, needs_data

from anra_torch.batch import BatchOptions, read_table, run_batch
from anra_torch.cli import main
from anra_torch.recording import diagnose_recording
from anra_torch.video import (
    save_npz,
)


@pytest.mark.slow
@needs_data
def test_batch_and_estimate_agree_on_every_shared_recording(tmp_path: Path, capsys) -> None:
    """One recording policy: ``anra batch`` and ``anra estimate`` give the same diffusivity, status and phase
    for every recording in ../shared/data (the FLIR JPEG folders at 0.55 mm/px, the CSV box exports at an
    assumed 10 frames/s and 0.25 mm/px)."""
    data = DATA
    cases = [(data / "laser_silicone" / name, {"dx": 0.55}) for name in ("Nov19", "Nov19_2")]
    cases += [(path, {"dt": 0.1, "dx": 0.25}) for path in sorted((data / "flir_csv").glob("* M1.csv"))]
    cases += [(data / "flir_csv" / "Q 100 Silver 1.csv", {"dt": 0.1, "dx": 0.25})]
    for path, spacing in cases:
        flags = [x for key, value in spacing.items() for x in (f"--{key}", str(value))]
        capsys.readouterr()
        code = main(["estimate", str(path), *flags, "--json"])
        estimate = json.loads(capsys.readouterr().out)
        out = tmp_path / f"{path.stem}.csv"
        run_batch([path], out, options=BatchOptions(dtype="float64", **spacing), progress=False)
        (row,) = read_table(out)
        several = len(estimate["phases"]) > 1
        assert row["phase"] == (estimate["phase"] if several else None), path.name
        assert (row["status"] == "ok") == (code == 0) == estimate["valid"], path.name
        if estimate["diffusivity"] is None:
            assert row["diffusivity"] is None, path.name
        else:
            assert row["diffusivity"] == pytest.approx(estimate["diffusivity"], rel=1e-9), path.name
            assert int(row["frames"]) == estimate["frames"], path.name


def test_a_still_box_is_flagged_by_estimate_diagnose_and_batch(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """No silent near-zero diffusivity: estimate, the phase record and the batch row all say why."""
    path = save_npz(tmp_path / "still.npz", still_box(0).numpy(), dt=DT, dx=DX)
    assert main(["estimate", str(path), "--json"]) == 2
    out = json.loads(capsys.readouterr().out)
    assert out["valid"] is False and "within 3 standard errors of 0" in out["message"]
    assert out["std_error"] > abs(out["diffusivity"]) / 3
    (phase,) = diagnose_recording(still_box(0), DT, DX)
    assert phase.family == "small_box" and "not_significant" in phase.to_record()["base"]["flags"]
    assert phase.to_record()["base"]["std_error"] == pytest.approx(phase.diffusivity_std_error)
    main(["batch", str(path), "--out", str(tmp_path / "rows.csv")])
    capsys.readouterr()
    with open(tmp_path / "rows.csv") as table:
        (row,) = list(csv.DictReader(table))
    assert row["status"] == "error" and "within 3 standard errors of 0" in row["error"]
    assert float(row["std_error"]) > 0
