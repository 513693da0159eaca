"""Shared fixtures: a fixed seed for every test, and the two floating dtypes with their tolerances."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

if "PYTEST_XDIST_WORKER_COUNT" in os.environ:
    # Under `pytest -n N` each worker gets its share of the cores: torch's default (all cores per worker)
    # oversubscribes them, and its OpenMP kernels (e.g. reflect padding) then spin for ~10 ms per call.
    torch.set_num_threads(max(1, (os.cpu_count() or 1) // int(os.environ["PYTEST_XDIST_WORKER_COUNT"])))

TOLERANCES = {torch.float32: 1e-4, torch.float64: 1e-10}
"""Relative tolerance for results that are exact up to rounding, per dtype."""


@pytest.fixture(autouse=True)
def _seed() -> None:
    """Seed torch and NumPy (seed 0) so every test sees the same random draws, alone or under xdist."""
    torch.manual_seed(0)
    np.random.seed(0)  # noqa: NPY002 - seeds the legacy global state that library code might use


@pytest.fixture(params=[torch.float32, torch.float64], ids=["float32", "float64"])
def dtype(request: pytest.FixtureRequest) -> torch.dtype:
    """Both floating dtypes the package supports."""
    return request.param


@pytest.fixture
def tol(dtype: torch.dtype) -> float:
    """Relative tolerance for an exact-up-to-rounding comparison in ``dtype``."""
    return TOLERANCES[dtype]


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the tests marked slow first (in their usual order): under ``pytest -n 2`` the long ones then
    start while the other worker still has short ones left, instead of one running alone at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
