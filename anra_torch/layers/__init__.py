"""nn.Modules on fixed convolution kernels: derivatives, RTC attention and the ANRA estimator."""

from anra_torch.layers.attention import RTCAttention, confidence_mask, rtc_attention
from anra_torch.layers.derivatives import (
    GaussianSmoothing,
    Gradient,
    Laplacian,
    SecondDerivatives,
    TimeDerivative,
    gaussian_smooth,
    gradient,
    laplacian,
    second_derivatives,
    time_derivative,
)
from anra_torch.layers.estimator import AUTO_SMOOTHING, ANRAEstimator, ANRAResult

__all__ = [
    "ANRAEstimator",
    "ANRAResult",
    "AUTO_SMOOTHING",
    "GaussianSmoothing",
    "Gradient",
    "Laplacian",
    "RTCAttention",
    "SecondDerivatives",
    "TimeDerivative",
    "confidence_mask",
    "gaussian_smooth",
    "gradient",
    "laplacian",
    "rtc_attention",
    "second_derivatives",
    "time_derivative",
]
