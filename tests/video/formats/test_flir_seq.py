"""FLIR .seq / .csq recordings written by the tests: exact round trips of counts and times, frames found by
walking the record directories (not the magic bytes), every layout, partial frames, files over 4 GiB,
lazy reading through the chunked estimator."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import torch
from fff_writer import (
    Camera,
    camera_record,
    counts_for,
    frame,
    planck_celsius,
    raw_record,
    simple_frame,
)
from shared_data import DATA as SHARED_DATA

from anra_torch.cli import main
from anra_torch.estimation import Chunking, estimate_chunked
from anra_torch.video import input_warnings, load_video, prepare_video
from anra_torch.video.formats.flir_seq import FLIRFrames, index_sequence
from anra_torch.video.lazy import FrameSource, frame_span, in_memory, lazy_video

pytest.importorskip("imagecodecs", reason="the formats extra (imagecodecs) is not installed")


def gaussian(n: int, h: int, w: int, *, a: float = 0.2, dx: float = 0.1, dt: float = 0.04) -> np.ndarray:
    """A Gaussian spreading by the heat equation (closed form), degC: ``(n, h, w)``."""
    y, x = np.mgrid[0:h, 0:w] * dx
    r2 = (x - x.mean()) ** 2 + (y - y.mean()) ** 2
    s2 = (0.25 * min(h, w) * dx) ** 2 + 2 * a * np.arange(n)[:, None, None] * dt
    return 25 + 30 * (0.25 * min(h, w) * dx) ** 2 / s2 * np.exp(-r2 / (2 * s2))


def stamps(cam: Camera, t: float) -> Camera:
    """``cam`` captured ``t`` s after its own time, kept to the millisecond (truncated, as a clock ticks)."""
    ms = cam.seconds * 1000 + cam.millis + int(np.floor(t * 1000 + 1e-9))
    return Camera(**{**cam.__dict__, "seconds": ms // 1000, "millis": ms % 1000})


BLACKBODY = Camera(emissivity=1.0, distance=0.0)  # counts_for's temperatures are the object's


def write_seq(path: Path, counts: np.ndarray, times: np.ndarray, cam: Camera | None = None, **kw) -> Path:
    cam = cam or BLACKBODY
    path.write_bytes(
        b"".join(simple_frame(c, stamps(cam, t), **kw) for c, t in zip(counts, times, strict=True))
    )
    return path


# ------------------------------------------------------------------------------------------ round trips
def test_counts_times_and_per_frame_constants_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    counts = rng.integers(15000, 22000, size=(12, 10, 14)).astype(np.uint16)
    times = np.cumsum(rng.integers(30, 60, size=12)) / 1000.0
    cams = [stamps(Camera(emissivity=0.95 if k < 6 else 0.9, millis=7), t) for k, t in enumerate(times)]
    path = tmp_path / "rec.seq"
    path.write_bytes(b"".join(simple_frame(c, cam) for c, cam in zip(counts, cams, strict=True)))
    raw = FLIRFrames(index_sequence(path))
    np.testing.assert_array_equal(raw.counts(slice(None)), counts)
    video = load_video(path, timestamps="keep")
    np.testing.assert_allclose(video.t.numpy(), times - times[0], rtol=0, atol=1e-15)
    for k in (0, 5, 6, 11):
        expected = planck_celsius(float(counts[k, 3, 4]), cams[k])
        assert video.frames[k, 3, 4].item() == pytest.approx(expected, abs=2e-4)
    assert video.meta["camera"]["constants_vary_by_frame"] == ["emissivity"]
    assert video.meta["object_parameters"]["emissivity"]["source"].startswith("file (varies by frame")
    assert video.meta["t0_utc"] == f"2023-11-14T22:13:20.{7 + round(1000 * times[0]):03d}+00:00"
    assert video.meta["camera"]["capture_local"].endswith("+01:00")


def test_every_layout_in_one_sequence(tmp_path: Path) -> None:
    """Big- and little-endian headers and records, records in any order among others, uint16 / PNG /
    JPEG-LS counts, zero padding between frames: each frame read through its own directory."""
    rng = np.random.default_rng(1)
    counts = rng.integers(16000, 20000, size=(8, 9, 11)).astype(np.uint16)
    layouts = [("<", "<", "uint16"), (">", "<", "uint16"), (">", ">", "uint16"), ("<", ">", "png")]
    layouts += [("<", "<", "jpeg-ls"), (">", "<", "png"), ("<", "<", "uint16"), (">", ">", "jpeg-ls")]
    parts = []
    for k, (header, inner, encoding) in enumerate(layouts):
        cam = stamps(Camera(), 0.05 * k)
        records = [
            (0x20, camera_record(cam, inner)),
            (0x22, bytes(40)),
            (0x01, raw_record(counts[k], inner, encoding)),
        ]
        parts.append(frame(records if k % 2 else records[::-1], header, empty=k % 3, gap=16 * k))
        parts.append(bytes(512 if k == 3 else 0))  # zero padding between two frames
    path = tmp_path / "mixed.seq"
    path.write_bytes(b"".join(parts))
    index = index_sequence(path)
    assert index.shape == (8, 9, 11) and index.warnings == []
    np.testing.assert_array_equal(FLIRFrames(index).counts(slice(None)), counts)
    video = load_video(path)
    assert video.dt == pytest.approx(0.05) and sorted(video.meta["camera"]["counts"]) == [
        "jpeg-ls <", "jpeg-ls >", "png <", "png >", "uint16 <", "uint16 >"
    ]  # fmt: skip


def test_magic_bytes_inside_the_image_data_do_not_split_frames(tmp_path: Path) -> None:
    counts = counts_for(gaussian(5, 16, 16, a=0.0) - 7.5, BLACKBODY)  # near 17900 counts
    counts[:, 2:12, 2:10:2], counts[:, 2:12, 3:11:2] = 0x4646, 0x4600  # "FFF\0" in big-endian counts
    path = write_seq(tmp_path / "magic.seq", counts, np.arange(5) * 0.1, record_order=">")
    assert path.read_bytes().count(b"FFF\x00") > 5 * 20  # a search for the magic bytes would find many frames
    assert index_sequence(path).shape == (5, 16, 16) and index_sequence(path).swapped == []
    np.testing.assert_array_equal(FLIRFrames(index_sequence(path)).counts(slice(1, 4)), counts[1:4])


def test_counts_stored_byte_swapped_are_recognised_and_flagged(tmp_path: Path) -> None:
    counts = counts_for(gaussian(3, 16, 16), BLACKBODY)
    path = write_seq(tmp_path / "swapped.seq", counts, np.arange(3) * 0.1, encoding="uint16-swapped")
    index = index_sequence(path)
    assert index.swapped == ["uint16 <"]
    np.testing.assert_array_equal(FLIRFrames(index).counts(slice(None)), counts)


@pytest.mark.slow
def test_csq_jpeg_ls_decodes_100_frames(tmp_path: Path) -> None:
    """100 JPEG-LS frames of 640 x 512 decode to finite temperatures, each frame's own counts exactly (the
    decode time is measured by ``python -m benchmarks.bench_sequence``, not here)."""
    rng = np.random.default_rng(2)
    scene = counts_for(gaussian(4, 512, 640, dx=0.02), Camera()).astype(np.int32)
    distinct = [
        np.clip(scene[k] + rng.integers(-20, 20, scene[k].shape), 0, 65535).astype(np.uint16)
        for k in range(4)
    ]
    blobs = [simple_frame(distinct[k % 4], stamps(Camera(), k / 30), encoding="jpeg-ls") for k in range(100)]
    path = tmp_path / "rec.csq"
    path.write_bytes(b"".join(blobs))
    frames = FLIRFrames(index_sequence(path))
    decoded = frames[0:100]
    assert decoded.shape == (100, 512, 640) and decoded.dtype == np.float32 and np.isfinite(decoded).all()
    np.testing.assert_array_equal(frames.counts(slice(97, 98))[0], distinct[1])


# ------------------------------------------------------------------------------------------ damaged files
def test_a_cut_off_last_frame_is_left_out_and_flagged(tmp_path: Path) -> None:
    counts = counts_for(gaussian(6, 12, 12), BLACKBODY)
    path = write_seq(tmp_path / "cut.seq", counts, np.arange(6) * 0.1)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 100])
    video = prepare_video(path, dx=0.1)
    assert video.frames.shape == (5, 12, 12)
    (line,) = [w for w in input_warnings(video) if "cut off" in w]
    assert line.startswith("input: frame 5 (from byte ") and line.endswith("left out")
    # a few trailing bytes that hold no frame are flagged; as many as a frame are an error
    path.write_bytes(data + b"\x01" * 50)
    assert "50 trailing bytes after frame 5" in load_video(path).meta["input_warnings"][0]
    path.write_bytes(data + b"\x01" * len(data))
    with pytest.raises(ValueError, match=r"cut\.seq: no FFF frame header at byte \d+ after frame 5"):
        load_video(path)


def test_a_frame_without_counts_is_left_out_and_flagged(tmp_path: Path) -> None:
    counts = counts_for(gaussian(3, 8, 8), BLACKBODY)
    metadata_only = frame([(0x20, camera_record(BLACKBODY, "<")), (0x22, bytes(64))], "<")
    blobs = [simple_frame(c, stamps(BLACKBODY, 0.1 * k)) for k, c in enumerate(counts)]
    path = tmp_path / "meta.seq"
    path.write_bytes(blobs[0] + metadata_only + blobs[1] + blobs[2])
    video = load_video(path)
    assert video.frames.shape == (3, 8, 8) and video.dt == pytest.approx(0.1)
    (line,) = video.meta["input_warnings"]
    assert line.startswith("input: the FFF frame at byte ") and line.endswith(
        "has no RawData record: left out"
    )


def test_times_that_repeat_or_go_backwards_are_one_line_errors(tmp_path: Path) -> None:
    counts = counts_for(gaussian(6, 12, 12), BLACKBODY)
    for name, times, kind in [
        ("dup", [0, 0.1, 0.2, 0.2, 0.3, 0.4], "duplicate"),
        ("back", [0, 0.1, 0.3, 0.2, 0.4, 0.5], "unsorted"),
    ]:
        path = write_seq(tmp_path / f"{name}.seq", counts, np.array(times))
        with pytest.raises(ValueError, match=rf"{name}\.seq: {kind} timestamps") as err:
            load_video(path, timestamps="keep")
        assert "\n" not in str(err.value)
        with pytest.raises(ValueError, match=rf"{name}\.seq: {kind} timestamps: frame 3 was captured"):
            lazy_video(path, dx=0.1)


def test_frames_of_different_sizes_are_an_error(tmp_path: Path) -> None:
    path = tmp_path / "sizes.seq"
    path.write_bytes(
        simple_frame(np.zeros((4, 4), np.uint16) + 17000, Camera())
        + simple_frame(np.zeros((4, 5), np.uint16) + 17000, Camera())
    )
    with pytest.raises(ValueError, match=r"sizes\.seq: frame 1 is 5 x 4 px, frame 0 is 4 x 4 px"):
        load_video(path)


def test_a_file_over_4_gib_is_walked_with_64_bit_offsets(tmp_path: Path) -> None:
    """Frame 0 carries a 4 GiB record (a sparse hole): frames 1 and 2 lie beyond 2^32 bytes."""
    counts = counts_for(gaussian(3, 6, 7), Camera())
    big = (1 << 32) - 1
    first = frame(
        [(0x01, raw_record(counts[0], "<")), (0x20, camera_record(Camera(), "<")), (0x22, b"")], "<"
    )
    # the third record's length: patch the directory entry to span the hole
    directory = bytearray(first)
    entry = 0x40 + 2 * 0x20
    directory[entry + 0x10 : entry + 0x14] = big.to_bytes(4, "little")
    path = tmp_path / "huge.seq"
    try:
        with path.open("wb") as handle:
            handle.write(directory)
            handle.seek(len(directory) + big)
            for k in (1, 2):
                handle.write(simple_frame(counts[k], stamps(Camera(), 0.5 * k)))
        assert path.stat().st_size > 1 << 32
        index = index_sequence(path)
        assert index.shape == (3, 6, 7) and index.raws[2].offset > 1 << 32
        np.testing.assert_array_equal(FLIRFrames(index).counts(slice(None)), counts)
        np.testing.assert_array_equal(index.t, [0, 0.5, 1.0])
    finally:
        path.unlink(missing_ok=True)


# ------------------------------------------------------------------------------------------ lazy reading
def test_ms_times_at_30_hz_are_uniform_within_the_clock(tmp_path: Path) -> None:
    counts = counts_for(gaussian(31, 8, 8), BLACKBODY)
    path = write_seq(tmp_path / "hz30.seq", counts, np.arange(31) / 30)
    steps = np.diff(load_video(path, timestamps="keep").t.numpy())
    assert set(np.round(steps * 1000).astype(int)) == {33, 34}  # truncated to the millisecond
    assert load_video(path).dt == pytest.approx(1 / 30, abs=1e-6)
    assert lazy_video(path, dx=0.1).dt == pytest.approx(1 / 30, abs=1e-6)


def test_a_sequence_is_read_lazily_and_estimates_as_in_memory(tmp_path: Path) -> None:
    celsius = gaussian(40, 48, 48)
    path = write_seq(tmp_path / "rec.seq", counts_for(celsius, BLACKBODY), np.arange(40) * 0.04)
    lazy = lazy_video(path, dx=0.1)
    assert isinstance(lazy.frames, FrameSource) and lazy.meta["read"] == "in chunks"
    assert lazy.dt == pytest.approx(0.04) and lazy.meta["dt_source"] == "t"
    whole = load_video(path, dx=0.1)
    np.testing.assert_array_equal(in_memory(lazy.frames).numpy(), whole.frames.numpy())
    np.testing.assert_array_equal(frame_span(lazy.frames, 5, 9)[1:3], whole.frames[6:8].numpy())
    np.testing.assert_allclose(whole.frames.numpy(), celsius, atol=0.05)  # one count is ~0.03 K here
    a = estimate_chunked(lazy.frames, lazy.dt, lazy.dx, chunking=Chunking(chunk_frames=12))
    b = estimate_chunked(whole.frames, whole.dt, whole.dx, chunking=Chunking(chunk_frames=12))
    assert a.result.diffusivity == b.result.diffusivity
    assert abs(a.result.diffusivity - 0.2) < 0.03  # the Gaussian's diffusivity, mm^2/s


def test_estimate_reads_a_sequence_in_chunks_and_states_the_object_parameters(tmp_path: Path, capsys) -> None:
    path = write_seq(
        tmp_path / "rec.seq", counts_for(gaussian(40, 48, 48), Camera()), np.arange(40) * 0.04, Camera()
    )
    argv = ["estimate", str(path), "--dx", "0.1", "--emissivity", "0.97", "--precision", "20%", "--json"]
    assert main(argv) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["chunked"] is not None and record["frames"] == 40
    used = record["input"]["object_parameters"]
    assert used["emissivity"] == {"value": 0.97, "unit": None, "source": "argument", "file": 0.95}
    assert used["distance"] == {"value": 1.0, "unit": "m", "source": "file"}


def test_flirframes_views_and_bad_requests(tmp_path: Path) -> None:
    counts = counts_for(gaussian(6, 5, 5), Camera())
    frames = FLIRFrames(index_sequence(write_seq(tmp_path / "v.seq", counts, np.arange(6) * 0.1)))
    view = frames.window(2, 5)
    assert view.shape == (3, 5, 5) and len(view) == 3
    np.testing.assert_array_equal(view.counts(slice(1, 3)), counts[3:5])
    with pytest.raises(ValueError, match="step 1"):
        frames[::2]
    with pytest.raises(TypeError, match="slices of frames"):
        frames[3]  # type: ignore[index]
    with pytest.raises(ValueError, match=r"0 <= start <= stop <= 6"):
        FLIRFrames(frames.index, start=4, stop=9)
    assert torch.as_tensor(frames[0:0]).shape == (0, 5, 5)


def test_an_empty_file_is_one_line(tmp_path: Path) -> None:
    for suffix in (".fff", ".seq", ".csq"):
        path = tmp_path / f"empty{suffix}"
        path.write_bytes(b"")
        with pytest.raises(ValueError, match=rf"^\S*empty\{suffix}: the file is empty \(0 bytes\)"):
            load_video(path, dt=0.1)


def test_a_last_csq_frame_stored_shorter_than_its_record_is_read_when_its_image_is_whole(
    tmp_path: Path,
) -> None:
    """A real camera's last frame: the CameraInfo record first, then the RawData record whose directory
    length counts padding that the file does not hold; the JPEG-LS stream ends with its end-of-image marker.
    Cut one byte into the stream, the frame is left out and said."""
    counts = counts_for(gaussian(4, 16, 20), BLACKBODY)

    def csq_frame(k: int, padding: int) -> bytes:
        raw = raw_record(counts[k], "<", "jpeg-ls") + bytes(padding)
        return frame([(0x20, camera_record(stamps(BLACKBODY, 0.1 * k), "<")), (0x01, raw)], "<")

    blobs = [csq_frame(k, 512) for k in range(4)]
    whole = b"".join(blobs)
    path = tmp_path / "rec.csq"
    path.write_bytes(whole[:-512])  # the last record's padding is not in the file
    video = load_video(path)
    assert video.frames.shape == (4, 16, 20) and video.meta["input_warnings"] == []
    np.testing.assert_array_equal(FLIRFrames(index_sequence(path)).counts(slice(3, 4))[0], counts[3])
    path.write_bytes(whole[: -512 - 1])  # the end-of-image marker cut
    video = load_video(path)
    assert video.frames.shape == (3, 16, 20)
    (line,) = video.meta["input_warnings"]
    assert line.startswith("input: frame 3 (from byte ") and line.endswith(
        "cut off at the end of the file (" + (f"{len(blobs[3]) - 513} bytes): left out")
    )


def fff_folder(folder: Path, counts: np.ndarray, seconds: list[float], names: list[str]) -> Path:
    folder.mkdir()
    for c, t, name in zip(counts, seconds, names, strict=True):
        (folder / name).write_bytes(simple_frame(c, stamps(BLACKBODY, t)))
    return folder


def test_a_folder_of_fff_frames_is_one_video_in_capture_order(tmp_path: Path) -> None:
    """Names that sort against the capture times, an ExifTool text dump and a note beside the frames."""
    counts = counts_for(gaussian(5, 10, 12), BLACKBODY)
    times = [0.0, 0.1, 0.2, 0.3, 0.4]
    names = ["e.fff", "d.fff", "c.FFF", "b.fff", "a.fff"]
    folder = fff_folder(tmp_path / "frames", counts, times, names)
    (folder / "a.exiftool.txt").write_text("ExifTool Version Number : 12.40\nCamera Model : Test\n")
    (folder / "notes.md").write_text("bench 2\n")
    video = load_video(folder)
    assert video.frames.shape == (5, 10, 12) and video.dt == pytest.approx(0.1)
    assert video.meta["format"] == "flir_fff_folder" and video.meta["files"] == "e.fff .. a.fff"
    assert video.meta["ignored"] == 2
    expected = np.array([[planck_celsius(float(c[3, 4]), BLACKBODY)] for c in counts])[:, 0]
    np.testing.assert_allclose(video.frames[:, 3, 4].numpy(), expected, atol=2e-4)
    assert main(["convert", str(folder), "-o", str(tmp_path / "v.npz")]) == 0
    with np.load(tmp_path / "v.npz") as data:
        np.testing.assert_array_equal(data["t"], times)


def test_a_folder_of_fff_frames_refuses_a_repeated_time_and_two_sizes_by_name(tmp_path: Path) -> None:
    counts = counts_for(gaussian(3, 8, 8), BLACKBODY)
    folder = fff_folder(tmp_path / "dup", counts, [0.0, 0.1, 0.1], ["f0.fff", "f1.fff", "f2.fff"])
    with pytest.raises(
        ValueError, match=r"dup: duplicate timestamps: f2\.fff and f1\.fff were captured at the"
    ):
        load_video(folder)
    other = tmp_path / "sizes"
    other.mkdir()
    (other / "a.fff").write_bytes(simple_frame(counts[0], BLACKBODY))
    (other / "b.fff").write_bytes(simple_frame(np.zeros((8, 9), np.uint16) + 17000, stamps(BLACKBODY, 1.0)))
    with pytest.raises(ValueError, match=r"sizes: mixed frame sizes: b\.fff is 8 x 9 px, a\.fff is 8 x 8 px"):
        load_video(other)


REAL = SHARED_DATA / "flir_fff"


@pytest.mark.skipif(not REAL.is_dir(), reason=f"measured data folder {REAL} is absent")
def test_a_folder_of_real_fff_frames_streams_as_one_video(tmp_path: Path) -> None:
    """The real 640 x 512 frame copied three times with its capture time moved (the record's own bytes,
    little-endian inside the big-endian frame), named against their order, ExifTool's text beside them;
    the shared folder itself holds two cameras' frames of two sizes: one line naming both."""
    data = (REAL / "frame_000000.fff").read_bytes()
    seconds = 1541416483  # 2018-11-05 11:14:43 UTC, ms 84 (ExifTool's DateTimeOriginal)
    at = data.index(struct.pack("<I", seconds))
    assert struct.unpack_from("<I", data, at + 4)[0] & 0xFFFF == 84
    folder = tmp_path / "stream"
    folder.mkdir()
    for name, ms in (("z.fff", 84), ("y.fff", 117), ("x.fff", 150)):
        (folder / name).write_bytes(data[:at] + struct.pack("<II", seconds, ms) + data[at + 8 :])
    (folder / "frame_000000.exiftool.txt").write_bytes((REAL / "frame_000000.exiftool.txt").read_bytes())
    video = load_video(folder, timestamps="keep")
    assert video.frames.shape == (3, 512, 640) and video.t.tolist() == pytest.approx([0.0, 0.033, 0.066])
    assert video.meta["files"] == "z.fff .. x.fff" and video.meta["t0_utc"].startswith(
        "2018-11-05T11:14:43.084"
    )
    assert 9.5 < float(video.frames.min()) < float(video.frames.max()) < 12.7
    with pytest.raises(
        ValueError, match=r"flir_fff: mixed frame sizes: frame_000000_le\.fff is 240 x 320 px"
    ):
        load_video(REAL)
