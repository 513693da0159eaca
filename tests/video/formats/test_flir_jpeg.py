"""FLIR radiometric JPEGs: temperatures against an independent decode, EXIF/FFF times, one-line errors."""

from __future__ import annotations

import shutil
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
import torch
from flir_reference import decode
from shared_data import DATA as SHARED_DATA

from anra_torch.video import load_video
from anra_torch.video.formats.flir_jpeg import flir_timestamp
from anra_torch.video.resample import resample_uniform

DATA = SHARED_DATA / "laser_silicone"


pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"measured data folder {DATA} is absent")


RUNS = ("Nov19", "Nov19_2")


@pytest.fixture(scope="module", params=RUNS)
def run(request: pytest.FixtureRequest) -> tuple[Path, object]:
    folder = DATA / request.param
    return folder, load_video(folder, timestamps="keep")


def test_folder_is_one_video_in_celsius(run: tuple) -> None:
    folder, video = run
    assert video.frames.shape == (25, 96, 128) and video.unit == "degC"
    assert video.meta["format"] == "flir_jpeg" and not video.uniform


@pytest.mark.parametrize("k", [0, 7, 12, 13, 24])
def test_temperatures_agree_with_an_independent_decode(run: tuple, k: int) -> None:
    folder, video = run
    files = sorted(folder.glob("*.jpg"))
    reference, _ = decode(files[k])
    error = np.abs(video.frames[k].numpy() - reference)
    assert error.max() < 0.1  # degC, the acceptance bound
    assert error.max() < 1e-3  # what the decoders actually agree to (3.0e-4 at most over the 50 frames)
    # A spot check at the hottest pixel, which reaches 200-390 degC.
    row, col = np.unravel_index(reference.argmax(), reference.shape)
    assert abs(float(video.frames[k, row, col]) - reference[row, col]) < 0.1
    assert reference.max() > (150 if k == 12 else 50)  # the laser spot: up to 390 degC at switch-off


def test_times_are_the_capture_times_to_the_millisecond(run: tuple) -> None:
    from PIL import Image

    folder, video = run
    files = sorted(folder.glob("*.jpg"))
    stamps = np.array([decode(f)[1] for f in files])
    np.testing.assert_allclose(video.t.numpy(), stamps - stamps[0], atol=1e-6)
    # The EXIF DateTimeOriginal (local time, whole seconds) is the same instant.
    exif = Image.open(files[3]).getexif().get_ifd(0x8769)[0x9003]
    local = datetime.strptime(exif, "%Y:%m:%d %H:%M:%S")
    utc = datetime.fromisoformat(video.meta["t0_utc"]).replace(tzinfo=None) + timedelta(
        seconds=float(video.t[3])
    )
    offset = (local - utc).total_seconds()
    assert abs(offset - round(offset / 3600) * 3600) < 1.0
    steps = np.diff(video.t.numpy())
    assert 4.0 < steps.min() < 4.2 and 5.5 < steps.max() < 6.0  # not uniform: 4.1-5.9 s


def test_non_uniform_times_are_refused_unless_resampled(run: tuple) -> None:
    folder, video = run
    with pytest.raises(ValueError, match=rf"{folder.name}: t must be uniformly spaced.*resample"):
        load_video(folder)
    resampled = load_video(folder, timestamps="resample")
    assert resampled.meta["resampled"]["from_frames"] == 25
    # the median step (the lower middle value of an even count, as torch.median)
    assert resampled.dt == pytest.approx(float(np.quantile(np.diff(video.t.numpy()), 0.5, method="lower")))


def test_exif_times_drive_the_resampled_frames(run: tuple) -> None:
    _, video = run
    resampled = resample_uniform(video, method="linear")
    t = video.t.numpy()
    grid = resampled.t.numpy()
    np.testing.assert_allclose(np.diff(grid), resampled.dt)
    for row, col in [(10, 10), (50, 60), (48, 70)]:
        expected = np.interp(grid, t, video.frames[:, row, col].numpy())
        np.testing.assert_allclose(resampled.frames[:, row, col].numpy(), expected, rtol=1e-12)
    # Another time base gives other frames: the timestamps matter.
    assert not torch.allclose(resampled.frames[5], video.frames[5].double())


# ------------------------------------------------------------------------------------------ bad input
def test_jpeg_without_thermal_data(tmp_path: Path) -> None:
    from PIL import Image

    path = tmp_path / "photo.jpg"
    Image.new("RGB", (16, 12), (200, 10, 10)).save(path)
    with pytest.raises(ValueError, match=r"photo\.jpg: no FLIR thermal data \(no FFF record") as err:
        load_video(path, dt=1.0)
    assert "\n" not in str(err.value)


def test_truncated_and_corrupt_jpeg(tmp_path: Path) -> None:
    source = (DATA / "Nov19" / "FLIR2167.jpg").read_bytes()
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(source[:20000])
    with pytest.raises(ValueError, match=r"cut\.jpg: .*(truncated|corrupt|cannot decode)") as err:
        load_video(cut, dt=1.0)
    assert "\n" not in str(err.value)
    junk = tmp_path / "junk.jpg"
    junk.write_bytes(b"not a jpeg at all")
    with pytest.raises(ValueError, match=r"junk\.jpg: not a JPEG"):
        load_video(junk, dt=1.0)


def test_unsorted_and_duplicate_times_name_the_files(tmp_path: Path) -> None:
    folder = tmp_path / "swapped"
    folder.mkdir()
    shutil.copy(DATA / "Nov19" / "FLIR2169.jpg", folder / "a1.jpg")
    shutil.copy(DATA / "Nov19" / "FLIR2167.jpg", folder / "a2.jpg")
    with pytest.raises(ValueError, match=r"swapped: unsorted timestamps: a2\.jpg .* not after a1\.jpg"):
        load_video(folder)
    shutil.copy(DATA / "Nov19" / "FLIR2169.jpg", folder / "a2.jpg")
    with pytest.raises(ValueError, match=r"duplicate timestamps: a2\.jpg"):
        load_video(folder)


def test_single_jpeg_is_one_frame() -> None:
    video = load_video(DATA / "Nov19" / "FLIR2191.jpg", dt=1.0, dx=0.55)
    assert video.frames.shape == (1, 96, 128)
    assert flir_timestamp(DATA / "Nov19" / "FLIR2191.jpg") == pytest.approx(
        decode(DATA / "Nov19" / "FLIR2191.jpg")[1]
    )
