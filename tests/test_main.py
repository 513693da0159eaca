"""``python -m anra_torch`` and the ``anra`` script (:mod:`anra_torch.__main__`), run in a new process."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.slow
def test_entry_points_run_outside_the_process(tmp_path: Path) -> None:
    helped = subprocess.run(
        [sys.executable, "-m", "anra_torch", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert helped.returncode == 0 and helped.stdout.startswith("usage: anra ")
    script = Path(sys.executable).with_name("anra")
    failed = subprocess.run(
        [str(script), "estimate", str(tmp_path / "none.npz")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert failed.returncode == 2 and failed.stdout == ""
    assert failed.stderr == f"anra: error: {tmp_path / 'none.npz'}: no such file\n"


def test_importing_the_package_leaves_the_garbage_collector_as_the_importer_had_it() -> None:
    """The package's imports run with the collector off (a faster start) and leave it as it was."""
    import gc
    import importlib

    import anra_torch

    was = gc.isenabled()
    try:
        gc.disable()
        importlib.reload(anra_torch)
        assert not gc.isenabled()
        gc.enable()
        importlib.reload(anra_torch)
        assert gc.isenabled()
    finally:
        (gc.enable if was else gc.disable)()


def test_a_failed_import_of_the_package_still_gives_the_garbage_collector_back(monkeypatch) -> None:
    """An import that raises inside the package's imports leaves the collector on, as the importer had it."""
    import gc
    import importlib

    import anra_torch

    assert gc.isenabled()
    monkeypatch.setitem(sys.modules, "anra_torch.video", None)  # its import now raises ImportError
    with pytest.raises(ImportError):
        importlib.reload(anra_torch)
    assert gc.isenabled()
    monkeypatch.undo()
    importlib.reload(anra_torch)
