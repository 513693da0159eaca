"""FLIR FFF frames: every header field against ExifTool's reading of the real frames, temperatures against an
independent Planck, both byte orders, uint16 and PNG counts, object-parameter overrides, one-line errors."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np
import pytest
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
from anra_torch.video import load_video, save_npz
from anra_torch.video.formats.flir_counts import decode_counts
from anra_torch.video.formats.flir_fff import read_frame
from anra_torch.video.formats.flir_objects import ObjectParameters
from anra_torch.video.formats.flir_seq import index_sequence

pytest.importorskip("imagecodecs", reason="the formats extra (imagecodecs) is not installed")
DATA = SHARED_DATA / "flir_fff"
real = pytest.mark.skipif(not DATA.is_dir(), reason=f"measured data folder {DATA} is absent")


def exiftool_fields(path: Path) -> dict[str, str]:
    lines = path.read_text().splitlines()
    return {k.strip(): v.strip() for k, v in (line.split(":", 1) for line in lines if ":" in line)}


def read(path: Path):
    data = path.read_bytes()
    return read_frame(lambda o, n: data[o : o + n], 0, where=path.name), data


# ------------------------------------------------------------------------------------------ real frames
@real
def test_every_header_field_is_what_exiftool_reads() -> None:
    want = exiftool_fields(DATA / "frame_000000.exiftool.txt")
    fr, _ = read(DATA / "frame_000000.fff")
    p, cam = fr.camera.planck, fr.camera.camera
    c = lambda v: f"{v:.1f} C"  # noqa: E731  ExifTool's temperature print format
    ours = {
        "Creator Software": fr.creator,
        "Raw Thermal Image Width": str(fr.raw.width),
        "Raw Thermal Image Height": str(fr.raw.height),
        "Raw Thermal Image Type": "TIFF" if (fr.raw.encoding, fr.raw.order) == ("uint16", "<") else "?",
        "Emissivity": f"{p['emissivity']:.2f}",
        "Object Distance": f"{p['object_distance']:.2f} m",
        "Reflected Apparent Temperature": c(p["reflected_temp"]),
        "Atmospheric Temperature": c(p["atmospheric_temp"]),
        "IR Window Temperature": c(p["ir_window_temp"]),
        "IR Window Transmission": f"{p['ir_window_transmission']:.2f}",
        "Relative Humidity": f"{100 * p['relative_humidity']:.1f} %",
        "Planck R1": f"{p['planck_r1']:.8g}",
        "Planck B": f"{p['planck_b']:.8g}",
        "Planck F": f"{p['planck_f']:.8g}",
        "Planck O": f"{p['planck_o']:.0f}",
        "Planck R2": f"{p['planck_r2']:.8g}",
        "Atmospheric Trans Alpha 1": f"{p['alpha1']:.6f}",
        "Atmospheric Trans Alpha 2": f"{p['alpha2']:.6f}",
        "Atmospheric Trans Beta 1": f"{p['beta1']:.6f}",
        "Atmospheric Trans Beta 2": f"{p['beta2']:.6f}",
        "Atmospheric Trans X": f"{p['x']:.6f}",
        "Camera Model": cam["camera_model"],
        "Camera Part Number": cam["camera_part_number"],
        "Camera Serial Number": cam["camera_serial_number"],
        "Camera Software": cam["camera_software"],
        "Lens Model": cam["lens_model"],
        "Field Of View": f"{cam['field_of_view']:.1f} deg",
        "Raw Value Median": str(cam["raw_value_median"]),
        "Raw Value Range": str(cam["raw_value_range"]),
        "Focus Step Count": str(cam["focus_step_count"]),
        "Focus Distance": f"{cam['focus_distance']:.1f} m",
        "Frame Rate": str(cam["frame_rate"]),
    }
    for key, name in (("Range Max", "range_max"), ("Range Min", "range_min"), ("Max Clip", "max_clip")):
        ours[f"Camera Temperature {key}"] = c(cam[f"camera_temperature_{name}"])
    for key in ("Min Clip", "Max Warn", "Min Warn", "Max Saturated", "Min Saturated"):
        ours[f"Camera Temperature {key}"] = c(cam["camera_temperature_" + key.lower().replace(" ", "_")])
    assert {k: want[k] for k in ours} == ours
    # DateTimeOriginal: local time to the millisecond and the zone, from Unix s + ms and minutes west of UTC
    from datetime import datetime, timedelta, timezone

    zone = timezone(timedelta(minutes=fr.camera.utc_offset_min))
    local = datetime.fromtimestamp(fr.camera.capture_time, zone)
    shown = local.strftime("%Y:%m:%d %H:%M:%S.") + f"{local.microsecond // 1000:03d}" + local.strftime("%z")
    assert shown[:-2] + ":" + shown[-2:] == want["Date/Time Original"]


@real
@pytest.mark.parametrize(
    ("name", "low", "high", "shape"),
    [("frame_000000.fff", 9.6, 12.6, (512, 640)), ("frame_000000_le.fff", 22.9, 29.5, (240, 320))],
)
def test_real_frames_load_in_the_stated_ranges(name: str, low: float, high: float, shape: tuple) -> None:
    video = load_video(DATA / name, dt=1.0)
    frames = video.frames.numpy()
    assert frames.shape == (1, *shape) and video.unit == "degC" and np.isfinite(frames).all()
    assert abs(frames.min() - low) < 0.05 and abs(frames.max() - high) < 0.05
    # the same pixels by an independent Planck on counts read by hand (uint16 little-endian at 0x20)
    fr, data = read(DATA / name)
    counts = np.frombuffer(data, "<u2", fr.raw.width * fr.raw.height, fr.raw.offset).reshape(shape)
    cam = _camera_of(fr)
    for row, col in [(0, 0), (shape[0] // 2, shape[1] // 3), (shape[0] - 1, shape[1] - 1)]:
        assert frames[0, row, col] == pytest.approx(planck_celsius(float(counts[row, col]), cam), abs=2e-4)


def _camera_of(fr) -> Camera:
    """The test's Camera with the values a parsed frame holds (to run the independent Planck on them)."""
    p = fr.camera.planck
    keys = {"r1": "planck_r1", "b": "planck_b", "f": "planck_f", "o": "planck_o", "r2": "planck_r2"}
    keys.update(a1="alpha1", a2="alpha2", b1="beta1", b2="beta2", x="x")
    return Camera(
        emissivity=p["emissivity"],
        distance=p["object_distance"],
        reflected_k=p["reflected_temp"] + 273.15,
        atmospheric_k=p["atmospheric_temp"] + 273.15,
        window_k=p["ir_window_temp"] + 273.15,
        window_transmission=p["ir_window_transmission"],
        humidity=p["relative_humidity"],
        constants={k: p[v] for k, v in keys.items()},
    )


# ------------------------------------------------------------------------------------------ written frames
@pytest.fixture
def counts() -> np.ndarray:
    rng = np.random.default_rng(3)
    return counts_for(25 + 10 * rng.random((12, 16)), Camera())


@pytest.mark.parametrize("header", ["<", ">"])
@pytest.mark.parametrize("inner", ["<", ">"])
@pytest.mark.parametrize("encoding", ["uint16", "png"])
def test_counts_round_trip_in_every_byte_order(
    tmp_path: Path, counts: np.ndarray, header: str, inner: str, encoding: str
) -> None:
    path = tmp_path / "one.fff"
    path.write_bytes(simple_frame(counts, Camera(millis=250), header, encoding, record_order=inner))
    fr, data = read(path)
    assert fr.raw.order == inner and fr.raw.encoding == encoding
    np.testing.assert_array_equal(
        decode_counts(fr.raw, data[fr.raw.offset : fr.raw.offset + fr.raw.length]), counts
    )
    assert fr.camera.capture_ms == 1_700_000_000_250 and fr.camera.utc_offset_min == 60
    assert fr.camera.planck["emissivity"] == pytest.approx(0.95) and fr.end == len(data)
    video = load_video(path, dt=1.0)
    expected = [planck_celsius(float(v), Camera()) for v in counts.reshape(-1)]
    np.testing.assert_allclose(video.frames.numpy().reshape(-1), expected, atol=2e-4)


def test_a_png_stored_in_the_plain_order_is_recognised_and_flagged(
    tmp_path: Path, counts: np.ndarray
) -> None:
    path = tmp_path / "plain.fff"
    path.write_bytes(simple_frame(counts, Camera(), "<", "png-plain"))
    index = index_sequence(path)
    assert index.swapped == ["png <"]
    video = load_video(path, dt=1.0)
    assert video.meta["camera"]["counts_byteswapped"] == ["png <"]
    np.testing.assert_allclose(
        video.frames[0, 0, 0].item(), planck_celsius(float(counts[0, 0]), Camera()), atol=2e-4
    )


def test_percent_humidity_and_several_record_types(tmp_path: Path, counts: np.ndarray) -> None:
    cam = Camera(humidity=30.0, distance=20.0, window_transmission=0.9, window_k=300.0)
    records = [(0x22, b"\x01" * 100), (0x20, camera_record(cam, "<")), (0x2B, b"\x00" * 64)]
    path = tmp_path / "several.fff"
    path.write_bytes(frame([*records, (0x01, raw_record(counts, "<"))], ">", empty=5))
    video = load_video(path, dt=1.0)
    assert video.meta["object_parameters"]["humidity"] == {"value": 30.0, "unit": "%", "source": "file"}
    expected = planck_celsius(float(counts[2, 3]), Camera(**{**cam.__dict__, "humidity": 0.30}))
    assert video.frames[0, 2, 3].item() == pytest.approx(expected, abs=2e-4)


# ------------------------------------------------------------------------------------------ overrides
def test_emissivity_override_changes_temperatures_as_planck_says(tmp_path: Path, counts: np.ndarray) -> None:
    path = tmp_path / "e.fff"
    cam = Camera(emissivity=0.95, reflected_k=283.15)
    path.write_bytes(simple_frame(counts, cam))
    before = load_video(path, dt=1.0).frames.numpy()[0]
    after = load_video(path, dt=1.0, emissivity=0.5)
    for row, col in [(0, 0), (5, 9), (11, 15)]:
        raw = float(counts[row, col])
        assert before[row, col] == pytest.approx(planck_celsius(raw, cam), abs=2e-4)
        assert after.frames[0, row, col].item() == pytest.approx(
            planck_celsius(raw, cam, emissivity=0.5), abs=2e-4
        )
    # a lower emissivity means the object emits the same counts from a hotter surface
    assert (after.frames.numpy()[0] - before > 5).all()
    record = after.meta["object_parameters"]
    assert record["emissivity"] == {"value": 0.5, "unit": None, "source": "argument", "file": 0.95}
    assert record["reflected_temp"] == {"value": 10.0, "unit": "degC", "source": "file"}


def test_every_override_reaches_the_formula(tmp_path: Path, counts: np.ndarray) -> None:
    path = tmp_path / "all.fff"
    path.write_bytes(simple_frame(counts, Camera()))
    video = load_video(
        path, dt=1.0, emissivity=0.8, reflected_temp=35.0, distance=30.0, atmospheric_temp=5.0, humidity=80.0
    )
    cam = Camera(emissivity=0.8, reflected_k=308.15, distance=30.0, atmospheric_k=278.15, humidity=0.8)
    assert video.frames[0, 4, 4].item() == pytest.approx(planck_celsius(float(counts[4, 4]), cam), abs=2e-4)
    assert {v["source"] for v in video.meta["object_parameters"].values()} == {"argument"}


def test_bad_overrides_get_one_line_errors(tmp_path: Path, counts: np.ndarray) -> None:
    path = tmp_path / "one.fff"
    path.write_bytes(simple_frame(counts, Camera()))
    for kwargs, pattern in [
        ({"emissivity": 0.0}, r"emissivity must be in \(0, 1\], got 0"),
        ({"emissivity": 1.5}, r"emissivity must be in \(0, 1\], got 1\.5"),
        ({"humidity": 120.0}, r"humidity must be in \[0, 100\] %, got 120"),
        ({"distance": -1.0}, r"distance must be >= 0 m"),
        ({"reflected_temp": -300.0}, r"reflected_temp must be above -273\.15 degC"),
    ]:
        with pytest.raises(ValueError, match=pattern):
            load_video(path, dt=1.0, **kwargs)
    with pytest.raises(TypeError, match="emissivity must be a number"):
        ObjectParameters(emissivity="high")  # type: ignore[arg-type]
    npz = save_npz(tmp_path / "v.npz", np.zeros((3, 4, 4)), dt=0.1, dx=0.1)
    with pytest.raises(ValueError, match=r"v\.npz: emissivity, .* apply to FLIR radiometric recordings"):
        load_video(npz, emissivity=0.5)
    assert main(["estimate", str(npz), "--emissivity", "0.5"]) == 2


# ------------------------------------------------------------------------------------------ damaged frames
def test_damaged_frames_get_one_line_errors(tmp_path: Path, counts: np.ndarray) -> None:
    good = simple_frame(counts, Camera())
    cases = {
        "magic": (b"XYZ\x00" + good[4:], r"not a FLIR FFF recording \(no 'FFF' frame header at byte 0\)"),
        "version": (good[:0x14] + struct.pack("<I", 999) + good[0x18:], "unsupported FFF format version"),
        "cut": (good[:300], r"no whole FFF frame .*cut off"),
        "nocamera": (frame([(0x01, raw_record(counts, "<"))], "<"), "has no CameraInfo record"),
        "short": (
            frame([(0x01, raw_record(counts, "<")[:100]), (0x20, camera_record(Camera(), "<"))], "<"),
            "",
        ),
    }
    for name, (data, pattern) in cases.items():
        path = tmp_path / f"{name}.fff"
        path.write_bytes(data)
        with pytest.raises(ValueError, match=re.escape(path.name) + ".*" + pattern) as err:
            load_video(path, dt=1.0)
        assert "\n" not in str(err.value)
