"""anra_torch: learning heat-transfer physics directly from thermal video.

The ANRA method (El-Kebir, Lee, Bentsman, arXiv 2203.13148) as PyTorch layers: noise-robust Holoborodko
derivatives on fixed kernels, RTC attention, and a direct estimator of the thermal diffusivity of
``dT/dt = a (d11 + d22) T`` that never solves the PDE; then what the plain heat equation gets wrong: hidden
effects named from the same balance, and the forecast gain of the extended model. Units: mm, s, mm^2/s.

The names here are the everyday ones; everything else lives in its subpackage, bottom up:

- :mod:`anra_torch.layers`: derivative, smoothing and attention layers on fixed kernels;
- :mod:`anra_torch.balance`: the PDE-balance core (matched filters, term bank, noise model, moments
  with the errors-in-variables correction, the balance of one video);
- :mod:`anra_torch.estimation`: the ANRA estimator family (offline, frame by frame, in chunks, small boxes);
- :mod:`anra_torch.recording`: what happens to one recording (read, phases, route, record), for every command;
- :mod:`anra_torch.effects`: one module per effect, one registry; :mod:`anra_torch.simulation`: the one
  integrator, the heat equation and exact solutions;
- :mod:`anra_torch.selection`: which effects act; :mod:`anra_torch.forecast` (forecasts, gain,
  the source map, Problem-1 refinement);
- :mod:`anra_torch.video`: loading and preparing recordings; :mod:`anra_torch.tissue.features`,
  :mod:`anra_torch.tissue.dose`, :mod:`anra_torch.tissue.learned`: tissue features and damage;
- :mod:`anra_torch.data`: :class:`ThermalVideoDataset` and batches for ``torch.utils.data.DataLoader``;
- :mod:`anra_torch.batch`, :mod:`anra_torch.report`, :mod:`anra_torch.cli`.
"""

import gc

# The imports below (torch's first) build ~170,000 objects that live as long as the process: the garbage
# collector, left on, would walk them again and again while they are built (0.2 s CPU of every start).
_COLLECTING = gc.isenabled()
gc.disable()
try:
    from anra_torch.batch import run_batch
    from anra_torch.data import ThermalVideoDataset
    from anra_torch.effects import EFFECTS, Effect, hidden_effect_video, simulate_effects
    from anra_torch.estimation import ANRAEstimator, ANRAResult, StreamingEstimator
    from anra_torch.forecast import GainResult, assess_gain
    from anra_torch.selection import Diagnosis, diagnose_terms
    from anra_torch.simulation import paper_video, simulate_heat
    from anra_torch.tissue import TissueFeatures
    from anra_torch.video import Video, load_video
finally:  # as the importer had it, also when an import fails
    if _COLLECTING:
        gc.enable()

__version__ = "0.1.0"

__all__ = [
    "ANRAEstimator",
    "ANRAResult",
    "Diagnosis",
    "EFFECTS",
    "Effect",
    "GainResult",
    "StreamingEstimator",
    "ThermalVideoDataset",
    "TissueFeatures",
    "Video",
    "assess_gain",
    "diagnose_terms",
    "hidden_effect_video",
    "load_video",
    "paper_video",
    "run_batch",
    "simulate_effects",
    "simulate_heat",
]
