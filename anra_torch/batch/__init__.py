"""Many videos in one run: input expansion, batched estimation, resumable atomic CSV/Parquet tables.

Modules: :mod:`~anra_torch.batch.inputs` (what to read), :mod:`~anra_torch.batch.table` (the table),
:mod:`~anra_torch.batch.options` (shared options, the result-changing ones), :mod:`~anra_torch.batch.resume`
(what is done), :mod:`~anra_torch.batch.run` (the run).

:func:`run_batch` reads every input (files, folders, glob patterns; any format in
:data:`anra_torch.video.REGISTRY`) as :func:`anra_torch.video.prepare_video` does for every command (resample,
region of interest, calibration), sends same-shaped videos through one
:class:`~anra_torch.estimation.ANRAEstimator` call as a batch, optionally diagnoses each video
(:func:`anra_torch.forecast.assess_gain`) and writes one row per input:

- ``path``; ``status`` (``"ok"`` or ``"error"``); ``error`` (one line, empty when ok);
- ``diffusivity``, ``std_error`` (mm^2/s); ``smoothing_px`` (px); ``noise_sd`` (data units);
  ``reliability``; ``n_masked``; ``frames``, ``height``, ``width`` (px); ``dt`` (s); ``dx`` (mm);
  ``a_true`` (mm^2/s, when the file records it); ``seconds`` (this video's share of its batch's time);
- with ``diagnose``: ``top_effect`` (``"none"`` for pure heat diffusion), ``effects`` (``;``-separated),
  ``gain``, ``noise_floor`` (data units), ``base_rmse``, ``extended_rmse`` (data units);
- ``roi`` (``"X0,Y0,W,H"`` px) and ``calibration`` (the table's path) when the video was cropped or
  calibrated, else empty;
- ``message``: what the estimator said about the video, ``;``-joined: its warnings (a significantly
  negative diffusivity, ...) and, when it measured nothing, why; and a note when the row was recomputed
  because its input changed;
- ``input_stamp`` (the input's size and modification time) and ``parameters`` (JSON: every option that
  changes a result): the resume key;
- ``explained``: the share of dT/dt the plain heat equation explains (below 0.9 the row's ``message``
  flags a poor fit);
- ``frames_used``: frames read when the video was read in time chunks (over
  :data:`~anra_torch.estimation.CHUNKED_VALUES` pixel values, or with ``precision``), else empty;
- ``phase``: for a recording with a heating and a cooling (found as ``anra estimate`` finds them), the
  phase the row measures: the longest source-free one with frames enough (``frames`` is its length); empty
  for a recording of one phase, and for one read in chunks (estimated whole).

A bad input (missing, unreadable, too small, no thermal activity) gets an ``error`` row and never stops the
others. The table is rewritten after every batch through a temporary file and :func:`os.replace`, so an
interrupted run keeps every finished row; the files are created with the mode the umask gives (0644 under
umask 022).

Resuming: a re-run skips an input whose row is ``ok``, was made with the same ``parameters`` and whose file
has not changed since (same ``input_stamp``); errors are retried, a changed input (or a row without a key,
from an older version) is recomputed. A row made with other parameters (another ``dx``, ``roi``,
calibration, ...) stops the run before any work with a one-line message naming the differences: replacing
it would lose a result made on purpose; ``rerun=True`` (``--rerun``) recomputes and replaces such rows.
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
