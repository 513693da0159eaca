"""Folders of per-frame matrices (:mod:`anra_torch.video.formats.matrices`): natural order, times from file
names, a timestamps file or comment lines, mixed frame sizes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from anra_torch.video import load_video

VIDEO = np.random.default_rng(1).normal(30, 2, (6, 5, 7))


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
