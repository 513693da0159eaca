"""Every docstring example in the package runs and prints what it shows (so the examples cannot go stale)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import anra_torch

MODULES = sorted(
    info.name
    for info in pkgutil.walk_packages(anra_torch.__path__, prefix="anra_torch.")
    if "__main__" not in info.name
)


SLOW = {"anra_torch.forecast.gain", "anra_torch.selection.diagnose"}
"""Modules whose examples diagnose a simulated video (over a second each on a quiet 2-core machine)."""


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in MODULES]
)
def test_docstring_examples(name: str) -> None:
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} docstring examples failed in {name}"
