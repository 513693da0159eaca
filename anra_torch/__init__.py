"""anra_torch: learning heat-transfer physics directly from thermal video.

The ANRA method (El-Kebir, Lee, Bentsman, arXiv 2203.13148) as PyTorch layers: noise-robust Holoborodko
derivatives on fixed kernels, RTC attention, and a direct estimator of the thermal diffusivity of
``dT/dt = a (d11 + d22) T`` that never solves the PDE. Units: mm, s, mm^2/s.
"""

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
from anra_torch.noise import estimate_noise_sd
from anra_torch.simulate import gaussian_blob, gaussian_blobs, heat_spectral, simulate_heat
from anra_torch.synthetic import SyntheticVideo, blobs_video, paper_video

__version__ = "0.1.0"

__all__ = [
    "ANRAEstimator",
    "ANRAResult",
    "AUTO_SMOOTHING",
    "GaussianSmoothing",
    "Gradient",
    "Laplacian",
    "RTCAttention",
    "SecondDerivatives",
    "SyntheticVideo",
    "TimeDerivative",
    "blobs_video",
    "estimate_noise_sd",
    "gaussian_blob",
    "gaussian_blobs",
    "gaussian_smooth",
    "gradient",
    "heat_spectral",
    "laplacian",
    "paper_video",
    "rtc_attention",
    "second_derivatives",
    "simulate_heat",
    "time_derivative",
]
