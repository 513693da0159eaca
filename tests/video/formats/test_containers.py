"""MATLAB, HDF5 and TIFF (:mod:`anra_torch.video.formats.containers`): round trips, corrupt files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from anra_torch.video import load_video

VIDEO = np.random.default_rng(1).normal(30, 2, (6, 5, 7))


def test_mat_round_trip(tmp_path: Path) -> None:
    scipy_io = pytest.importorskip("scipy.io")
    t = 0.5 * np.arange(6)
    scipy_io.savemat(tmp_path / "v.mat", {"frames": VIDEO, "t": t, "dx": 0.2})
    video = load_video(tmp_path / "v.mat")
    np.testing.assert_array_equal(video.frames.numpy(), VIDEO)
    assert video.dt == pytest.approx(0.5) and video.dx == pytest.approx(0.2)
    np.testing.assert_array_equal(video.t.numpy(), t)


def test_hdf5_round_trip_with_attributes(tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    with h5py.File(tmp_path / "v.h5", "w") as handle:
        data = handle.create_dataset("group/cube", data=VIDEO.astype(np.float32))
        data.attrs["dt"], data.attrs["dx"] = 0.04, 0.1
    video = load_video(tmp_path / "v.h5")
    np.testing.assert_array_equal(video.frames.numpy(), VIDEO.astype(np.float32))
    assert (video.dt, video.dx) == (pytest.approx(0.04), pytest.approx(0.1))


def test_tiff_round_trip(tmp_path: Path) -> None:
    tifffile = pytest.importorskip("tifffile")
    counts = (VIDEO * 100).astype(np.uint16)
    tifffile.imwrite(tmp_path / "v.tif", counts, imagej=True, metadata={"axes": "TYX", "finterval": 0.25})
    video = load_video(tmp_path / "v.tif", dx=0.3)
    np.testing.assert_array_equal(video.frames.numpy(), counts)
    assert video.dt == pytest.approx(0.25)


@pytest.mark.parametrize("suffix", [".mat", ".h5", ".tif"])
def test_corrupt_containers(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"bad{suffix}"
    path.write_bytes(b"\x00garbage" * 20)
    with pytest.raises(ValueError, match=rf"bad\{suffix}: cannot read as .*") as err:
        load_video(path, dt=0.1)
    assert "\n" not in str(err.value)


def test_truncated_hdf5(tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    with h5py.File(tmp_path / "v.h5", "w") as handle:
        handle["frames"] = VIDEO
    data = (tmp_path / "v.h5").read_bytes()
    (tmp_path / "v.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"v\.h5: cannot read as HDF5"):
        load_video(tmp_path / "v.h5", dt=0.1)
