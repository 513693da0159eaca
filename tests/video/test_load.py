"""``load_video`` (:mod:`anra_torch.video.load`): explicit spacing overrides, timestamps, integer frames,
the registry, folders, one-line errors naming the file.
"""

from __future__ import annotations

import pickle
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from scenes import random_frames as frames

from anra_torch.simulation.synthetic import paper_video
from anra_torch.video import REGISTRY, RawVideo, load_video, save_npz

DT, DX = 1 / 27, 0.05


def test_synthetic_video_to_npz_is_readable(tmp_path: Path) -> None:
    synthetic = paper_video(size=32)
    synthetic.to_npz(tmp_path / "paper.npz")
    loaded = load_video(tmp_path / "paper.npz")
    torch.testing.assert_close(loaded.frames, synthetic.frames[0], rtol=0, atol=0)
    assert loaded.dt == pytest.approx(synthetic.dt) and loaded.dx == synthetic.dx
    assert loaded.meta["a_true"] == synthetic.a


def test_explicit_spacing_overrides_the_file(tmp_path: Path) -> None:
    path = save_npz(tmp_path / "v.npz", frames(), dt=DT, dx=DX, t=np.arange(8) * DT)
    loaded = load_video(path, dt=0.5, dx=0.2)
    assert (loaded.dt, loaded.dx) == (0.5, 0.2)
    # An explicit dt replaces the file's timestamps too (they imply the other step).
    assert loaded.t is None
    assert loaded.meta["dt_source"] == "argument" and loaded.meta["dx_source"] == "argument"


def test_explicit_dt_wins_over_non_uniform_timestamps(tmp_path: Path) -> None:
    path = tmp_path / "v.npz"
    np.savez(path, frames=frames(), t=np.array([0, 1, 2, 3, 5, 6, 7, 8.0]))
    assert load_video(path, dt=0.25).dt == 0.25


def test_timestamps_alone_give_dt(tmp_path: Path) -> None:
    path = tmp_path / "v.npz"
    np.savez(path, frames=frames(), t=10.0 + 0.04 * np.arange(8))
    loaded = load_video(path)
    assert loaded.dt == pytest.approx(0.04, rel=1e-12) and loaded.dx is None
    assert loaded.meta["dt_source"] == "t"


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.uint16, np.int32])
def test_integer_frames_are_kept(tmp_path: Path, dtype: type) -> None:
    video = frames(dtype=dtype)
    path = save_npz(tmp_path / "v.npz", video, dt=DT, dx=DX)
    loaded = load_video(path)
    assert not loaded.frames.is_floating_point()
    np.testing.assert_array_equal(loaded.frames.numpy(), video)


def test_suffix_is_case_insensitive(tmp_path: Path) -> None:
    assert load_video(_write(tmp_path, "V.NPZ", frames=frames(), dt=0.1)).dt == 0.1


def test_registry_entry_adds_a_format(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def load_text(path: Path) -> RawVideo:
        values = np.loadtxt(path).reshape(-1, 2, 2)
        return RawVideo(frames=values, dt=0.5, meta={"unit": "K"})

    monkeypatch.setitem(REGISTRY, ".frames.txt", load_text)
    path = tmp_path / "video.frames.txt"
    path.write_text(" ".join(str(v) for v in range(12)))
    loaded = load_video(path, dx=1.0)
    assert loaded.frames.shape == (3, 2, 2) and loaded.dt == 0.5 and loaded.unit == "K"


# --------------------------------------------------------------------------------------------- errors
def _write(tmp_path: Path, name: str, **arrays: object) -> Path:
    path = tmp_path / name
    with open(path, "wb") as handle:
        np.savez(handle, **arrays)
    return path


def _bytes(tmp_path: Path, name: str, data: bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def _good_npz_bytes(tmp_path: Path) -> bytes:
    return _write(tmp_path, "good.npz", frames=frames(16, 16, 16), dt=0.1).read_bytes()


def _corrupt(tmp_path: Path) -> Path:
    data = bytearray(_good_npz_bytes(tmp_path))
    data[200:260] = bytes(60)
    return _bytes(tmp_path, "corrupt.npz", bytes(data))


BAD: dict[str, tuple[Callable[[Path], Path], dict, str]] = {
    "missing file": (lambda p: p / "nope.npz", {}, r"nope\.npz: no such file"),
    "directory": (lambda p: (p / "d.npz").mkdir() or p / "d.npz", {}, r"is a directory"),
    "unknown suffix": (
        lambda p: _bytes(p, "video.avi", b"x"),
        {},
        r"video\.avi: unknown video format '\.avi'; expected one of: \.npz, \.npy",
    ),
    "no suffix": (lambda p: _bytes(p, "video", b"x"), {}, r"video: unknown video format \(no suffix\)"),
    "no frames": (
        lambda p: _write(p, "v.npz", video=frames(), dt=0.1),
        {},
        r"v\.npz: no 'frames' array; expected 'frames' \(T, H, W\) with 'dt' or 't', found 'video', 'dt'",
    ),
    "2-D frames": (
        lambda p: _write(p, "v.npz", frames=np.zeros((6, 6)), dt=0.1),
        {},
        r"v\.npz: frames must have shape \(T, H, W\), got \(6, 6\)$",
    ),
    "batched frames": (
        lambda p: _write(p, "v.npz", frames=np.zeros((2, 6, 6, 6)), dt=0.1),
        {},
        r"got \(2, 6, 6, 6\); store one video per file",
    ),
    "empty frames": (
        lambda p: _write(p, "v.npz", frames=np.zeros((0, 6, 6)), dt=0.1),
        {},
        r"must not be empty",
    ),
    "complex frames": (
        lambda p: _write(p, "v.npz", frames=np.zeros((6, 6, 6), complex), dt=0.1),
        {},
        r"frames must hold real numbers .* got dtype complex128",
    ),
    "bool frames": (
        lambda p: _write(p, "v.npz", frames=np.zeros((6, 6, 6), bool), dt=0.1),
        {},
        r"got dtype bool",
    ),
    "no dt": (
        lambda p: _write(p, "v.npz", frames=frames(), dx=0.1),
        {},
        r"v\.npz: no frame period: the file has neither 'dt' nor 't'; pass dt in s \(--dt",
    ),
    "npy without dt": (
        lambda p: np.save(p / "v.npy", frames()) or p / "v.npy",
        {},
        r"v\.npy: no frame period",
    ),
    "non-uniform t": (
        lambda p: _write(p, "v.npz", frames=frames(), t=np.array([0, 1, 2, 3, 5, 6, 7, 8.0])),
        {},
        r"v\.npz: t must be uniformly spaced, got steps from 1 to 2 s; resample the video first",
    ),
    "decreasing t": (
        lambda p: _write(p, "v.npz", frames=frames(), t=-np.arange(8.0)),
        {},
        r"t must be strictly increasing",
    ),
    "t of wrong length": (
        lambda p: _write(p, "v.npz", frames=frames(), t=np.arange(5.0)),
        {},
        r"t must hold 8 timestamps in s \(one per frame\), got shape \(5,\)",
    ),
    "dt disagrees with t": (
        lambda p: _write(p, "v.npz", frames=frames(), t=np.arange(8.0), dt=0.5),
        {},
        r"dt = 0\.5 s disagrees with the step of t = 1 s",
    ),
    "negative dt in file": (
        lambda p: _write(p, "v.npz", frames=frames(), dt=-0.1),
        {},
        r"v\.npz: dt in the file must be a positive finite number in s, got -0\.1",
    ),
    "vector dt in file": (
        lambda p: _write(p, "v.npz", frames=frames(), dt=np.ones(3)),
        {},
        r"dt in the file must be a positive finite number in s, got \[1\.0, 1\.0, 1\.0\]",
    ),
    "zero dx in file": (
        lambda p: _write(p, "v.npz", frames=frames(), dt=0.1, dx=0.0),
        {},
        r"dx in the file must be a positive finite number in mm",
    ),
    "negative dx argument": (
        lambda p: _write(p, "v.npz", frames=frames(), dt=0.1),
        {"dx": -1.0},
        r"dx \(argument\) must be a positive finite number in mm, got -1\.0",
    ),
    "nan dt argument": (
        lambda p: _write(p, "v.npz", frames=frames(), dt=0.1),
        {"dt": float("nan")},
        r"dt \(argument\) must be a positive finite number in s, got nan",
    ),
    "truncated npz": (
        lambda p: _bytes(p, "t.npz", _good_npz_bytes(p)[:700]),
        {},
        r"t\.npz: cannot read as \.npz \(BadZipFile: .*\); the file may be truncated or corrupt",
    ),
    "corrupt npz": (
        lambda p: _corrupt(p),
        {},
        r"corrupt\.npz: cannot read as \.npz \(BadZipFile: Bad CRC-32",
    ),
    "empty npz": (
        lambda p: _bytes(p, "e.npz", b""),
        {},
        r"e\.npz: is empty \(0 bytes\), not a valid \.npz \(zip\)",
    ),
    "junk npz": (lambda p: _bytes(p, "j.npz", b"hello" * 20), {}, r"j\.npz: not a valid \.npz \(zip\) file"),
    "pickle npz": (
        lambda p: _bytes(p, "k.npz", pickle.dumps({"frames": [1, 2]}, protocol=4)),
        {},
        r"k\.npz: holds pickled Python objects, which are never loaded",
    ),
    "junk npy": (lambda p: _bytes(p, "j.npy", b"hello" * 20), {}, r"j\.npy: not a valid \.npy file"),
    "object array": (
        lambda p: _write(p, "o.npz", frames=np.array([None, 1], dtype=object), dt=0.1),
        {},
        r"o\.npz: holds pickled Python objects, which are never loaded",
    ),
    "npy named npz": (
        lambda p: np.save(p / "a.npy", frames()) or (p / "a.npy").rename(p / "a.npz") or p / "a.npz",
        {},
        r"a\.npz: is a single \.npy array, not an \.npz archive; rename it to \.npy",
    ),
    "npz named npy": (
        lambda p: _write(p, "a.npy", frames=frames(), dt=0.1),
        {},
        r"a\.npy: is an \.npz archive, not a single \.npy array",
    ),
    "truncated npy": (
        lambda p: np.save(p / "a.npy", frames()) or _bytes(p, "b.npy", (p / "a.npy").read_bytes()[:300]),
        {},
        r"b\.npy: cannot read as \.npy \(.*\); the file may be (truncated or )?corrupt",
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_gives_one_line_error_naming_the_file(tmp_path: Path, case: str) -> None:
    make, kwargs, match = BAD[case]
    path = make(tmp_path)
    with pytest.raises(ValueError, match=match) as info:
        load_video(path, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path)), message


VIDEO = np.random.default_rng(1).normal(30, 2, (6, 5, 7))


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
