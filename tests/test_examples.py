"""Every script of the gallery (``examples/``) runs as written and prints what its docstring promises.

Each runs in a fresh interpreter (``python examples/NAME.py``), as a user would run it. A script that reads
the shared data folder (``../shared/data``) is left out where that folder is absent.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

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
"""Over ~2 s each on a quiet 2-core machine (a fresh process each): out of `make test-fast`."""


def test_every_example_is_listed() -> None:
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(EXPECTED)
    page = (ROOT / "docs" / "examples.md").read_text()
    assert all(f"examples/{name}" in page for name in EXPECTED)


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in sorted(EXPECTED)]
)
def test_example_runs(name: str, tmp_path: Path) -> None:
    expected, needs_data = EXPECTED[name]
    if needs_data and not DATA.is_dir():
        pytest.skip(f"{name} reads {DATA}, absent here")
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / name)], cwd=tmp_path, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert expected in done.stdout, done.stdout
