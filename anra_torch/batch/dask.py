"""The batch run on Dask: the same rows as :func:`anra_torch.batch.run_batch`, computed by Dask workers.

Each task is one chunk of inputs processed by :func:`anra_torch.batch.process_paths` on a worker (same-shaped
videos estimated together there); the driver writes the table atomically as chunks finish, so resuming and
error rows behave exactly as in the local run. Workers read the files themselves: every path must be
readable by every worker (a shared file system for a remote ``scheduler``).

Needs the ``dask`` extra: ``pip install 'anra_torch[dask]'``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from typing import Any

import torch

from anra_torch.batch.inputs import PathLike
from anra_torch.batch.options import BatchOptions
from anra_torch.batch.run import BatchSummary, process_paths, run_batch

__all__ = ["run_batch_dask"]


def _import_distributed():
    try:
        import distributed
    except ImportError as err:
        raise ImportError("the Dask engine needs dask.distributed: pip install 'anra_torch[dask]'") from err
    return distributed


def _work(chunk: list[str], options: BatchOptions) -> list[dict[str, Any]]:

    torch.set_num_threads(1)  # one thread per Dask worker thread: workers, not torch, share the cores
    return process_paths(chunk, options)


@contextlib.contextmanager
def _client(scheduler: str | None, workers: int):
    distributed = _import_distributed()
    if scheduler is not None:
        with distributed.Client(scheduler) as client:
            yield client
        return
    with (
        distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        yield client


def run_batch_dask(
    inputs: Iterable[PathLike],
    out: PathLike,
    *,
    scheduler: str | None = None,
    workers: int = 2,
    **options: Any,
) -> BatchSummary:
    """:func:`anra_torch.batch.run_batch` with the chunks computed on a Dask cluster.

    Args:
        inputs: files, folders or glob patterns.
        out: the table (``.csv`` or ``.parquet``), written by this process.
        scheduler: address of a running Dask scheduler (e.g. ``"tcp://10.0.0.5:8786"``); None starts an
            embedded :class:`distributed.LocalCluster` of ``workers`` single-threaded worker processes.
        workers: workers of the embedded cluster, >= 1.
        **options: :func:`run_batch` keywords (``options``, a :class:`~anra_torch.batch.BatchOptions`;
            ``batch_size``, ``progress``, ``rerun``).

    Returns:
        :class:`anra_torch.batch.BatchSummary`.

    Raises:
        ImportError: dask.distributed missing.
        ValueError: ``workers`` < 1 and the errors of :func:`run_batch`; a scheduler that cannot be reached
            raises ``OSError``.
    """
    if not (isinstance(workers, int) and workers >= 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    distributed = _import_distributed()

    def runner(chunks: list[list[str]], batch_options: BatchOptions) -> Iterator[list[dict[str, Any]]]:
        if not chunks:
            return
        with _client(scheduler, workers) as client:
            futures = [client.submit(_work, chunk, batch_options, pure=False) for chunk in chunks]
            for future in distributed.as_completed(futures):
                yield future.result()

    return run_batch(inputs, out, runner=runner, **options)
