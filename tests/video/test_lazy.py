"""Frames read on demand: .npy files and uncompressed .npz members, windows, and what is not read lazily."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from anra_torch.video import save_npz
from anra_torch.video.lazy import LazyFrames, lazy_video


@pytest.fixture()
def frames() -> np.ndarray:
    return np.random.default_rng(0).standard_normal((12, 6, 7)).astype(np.float32)


def test_npy_and_npz_frames_read_the_same_slices(tmp_path: Path, frames: np.ndarray) -> None:
    np.save(tmp_path / "v.npy", frames)
    save_npz(tmp_path / "v.npz", frames, dt=0.1, dx=0.2, a_true=0.3, unit="degC")
    for path in (tmp_path / "v.npy", tmp_path / "v.npz"):
        lazy = LazyFrames(path)
        assert lazy.shape == (12, 6, 7) and len(lazy) == 12
        np.testing.assert_array_equal(lazy[3:8], frames[3:8])
        np.testing.assert_array_equal(lazy[10:99], frames[10:])
        window = lazy.window(2, 9)
        assert window.shape == (7, 6, 7)
        np.testing.assert_array_equal(window[1:4], frames[3:6])
        np.testing.assert_array_equal(window.window(1, 3)[0:2], frames[3:5])


def test_lazy_video_takes_the_spacing_and_truth_of_an_npz(tmp_path: Path, frames: np.ndarray) -> None:
    save_npz(tmp_path / "v.npz", frames, dt=0.1, dx=0.2, a_true=0.3, unit="degC")
    video = lazy_video(tmp_path / "v.npz")
    assert video is not None and isinstance(video.frames, LazyFrames)
    assert (video.dt, video.dx, video.unit) == (0.1, 0.2, "degC")
    assert video.truth is not None and video.truth.a == 0.3
    assert lazy_video(tmp_path / "v.npz", dt=0.5).dt == 0.5  # the argument overrides the file
    np.save(tmp_path / "v.npy", frames)
    assert lazy_video(tmp_path / "v.npy") is None  # no spacing: the loader says what is missing
    assert lazy_video(tmp_path / "v.npy", dt=0.1, dx=0.2).frames.shape == (12, 6, 7)


def test_what_is_not_read_lazily_is_left_to_the_loader(tmp_path: Path, frames: np.ndarray) -> None:
    np.savez_compressed(tmp_path / "packed.npz", frames=frames, dt=0.1, dx=0.2)
    with pytest.raises(ValueError, match="'frames' is compressed; only an uncompressed .npz is read lazily"):
        LazyFrames(tmp_path / "packed.npz")
    assert lazy_video(tmp_path / "packed.npz") is None
    t = np.array([0, 1, 2, 4, 5, 6, 7, 8, 9, 10, 11, 12], dtype=np.float64)  # non-uniform: resampled
    np.savez(tmp_path / "stamps.npz", frames=frames, t=t, dx=0.2)
    assert lazy_video(tmp_path / "stamps.npz") is None
    np.savez(tmp_path / "uniform.npz", frames=frames, t=np.arange(12) * 0.25, dx=0.2)
    assert lazy_video(tmp_path / "uniform.npz").dt == pytest.approx(0.25)
    assert lazy_video(tmp_path / "missing.npz") is None
    (tmp_path / "v.csv").write_text("1,2\n")
    assert lazy_video(tmp_path / "v.csv") is None


def test_bad_files_and_requests_get_one_line_errors(tmp_path: Path, frames: np.ndarray) -> None:
    np.save(tmp_path / "flat.npy", frames[0])
    with pytest.raises(
        ValueError, match=r"frames must be a C-ordered real array \(T, H, W\), got shape \(6, 7\)"
    ):
        LazyFrames(tmp_path / "flat.npy")
    np.save(tmp_path / "v.npy", frames)
    cut = tmp_path / "cut.npy"
    cut.write_bytes((tmp_path / "v.npy").read_bytes()[:-100])
    with pytest.raises(ValueError, match="truncated: frames 0-11 are not all in the file"):
        LazyFrames(cut)[0:12]
    lazy = LazyFrames(tmp_path / "v.npy")
    with pytest.raises(TypeError, match="LazyFrames supports slices of frames, got int"):
        lazy[3]
    with pytest.raises(ValueError, match=r"reads contiguous frames only \(step 1\), got step 2"):
        lazy[0:10:2]
    with pytest.raises(ValueError, match="no readable 'frames' array"):
        np.savez(tmp_path / "other.npz", video=frames)
        LazyFrames(tmp_path / "other.npz")
