"""Independent pieces of work side by side: one per torch thread, each on one thread.

Estimating one recording is a chain of many memory-bound passes and small operations that one core runs
about as fast as two; several recordings at once, one per core, use every core (``anra batch``:
``benchmarks/bench_batch.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch

__all__ = ["CAUGHT", "side_by_side"]

Item = TypeVar("Item")
Result = TypeVar("Result")

CAUGHT = (ValueError, TypeError, OSError, RuntimeError)
"""The errors a piece of work may end in: returned beside its item, never raised (the others go on)."""


def side_by_side(
    items: Sequence[Item], run: Callable[[Item], Result]
) -> Iterator[tuple[Item, Result | None, BaseException | None]]:
    """``run(item)`` for every item, in order: ``(item, result, None)``, or ``(item, None, error)`` for an
    error of :data:`CAUGHT`. With two or more torch threads and items, as many at once as threads, each
    on one torch thread (the thread count is restored after).

    Shape:
        No tensors of its own.
    """

    def one(item: Item) -> tuple[Item, Result | None, BaseException | None]:
        try:
            return item, run(item), None
        except CAUGHT as err:
            return item, None, err

    threads = torch.get_num_threads()
    workers = min(len(items), threads)
    if workers < 2:
        yield from map(one, items)
        return
    torch.set_num_threads(1)
    try:
        with ThreadPoolExecutor(workers) as pool:
            yield from pool.map(one, items)
    finally:
        torch.set_num_threads(threads)
