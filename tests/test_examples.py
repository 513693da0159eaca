"""Every script of the gallery (``examples/``) runs as written and prints what its docstring promises.

Each runs as ``python examples/NAME.py`` runs it (as ``__main__``, its own ``__file__``, no arguments, from an
empty folder), in this process: a fresh interpreter would pay the import of torch and the package again
(~2 CPU-s a script); ``tests/test_main.py`` runs the entry points in processes of their own. What a script
changes in torch's global state (threads, default dtype, gradient mode) is put back. A script that reads
the shared data folder (``../shared/data``) is left out where that folder is absent.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
DATA = ROOT.parent / "shared" / "data"

EXPECTED = {
    "flir_folder.py": ("cooling: a = 0.09", True),
    "dataloader.py": ("finite True", False),
    "tissue_features.py": ("damaged (Omega >= 1):", False),
    "diagnose_simulated.py": ("named: ['advection']", False),
    "convert_flir.py": ("frames (1, 512, 640)", True),
}
"""Script -> (a line its output must hold, whether it reads the shared data)."""

SLOW = {"diagnose_simulated.py", "tissue_features.py", "flir_folder.py", "dataloader.py", "convert_flir.py"}
"""Over ~2 s each on a quiet 2-core machine when each ran in a fresh process: out of `make test-fast`."""


def test_every_example_is_listed() -> None:
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(EXPECTED)
    page = (ROOT / "docs" / "examples.md").read_text()
    assert all(f"examples/{name}" in page for name in EXPECTED)


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in sorted(EXPECTED)]
)
def test_example_runs(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    expected, needs_data = EXPECTED[name]
    if needs_data and not DATA.is_dir():
        pytest.skip(f"{name} reads {DATA}, absent here")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", [str(EXAMPLES / name)])
    threads, dtype, grad = torch.get_num_threads(), torch.get_default_dtype(), torch.is_grad_enabled()
    try:
        runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    finally:
        torch.set_num_threads(threads)
        torch.set_default_dtype(dtype)
        torch.set_grad_enabled(grad)
    assert expected in capsys.readouterr().out
