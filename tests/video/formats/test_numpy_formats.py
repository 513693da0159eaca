"""``.npz`` and ``.npy`` (:mod:`anra_torch.video.formats.numpy_formats`): round trips, the writer's suffix
and atomicity, byte order, one-line errors of ``save_npz``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scenes import random_frames as frames

from anra_torch.video import Video, load_video, save_npz

DT, DX = 1 / 27, 0.05


# --------------------------------------------------------------------------------------- round trips
def test_save_load_round_trip_keeps_everything(tmp_path: Path) -> None:
    video = frames()
    t = 2.0 + np.arange(8) * DT
    path = save_npz(tmp_path / "v.npz", video, dt=DT, dx=DX, t=t, a_true=0.2, unit="degC")
    loaded = load_video(path)
    assert isinstance(loaded, Video) and loaded.source == path and loaded.name == "v.npz"
    np.testing.assert_array_equal(loaded.frames.numpy(), video)
    assert loaded.frames.dtype == torch.float64 and loaded.frames.shape == (8, 6, 7)
    assert loaded.dt == pytest.approx(DT, rel=1e-12) and loaded.dx == DX
    np.testing.assert_array_equal(loaded.t.numpy(), t)
    assert loaded.meta == {"a_true": 0.2, "unit": "degC", "dt_source": "t", "dx_source": "file"}
    assert loaded.unit == "degC"


def test_save_npz_appends_suffix_creates_dirs_and_leaves_no_partial_file(tmp_path: Path) -> None:
    path = save_npz(tmp_path / "new" / "video", torch.zeros(5, 4, 4), dt=0.1, dx=None)
    assert path == tmp_path / "new" / "video.npz"
    assert sorted(p.name for p in path.parent.iterdir()) == ["video.npz"]
    loaded = load_video(path)
    assert loaded.dx is None and loaded.t is None and loaded.meta == {"dt_source": "file"}
    assert loaded.unit == "data units"


def test_npy_holds_frames_only(tmp_path: Path) -> None:
    np.save(tmp_path / "v.npy", frames())
    loaded = load_video(tmp_path / "v.npy", dt=0.1, dx=0.3)
    assert (loaded.dt, loaded.dx, loaded.t) == (0.1, 0.3, None)
    assert load_video(tmp_path / "v.npy", dt=0.1).dx is None


def test_big_endian_frames_are_read(tmp_path: Path) -> None:
    video = frames().astype(">f8")
    np.save(tmp_path / "v.npy", video)
    np.testing.assert_array_equal(load_video(tmp_path / "v.npy", dt=1.0).frames.numpy(), video)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (
            {"frames": np.zeros((4, 4)), "dt": 0.1, "dx": 0.1},
            r"frames must have shape \(T, H, W\), got \(4, 4\)",
        ),
        ({"frames": np.zeros((4, 4, 4)), "dt": 0.0, "dx": 0.1}, r"dt \(argument\) must be a positive"),
        ({"frames": np.zeros((4, 4, 4)), "dt": 0.1, "dx": -2}, r"dx \(argument\) must be a positive"),
        (
            {"frames": np.zeros((4, 4, 4)), "dt": 0.1, "dx": 0.1, "t": np.arange(3.0)},
            r"t must have shape \(4,\) in s, got \(3,\)",
        ),
    ],
)
def test_save_npz_errors(tmp_path: Path, kwargs: dict, match: str) -> None:
    frames_ = kwargs.pop("frames")
    with pytest.raises(ValueError, match=match):
        save_npz(tmp_path / "out.npz", frames_, **kwargs)
    assert not list(tmp_path.iterdir())
