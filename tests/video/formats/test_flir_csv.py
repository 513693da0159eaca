"""FLIR CSV exports: exact parse of the real files against a direct reading, fixtures, one-line errors."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from shared_data import DATA as SHARED_DATA

from anra_torch.video import load_video

DATA = SHARED_DATA / "flir_csv"


EXPECTED = {
    "Q 100 Silver 1.csv": (1368, 9, 31),
    "Sample2 300 M1.csv": (2093, 14, 15),
    "Sample2 RT M1.csv": (1923, 15, 15),
}


def direct_reading(path: Path) -> np.ndarray:
    """The csv module, rows grouped by their 'Frame N' label: no code shared with the loader."""
    frames: list[list[list[float]]] = []
    with open(path, newline="", encoding="utf-8-sig") as handle:
        for row in csv.reader(handle):
            if row and row[0].startswith("Frame "):
                frames.append([])
            elif not frames or not row or not any(cell.strip() for cell in row):
                continue
            values = [float(c) for c in row[1:] if c.strip()]
            frames[-1].append(values)
    return np.array(frames)


@pytest.mark.skipif(not DATA.is_dir(), reason=f"measured data folder {DATA} is absent")
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_real_exports_parse_exactly(name: str) -> None:
    path = DATA / name
    video = load_video(path, dt=0.1, dx=0.25)
    assert tuple(video.frames.shape) == EXPECTED[name]
    text = path.read_text(encoding="utf-8-sig")
    assert text.count("\nFrame ") == EXPECTED[name][0]
    np.testing.assert_array_equal(video.frames.numpy(), direct_reading(path))
    assert video.unit == "degC" and video.meta["flir_emissivity"] == 1.0


def _export(
    tmp_path: Path, blocks: list[np.ndarray], name: str = "box.csv", drop: tuple | None = None
) -> Path:
    lines = ["Parameters:,Emissivity:,0.95 ", ",Refl. temp.:,20.0 °C", ",", "Bx1", ""]
    for k, block in enumerate(blocks, start=1):
        for r, row in enumerate(block):
            if drop == (k, r):
                continue
            label = f"Frame {k}" if r == 0 else ""
            lines.append(
                label + "," + ",".join(f"{v:.3f}" for v in row) + ("," if r == len(block) - 1 else "")
            )
        lines.append("")
    path = tmp_path / name
    path.write_text("\ufeff" + "\n".join(lines), encoding="utf-8")
    return path


def test_fixture_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    blocks = [np.round(20 + 10 * rng.random((4, 6)), 3) for _ in range(5)]
    video = load_video(_export(tmp_path, blocks), dt=0.2, dx=0.1)
    np.testing.assert_allclose(video.frames.numpy(), np.stack(blocks), atol=5e-4)
    assert video.meta["flir_emissivity"] == 0.95 and video.meta["flir_refl_temp"] == 20.0


def test_missing_row_names_file_and_frame(tmp_path: Path) -> None:
    blocks = [np.ones((4, 6)) * k for k in range(5)]
    path = _export(tmp_path, blocks, drop=(3, 2))
    with pytest.raises(ValueError, match=r"box\.csv: frame 3 \(line \d+\) has 3 rows, expected 4") as err:
        load_video(path, dt=0.1)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda t: t.replace(",2.000,", ",2.000,9.000,", 1), r"frame 3 row 1 has 7 values, expected 6"),
        (lambda t: t.replace(",1.000", ",abc", 1), r"frame 2 row 1: not a number: 'abc'"),
        (lambda t: t.replace("Frame 4", "Frame 5"), r"frame 5 where frame 4 was expected"),
        (lambda t: t.split("Frame 1")[0], r"no 'Frame N,' blocks"),
    ],
)
def test_bad_exports(tmp_path: Path, edit, match: str) -> None:
    path = _export(tmp_path, [np.ones((4, 6)) * k for k in range(5)])
    path.write_text(edit(path.read_text(encoding="utf-8")), encoding="utf-8")
    with pytest.raises(ValueError, match=match):
        load_video(path, dt=0.1)


def test_binary_file_with_csv_suffix(tmp_path: Path) -> None:
    path = tmp_path / "bin.csv"
    path.write_bytes(b"\xff\xfe\x00\x81" * 10)
    with pytest.raises(ValueError, match=r"bin\.csv: not a text file"):
        load_video(path, dt=0.1)
