"""Where outputs go (:mod:`anra_torch.checks.outputs`): never over an input, never half-written."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from anra_torch.checks import atomic_output, check_output, write_text


def test_an_output_that_is_an_input_is_refused_by_any_path(tmp_path: Path, monkeypatch) -> None:
    source = tmp_path / "v.npz"
    source.write_bytes(b"kept")
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.npz").symlink_to(source)
    monkeypatch.chdir(tmp_path / "sub")
    for given in (source, "../v.npz", tmp_path / "sub" / ".." / "v.npz", tmp_path / "link.npz"):
        with pytest.raises(
            ValueError, match=r"^-o .*\.npz is the input .*v\.npz: writing there would replace"
        ):
            check_output(given, [source], name="-o")
    assert check_output(tmp_path / "w.npz", [source], name="-o") == tmp_path / "w.npz"
    assert source.read_bytes() == b"kept"


def test_a_file_output_on_a_folder_or_a_device_and_a_folder_output_on_a_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"^-o /dev/null must be a file path, got a character device"):
        check_output("/dev/null", name="-o")
    with pytest.raises(ValueError, match=r"^--out .* must be a file path, got a folder; name a file$"):
        check_output(tmp_path, name="--out")
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(ValueError, match=r"^--report .*afile must be a folder \(DIR\), got an existing file"):
        check_output(afile, name="--report", folder=True)
    assert check_output(tmp_path, name="--report", folder=True) == tmp_path
    assert check_output(tmp_path / "new", name="--report", folder=True) == tmp_path / "new"
    os.mkfifo(tmp_path / "pipe")
    with pytest.raises(ValueError, match=r"got a pipe"):
        check_output(tmp_path / "pipe", name="-o")


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "deep" / "maps.npz"
    write_text(target, "old")
    with pytest.raises(RuntimeError, match="disk full"), atomic_output(target) as temp:
        assert temp.parent == target.parent and temp.name.endswith(".npz") and temp.name.startswith(".")
        temp.write_text("half")
        raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert [p.name for p in target.parent.iterdir()] == ["maps.npz"]
    with atomic_output(target) as temp:
        temp.write_text("new")
    assert target.read_text() == "new" and [p.name for p in target.parent.iterdir()] == ["maps.npz"]


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_the_written_file_has_the_mode_the_umask_allows(tmp_path: Path, umask: int) -> None:
    previous = os.umask(umask)
    try:
        path = write_text(tmp_path / "report.md", "# report\n")
    finally:
        os.umask(previous)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask
