"""Tests for anra_torch.recording.parallel: work side by side, results in order, errors beside their item."""

from __future__ import annotations

import threading

import pytest
import torch

from anra_torch.recording.parallel import side_by_side


@pytest.mark.parametrize("threads", [1, 2])
def test_results_in_order_errors_beside_their_item_threads_restored(threads: int) -> None:
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    seen: set[int] = set()

    def run(k: int) -> int:
        seen.add(threading.get_ident())
        assert torch.get_num_threads() == (1 if threads > 1 else threads)
        if k == 3:
            raise ValueError("three is bad")
        return k * k

    try:
        out = list(side_by_side(list(range(6)), run))
        assert torch.get_num_threads() == threads
    finally:
        torch.set_num_threads(before)
    assert [(k, r) for k, r, e in out if e is None] == [(0, 0), (1, 1), (2, 4), (4, 16), (5, 25)]
    (bad,) = [(k, str(e)) for k, r, e in out if e is not None]
    assert bad == (3, "three is bad")


def test_an_unexpected_error_is_raised() -> None:
    def run(k: int) -> int:
        raise KeyError(k)

    with pytest.raises(KeyError):
        list(side_by_side([1], run))
