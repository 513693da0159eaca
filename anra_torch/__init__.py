"""anra_torch: learning heat-transfer physics directly from thermal video.

The ANRA method (El-Kebir, Lee, Bentsman, arXiv 2203.13148) as PyTorch layers: noise-robust Holoborodko
derivatives on fixed kernels, RTC attention, and a direct estimator of the thermal diffusivity of
``dT/dt = a (d11 + d22) T`` that never solves the PDE. Units: mm, s, mm^2/s.
"""

from anra_torch.balance.noise import estimate_noise_sd
from anra_torch.batch import run_batch
from anra_torch.dose import SKIN, ArrheniusConstants, arrhenius_omega, cem43, time_above
from anra_torch.effects import EFFECTS, Effect, hidden_effect_video, simulate_effects
from anra_torch.features import TissueFeatureMaps, TissueFeatures
from anra_torch.forecast import (
    GainResult,
    Refinement,
    SourceMapModel,
    assess_gain,
    fit_source_map,
    refine_model,
)
from anra_torch.layers import (
    AUTO_SMOOTHING,
    ANRAEstimator,
    ANRAResult,
    GaussianSmoothing,
    Gradient,
    Laplacian,
    RTCAttention,
    SecondDerivatives,
    TimeDerivative,
    gaussian_smooth,
    gradient,
    laplacian,
    rtc_attention,
    second_derivatives,
    time_derivative,
)
from anra_torch.selection import Diagnosis, diagnose_terms
from anra_torch.simulation import (
    MovingSource,
    gaussian_blob,
    gaussian_blobs,
    heat_spectral,
    simulate_heat,
    simulate_tissue,
)
from anra_torch.streaming import StreamingEstimator, estimate_long
from anra_torch.synthetic import SyntheticVideo, blobs_video, paper_video
from anra_torch.tissue_model import LearnedTissueModel
from anra_torch.video import Phase, Video, load_video, resample_uniform, segment_phases

__version__ = "0.1.0"

__all__ = [
    "ANRAEstimator",
    "ANRAResult",
    "AUTO_SMOOTHING",
    "Diagnosis",
    "EFFECTS",
    "Effect",
    "GainResult",
    "GaussianSmoothing",
    "Gradient",
    "Laplacian",
    "RTCAttention",
    "SecondDerivatives",
    "SyntheticVideo",
    "TimeDerivative",
    "assess_gain",
    "refine_model",
    "Refinement",
    "SourceMapModel",
    "fit_source_map",
    "blobs_video",
    "diagnose_terms",
    "estimate_noise_sd",
    "gaussian_blob",
    "gaussian_blobs",
    "gaussian_smooth",
    "gradient",
    "heat_spectral",
    "hidden_effect_video",
    "laplacian",
    "paper_video",
    "rtc_attention",
    "second_derivatives",
    "simulate_effects",
    "simulate_heat",
    "time_derivative",
    "Phase",
    "Video",
    "load_video",
    "resample_uniform",
    "segment_phases",
    # tissue features, thermal dose and the learned tissue model
    "SKIN",
    "ArrheniusConstants",
    "LearnedTissueModel",
    "MovingSource",
    "TissueFeatureMaps",
    "TissueFeatures",
    "arrhenius_omega",
    "cem43",
    "simulate_tissue",
    "time_above",
    "run_batch",
    "StreamingEstimator",
    "estimate_long",
]
