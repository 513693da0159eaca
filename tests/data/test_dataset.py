"""ThermalVideoDataset: a DataLoader with two workers over a folder mixing a FLIR JPEG folder, a FLIR CSV
export and .npz files yields batches the estimator and the tissue features take; sources (folder, glob,
manifest, list), spacing rules, labels, lazy and picklable reading, one-line errors."""

from __future__ import annotations

import contextlib
import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from flir_reference import decode
from tolerances import assert_rounding_close
from torch.utils.data import DataLoader

from anra_torch.data import RegionOfInterest, ThermalVideoDataset, VideoBatch
from anra_torch.estimation import ANRAEstimator
from anra_torch.tissue import TissueFeatures
from anra_torch.video import save_npz

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
JPEG_RUN = DATA / "laser_silicone" / "Nov19"
CSV_EXPORT = DATA / "flir_csv" / "Sample2 RT M1.csv"

HEADER = (
    "\ufeffParameters:,Emissivity:,1.00 \n,Refl. temp.:,5.0 \u00b0C\n,Distance:,0.0 m\n"
    ",Atmospheric temp.:,20.0 \u00b0C\n,Ext. optics temp.:,20.0 \u00b0C\n,Ext. optics trans.:,1.0 \n"
    ",Relative humidity:,0.0 %\n,\nBx1\n\nParameters:,Emissivity:,1.00 \n,Refl. temp.:,5.0 \u00b0C\n"
    ",Distance:,0.0 m\n,\n"
)
"""The header FLIR Tools writes before the frame blocks (as in ../shared/data/flir_csv)."""


def diffusing_gaussian(t: int, h: int, w: int, a: float, dt: float, dx: float, seed: int = 0) -> np.ndarray:
    """The exact 2D solution of dT/dt = a Lap T from a Gaussian of sigma 2.5 px, 25 K over 30 C, plus white
    noise of 0.01 K."""
    time = np.arange(t).reshape(-1, 1, 1) * dt
    y = (np.arange(h).reshape(1, -1, 1) - (h - 1) / 2) * dx
    x = (np.arange(w).reshape(1, 1, -1) - (w - 1) / 2) * dx
    s2 = (2.5 * dx) ** 2 + 2 * a * time
    clean = 30.0 + 25.0 * (2.5 * dx) ** 2 / s2 * np.exp(-(x**2 + y**2) / (2 * s2))
    return clean + 0.01 * np.random.default_rng(seed).standard_normal(clean.shape)


def write_flir_csv(path: Path, frames: np.ndarray) -> np.ndarray:
    """A FLIR Tools CSV export of ``frames`` (3 decimals, as FLIR writes); returns the values written."""
    blocks = []
    for k, frame in enumerate(frames, start=1):
        rows = [",".join(f"{v:.3f}" for v in row) for row in frame]
        blocks.append(f"Frame {k}," + rows[0] + "\n" + "".join(f",{r}\n" for r in rows[1:]))
    path.write_text(HEADER + "\n".join(blocks) + "\n", encoding="utf-8")
    return np.round(frames, 3)


@pytest.fixture
def mixed_folder(tmp_path: Path) -> dict:
    """A FLIR JPEG folder (10 real frames), a FLIR CSV export (no dt, no dx), two .npz files, and what is no
    video: a calibration CSV and an empty folder."""
    if not JPEG_RUN.is_dir():
        pytest.skip(f"measured data folder {JPEG_RUN} is absent")
    pytest.importorskip("flyr", reason="the formats extra (flyr) is not installed")
    folder = tmp_path / "videos"
    (folder / "flir_jpeg").mkdir(parents=True)
    for name in sorted(p.name for p in JPEG_RUN.glob("*.jpg"))[:10]:
        shutil.copy(JPEG_RUN / name, folder / "flir_jpeg" / name)
    written = write_flir_csv(folder / "export.csv", diffusing_gaussian(20, 24, 30, 0.4, 0.2, 0.5, seed=1))
    save_npz(
        folder / "a.npz", diffusing_gaussian(30, 32, 36, 0.1, 0.1, 0.2, seed=2), dt=0.1, dx=0.2, a_true=0.1
    )
    save_npz(
        folder / "b.npz", diffusing_gaussian(25, 32, 32, 0.2, 0.1, 0.2, seed=3), dt=0.1, dx=0.2, a_true=0.2
    )
    (folder / "calibration.csv").write_text("true,apparent\n25,24.1\n100,96.0\n")
    (folder / "empty").mkdir()
    return {"folder": folder, "csv": written}


@pytest.mark.slow
def test_a_dataloader_with_two_workers_feeds_the_estimator_and_the_features(mixed_folder: dict) -> None:
    dataset = ThermalVideoDataset(mixed_folder["folder"], dt=0.2, dx=0.5, labels=("a_true",))
    assert [p.name for p in dataset.sources] == ["a.npz", "b.npz", "export.csv", "flir_jpeg"]
    assert set(dataset.skipped) == {"calibration.csv", "empty"}
    loader = DataLoader(dataset, batch_size=2, num_workers=2, collate_fn=dataset.collate)
    batches = list(loader)
    assert len(batches) == 2 and all(isinstance(b, VideoBatch) and b.mode == "pad" for b in batches)
    npz, files = batches
    # Each file keeps its own spacing; the dataset's dt and dx fill in only what a file lacks.
    assert npz.dt.tolist() == [0.1, 0.1] and npz.dx.tolist() == [0.2, 0.2]
    assert npz.labels["a_true"].tolist() == [0.1, 0.2]
    assert files.dt[0] == 0.2 and files.dx.tolist() == [0.5, 0.5]
    assert files.meta[0]["dt_source"] == "dataset" and files.meta[1]["dt_source"] == "resampled"
    assert 4.0 < float(files.dt[1]) < 6.0  # the JPEGs' EXIF times, 4.1-5.9 s apart, resampled
    assert files.meta[1]["resampled"]["from_frames"] == 10
    t_jpeg = int(files.sizes[1, 0])
    assert files.sizes.tolist() == [[20, 24, 30], [t_jpeg, 96, 128]]
    assert files.padding.tolist() == [20 * 96 * 128 - 20 * 24 * 30, (20 - t_jpeg) * 96 * 128]
    csv_frames = torch.from_numpy(mixed_folder["csv"])
    assert_rounding_close(files.frames[0, :, :24, :30], csv_frames)
    # The first JPEG frame is a measured sample: it agrees with an independent decoder.
    reference, _ = decode(sorted((mixed_folder["folder"] / "flir_jpeg").glob("*.jpg"))[0])
    assert float((files.frames[1, 0] - torch.from_numpy(reference)).abs().max()) < 1e-3

    estimator, features = ANRAEstimator(strict=False), TissueFeatures()
    for batch in batches:
        result = batch.apply(estimator)
        maps = batch.apply(features)
        direct = estimator(batch.frames, batch.dt, batch.dx)  # NaN padding straight in: masked and counted
        direct_maps = features(batch.frames, batch.dt, batch.dx)
        own = (~torch.isfinite(batch.frames) & batch.mask).sum((1, 2, 3))
        assert result.n_masked.tolist() == own.tolist() == maps.summary["n_masked"].tolist()
        assert direct.n_masked.tolist() == (own + batch.padding).tolist()
        assert direct_maps.summary["n_masked"].tolist() == (own + batch.padding).tolist()
        assert tuple(maps.maps["omega"].shape) == tuple(batch.pixel_mask.shape)
        for k, index in enumerate(dataset.sources.index(s) for s in batch.sources):
            video = dataset[index]  # read again, alone
            alone = estimator(video.frames, video.dt, video.dx)
            assert_rounding_close(result.diffusivity[k], alone.diffusivity, ops=1000)
    # The exact solutions' diffusivities come back: each video was analysed at its own spacing.
    a_npz = npz.apply(estimator).diffusivity
    torch.testing.assert_close(a_npz, torch.tensor([0.1, 0.2], dtype=torch.float64), rtol=0.02, atol=0)
    a_csv = float(files.apply(estimator).diffusivity[0])
    assert abs(a_csv / 0.4 - 1) < 0.03


def test_a_real_flir_csv_export_is_read_and_refused_by_name_where_too_small(tmp_path: Path) -> None:
    if not CSV_EXPORT.is_file():
        pytest.skip(f"measured data file {CSV_EXPORT} is absent")
    lines = CSV_EXPORT.read_text(encoding="utf-8-sig").splitlines(keepends=True)
    stop = next(k for k, line in enumerate(lines) if line.startswith("Frame 41,"))
    cut = tmp_path / "first_40_frames.csv"
    cut.write_text("".join(lines[:stop]), encoding="utf-8")
    dataset = ThermalVideoDataset([cut], dt=0.1, dx=0.25)
    video = dataset[0]
    assert video.frames.shape[0] == 40 and video.unit == "degC" and video.dt == 0.1
    first = [
        float(v)
        for v in lines[next(k for k, s in enumerate(lines) if s.startswith("Frame 1,"))].split(",")[1:]
    ]
    assert_rounding_close(video.frames[0, 0], torch.tensor(first, dtype=torch.float64))
    batch = dataset.collate([video, dataset[0]])
    maps = batch.apply(TissueFeatures())  # a 15 x 12 px box: the dose maps, the ANRA maps absent with why
    assert "omega" in maps.maps and "diffusivity" in maps.absent
    with pytest.raises(
        ValueError, match=r"^first_40_frames.csv, first_40_frames.csv: frames must be at least 20"
    ):
        batch.apply(ANRAEstimator())


def test_sources_glob_list_and_manifest(tmp_path: Path) -> None:
    for k in range(3):
        frames = diffusing_gaussian(8, 20, 20 + k, 0.1, 0.1, 0.2, seed=k)
        save_npz(tmp_path / "runs" / f"run{k}" / "video.npz", frames, dt=0.1, dx=0.2, a_true=0.1 * k)
    np.save(tmp_path / "runs" / "mask.npy", np.eye(20, 21, dtype=bool))
    found = ThermalVideoDataset(str(tmp_path / "runs" / "**" / "*.npz"))
    assert [p.parent.name for p in found.sources] == ["run0", "run1", "run2"]
    listed = ThermalVideoDataset([tmp_path / "runs" / "run2" / "video.npz"])
    assert len(listed) == 1 and listed[0].frames.shape == (8, 20, 22)
    manifest = tmp_path / "runs" / "manifest.csv"
    manifest.write_text(
        "path,dt,dx,grade,site,mask\nrun0/video.npz,0.05,,1,arm,\nrun1/video.npz,,0.4,2.5,,mask.npy\n"
    )
    dataset = ThermalVideoDataset(manifest)
    first, second = dataset[0], dataset[1]
    assert (first.dt, first.dx, second.dt, second.dx) == (0.05, 0.2, 0.1, 0.4)  # a filled cell overrides
    assert first.meta["dt_source"] == "argument" and second.meta["dx_source"] == "argument"
    assert first.meta["labels"] == {"grade": 1.0, "site": "arm", "mask": None}
    assert second.meta["labels"]["site"] is None and torch.equal(
        second.meta["labels"]["mask"], torch.eye(20, 21, dtype=torch.bool)
    )
    batch = dataset.collate([first, second])
    assert batch.labels["grade"].tolist() == [1.0, 2.5] and batch.labels["site"] == ("arm", None)
    assert batch.labels["mask"][0] is None and batch.labels["mask"][1] is second.meta["labels"]["mask"]
    # In a folder, the manifest is not a video: it is left out with the reason.
    (tmp_path / "runs" / "run0" / "copy.csv").write_text(manifest.read_text())
    assert "manifest" in ThermalVideoDataset(tmp_path / "runs" / "run0").skipped["copy.csv"]


def test_reading_is_lazy_and_the_dataset_pickles(tmp_path: Path) -> None:
    path = save_npz(tmp_path / "v.npz", np.zeros((8, 20, 20)), dt=0.1, dx=0.2, grade=3)
    dataset = ThermalVideoDataset(tmp_path, labels=("grade",), transform=RegionOfInterest("2,3,10,12"))
    save_npz(path, np.ones((8, 20, 20)), dt=0.1, dx=0.2, grade=4)  # changed after the dataset was built
    copy = pickle.loads(pickle.dumps(dataset))
    video = copy[0]
    assert float(video.frames.sum()) == 8 * 12 * 10 and video.meta["labels"] == {"grade": 4}
    # Large uncompressed files stay on disk (the recording policy) and are read by collate.
    on_disk = ThermalVideoDataset(tmp_path, on_disk_above=0)[0]
    assert on_disk.on_disk and torch.equal(
        on_disk.loaded().frames, torch.ones(8, 20, 20, dtype=torch.float64)
    )
    batch = ThermalVideoDataset(tmp_path, on_disk_above=0).collate([on_disk])
    assert torch.equal(batch.frames[0], torch.ones(8, 20, 20, dtype=torch.float64))


def test_errors_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"source .*nowhere: no such file or folder"):
        ThermalVideoDataset(tmp_path / "nowhere")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ValueError, match=r": no video found \(left out: notes.txt: not a video format\)"):
        ThermalVideoDataset(tmp_path)
    with pytest.raises(TypeError, match=r"source must be a folder, a glob pattern, .* got int"):
        ThermalVideoDataset(3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"dt must be a positive number in s or None, got -1"):
        ThermalVideoDataset(tmp_path, dt=-1)
    with pytest.raises(TypeError, match=r"transform must be callable"):
        ThermalVideoDataset(tmp_path, transform="roi")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"collate_mode must be one of pad, crop, same, got 'fit'"):
        ThermalVideoDataset(tmp_path, collate_mode="fit")
    manifest = tmp_path / "m.csv"
    manifest.write_text("path,dt\nv.npy,fast\n")
    with pytest.raises(ValueError, match=r"m.csv: line 2: dt must be a positive number in s, got 'fast'"):
        ThermalVideoDataset(manifest)
    np.save(tmp_path / "v.npy", np.zeros((8, 20, 20)))
    save_npz(tmp_path / "w.npz", np.zeros((8, 20, 20)), dt=0.1, dx=0.2)
    no_dt = ThermalVideoDataset([tmp_path / "v.npy"], on_error="raise")
    with pytest.raises(ValueError, match=r"v.npy: no frame period: the file has neither 'dt' nor 't'"):
        no_dt[0]
    with pytest.raises(IndexError, match=r"index must be in \[-1, 0\], got 1"):
        no_dt[1]
    with pytest.raises(ValueError, match=r"w.npz: no label 'grade' in the file; it holds frames, dt, dx"):
        ThermalVideoDataset([tmp_path / "w.npz"], labels=("grade",), on_error="raise")[0]


# ------------------------------------------------------------------------------------- unreadable files
def corrupt(folder: Path, kind: str, name: str, rng: np.random.Generator) -> Path:
    """One file (or folder of frames) that cannot be read as a video, of ``kind``."""
    good = folder / "good.npz"
    if kind == "truncated":
        path = folder / f"{name}.npz"
        path.write_bytes(good.read_bytes()[: int(rng.integers(1, good.stat().st_size))])
    elif kind == "bytes":
        path = folder / f"{name}{rng.choice(['.npz', '.npy', '.h5', '.tif', '.mat', '.fff', '.seq', '.csq'])}"
        path.write_bytes(rng.bytes(int(rng.integers(0, 4000))))
    elif kind == "empty":
        path = folder / f"{name}{rng.choice(['.npz', '.npy', '.fff', '.csq', '.csv'])}"
        path.write_bytes(b"")
    elif kind == "shape":
        path = folder / f"{name}.npz"
        np.savez(path, frames=np.ones(tuple(int(v) for v in rng.integers(1, 6, size=rng.choice([1, 2, 4])))))
    elif kind == "all_nan":
        path = save_npz(folder / f"{name}.npz", np.full((6, 8, 8), np.nan), dt=0.1, dx=0.2)
    elif kind == "no_dt":
        path = folder / f"{name}.npy"
        np.save(path, np.ones((6, 8, 8)))
    elif kind == "bad_dt":
        path = folder / f"{name}.npz"
        np.savez(path, frames=np.ones((6, 8, 8)), dt=rng.choice([0.0, -1.0, np.nan, np.inf]))
    elif kind == "flir_csv":
        path = folder / f"{name}.csv"
        path.write_text(HEADER + "Frame 1,1,2,x\n,3,4\n", encoding="utf-8")
    else:  # a folder of frames, one of them bad
        path = folder / name
        path.mkdir()
        np.savetxt(path / "f1.txt", np.ones((4, 4)))
        (path / "f2.txt").write_text("1 2\n3 nope\n")
    return path


def test_an_unreadable_file_is_skipped_said_and_listed_or_raised_when_asked(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    save_npz(tmp_path / "good.npz", diffusing_gaussian(8, 20, 20, 0.1, 0.1, 0.2), dt=0.1, dx=0.2)
    save_npz(tmp_path / "more.npz", diffusing_gaussian(8, 20, 24, 0.1, 0.1, 0.2), dt=0.1, dx=0.2)
    bad = corrupt(tmp_path, "truncated", "bad", rng)
    dataset = ThermalVideoDataset(tmp_path)
    assert [p.name for p in dataset.sources] == ["bad.npz", "good.npz", "more.npz"]
    with pytest.warns(RuntimeWarning, match=r"skipped, cannot be read: .*bad\.npz: cannot read as \.npz"):
        batch = next(iter(DataLoader(dataset, batch_size=3, collate_fn=dataset.collate)))
    assert len(batch) == 2 and [s.name for s in batch.sources] == ["good.npz", "more.npz"]
    (skipped,) = batch.skipped
    assert skipped.path == bad and "\n" not in skipped.reason and skipped.reason.startswith(str(bad))
    assert dataset.failed == {str(bad): skipped.reason}
    with pytest.warns(RuntimeWarning):
        alone = dataset.collate([dataset[0]])
    assert len(alone) == 0 and alone.skipped[0].path == bad
    with pytest.raises(ValueError, match=r"the batch holds no video \(skipped: bad\.npz: "):
        alone.apply(ANRAEstimator())
    strict = ThermalVideoDataset(tmp_path, on_error="raise")
    with pytest.raises(ValueError, match=r"bad\.npz: cannot read as \.npz"):
        next(iter(DataLoader(strict, batch_size=3, collate_fn=strict.collate)))
    with pytest.raises(ValueError, match=r"on_error must be one of skip, raise, got 'ignore'"):
        ThermalVideoDataset(tmp_path, on_error="ignore")


KINDS = ("truncated", "bytes", "empty", "shape", "all_nan", "no_dt", "bad_dt", "flir_csv", "frames")


@pytest.mark.parametrize("workers", [0, 2])
def test_fuzzed_folders_with_corrupt_files_never_stop_an_epoch(tmp_path: Path, workers: int) -> None:
    """Folders of good videos (two sizes, a masked sample) among corrupt files of every kind, read through a
    DataLoader: every item is a video of its batch or listed in ``skipped`` with a one-line reason that
    names its file; the good ones are all there; no infinity anywhere, NaN only on masked samples and
    padding; spacing and times finite."""
    rng = np.random.default_rng(int(os.environ.get("FUZZ_SEED", 45)) + workers)
    for trial in range(int(os.environ.get("FUZZ_TRIALS", 3 if workers else 6))):
        folder = tmp_path / f"trial{trial}"
        folder.mkdir()
        frames = diffusing_gaussian(8, 20, 20, 0.1, 0.1, 0.2, seed=trial)
        frames[2, 3, 4] = np.inf  # masked on reading, counted
        save_npz(folder / "good.npz", frames, dt=0.1, dx=0.2)
        save_npz(folder / "wide.npz", diffusing_gaussian(6, 20, 26, 0.2, 0.1, 0.2, seed=9), dt=0.1, dx=0.2)
        bad = {
            corrupt(folder, str(rng.choice(KINDS)), f"bad{k}", rng).name
            for k in range(int(rng.integers(2, 6)))
        }
        dataset = ThermalVideoDataset(folder)
        loader = DataLoader(
            dataset, batch_size=int(rng.integers(1, 4)), num_workers=workers, collate_fn=dataset.collate
        )
        with pytest.warns(RuntimeWarning) if workers == 0 else contextlib.nullcontext():
            batches = list(loader)
        read = [s.name for b in batches for s in b.sources]
        skipped = [s for b in batches for s in b.skipped]
        assert sorted(read + [s.path.name for s in skipped]) == sorted(p.name for p in dataset.sources)
        assert {"good.npz", "wide.npz"} <= set(read) and {s.path.name for s in skipped} <= bad
        print(f"fuzz dataset ({workers} workers): {len(read)} read, {len(skipped)} skipped of {len(dataset)}")
        for s in skipped:
            assert s.path.name in s.reason and "\n" not in s.reason and "Traceback" not in s.reason
        for b in batches:
            if not len(b):
                continue
            assert not torch.isinf(b.frames).any() and torch.isfinite(b.dt).all()
            assert bool(torch.isnan(b.frames[~b.mask]).all())
            own = torch.isnan(b.frames).sum((1, 2, 3)) - b.padding
            masked = [m.get("masked_values", {}).get("non_finite", 0) for m in b.meta]
            assert own.tolist() == masked
