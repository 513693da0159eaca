"""Which videos a batch reads (:mod:`anra_torch.batch.inputs`): files, folders, globs, folders of frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from anra_torch.batch import expand_inputs


def test_expand_inputs_files_folders_globs(video_folder: Path) -> None:
    found = expand_inputs([video_folder])
    names = [Path(p).name for p in found]
    assert names == ["broken.npz", "nodt.npy", "p0.npz", "p1.npz", "p2.npz", "q.npz"]  # no notes.txt
    globbed = expand_inputs(
        [str(video_folder / "p*.npz"), video_folder / "p1.npz", str(video_folder / "zz*.npz")]
    )
    assert [Path(p).name for p in globbed] == ["p0.npz", "p1.npz", "p2.npz", "zz*.npz"]
    assert expand_inputs(["missing.npz"]) == ["missing.npz"]  # kept: it gets an error row


def test_a_folder_of_frames_is_one_input(tmp_path: Path) -> None:
    """Per-frame matrices and FLIR JPEG folders are one video each; FLIR CSV exports stay one per file."""
    frames = tmp_path / "run" / "frames"
    frames.mkdir(parents=True)
    for k in range(3):
        np.savetxt(frames / f"f{k:03d}.csv", np.full((4, 5), float(k)), delimiter=",")
    (tmp_path / "run" / "a.npz").write_bytes(b"")
    exports = tmp_path / "exports"
    exports.mkdir()
    (exports / "one.csv").write_text("File Name,x\nFrame 1,\n1,2\n")
    (exports / "two.csv").write_text("File Name,y\nFrame 1,\n1,2\n")
    assert expand_inputs([tmp_path]) == [
        str(exports / "one.csv"),
        str(exports / "two.csv"),
        str(tmp_path / "run" / "a.npz"),
        str(frames),
    ]
