"""``prepare_video`` (:mod:`anra_torch.video.prepare`): load -> resample -> roi -> calibration, recorded in
meta, with the truth of a simulation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch.cli import main
from anra_torch.effects import Effect, hidden_effect_video
from anra_torch.video import (
    CalibrationTable,
    Truth,
    apply_calibration,
    crop,
    load_video,
    prepare_video,
    resample_uniform,
    save_npz,
)

TABLE = CalibrationTable(true=np.array([0.0, 50.0, 200.0]), apparent=np.array([0.0, 40.0, 60.0]), source="t")
"""Apparent 0-60 -> true 0-200, piecewise linear with a kink at 40."""


@pytest.fixture
def jittered(tmp_path: Path) -> Path:
    """10 frames of 6 x 8 px at non-uniform times; pixel (row, col) of frame k holds 10 row + col + 3 t."""
    t = np.array([0.0, 1.0, 2.5, 3.0, 4.0, 5.5, 6.0, 7.0, 8.5, 9.0])
    rows, cols = np.mgrid[:6, :8]
    frames = 10.0 * rows + cols + 3.0 * t[:, None, None]
    return save_npz(tmp_path / "jitter.npz", frames, dt=1.0, dx=0.25, t=t, unit="degC")


def test_steps_run_in_order_and_are_recorded(jittered: Path) -> None:
    video = prepare_video(jittered, timestamps="resample", roi="2,1,4,3", calibration=TABLE)
    # The same steps by hand, in the documented order: crop after resampling, calibrate the crop.
    expected = apply_calibration(
        crop(resample_uniform(load_video(jittered, timestamps="keep")), (2, 1, 4, 3)), TABLE
    )
    torch.testing.assert_close(video.frames, expected.frames, rtol=0, atol=0)
    assert video.meta["steps"] == ["load", "resample", "roi", "calibration"]
    assert video.meta["roi"] == [2, 1, 4, 3] and video.meta["resampled"]["from_frames"] == 10
    # The extrapolated fraction is counted on the analysed (cropped) values only: rows 1-3 pass 60 late,
    # the full frame (rows up to 5) much earlier.
    full = apply_calibration(resample_uniform(load_video(jittered, timestamps="keep")), TABLE)
    assert video.meta["calibration"] == {
        "table": "t",
        "outside_fraction": expected.meta["calibration"]["outside_fraction"],
    }
    assert 0 < video.meta["calibration"]["outside_fraction"] < full.meta["calibration"]["outside_fraction"]
    # At the median step (1 s) the 5.5 s and 6 s samples would share a frame: every sample keeps one at 0.5 s.
    assert video.frames.shape == (19, 3, 4) and video.dt == pytest.approx(0.5) and video.dx == 0.25


def test_defaults_only_load_and_accept_tuples_and_paths(jittered: Path, tmp_path: Path) -> None:
    plain = prepare_video(jittered, dt=0.5)
    assert plain.meta["steps"] == ["load"] and "roi" not in plain.meta and plain.dt == 0.5
    torch.testing.assert_close(plain.frames, load_video(jittered, dt=0.5).frames)
    table = tmp_path / "table.csv"
    table.write_text("T,IR\n0,0\n50,40\n200,60\n")
    by_path = prepare_video(jittered, dt=0.5, roi=(2, 1, 4, 3), calibration=table)
    by_text = prepare_video(jittered, dt=0.5, roi="2,1,4,3", calibration=TABLE)
    torch.testing.assert_close(by_path.frames, by_text.frames, rtol=0, atol=0)
    assert by_path.meta["calibration"]["table"] == str(table)


def test_errors_are_one_line(jittered: Path, tmp_path: Path) -> None:
    nodx = save_npz(tmp_path / "nodx.npz", np.zeros((6, 4, 4)), dt=0.1, dx=None)
    with pytest.raises(
        ValueError, match=r"^\S*nodx\.npz: no pixel size: the file has no 'dx'; pass --dx in mm$"
    ):
        prepare_video(nodx)
    assert prepare_video(nodx, need_dx=False).dx is None
    with pytest.raises(ValueError, match=r"t must be uniformly spaced"):
        prepare_video(jittered)
    with pytest.raises(ValueError, match=r"roi 6,0,4,2 \(x0,y0,W,H px\) does not fit in the 8 x 6 px frame"):
        prepare_video(jittered, dt=1.0, roi="6,0,4,2")
    with pytest.raises(ValueError, match="four integers"):
        prepare_video(jittered, dt=1.0, roi="1,2")
    with pytest.raises(ValueError, match="no such calibration file"):
        prepare_video(jittered, dt=1.0, calibration=tmp_path / "none.csv")


# ------------------------------------------------------------------------------------------------ truth
def test_truth_from_anra_simulate_with_an_effect(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "adv.npz"
    argv = [
        "simulate",
        "--effect",
        "advection",
        "--seed",
        "2",
        "--size",
        "32",
        "--duration",
        "0.5",
        "-o",
        str(path),
    ]
    assert main(argv) == 0
    capsys.readouterr()
    video = load_video(path)
    expected = hidden_effect_video(["advection"], seed=2, size=32, duration=0.5)
    assert isinstance(video.truth, Truth)
    assert video.truth.a == 0.15 and video.truth.seed == 2 and video.truth.clean is None
    assert video.truth.noise_sd == pytest.approx(expected.noise_sd, rel=1e-12)
    assert [r["name"] for r in video.truth.effects] == ["advection"]
    assert tuple(Effect.from_dict(r) for r in video.truth.effects) == expected.effects
    assert video.meta["a_true"] == video.truth.a  # meta keeps the scalars as before
    # The truth follows the preparation steps (the frames change, what the video was made with does not).
    assert prepare_video(path, roi="4,4,16,16").truth == video.truth
