"""MATLAB, HDF5, TIFF and folders of per-frame matrices: round trips, folder dispatch, one-line errors."""

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


@pytest.mark.parametrize("suffix, delimiter", [(".csv", ","), (".txt", " ")])
def test_matrix_folder_in_natural_order(tmp_path: Path, suffix: str, delimiter: str) -> None:
    for k in range(6):  # frame_10 style names: natural order, not lexical
        np.savetxt(tmp_path / f"frame_{[0, 1, 2, 3, 10, 20][k]}{suffix}", VIDEO[k], delimiter=delimiter)
    video = load_video(tmp_path, dt=0.1, dx=0.5)
    np.testing.assert_allclose(video.frames.numpy(), VIDEO, rtol=1e-15)


IRREGULAR = [0.0, 5.0, 15.0, 20.0, 30.0, 60.0]  # s: a camera triggered by hand


def _save_frames(folder: Path, names: list[str], header: list[str] | None = None) -> None:
    folder.mkdir(exist_ok=True)
    for k, name in enumerate(names):
        np.savetxt(folder / name, VIDEO[k], delimiter=",", header="" if header is None else header[k])


def test_matrix_folder_times_from_file_names(tmp_path: Path) -> None:
    # Natural order puts "1min" first; the times the names state order the frames.
    names = ["0s.csv", "5s.csv", "15 s.csv", "t=20s.csv", "frame_30.0sec.csv", "1min.csv"]
    _save_frames(tmp_path, names)
    video = load_video(tmp_path, timestamps="keep")
    np.testing.assert_array_equal(video.t.numpy(), IRREGULAR)
    np.testing.assert_array_equal(video.frames.numpy(), VIDEO)
    assert video.meta["timestamps"] == "file names" and video.dt == pytest.approx(10.0)  # median step


def test_matrix_folder_times_from_a_timestamps_file(tmp_path: Path) -> None:
    _save_frames(tmp_path / "list", [f"frame_{k}.csv" for k in range(6)])
    (tmp_path / "list" / "times.txt").write_text("time (ms)\n" + "\n".join(f"{1e3 * t:g}" for t in IRREGULAR))
    video = load_video(tmp_path / "list", timestamps="keep")
    np.testing.assert_allclose(video.t.numpy(), IRREGULAR, rtol=1e-15)
    assert video.meta["timestamps"] == "times.txt" and video.frames.shape == (6, 5, 7)
    # 'file name, time' rows in any order: the names carry the times
    _save_frames(tmp_path / "named", [f"img{k}.csv" for k in range(6)])
    rows = [f"img{k}.csv, {t:g}" for k, t in enumerate(IRREGULAR)][::-1]
    (tmp_path / "named" / "timestamps.csv").write_text("file, t_s\n" + "\n".join(rows))
    named = load_video(tmp_path / "named", timestamps="keep")
    np.testing.assert_array_equal(named.t.numpy(), IRREGULAR)
    np.testing.assert_array_equal(named.frames.numpy(), VIDEO)


def test_matrix_folder_times_from_comment_lines(tmp_path: Path) -> None:
    _save_frames(tmp_path, [f"f{k}.csv" for k in range(6)], header=[f"t = {t:g} s" for t in IRREGULAR])
    video = load_video(tmp_path, timestamps="keep")
    np.testing.assert_array_equal(video.t.numpy(), IRREGULAR)
    np.testing.assert_allclose(video.frames.numpy(), VIDEO, rtol=1e-15)
    assert video.meta["timestamps"] == "comment lines"


def test_matrix_folder_timestamps_errors(tmp_path: Path) -> None:
    _save_frames(tmp_path / "short", [f"f{k}.csv" for k in range(6)])
    (tmp_path / "short" / "times.csv").write_text("0\n5\n15\n")
    with pytest.raises(ValueError, match=r"times\.csv: 3 timestamps for 6 frame files; give one per frame"):
        load_video(tmp_path / "short", timestamps="keep")
    (tmp_path / "short" / "times.csv").write_text("0\n5\n15\n10\n30\n60\n")  # in file order, not rising
    with pytest.raises(ValueError, match=r"unsorted timestamps: .*t\[2\]=15 s then t\[3\]=10 s"):
        load_video(tmp_path / "short", timestamps="keep")
    # One time every name shares is no capture time: the folder then needs dt.
    _save_frames(tmp_path / "shared", [f"exposure_3s_{k}.csv" for k in range(6)])
    with pytest.raises(ValueError, match=r"no frame period"):
        load_video(tmp_path / "shared")
    assert load_video(tmp_path / "shared", dt=0.5).t is None


def test_folder_with_mixed_frame_sizes(tmp_path: Path) -> None:
    np.savetxt(tmp_path / "f1.csv", VIDEO[0], delimiter=",")
    np.savetxt(tmp_path / "f2.csv", VIDEO[1][:, :4], delimiter=",")
    with pytest.raises(ValueError, match=r"mixed frame sizes: f2\.csv is 5 x 4 px, f1\.csv is 5 x 7 px"):
        load_video(tmp_path, dt=0.1)


def test_folder_errors(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"empty: is a directory without frame files"):
        load_video(tmp_path / "empty")
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    np.savetxt(mixed / "a.csv", VIDEO[0], delimiter=",")
    (mixed / "b.jpg").write_bytes(b"x")
    with pytest.raises(ValueError, match=r"mixes frame files of different formats"):
        load_video(mixed)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "f1.txt").write_text("1 2\n3 x\n")
    with pytest.raises(ValueError, match=r"f1\.txt: cannot read as a numeric matrix"):
        load_video(bad, dt=0.1)


def test_unsorted_and_duplicate_timestamps(tmp_path: Path) -> None:
    for name, t in {"u.npz": [0, 2, 1, 3, 4, 5.0], "d.npz": [0, 1, 1, 2, 3, 4.0]}.items():
        np.savez(tmp_path / name, frames=VIDEO, t=np.array(t))
    with pytest.raises(ValueError, match=r"u\.npz: unsorted timestamps: .*t\[1\]=2 s then t\[2\]=1 s"):
        load_video(tmp_path / "u.npz", timestamps="keep")
    with pytest.raises(ValueError, match=r"d\.npz: duplicate timestamps"):
        load_video(tmp_path / "d.npz", timestamps="resample")


def test_resampling_is_linear_in_time_and_stated(tmp_path: Path) -> None:
    t = np.array([0.0, 1.0, 5.0, 10.0, 15.5, 20.0])
    ramp = (3.0 * t)[:, None, None] + VIDEO[:1] * 0  # T = 3 t: linear interpolation is exact
    np.savez(tmp_path / "r.npz", frames=ramp, t=t)
    video = load_video(tmp_path / "r.npz", timestamps="resample")
    grid = video.t.numpy()
    np.testing.assert_allclose(grid, np.arange(len(grid)) * video.dt)
    np.testing.assert_allclose(video.frames[:, 2, 3].numpy(), 3.0 * grid, rtol=1e-12)
    assert video.meta["resampled"]["from_frames"] == 6 and video.meta["resampled"]["step_min"] == 1.0
    kept = load_video(tmp_path / "r.npz", timestamps="keep")
    assert not kept.uniform and kept.frames.shape[0] == 6
