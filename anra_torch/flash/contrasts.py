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

from anra_torch.checks import as_video, check_choice, check_int, spacing_in_range

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


def _flash_times(times: Tensor, video: Tensor, degree: int) -> Tensor:
    """:func:`tsr`'s ``times`` checked, float64 on the video's device."""
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
    return times


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
        ValueError: bad shapes, non-finite frames or baseline, times not positive, a pixel with fewer
            usable samples than ``degree + 1`` (its baseline is above its signal).

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
    times = _flash_times(times, video, degree)
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
    """A number or a map as ``(B, H, W)`` on the video's device and dtype, finite there."""
    b, _, h, w = video.shape
    if not isinstance(value, Tensor):
        value = torch.tensor(float(value), device=video.device, dtype=torch.float64)
    if value.shape not in ((h, w), (b, h, w), ()):
        raise ValueError(f"{name} must be a number or have shape ({h}, {w}) or ({b}, {h}, {w}), got "
                         f"{tuple(value.shape)}")  # fmt: skip
    converted = value.to(device=video.device, dtype=video.dtype)
    if not bool(torch.isfinite(converted).all()):
        largest = torch.finfo(video.dtype).max
        raise ValueError(
            f"{name} must be finite (within +-{largest:.3g} in {video.dtype}), got non-finite values"
        )
    return converted.expand(b, h, w)


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
        :class:`PCTResult`, the components in decreasing order of variance; a component beyond the
        standardised video's rank (no variance left) is zero, map and time alike, with variance 0.

    Raises:
        ValueError: bad shapes, non-finite frames, an unknown ``standardise``, too many components, a single
            pixel with ``"frame"``, a video in which nothing varies after standardising (no component).

    Shape:
        as in :class:`PCTResult`.
    """
    video, batched = _video(frames)
    components = check_int(components, "components", 1)
    check_choice(standardise, "standardise", PCT_STANDARDISE)
    b, t, h, w = video.shape
    if components > min(t, h * w):
        raise ValueError(f"components must be at most min(T, H W) = {min(t, h * w)}, got {components}")
    if standardise == "frame" and h * w < 2:
        raise ValueError(f"standardise='frame' needs at least 2 pixels per frame, got {h} x {w}")
    # float64 throughout, each video scaled to a largest magnitude of 1: no square over- or underflows
    matrix = video.reshape(b, t, h * w).to(torch.float64)
    tiny = torch.finfo(torch.float64).tiny
    if standardise == "frame":
        matrix = matrix - matrix.mean(2, keepdim=True)
        matrix = matrix / matrix.std(2, keepdim=True).clamp_min(tiny)
    else:
        matrix = matrix - matrix.mean(1, keepdim=True)
        if standardise == "pixel":
            matrix = matrix / matrix.std(1, keepdim=True).clamp_min(tiny)
    matrix = matrix / matrix.abs().amax((1, 2), keepdim=True).clamp_min(tiny)
    total = (matrix**2).sum((1, 2))
    if not bool((total > 0).all()):
        k = int((total > 0).logical_not().nonzero()[0])
        raise ValueError(
            f"frames{f' of video {k}' if batched else ''} do not vary after standardise={standardise!r} "
            "(a constant video): PCT has no component"
        )
    u, s, vh = _svd(matrix, components)
    maps, eofs = vh, u.transpose(1, 2)
    centred = maps - maps.mean(2, keepdim=True)
    sign = torch.where((centred**3).sum(2) < 0, -1.0, 1.0).to(matrix.dtype)  # positive skew
    variance = s**2 / total[:, None]
    maps = (maps * sign[..., None]).reshape(b, components, h, w)
    dtype = video.dtype
    result = PCTResult(maps.to(dtype), (eofs * sign[..., None]).to(dtype), variance.to(dtype))
    return result if batched else _unbatch(result)


def _svd(matrix: Tensor, k: int) -> tuple[Tensor, Tensor, Tensor]:
    """The ``k`` leading singular triplets of float64 ``(B, T, P)`` matrices through the smaller Gram
    matrix (a long recording's Gram matrix is cheaper than the full SVD); a triplet whose singular value is
    zero to rounding (beyond the rank) is zero."""
    wide = matrix.shape[1] <= matrix.shape[2]
    a = matrix
    gram = a @ a.transpose(1, 2) if wide else a.transpose(1, 2) @ a
    values, vectors = torch.linalg.eigh(gram)
    values, vectors = values.flip(-1)[:, :k], vectors.flip(-1)[:, :, :k]
    rank = values > values[:, :1] * torch.finfo(torch.float64).eps * max(a.shape[1:])  # above its rounding
    s = torch.where(rank, values, 0.0).sqrt()
    vectors = vectors * rank[:, None]
    other = (a.transpose(1, 2) if wide else a) @ vectors / torch.where(rank, s, 1.0)[:, None]
    u, v = (vectors, other) if wide else (other, vectors)
    return u, s, v.transpose(1, 2)


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
        ValueError: bad shapes, non-finite frames, a ``dt`` that is not positive or outside
            :data:`~anra_torch.checks.SPACING_RANGE`, more frequencies than ``N / 2``.

    Shape:
        as in :class:`PPTResult`.
    """
    video, batched = _video(frames)
    if isinstance(dt, bool) or not isinstance(dt, int | float) or not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number in s, got {dt!r}")
    spacing_in_range(float(dt), "dt", "s")
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
