"""nn.Modules on fixed convolution kernels: Holoborodko derivatives, Gaussian smoothing, RTC attention.

The ANRA estimator built on them is :mod:`anra_torch.estimation.estimator` (through the balance core).
"""

from anra_torch.layers.attention import RTCAttention, UniformAttention, confidence_mask, rtc_attention
from anra_torch.layers.correlate import correlate1d
from anra_torch.layers.derivatives import (
    Gradient,
    Laplacian,
    SecondDerivatives,
    TimeDerivative,
    gradient,
    laplacian,
    second_derivatives,
    time_derivative,
)
from anra_torch.layers.smoothing import GaussianSmoothing, gaussian_smooth
from anra_torch.layers.stencils import gaussian_taps

__all__ = [
    "GaussianSmoothing",
    "Gradient",
    "Laplacian",
    "RTCAttention",
    "SecondDerivatives",
    "TimeDerivative",
    "UniformAttention",
    "confidence_mask",
    "correlate1d",
    "gaussian_smooth",
    "gaussian_taps",
    "gradient",
    "laplacian",
    "rtc_attention",
    "second_derivatives",
    "time_derivative",
]
