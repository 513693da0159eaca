"""``anra convert``: FLIR sequences (and any readable recording) to .npz / .h5 / .tif, chunk by chunk, with
--frames and --roi; what is written is read back by anra and by plain numpy / h5py / tifffile."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from commands import assert_clean, run_isolated
from fff_writer import Camera, counts_for, planck_celsius, simple_frame
from shared_data import DATA as SHARED_DATA

from anra_torch.cli import main
from anra_torch.video import load_video, save_npz
from anra_torch.video.lazy import LazyFrames

pytest.importorskip("imagecodecs", reason="the formats extra (imagecodecs) is not installed")
DATA = SHARED_DATA / "flir_fff"
CAMERA = Camera(emissivity=0.95, distance=2.0)


@pytest.fixture
def recording(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """A 20-frame .seq of 24 x 32 px (frames at 1/30 s, kept to the millisecond), its counts and times."""
    rng = np.random.default_rng(4)
    counts = counts_for(30 + 5 * rng.random((20, 24, 32)), CAMERA)
    ms = np.floor(np.arange(20) * 1000 / 30).astype(int)
    blobs = []
    for k in range(20):
        cam = Camera(
            **{**CAMERA.__dict__, "millis": int(ms[k] % 1000), "seconds": 1_700_000_000 + ms[k] // 1000}
        )
        blobs.append(simple_frame(counts[k], cam, encoding="jpeg-ls" if k % 2 else "uint16"))
    path = tmp_path / "rec.seq"
    path.write_bytes(b"".join(blobs))
    return path, counts, ms / 1000.0


def test_seq_to_npz_holds_celsius_times_and_metadata(tmp_path: Path, recording, capsys) -> None:
    path, counts, times = recording
    out = tmp_path / "out.npz"
    assert main(["convert", str(path), "-o", str(out)]) == 0
    assert "20 frames of 24 x 32 px" in capsys.readouterr().out
    with np.load(out) as data:
        frames, t, meta = data["frames"], data["t"], json.loads(str(data["meta"]))
        assert "dx" not in data.files and str(data["unit"]) == "degC"
    assert frames.shape == (20, 24, 32) and frames.dtype == np.float32
    np.testing.assert_array_equal(t, times)  # each frame's capture time, exact to the millisecond
    for k, (row, col) in [(0, (0, 0)), (7, (12, 20)), (19, (23, 31))]:
        assert frames[k, row, col] == pytest.approx(
            planck_celsius(float(counts[k, row, col]), CAMERA), abs=2e-4
        )
    assert meta["frames"] == [0, 20] and meta["roi"] is None and meta["warnings"] == []
    assert meta["camera"]["camera_model"] == "Test Camera" and meta["camera"]["planck"][
        "planck_b"
    ] == pytest.approx(1420.1)
    assert meta["object_parameters"]["distance"] == {"value": 2.0, "unit": "m", "source": "file"}
    assert sorted(meta["camera"]["counts"]) == ["jpeg-ls <", "uint16 <"]
    # anra reads it back (the millisecond times are uniform within the clock's resolution) and lazily
    video = load_video(out, dx=0.1)
    assert video.dt == pytest.approx(1 / 30, abs=1e-3 / 19) and video.unit == "degC"  # 1 ms over the span
    np.testing.assert_array_equal(LazyFrames(out)[3:5], frames[3:5])


def test_frames_roi_dx_and_object_parameters(tmp_path: Path, recording) -> None:
    path, counts, times = recording
    out = tmp_path / "part.npz"
    argv = ["convert", str(path), "-o", str(out), "--frames", "3:-5", "--roi", "4,2,10,6", "--dx", "0.25"]
    assert main([*argv, "--emissivity", "0.5", "--chunk-values", "1000"]) == 0  # two frames a chunk
    with np.load(out) as data:
        frames, t, dx, meta = data["frames"], data["t"], float(data["dx"]), json.loads(str(data["meta"]))
    assert frames.shape == (12, 6, 10) and dx == 0.25
    np.testing.assert_allclose(t, times[3:15] - times[3], rtol=0, atol=1e-12)
    assert meta["frames"] == [3, 15] and meta["roi"] == [4, 2, 10, 6] and meta["t_first_s"] == times[3]
    assert meta["object_parameters"]["emissivity"]["source"] == "argument"
    expected = planck_celsius(float(counts[3 + 4, 2 + 1, 4 + 7]), CAMERA, emissivity=0.5)
    assert frames[4, 1, 7] == pytest.approx(expected, abs=2e-4)


@pytest.mark.parametrize("suffix", [".h5", ".tif"])
def test_h5_and_tif_read_back_as_the_npz(tmp_path: Path, recording, suffix: str) -> None:
    path = recording[0]
    assert main(["convert", str(path), "-o", str(tmp_path / "a.npz"), "--dx", "0.2"]) == 0
    assert (
        main(
            [
                "convert",
                str(path),
                "-o",
                str(tmp_path / f"a{suffix}"),
                "--dx",
                "0.2",
                "--chunk-values",
                "2000",
            ]
        )
        == 0
    )
    reference = load_video(tmp_path / "a.npz", timestamps="keep")
    other = load_video(tmp_path / f"a{suffix}", timestamps="keep")
    np.testing.assert_array_equal(other.frames.numpy(), reference.frames.numpy())
    np.testing.assert_array_equal(other.t.numpy(), reference.t.numpy())
    assert other.dx == 0.2 and other.unit == "degC"


def test_an_npz_converts_chunk_by_chunk(tmp_path: Path) -> None:
    frames = np.random.default_rng(5).random((9, 5, 6))
    source = save_npz(tmp_path / "in.npz", frames, dt=0.5, dx=0.1, unit="K")
    assert main(["convert", str(source), "-o", str(tmp_path / "out.tif"), "--chunk-values", "30"]) == 0
    back = load_video(tmp_path / "out.tif")
    np.testing.assert_array_equal(back.frames.numpy(), frames.astype(np.float32))
    assert back.dt == pytest.approx(0.5) and back.dx == 0.1 and back.unit == "K"


def test_repeated_times_are_written_as_measured_and_flagged(tmp_path: Path, capsys) -> None:
    counts = counts_for(np.full((4, 6, 6), 30.0), CAMERA)
    cams = [Camera(millis=m) for m in (0, 40, 40, 80)]
    path = tmp_path / "dup.seq"
    path.write_bytes(b"".join(simple_frame(c, cam) for c, cam in zip(counts, cams, strict=True)))
    assert main(["convert", str(path), "-o", str(tmp_path / "dup.npz")]) == 0
    assert "times repeat or go backwards at 1 frames (first at frame 2" in capsys.readouterr().err
    with np.load(tmp_path / "dup.npz") as data:
        np.testing.assert_array_equal(data["t"], [0, 0.04, 0.04, 0.08])
        assert "written as measured" in json.loads(str(data["meta"]))["warnings"][0]


@pytest.mark.skipif(not DATA.is_dir(), reason="measured data folder absent")
def test_the_real_frame_converts_in_its_range(tmp_path: Path) -> None:
    assert main(["convert", str(DATA / "frame_000000.fff"), "-o", str(tmp_path / "f.npz")]) == 0
    with np.load(tmp_path / "f.npz") as data:
        assert (
            data["frames"].shape == (1, 512, 640) and 9.5 < data["frames"].min() < data["frames"].max() < 12.7
        )


def test_bad_requests_are_one_line_errors(tmp_path: Path, recording, capsys) -> None:
    path = recording[0]
    cases = [
        (
            ["-o", str(tmp_path / "x.mp4")],
            r"-o must end in one of \.npz, \.h5, \.hdf5, \.tif, \.tiff, got 'x\.mp4'",
        ),
        (
            ["-o", str(tmp_path / "x.npz"), "--frames", "5:5"],
            "--frames must keep at least one of the 20 frames",
        ),
        (["-o", str(tmp_path / "x.npz"), "--frames", "a:b"], "--frames must be START:STOP"),
        (
            ["-o", str(tmp_path / "x.npz"), "--roi", "30,0,5,5"],
            r"--roi 30,0,5,5 .* does not fit in the 32 x 24 px",
        ),
        (["-o", str(tmp_path / "x.npz"), "--emissivity", "2"], r"emissivity must be in \(0, 1\], got 2"),
    ]
    for extra, pattern in cases:
        assert main(["convert", str(path), *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("anra: error: ")
        assert re.search(pattern, err), err
    assert not list(tmp_path.glob("x.*"))  # nothing half-written


def test_help_names_the_outputs_and_units(capsys) -> None:
    assert main(["convert", "--help"]) == 0
    out = capsys.readouterr().out
    assert all(
        word in out
        for word in (".npz", ".h5", ".tif", "START:STOP", "X0,Y0,W,H", "degC", "relative humidity in %")
    )


def test_an_output_that_is_the_input_is_refused_and_the_input_kept(tmp_path: Path, capsys) -> None:
    path = save_npz(
        tmp_path / "same.npz", np.arange(5 * 4 * 4.0).reshape(5, 4, 4), dt=0.1, dx=0.2, a_true=0.2
    )
    before = path.read_bytes()
    for out in (path, tmp_path / "." / "same.npz"):
        assert main(["convert", str(path), "-o", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and re.search(r"-o .*same\.npz is the input .*same\.npz", err), err
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["same.npz"]


FLIPS = (1, 8, 64)
"""Bits flipped at random places in the bit-flip cases."""


def damaged(rng: np.random.Generator, data: bytes, frames: list[bytes]) -> tuple[str, bytes]:
    """One damage of a recording: empty, cut, frames shuffled, blocks of bytes swapped, bits flipped."""
    kind = str(rng.choice(["empty", "cut", "cut", "shuffle", "blocks", "flip", "flip", "flip"]))
    if kind == "empty":
        return kind, b""
    if kind == "cut":
        return kind, data[: int(rng.integers(1, len(data)))]
    if kind == "shuffle":
        return kind, b"".join(frames[k] for k in rng.permutation(len(frames)))
    if kind == "blocks":
        cuts = np.sort(rng.choice(len(data), size=3, replace=False))
        a, b, c = (data[: cuts[0]], data[cuts[0] : cuts[1]], data[cuts[1] : cuts[2]])
        return kind, a + c + b + data[cuts[2] :]
    array = np.frombuffer(data, dtype=np.uint8).copy()
    where = rng.integers(0, array.size, size=int(rng.choice(FLIPS)))
    array[where] ^= (1 << rng.integers(0, 8, size=where.size)).astype(np.uint8)
    return kind, array.tobytes()


def test_fuzzed_flir_files_convert_or_are_refused_in_one_line(tmp_path: Path) -> None:
    """``anra convert`` on .fff, .seq and .csq files (uint16, PNG and JPEG-LS counts, both byte orders)
    emptied, cut, shuffled, with blocks swapped or bits flipped: exit 0 or 2, one line naming the file on
    error, no Python warning; a written file has finite times and spacing, strict JSON metadata, frames
    whose only non-finite values are NaN and exactly as many as its warning counts; the input untouched,
    no temporary file left."""
    rng = np.random.default_rng(int(os.environ.get("FUZZ_SEED", 45)))
    counts = counts_for(30 + 5 * rng.random((5, 12, 16)), CAMERA)
    sources = {}
    for suffix, encoding, order in ((".seq", "uint16", "<"), (".csq", "jpeg-ls", ">"), (".fff", "png", "<")):
        frames = []
        for k, c in enumerate(counts if suffix != ".fff" else counts[:1]):
            cam = Camera(**{**CAMERA.__dict__, "millis": 40 * k})
            frames.append(simple_frame(c, cam, order=order, encoding=encoding))
        sources[suffix] = frames
    codes = {0: 0, 2: 0}
    for case in range(int(os.environ.get("FUZZ_CASES", 90))):
        suffix = str(rng.choice(list(sources)))
        kind, data = damaged(rng, b"".join(sources[suffix]), sources[suffix])
        path = tmp_path / f"case{case}{suffix}"
        path.write_bytes(data)
        out = tmp_path / f"case{case}{rng.choice(['.npz', '.npz', '.h5', '.tif'])}"
        code, stdout, err, caught = run_isolated(["convert", str(path), "-o", str(out)])
        label = f"case {case} ({kind} {suffix}): {err}"
        assert_clean(label, code, stdout, err, caught)
        codes[code] += 1
        assert path.read_bytes() == data, label
        assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], label
        if code == 2:
            assert path.name in err and not out.exists(), label
            continue
        if out.suffix != ".npz":
            continue
        with np.load(out) as written:
            frames, meta = written["frames"], json.loads(str(written["meta"]), parse_constant=float)
            assert np.isfinite(written["t"]).all() and not np.isinf(frames).any(), label
        nan = int(np.isnan(frames).sum())
        said = [w for w in meta["warnings"] if "samples masked" in w]
        assert (nan == 0 and not said) or said[0].startswith(f"{nan} samples masked"), label
    print(f"fuzz convert: {sum(codes.values())} files, exit 0: {codes[0]}, exit 2: {codes[2]}")
    assert codes[0] >= 15 and codes[2] >= 15, codes
