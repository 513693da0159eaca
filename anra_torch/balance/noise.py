"""The sensor noise measured from the video itself: its level (:func:`estimate_noise_sd`) and its model
(:func:`measure_noise`: correlation in time and space, a white component, a static pattern)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance.noise_model import NoiseModel
from anra_torch.balance.robust import (
    _GAIN,
    _MAD_TO_SD,
    _TAPS,
    PixelStats,
    _fourth_difference,
    _robust_var,
    _taps_sum,
    fourth_difference,
    pixel_stats,
    robust_sd,
    row_medians,
)
from anra_torch.checks import as_video

__all__ = ["estimate_noise_sd", "measure_noise"]

_NOISE_SAMPLE = 2**20
"""Values behind each axis' median of :func:`estimate_noise_sd` (a video holding more is read in evenly
spaced frames or rows): the median absolute deviation of a million values is within 0.1 % of its limit,
far inside the level's own error over a real recording."""


def estimate_noise_sd(frames: Tensor, *, mask: Tensor | None = None) -> Tensor:
    """Robust estimate of white sensor noise (units of the data), per video.

    The median absolute fourth difference along x, y and t (each scaled to a standard deviation by the
    filter gain and the normal MAD constant), over at most about :data:`_NOISE_SAMPLE` values per axis
    (evenly spaced frames, or rows for t); the median of the three axis estimates is returned, so one
    axis dominated by fast signal (e.g. a slow frame rate) does not inflate it. Non-finite pixels and
    ``mask == False`` pixels are ignored.

    Args:
        frames: video ``(T, H, W)`` or ``(B, T, H, W)``.
        mask: optional boolean, True for usable pixels, same shape as ``frames``.

    Returns:
        Noise standard deviation, shape ``(B,)`` (or a 0-d tensor for a single video).

    Shape:
        ``(B, T, H, W)`` -> ``(B,)``.
    """
    video, batched = as_video(frames, name="frames")
    # One sum tells a video without non-finite samples (inf and NaN carry through it): no masks then.
    everywhere = mask is None and bool(torch.isfinite(video.sum()))
    finite = None
    if not everywhere:
        finite = torch.isfinite(video)
        if mask is not None:
            finite = finite & mask.reshape(video.shape).to(torch.bool)
        everywhere = bool(finite.all())
    clean = video if everywhere else torch.where(finite, video, torch.zeros_like(video))
    estimates = []
    for dim in (1, 2, 3):
        if video.shape[dim] < 5:
            continue
        # Evenly spaced whole frames (rows, for the time axis) holding about _NOISE_SAMPLE values: what the
        # median needs, read as contiguous slices.
        step = max(1, math.ceil(clean[0].numel() / _NOISE_SAMPLE))
        index = (slice(None),) * (2 if dim == 1 else 1) + (slice(None, None, step),)
        part, part_finite = clean[index], None if finite is None else finite[index]
        if everywhere:  # no NaN to skip: the plain median is the same number, without a masked copy
            median = row_medians(_taps_sum(part, dim, 1).abs_().flatten(1))
        else:
            diff, ok = _fourth_difference(part, part_finite, dim)
            median = row_medians(diff.abs().flatten(1), ok.flatten(1))
        estimates.append(median * (_MAD_TO_SD / _GAIN))
    if not estimates:
        raise ValueError(
            f"frames must be at least 5 long along some axis to estimate noise, got {tuple(video.shape)}"
        )
    stacked = torch.stack(estimates, dim=1)
    stacked = torch.nan_to_num(stacked, nan=0.0)
    sd = stacked.median(dim=1).values if stacked.shape[1] != 2 else stacked.mean(dim=1)
    return sd if batched else sd[0]


_CORRELATED = 0.1  # rho_t(1) or rho_s(1) above this: the noise is measured as correlated
_MAX_TIME_LAG = 10
_MIN_CORRELATED_FRAMES = 20
"""Fewest frames in which noise is measured as correlated. Each pixel's time mean removes ``S / t`` of the
variance (``S = 1 + 2 sum rho``, 4-8 for camera noise): over a third in 12 frames, where only 3 lags are
measured, and the thermal field's own changes are not told from correlated noise. On the 12 frames of a
real laser cooling phase a correlated model (``rho_t`` 0.76, 0.49, 0.37 and 0.95 px) took the plain
diffusivity from 0.091 to 0.227 mm^2/s, with a standard error of 0.0002. Shorter videos are taken as white
(a fixed pattern is still measured: it is the noise's static part there)."""
_MAX_LENGTH = 3.0  # px: noise correlated this far (where the fitted lengths end) is not told from the field
_MAX_FRAMES = 6.0  # frames: the same in time (a Gaussian correlation of this length is 0.25 at lag 10)


def _gain(stride: int, length: float) -> float:
    """Variance of a stride-``stride`` fourth difference of unit noise with Gaussian correlation."""
    if length == 0:
        return 70.0
    rho = [math.exp(-((stride * m) ** 2) / (2 * length**2)) for m in range(5)]
    return 70 - 112 * rho[1] + 56 * rho[2] - 16 * rho[3] + 2 * rho[4]


_QUIET_SAMPLE = 50_000
"""Values behind each robust variance of :func:`measure_noise`: its relative error is then about 1 %, far
below the tenth of the variance that tells a correlated component from white noise."""


def _quiet_var(frames: Tensor, quiet: Tensor, dim: int, stride: int, *, mean: Tensor | None = None) -> float:
    """:func:`_robust_var` of the stride-``stride`` fourth difference of ``frames`` (``(T, H, W)``) along
    ``dim`` at the ``quiet`` pixels (``(H, W)``, centred on the difference), over evenly spaced frames
    holding about :data:`_QUIET_SAMPLE` values (each frame's difference is its own: no other is computed).
    With ``mean`` (``(H, W)``), of the deviations ``frames - mean`` of those frames, in ``mean``'s dtype."""
    n = frames.shape[dim] - 4 * stride
    centre = quiet.narrow(dim, 2 * stride, n)
    step = max(1, frames.shape[0] * int(centre.sum()) // _QUIET_SAMPLE)
    chosen = frames[::step] if mean is None else frames[::step].to(mean.dtype) - mean
    return robust_sd(fourth_difference(chosen, dim, stride)[:, centre], sample=None) ** 2


_QUIET_WINDOW = 9  # px: the window over which a pixel's deviation power is averaged


def _quiet_pixels(power: Tensor) -> Tensor:
    """The quieter half of the pixels ``(H, W)``: those whose deviation power ``power`` (``(H, W)``, the
    mean square of their deviations from their time mean), averaged over the
    :data:`_QUIET_WINDOW` px around them, is at most its median. The average keeps the choice on the
    thermal field's structure: ranking single pixels would also pick those whose noise happened to be low
    (with noise correlated over 3 frames, a pixel's power over 81 frames varies by about 40 %, and the
    quieter half's variance came out 15 % low)."""
    pad = _QUIET_WINDOW // 2
    padded = F.pad(power[None, None], (pad, pad, pad, pad), mode="replicate")
    local = F.avg_pool2d(padded, _QUIET_WINDOW, stride=1)[0, 0]
    return local <= row_medians(local.reshape(1, -1))[0]


def _high_pass(
    deviation: Tensor, quiet: Tensor, stride: int, sample: int | None, mean: Tensor | None = None
) -> Tensor:
    """Stride-``stride`` fourth differences along y and x of ``deviation`` (``(T, H, W)``) at the ``quiet``
    pixels, every frame: ``(T, N)``. With ``sample``, in evenly spaced rows holding about that many quiet
    pixels per axis (whole rows: contiguous reads), where ``deviation`` may be the frames themselves and
    ``mean`` their time mean (``(H, W)``), subtracted from each difference."""
    if sample is None:
        parts = []
        for dim in (-2, -1):
            h = fourth_difference(deviation, dim, stride)
            parts.append(h[:, quiet.narrow(dim, 2 * stride, h.shape[dim])])
        return torch.cat(parts, 1)
    t, height, width = deviation.shape
    reach = 2 * stride
    fraction = max(float(quiet.float().mean()), 1.0 / quiet.numel())
    parts = []
    for dim in (-2, -1):
        first, last = (reach, height - reach) if dim == -2 else (0, height)
        count = max(1, min(last - first, math.ceil(sample / (fraction * width))))
        rows = torch.arange(first, last, max(1, (last - first) // count), device=deviation.device)
        if dim == -2:  # the five rows of each difference, whole
            taps = [deviation[:, rows + (i - 2) * stride] for i in range(5)]
            level = None if mean is None else fourth_difference(mean, -2, stride)[rows - reach]
            keep = quiet[rows]
        else:
            inner = width - 2 * reach
            taps = [deviation[:, rows, i * stride : i * stride + inner] for i in range(5)]
            level = None if mean is None else fourth_difference(mean[rows], -1, stride)
            keep = quiet[rows, reach : reach + inner]
        out = taps[0] * _TAPS[0]
        for tap, values in zip(_TAPS[1:], taps[1:], strict=True):
            out.add_(values, alpha=tap)
        if level is not None:  # the time mean's own difference, the same at every frame
            out.sub_(level.to(out.dtype))
        parts.append(out[:, keep])
    return torch.cat(parts, 1)


def _time_correlation(
    deviation: Tensor,
    quiet: Tensor,
    *,
    stride: int = 1,
    white_ratio: float = 0.0,
    sample: int | None = None,
    mean: Tensor | None = None,
) -> tuple[float, ...]:
    """``rho_t(1 .. m)`` of the correlated noise, from a spatial high-pass: temporal autocorrelation of
    stride-``stride`` fourth differences along x and y (they remove the smooth thermal field) of the
    frames' ``deviation`` from their pixel's time mean, over the ``quiet`` pixels (where the thermal field
    does not leak in), or about ``sample`` of them per axis (``mean``: see :func:`_high_pass`).
    ``white_ratio`` is a white component's variance over the correlated one's in that high-pass of the
    deviations: it adds to lag 0 alone, and the time mean removes ``1 / t`` of it from every lag."""
    t = deviation.shape[0]
    lags = min(_MAX_TIME_LAG, t // 4)
    flat = _high_pass(deviation, quiet, stride, sample, mean)
    zero = float(torch.tensordot(flat, flat))
    if zero == 0 or lags < 1:
        return ()
    raw = [float(torch.tensordot(flat[:-k], flat[k:])) / zero * t / (t - k) for k in range(1, lags + 1)]
    # Each pixel's mean over t frames removes S / t (S = 1 + 2 sum rho) of the correlated part from every
    # lag's covariance, zero included, and 1 / t of a white part: with q the two parts' ratio in the
    # deviations, raw = (rho - S / t - q (1 - S / t) / (t - 1)) / ((1 - S / t) (1 + q)). S depends on rho
    # itself: solved by fixed-point iteration (a contraction while 2 sum (1 - raw) < t), which the raw
    # correlations alone would underestimate (rho_t(3) 0.57 for 0.61 on 41 frames of noise correlated over
    # 3 frames). Scaling by 1 + q after the mean's correction instead put rho_t(1) at 0.98 for 0.946 on 41
    # frames with a white part of half the correlated sd, and at 0.99 (taken for an undecayed thermal
    # field, so the noise for white) in a third of them.
    q = white_ratio
    rho = list(raw)
    for _ in range(50):
        share = min(0.9, (1 + 2 * sum(max(r, 0.0) for r in rho)) / t)
        new = [(1 - share) * (r * (1 + q) + q / (t - 1)) + share for r in raw]
        done = max(abs(a - b) for a, b in zip(new, rho, strict=True)) < 1e-9
        rho = new
        if done:
            break
    while rho and rho[-1] < 0.02:
        rho.pop()
    return tuple(rho)


def measure_noise(
    frames: Tensor,
    *,
    static_pattern: bool = False,
    white_sd: float | None = None,
    stats: PixelStats | None = None,
) -> NoiseModel:
    """The noise model of one (artefact-free) video, measured from the video itself.

    From the frames' deviations from their pixel's time mean (no static pattern, no static thermal field
    there), over the quieter half of the pixels: the variances of fourth differences at strides 1, 2 and 3
    separate a white component from a Gaussian-correlated one and give its length
    (:func:`_components`); the temporal autocorrelation of the high-pass gives the correlated part's
    ``rho_t``. When no component is correlated (in space, or at one lag in time by :data:`_CORRELATED`),
    the noise is white and its level is :func:`estimate_noise_sd` (the estimate used for white noise
    everywhere), unless the video has a static pattern (``static_pattern``), which the spatial differences
    of :func:`estimate_noise_sd` would count as noise: then the level comes from the deviations alone, and
    the pattern's parts from :func:`_static_parts`. ``white_sd`` is that white estimate when the caller
    has it already (one full pass over the video less), ``stats`` the frames'
    :class:`~anra_torch.balance.robust.PixelStats` likewise. A sampled screen (:func:`_clearly_white`) settles
    the common case, white noise, before any full-size copy.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    t, h, w = frames.shape
    short = t < 8 or min(h, w) < 12 or (t < _MIN_CORRELATED_FRAMES and not static_pattern)
    white_only = short or (not static_pattern and _clearly_white(frames, stats))
    video = frames if white_only and white_sd is not None else frames.double()
    white = NoiseModel(float(estimate_noise_sd(video)) if white_sd is None else float(white_sd))
    if white_only:
        return white
    deviation = video - video.mean(0)
    # Over the quieter half of the pixels (the least thermal signal in their deviations): ranked pixel by
    # pixel to decide whether the noise is white (the guards against thermal signal below were set on that
    # choice), then, for a correlated or static model, by the power around each pixel for its parts.
    power = deviation.pow(2).mean(0)
    model = _model_over(
        video, deviation, power <= row_medians(power.reshape(1, -1))[0], white, static_pattern
    )
    if model.white:
        return model
    local = _model_over(video, deviation, _quiet_pixels(power), white, static_pattern)
    return model if local.white else local


_SCREEN_SAMPLE = 4096
"""Quiet pixels per axis whose high-pass the screen correlates in time, every frame: about 2 x 4096 x T
values, a lag correlation to about 0.003 for 28 frames."""
_SCREEN_CORRELATION = 0.06  # rho_t(1) under this: clearly white in time (the rule is _CORRELATED, 0.1)


def _clearly_white(frames: Tensor, stats: PixelStats | None = None) -> bool:
    """Whether :func:`_model_over` on the pixel-ranked quiet half would find white noise, told without a
    full-size copy: the spatial components from the same differences of the same frames (the deviations
    computed at those frames only), and the time correlation over :data:`_SCREEN_SAMPLE` quiet pixels per
    axis instead of all of them, with a margin (:data:`_SCREEN_CORRELATION`) far beyond the sample's
    error. False sends the video to the full model; a correlated component in space always does."""
    video = frames if frames.is_floating_point() else frames.double()
    t, h, w = video.shape
    stats = pixel_stats(video) if stats is None else stats
    mean, quiet = stats.mean64, stats.quiet
    v = [[_quiet_var(video, quiet, d, s, mean=mean) for d in (-2, -1)] for s in (1, 2)]
    rounding = 100 * torch.finfo(torch.float64).eps * float(video.abs().amax())
    if min(v[0]) <= 70 * rounding**2:
        return True  # noiseless: white, as the full model finds
    v.append([_quiet_var(video, quiet, d, 3, mean=mean) for d in (-2, -1)] if min(h, w) >= 24 else v[1])
    if _components(*(sum(x) / 2 for x in v))[2] > 0:
        return False
    rho = _time_correlation(video, quiet, stride=1, sample=_SCREEN_SAMPLE, mean=mean.to(video.dtype))
    return not rho or rho[0] < _SCREEN_CORRELATION


def _model_over(
    video: Tensor, deviation: Tensor, quiet: Tensor, white: NoiseModel, static_pattern: bool
) -> NoiseModel:
    """:func:`measure_noise` over the ``quiet`` pixels ``(H, W)``; ``white`` where the noise is white."""
    t, h, w = video.shape
    v1 = [_quiet_var(deviation, quiet, d, 1) for d in (-2, -1)]
    v2 = [_quiet_var(deviation, quiet, d, 2) for d in (-2, -1)]
    rounding = 100 * torch.finfo(video.dtype).eps * float(video.abs().amax())  # a noiseless video
    if min(v1) <= 70 * rounding**2:
        return white
    v3 = [_quiet_var(deviation, quiet, d, 3) for d in (-2, -1)] if min(h, w) >= 24 else v2
    white_part, correlated_part, length = _components(sum(v1) / 2, sum(v2) / 2, sum(v3) / 2)
    # The lag products hold the correlated part alone; the white part adds to lag 0 only.
    white_ratio = 70 * white_part / (_gain(3, length) * correlated_part) if length > 0 else 0.0
    rho_t = _time_correlation(deviation, quiet, stride=3 if length > 0 else 1, white_ratio=white_ratio)
    rho_t = tuple(min(1.0, r) for r in rho_t)
    lags = min(_MAX_TIME_LAG, t // 4)
    # A correlation that decays more slowly than a Gaussian of _MAX_FRAMES frames is the thermal field's: on
    # a 32 px video of a slow field, 0.94 at lag 1 but 0.41 at lag 10 (noise over 3 frames: 0.004).
    slow = math.exp(-(lags**2) / (2 * _MAX_FRAMES**2))
    undecayed = bool(rho_t) and (rho_t[0] >= 0.99 or (len(rho_t) >= lags and rho_t[-1] > slow))
    if length >= _MAX_LENGTH or undecayed:
        # Thermal signal, not noise, dominates the differences (a nearly noiseless or a short video): a
        # correlation that does not decay within the lags measured cannot be told from the field.
        if not static_pattern:
            return white
        # With a fixed pattern, white's level (spatial differences of the frames) holds the pattern too:
        # the level comes from the deviations' differences below, as for white noise beside a pattern
        # (tests/test_artefacts.py -k changing_field: 3.1 noise sds before, and no static part).
        rho_t, length = (), 0.0
    time = rho_t if rho_t and rho_t[0] >= _CORRELATED else ()
    if not time and length == 0 and not static_pattern:
        return white
    keep_white = 1 - 1 / t  # the time mean removed that much of each sample's variance
    keep = 1 - (1 + 2 * sum(time)) / t
    if length == 0:  # one component, white in space: its variance from the stride-1 differences
        variance, white_var = 0.5 * sum(v1) / (70 * keep), 0.0
    else:
        variance, white_var = correlated_part / keep, white_part / keep_white
    averaged = _gain(1, length) * variance * (1 - keep) + 70 * white_var * (1 - keep_white)
    static = _static_parts(video, quiet, averaged) if static_pattern else {}
    return NoiseModel(
        math.sqrt(variance), time_corr=time, space_length=length, white_sd=math.sqrt(white_var), **static
    )


def _components(v1: float, v2: float, v3: float) -> tuple[float, float, float]:
    """Variances of a white and a Gaussian-correlated component and the latter's length in px from the
    variances of fourth differences at strides 1, 2 and 3 (``70 white + gain_s(length) correlated``).

    Least squares over a grid of lengths (:func:`_best_fit`); a correlated component under a tenth of the
    total, or a length under half a pixel (its correlation at one pixel under 0.14), is counted as white
    (length 0).
    """
    fit = _best_fit(v1, v2, v3)
    if fit is None or fit[1] < 0.1 * (fit[0] + fit[1]):
        return v1 / 70, 0.0, 0.0
    return fit


def _best_fit(v1: float, v2: float, v3: float) -> tuple[float, float, float] | None:
    """The white and correlated variances and the length of the best fit of :func:`_components`, before
    its rule; None where no fit is finite."""
    observed = torch.tensor([v1, v2, v3], dtype=torch.float64, device="cpu")
    design = _DESIGN
    solution = torch.linalg.lstsq(design, observed.expand(len(_LENGTHS), 3)[..., None]).solution[..., 0]
    solution = solution.clamp_min(0)
    residual = (((design @ solution[..., None])[..., 0] - observed) / observed).pow(2).sum(-1)
    best = int(residual.argmin())  # the first of equal residuals, as a scan would keep
    if not float(residual[best]) < float("inf"):
        return None
    return float(solution[best, 0]), float(solution[best, 1]), _LENGTHS[best]


_LENGTHS = [0.05 * k for k in range(10, 61)]
_DESIGN = torch.tensor(
    [[[70.0, _gain(s, length)] for s in (1, 2, 3)] for length in _LENGTHS], dtype=torch.float64, device="cpu"
)  # (lengths, 3, 2): every length's least squares in one batched solve


def _static_parts(video: Tensor, quiet: Tensor, averaged: float) -> dict[str, float]:
    """The fixed pattern's sd per pixel, per column and per row in data units, from the time-mean frame.

    Fourth differences of the time-mean frame along x hold the per-pixel and per-column parts, along y the
    per-pixel and per-row parts (each with ``averaged``, what the temporal noise leaves in a fourth
    difference of the mean); fourth differences of the column means (row means) hold the column (row)
    part alone. Over the quieter half of the pixels (:func:`measure_noise`), where no thermal structure is.
    """
    mean = video.mean(0)
    along = {d: max(0.0, _quiet_var(mean[None], quiet, d, 1) - averaged) / 70 for d in (-2, -1)}
    rows_quiet = quiet.float().mean(1) >= 0.5  # rows (columns) that are mostly quiet
    cols_quiet = quiet.float().mean(0) >= 0.5
    column = (
        _robust_var(fourth_difference(mean[rows_quiet].mean(0), -1, 1)) / 70 if int(rows_quiet.sum()) else 0.0
    )
    row = (
        _robust_var(fourth_difference(mean[:, cols_quiet].mean(1), -1, 1)) / 70
        if int(cols_quiet.sum())
        else 0.0
    )
    # A part counts when it holds at least a tenth of the pattern's variance along its axis.
    column = column if column > 0.1 * along[-1] else 0.0
    row = row if row > 0.1 * along[-2] else 0.0
    pixel = max(0.0, 0.5 * (along[-1] - column + along[-2] - row))
    return {"static_sd": math.sqrt(pixel), "column_sd": math.sqrt(column), "row_sd": math.sqrt(row)}
