"""Many videos in one run: input expansion, batched estimation, resumable atomic CSV/Parquet tables.

Modules: :mod:`~anra_torch.batch.inputs` (what to read), :mod:`~anra_torch.batch.table` (the table),
:mod:`~anra_torch.batch.options` (shared options, the result-changing ones), :mod:`~anra_torch.batch.resume`
(what is done), :mod:`~anra_torch.batch.run` (the run), :mod:`~anra_torch.batch.dask` (the chunks on a
Dask cluster).

:func:`run_batch` reads every input as ``anra estimate`` does, estimates same-shaped videos in one
:class:`~anra_torch.estimation.ANRAEstimator` call, optionally diagnoses each, and writes one row per input
to a table rewritten atomically after every batch. A bad input gets an ``error`` row and never stops the
others; a re-run skips the inputs already done with the same options from the same file. The columns:
``docs/reference/outputs.md`` ("anra batch columns"); resuming: ``docs/guides/folder-of-videos.md``.
"""

from anra_torch.batch.dask import run_batch_dask
from anra_torch.batch.inputs import PathLike, expand_inputs
from anra_torch.batch.options import BatchOptions
from anra_torch.batch.run import BatchSummary, process_paths, run_batch
from anra_torch.batch.table import BATCH_COLUMNS, read_table, write_table

__all__ = [
    "BATCH_COLUMNS",
    "BatchOptions",
    "BatchSummary",
    "PathLike",
    "expand_inputs",
    "process_paths",
    "read_table",
    "run_batch",
    "run_batch_dask",
    "write_table",
]
