"""The standard contrasts of pulsed (flash) thermography, each a batched tensor operation on the video.

- :func:`tsr`, thermographic signal reconstruction (Shepard 2003): per pixel a polynomial in ``ln t``
  fitted to ``ln (T - baseline)``, and its first and second derivatives in ``ln t``. Over a
  semi-infinite body the surface falls like ``1 / sqrt(t)``: the first derivative is ``-1/2`` and the
  second 0; an insulated plate of thickness ``L`` departs from it at the back wall, where the second
  derivative peaks at ``t = L^2 / (pi a_z)``; a defect above it departs sooner.
- :func:`pct`, principal component thermography (Rajic 2002): the singular value decomposition of the
  standardised video seen as a (time x pixels) matrix; its spatial components are the maps.
- :func:`ppt`, pulsed phase thermography (Maldague and Marinetti 1996): the phase of each pixel's discrete
  Fourier transform over time at the lowest frequencies (insensitive to a non-uniform flash, which scales
  a pixel's whole signal).

Frames are ``(T, H, W)`` or a batch ``(B, T, H, W)``; every result is computed on the frames' device and
in their floating dtype (integers are taken as float32).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from anra_torch.checks import as_video, check_choice, check_int

__all__ = ["PCT_STANDARDISE", "PCTResult", "PPTResult", "TSRResult", "pct", "ppt", "tsr"]

PCT_STANDARDISE = ("pixel", "frame", "none")
"""How :func:`pct` standardises the video: each pixel's time series to mean 0 and sd 1 (Rajic's
choice), each frame to mean 0 and sd 1, or only each pixel's mean removed."""


def _video(frames: object) -> tuple[Tensor, bool]:
    video, batched = as_video(frames, name="frames", min_frames=2)
    if not video.is_floating_point():
        video = video.float()
    if not bool(torch.isfinite(video).all()):
        raise ValueError("frames must be finite; repair or mask the non-finite samples first")
    return video, batched


# ------------------------------------------------------------------------------------------------- TSR
@dataclass(frozen=True)
class TSRResult:
    """Output of :func:`tsr`.

    Attributes:
        coefficients: the polynomial's coefficients in powers of ``x = (ln t - centre) / scale``, lowest
            first, ``(..., degree + 1, H, W)``.
        centre: ``centre`` of ``x`` (``ln s``).
        scale: ``scale`` of ``x``.
        log_excess: the reconstructed ``ln (T - baseline)`` at every frame, ``(..., T, H, W)``.
        first: ``d ln (T - baseline) / d ln t``, ``(..., T, H, W)``.
        second: ``d^2 ln (T - baseline) / d (ln t)^2``, ``(..., T, H, W)``.
        samples: the samples each pixel's fit used (an excess that is not positive has no logarithm and is
            left out), ``(..., H, W)``.

    Shape:
        ``(..., *)`` is ``(B,)`` for a batch and empty for one video.
    """

    coefficients: Tensor
    centre: float
    scale: float
    log_excess: Tensor
    first: Tensor
    second: Tensor
    samples: Tensor


def tsr(frames: Tensor, times: Tensor, *, degree: int = 7, baseline: float | Tensor = 0.0) -> TSRResult:
    """Thermographic signal reconstruction: ``ln (T - baseline)`` as a polynomial in ``ln t`` per pixel.

    Args:
        frames: temperatures, ``(T, H, W)`` or ``(B, T, H, W)``.
        times: each frame's time since the flash in s, all positive, ``(T,)``.
        degree: the polynomial's degree (Shepard's usual choice: 5-9).
        baseline: the temperature before the flash: a number, or a map ``(H, W)`` / ``(B, H, W)``.

    Returns:
        :class:`TSRResult`. A sample whose excess over ``baseline`` is not positive is left out of its
        pixel's fit (``samples`` counts what each fit used).

    Raises:
        ValueError: bad shapes, non-finite frames, times not positive, a pixel with fewer usable samples
            than ``degree + 1`` (its baseline is above its signal).

    Shape:
        ``times`` ``(T,)``; outputs as in :class:`TSRResult`.

    Example:
        >>> t = torch.linspace(0.1, 10.0, 50, dtype=torch.float64)
        >>> frames = (20.0 + 3.0 / t.sqrt())[:, None, None].expand(50, 2, 2)
        >>> round(float(tsr(frames, t, baseline=20.0).first[10, 0, 0]), 6)
        -0.5
    """
    video, batched = _video(frames)
    degree = check_int(degree, "degree", 1)
    if not isinstance(times, Tensor):
        times = torch.as_tensor(times, dtype=torch.float64, device=video.device)
    times = times.to(device=video.device, dtype=torch.float64)
    if times.shape != (video.shape[1],):
        raise ValueError(
            f"times must have shape ({video.shape[1]},) (one per frame), got {tuple(times.shape)}"
        )
    if not bool((times > 0).all()) or not bool(torch.isfinite(times).all()):
        raise ValueError("times must be positive seconds since the flash; shift them by the flash's time")
    if video.shape[1] <= degree:
        raise ValueError(f"frames need more than degree = {degree} frames, got {video.shape[1]}")
    excess = video - _as_map(baseline, video, "baseline")[:, None]
    log_t = times.log()
    centre, scale = float(0.5 * (log_t.max() + log_t.min())), float(0.5 * (log_t.max() - log_t.min())) or 1.0
    x = (log_t - centre) / scale
    powers = torch.arange(degree + 1, device=video.device, dtype=torch.float64)
    basis = x[:, None] ** powers  # (T, n)
    usable = excess > 0
    log_excess = torch.where(usable, excess.clamp_min(torch.finfo(video.dtype).tiny).log(), 0.0)
    coefficients = _weighted_fit(basis, log_excess, usable, degree)
    first_basis = torch.where(powers > 0, powers * x[:, None] ** (powers - 1).clamp_min(0), 0.0) / scale
    second_basis = powers * (powers - 1) * x[:, None] ** (powers - 2).clamp_min(0) / scale**2
    dtype = video.dtype

    def evaluate(b: Tensor) -> Tensor:
        return torch.einsum("tn,bnhw->bthw", b.to(dtype), coefficients)

    result = TSRResult(
        coefficients,
        centre,
        scale,
        evaluate(basis),
        evaluate(first_basis),
        evaluate(second_basis),
        usable.sum(1),
    )
    return result if batched else _unbatch(result)


def _weighted_fit(basis: Tensor, values: Tensor, usable: Tensor, degree: int) -> Tensor:
    """Least-squares coefficients ``(B, n, H, W)`` of ``values`` ``(B, T, H, W)`` on ``basis`` ``(T, n)``,
    each pixel over its ``usable`` samples (one pseudo-inverse when every sample is usable)."""
    b, t, h, w = values.shape
    flat, ok = values.reshape(b, t, h * w), usable.reshape(b, t, h * w)
    dtype = values.dtype
    if bool(ok.all()):
        return (torch.linalg.pinv(basis).to(dtype) @ flat).reshape(b, degree + 1, h, w)
    counts = ok.sum(1)
    if int(counts.min()) <= degree:
        raise ValueError(
            f"every pixel needs more than degree = {degree} samples above the baseline, got "
            f"{int(counts.min())} at a pixel; lower the baseline or the degree"
        )
    weight = ok.to(torch.float64)  # (B, T, P)
    gram = torch.einsum("btp,ti,tj->bpij", weight, basis, basis)
    moment = torch.einsum("btp,ti->bpi", weight * flat.to(torch.float64), basis)
    solved = torch.linalg.solve(gram, moment[..., None])[..., 0]  # (B, P, n)
    return solved.transpose(1, 2).reshape(b, degree + 1, h, w).to(dtype)


def _as_map(value: float | Tensor, video: Tensor, name: str) -> Tensor:
    """A number or a map as ``(B, H, W)`` on the video's device and dtype."""
    b, _, h, w = video.shape
    if not isinstance(value, Tensor):
        return torch.full((b, h, w), float(value), device=video.device, dtype=video.dtype)
    if value.shape not in ((h, w), (b, h, w), ()):
        raise ValueError(f"{name} must be a number or have shape ({h}, {w}) or ({b}, {h}, {w}), got "
                         f"{tuple(value.shape)}")  # fmt: skip
    return value.to(device=video.device, dtype=video.dtype).expand(b, h, w)


def _unbatch(result: TSRResult | PCTResult | PPTResult) -> TSRResult | PCTResult | PPTResult:
    fields = {
        name: (value[0] if isinstance(value, Tensor) and name != "frequencies" else value)
        for name, value in vars(result).items()
    }
    return type(result)(**fields)


# ------------------------------------------------------------------------------------------------- PCT
@dataclass(frozen=True)
class PCTResult:
    """Output of :func:`pct`.

    Attributes:
        maps: the spatial components (empirical orthogonal functions over the pixels), unit norm,
            ``(..., K, H, W)``; each oriented so that its map is skewed towards positive values (a small
            region that differs, such as a defect, then reads positive).
        time_components: the matching temporal components (unit norm), ``(..., K, T)``.
        variance: the share of the standardised video's variance each component holds, ``(..., K)``.
    """

    maps: Tensor
    time_components: Tensor
    variance: Tensor


def pct(frames: Tensor, *, components: int = 6, standardise: str = "pixel") -> PCTResult:
    """Principal component thermography: the SVD of the standardised (time x pixels) matrix.

    Args:
        frames: temperatures, ``(T, H, W)`` or ``(B, T, H, W)``.
        components: how many components to return (at most ``min(T, H W)``).
        standardise: one of :data:`PCT_STANDARDISE`.

    Returns:
        :class:`PCTResult`, the components in decreasing order of variance.

    Raises:
        ValueError: bad shapes, non-finite frames, an unknown ``standardise``, too many components.

    Shape:
        as in :class:`PCTResult`.
    """
    video, batched = _video(frames)
    components = check_int(components, "components", 1)
    check_choice(standardise, "standardise", PCT_STANDARDISE)
    b, t, h, w = video.shape
    if components > min(t, h * w):
        raise ValueError(f"components must be at most min(T, H W) = {min(t, h * w)}, got {components}")
    matrix = video.reshape(b, t, h * w)
    if standardise == "frame":
        matrix = matrix - matrix.mean(2, keepdim=True)
        matrix = matrix / matrix.std(2, keepdim=True).clamp_min(torch.finfo(video.dtype).tiny)
    else:
        matrix = matrix - matrix.mean(1, keepdim=True)
        if standardise == "pixel":
            matrix = matrix / matrix.std(1, keepdim=True).clamp_min(torch.finfo(video.dtype).tiny)
    u, s, vh = _svd(matrix, components)
    maps, eofs = vh, u.transpose(1, 2)
    centred = maps - maps.mean(2, keepdim=True)
    sign = torch.where((centred**3).sum(2) < 0, -1.0, 1.0).to(video.dtype)  # positive skew
    variance = s**2 / (matrix**2).sum((1, 2))[:, None]
    result = PCTResult(
        (maps * sign[..., None]).reshape(b, components, h, w), eofs * sign[..., None], variance
    )
    return result if batched else _unbatch(result)


def _svd(matrix: Tensor, k: int) -> tuple[Tensor, Tensor, Tensor]:
    """The ``k`` leading singular triplets of ``(B, T, P)`` matrices through the smaller Gram matrix (its
    eigenvectors in float64: a long recording's Gram matrix is cheaper than the full SVD)."""
    wide = matrix.shape[1] <= matrix.shape[2]
    a = matrix.to(torch.float64)
    gram = a @ a.transpose(1, 2) if wide else a.transpose(1, 2) @ a
    values, vectors = torch.linalg.eigh(gram)
    values, vectors = values.flip(-1)[:, :k].clamp_min(0), vectors.flip(-1)[:, :, :k]
    s = values.sqrt()
    other = (
        (a.transpose(1, 2) if wide else a) @ vectors / s.clamp_min(torch.finfo(torch.float64).tiny)[:, None]
    )
    u, v = (vectors, other) if wide else (other, vectors)
    dtype = matrix.dtype
    return u.to(dtype), s.to(dtype), v.transpose(1, 2).to(dtype)


# ------------------------------------------------------------------------------------------------- PPT
@dataclass(frozen=True)
class PPTResult:
    """Output of :func:`ppt`.

    Attributes:
        phase: the phase of each pixel's transform in rad, in ``(-pi, pi]``, ``(..., K, H, W)``.
        amplitude: its modulus (data units), ``(..., K, H, W)``.
        frequencies: the frequencies in Hz, ``(K,)``: ``k / (N dt)`` for ``k = 1 .. K``.
    """

    phase: Tensor
    amplitude: Tensor
    frequencies: Tensor


def ppt(frames: Tensor, dt: float, *, frequencies: int = 8, frames_used: int | None = None) -> PPTResult:
    """Pulsed phase thermography: the phase of the discrete Fourier transform of each pixel over time.

    ``X_k = sum_n T_n exp(-2 pi i k n / N)`` over the first ``N = frames_used`` frames; the phase of
    ``X_k`` at the ``frequencies`` lowest non-zero frequencies. A constant (the temperature before the
    flash) does not change it; a flash brighter at one pixel scales that pixel's whole signal and leaves its
    phase alone.

    Args:
        frames: temperatures, ``(T, H, W)`` or ``(B, T, H, W)``.
        dt: frame period in s.
        frequencies: how many frequencies (from the lowest non-zero one).
        frames_used: the first frames transformed (truncating the recording sets the frequency
            resolution ``1 / (N dt)``); default all.

    Returns:
        :class:`PPTResult`.

    Raises:
        ValueError: bad shapes, non-finite frames, a non-positive ``dt``, more frequencies than
            ``N / 2``.

    Shape:
        as in :class:`PPTResult`.
    """
    video, batched = _video(frames)
    if isinstance(dt, bool) or not isinstance(dt, int | float) or not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number in s, got {dt!r}")
    count = video.shape[1] if frames_used is None else check_int(frames_used, "frames_used", 2)
    if count > video.shape[1]:
        raise ValueError(f"frames_used must be at most the {video.shape[1]} frames, got {count}")
    frequencies = check_int(frequencies, "frequencies", 1)
    if frequencies > count // 2:
        raise ValueError(f"frequencies must be at most N / 2 = {count // 2} for N = {count} frames, got "
                         f"{frequencies}")  # fmt: skip
    spectrum = torch.fft.rfft(video[:, :count], dim=1)[:, 1 : frequencies + 1]
    freq = torch.arange(1, frequencies + 1, device=video.device, dtype=video.dtype) / (count * dt)
    result = PPTResult(spectrum.angle().to(video.dtype), spectrum.abs().to(video.dtype), freq)
    return result if batched else _unbatch(result)
