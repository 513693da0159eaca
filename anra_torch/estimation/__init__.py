"""The ANRA estimator family: the diffusivity of ``dT/dt = a (d11 + d22) T`` without solving the PDE.

- :mod:`~anra_torch.estimation.estimator`: :class:`ANRAEstimator` (offline, batched) and :class:`ANRAResult`;
- :mod:`~anra_torch.estimation.streaming`: :class:`StreamingEstimator`, frame by frame;
- :mod:`~anra_torch.estimation.chunked`: :func:`estimate_chunked`, recordings larger than memory;
- :mod:`~anra_torch.estimation.small_box`: regions too small for the filters (down to 3 x 3 px);
- :mod:`~anra_torch.estimation.baselines`: the naive estimators the paper compares against.
"""

from anra_torch.estimation.baselines import BASELINES, backward_log_estimate, log_kernel
from anra_torch.estimation.chunked import (
    CHUNK_BYTES,
    CHUNKED_VALUES,
    ChunkedEstimate,
    Chunking,
    estimate_chunked,
)
from anra_torch.estimation.estimator import AUTO_SMOOTHING, MODES, POOR_FIT, ANRAEstimator, ANRAResult
from anra_torch.estimation.small_box import (
    MODELS,
    SmallBoxModel,
    edge_explained,
    fit_small_box,
    forecast_small_box,
    harmonic_interior,
    small_box_estimate,
    unresolved_bound,
)
from anra_torch.estimation.streaming import NpyFrames, StreamingEstimate, StreamingEstimator, estimate_long

__all__ = [
    "ANRAEstimator",
    "ANRAResult",
    "AUTO_SMOOTHING",
    "BASELINES",
    "CHUNKED_VALUES",
    "CHUNK_BYTES",
    "ChunkedEstimate",
    "Chunking",
    "MODELS",
    "MODES",
    "NpyFrames",
    "POOR_FIT",
    "SmallBoxModel",
    "StreamingEstimate",
    "StreamingEstimator",
    "backward_log_estimate",
    "edge_explained",
    "estimate_chunked",
    "estimate_long",
    "fit_small_box",
    "forecast_small_box",
    "harmonic_interior",
    "log_kernel",
    "small_box_estimate",
    "unresolved_bound",
]
