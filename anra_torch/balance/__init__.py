"""The PDE balance: the heat equation balanced on the measured frames, with its noise, never solved.

- :mod:`~anra_torch.balance.filters`: :class:`MatchedFilters`, the same smoothing on both sides of the PDE
  and the bank of filtered terms (``U = dT/dt``, ``L = Lap T``, gradients, ...);
- :mod:`~anra_torch.balance.noise`: the sensor-noise model measured from the video (:func:`measure_noise`,
  :class:`NoiseModel`) and how it passes the filters;
- :mod:`~anra_torch.balance.moments`: the normal equations, with the errors-in-variables correction
  (:func:`accumulate`, the one place they are assembled);
- :mod:`~anra_torch.balance.system`: :class:`BalanceSystem`, the balance of one video and its fits;
- :mod:`~anra_torch.balance.artefacts`: camera artefacts found in the video and repaired first;
- :mod:`~anra_torch.balance.batch_noise`: the noise context of a batch of videos;
- :mod:`~anra_torch.balance.spectral`: the balance's ``U`` and ``L`` through the frames' spectra, shared
  by every smoothing candidate, and the standard error's pushed-back lever by Parseval;
- :mod:`~anra_torch.balance.loss`: the windowed loss-rate fit of the tissue features, and
  :mod:`~anra_torch.balance.loss_error` its standard error, propagated from the noise without copies.

Shape:
    Videos ``(B, T, H, W)``; a single video ``(T, H, W)``.
"""

from anra_torch.balance.artefacts import Artefacts, find_artefacts, stuck_pixels
from anra_torch.balance.batch_noise import (
    BatchNoise,
    PreparedBatch,
    batch_noise,
    concat_prepared,
    prepare_batch,
)
from anra_torch.balance.filters import MatchedFilters
from anra_torch.balance.loss import fit_loss_windows
from anra_torch.balance.moments import Moments, TermNoise, accumulate
from anra_torch.balance.noise import estimate_noise_sd, measure_noise
from anra_torch.balance.noise_model import NoiseModel
from anra_torch.balance.spectral import (
    SpectralStage,
    pushed_back,
    pushed_norm,
    spectral_stage,
    spectral_terms,
)
from anra_torch.balance.system import BalanceSystem, Fit, NoiseSpec

__all__ = [
    "Artefacts",
    "BalanceSystem",
    "BatchNoise",
    "Fit",
    "MatchedFilters",
    "Moments",
    "SpectralStage",
    "NoiseModel",
    "NoiseSpec",
    "PreparedBatch",
    "TermNoise",
    "accumulate",
    "batch_noise",
    "concat_prepared",
    "estimate_noise_sd",
    "find_artefacts",
    "fit_loss_windows",
    "measure_noise",
    "prepare_batch",
    "pushed_back",
    "pushed_norm",
    "spectral_stage",
    "spectral_terms",
    "stuck_pixels",
]
