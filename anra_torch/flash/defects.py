"""The defect map of a flash recording: per pixel, the through-thickness time constant its cooling says.

Per pixel, ``ln u`` (``u = T - T_ref``, the frames smoothed by 1 px) less the lateral conduction the
frames show (:mod:`~anra_torch.flash.lateral`: a non-uniform flash and the anisotropy spread heat
sideways, not into depth) is fitted by the insulated plate's cooling ``c + g(t; tau)``
(:mod:`~anra_torch.flash.cooling`) over the times up to ``window tau`` (where the heat stops: the back
wall, or a defect above it, whose layer is a thinner plate with ``tau = d^2 / a_z``), the window grown
with the pixel's own ``tau``. The frames' shared unknowns, the temperature the plate cools to
(``T_ref``) and the flash's time before the first frame, are fitted to all pixels; the lateral
diffusivities to the sound plate and to each region of equal depth, in turns with the map.

From the map: the plate's ``L^2 / a_z`` (the median of the sound pixels; front-face data fix only this
ratio, not ``L`` or ``a_z``) with its standard error over tiles of the frame; defects where ``tau`` is
significantly shorter than the plate's, each outlined where its log contrast ``ln(plate / tau)``, averaged
over the value's smoothing (1 px: each pixel's own fit is noisy, and the 95 % quantile of a noisy region
reads high), is above 0.6 of its peak (:mod:`~anra_torch.flash.outlines`) with its depth fraction
``d / L = sqrt(tau / plate)`` at the peak (the 95 % quantile), ``tau`` corrected for the sideways spread
of the heat the defect reflects (:mod:`~anra_torch.flash.spread`: a small deep defect otherwise reads
deeper).

Assumptions (each one a way for a recording to break the map): an instantaneous flash absorbed at the
surface, smooth across the frame; a plate of uniform thickness and diffusivity (lateral anisotropy with
axes anywhere) insulated on both faces over the recording (no loss to the air); defects planar, parallel
to the surface, that stop the heat; one ``T_ref`` for the whole frame; white camera noise. The results
page (docs/results/flash.md) measures it on plates from an independent simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from anra_torch.balance import estimate_noise_sd
from anra_torch.checks import as_video, spacing_in_range
from anra_torch.flash.cooling import (
    TauGrid,
    nelder_mead,
    profile_rss,
    smooth_minimum,
    tau_grid,
    time_bins,
    windowed_tau,
)
from anra_torch.flash.lateral import fit_lateral, lateral_integrals, local_quadratic, value_noise_gain
from anra_torch.flash.outlines import OUTLINE_SHARE, FoundDefect, outline_defects
from anra_torch.flash.regions import (
    components,
    dilate,
    edge_scatter,
    erode,
    plate_level,
    smooth,
    tile_standard_error,
)
from anra_torch.flash.spread import spread_depth_time

__all__ = ["DefectMap", "FoundDefect", "defect_map"]

_F64 = torch.float64
_SIGMA_VALUE = 1.0  # px: the smoothing of u
_SIGMA_LATERAL = 3.0  # px: the smoothing of its second derivatives
_MODEL_FLOOR = 0.003  # relative: the cooling model's own error per bin, beside the noise
_WINDOW = 0.4  # a pixel's fit reaches window * its tau
_ODD = 0.3  # |ln tau - ln plate| beyond this: another depth (the lateral fit's regions)
_CONTRAST = 0.2  # ln(plate / tau) a defect pixel exceeds (d / L < 0.9) ...
_SIGNIFICANCE = 3.0  # ... at this many standard deviations of its own fit
_SCATTER = 4.0  # a defect's peak contrast exceeds this many robust sd of the sound pixels' contrast
_MIN_PIXELS = math.ceil(math.pi * _SIGMA_LATERAL**2)  # smaller than the lateral derivatives' footprint
_SOUND_SHARE = 0.25  # a longer region this large is the sound plate (a defect only shortens tau)
_EDGE_RINGS = 10
_GRIDS_KEPT = 8  # tau grids kept per first-frame time (the globals' guesses use 5)
_ROUNDS = 3
_LONG = 2.0  # a recording longer than this many plate times: the globals fitted up to 1 / _LONG^2 of it
_BOUNDS = torch.tensor([[-9.2, -3.0], [3.4, 1.6]], device="cpu")
"""The globals' search box: ``ln`` of how far ``T_ref`` lies below the coolest pixel over the cooling's
span (1e-4 to 30), ``ln`` of the first frame's time since the flash in frame periods (0.05 to 5)."""


@dataclass(frozen=True)
class DefectMap:
    """Output of :func:`defect_map`.

    Attributes:
        depth_time: per pixel ``tau`` in s (``inf``: beyond the recording), ``(H, W)``.
        plate_time: the sound plate's ``L^2 / a_z`` in s.
        plate_time_se: its standard error in s.
        back_wall_reached: the recording lasts past ``plate_time / pi``, where the back wall shows.
        defect_score: ``ln(plate_time / tau)`` averaged over 1 px over the peak of its defect where one
            is found (about 1 in its core, 0.6 at its outline), elsewhere bounded at +-0.2 per pixel,
            averaged over 3 px and over twice the largest peak; higher = more likely a defect, ``(H, W)``.
        defect_mask: ``(H, W)`` booleans.
        depth_fraction: ``d / L`` of the defect at each pixel, NaN where sound, ``(H, W)``.
        defects: the defects found.
        lateral: ``(a_x, a_y, a_xy)`` in mm^2/s, the lateral diffusivities taken off (zeros where they
            could not be measured).
        t_ref: the temperature the plate cools to.
        first_time: the first frame's time since the flash in s.
        noise_sd: the frames' white noise sd.
    """

    depth_time: Tensor
    plate_time: float
    plate_time_se: float
    back_wall_reached: bool
    defect_score: Tensor
    defect_mask: Tensor
    depth_fraction: Tensor
    defects: tuple[FoundDefect, ...]
    lateral: tuple[float, float, float]
    t_ref: float
    first_time: float
    noise_sd: float


class _Cooling:
    """The frames averaged over time bins, smoothed, and their lateral second derivatives."""

    def __init__(self, frames: Tensor, dt: float, dx: float, noise_sd: float) -> None:
        self.dt, self.dx, self.shape, self.noise_sd = dt, dx, tuple(frames.shape), noise_sd
        self.bins = time_bins(len(frames), dt, dt)  # the bins' frames, whatever the flash's exact time
        self.frames = self.bins.average(frames)  # (N, H, W)
        self.counts = self.bins.counts.to(frames)
        self.offsets = self.bins.elapsed.to(frames) - dt  # each bin's time after the first frame
        value, _ = local_quadratic(self.frames, _SIGMA_VALUE, dx)
        _, second = local_quadratic(self.frames, _SIGMA_LATERAL, dx, cubic=True)
        self.value, self.second = value.flatten(1), second.flatten(2)  # (N, P), (3, N, P)
        self.sd = noise_sd * value_noise_gain(_SIGMA_VALUE)
        self.low = float(self.value[-1].min())  # the coolest late pixel: T_ref lies below it
        self.span = float(self.value[0].median()) - self.low
        self._grids: dict[float, TauGrid] = {}

    def grid(self, first: float) -> TauGrid:
        """:func:`~anra_torch.flash.cooling.tau_grid` at the bins' times for a first frame ``first`` s after
        the flash, kept for the globals' starting guesses (a few values of ``first`` each)."""
        if first not in self._grids:
            if len(self._grids) >= _GRIDS_KEPT:
                self._grids.clear()
            self._grids[first] = tau_grid(self.offsets + first)
        return self._grids[first]

    def series(
        self, t_ref: float, first: float, pixels: Tensor | None = None
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Per pixel and bin: ``ln u`` ``(P, N)``, the lateral integrals ``(3, P, N)``, the weights
        ``(P, N)``, and the bins' times since the flash ``(N,)``."""
        value = self.value if pixels is None else self.value[:, pixels]
        second = self.second if pixels is None else self.second[:, :, pixels]
        excess = (value - t_ref).clamp_min(torch.finfo(value.dtype).tiny)
        elapsed = self.offsets + first
        integrals = lateral_integrals(second, excess, elapsed)
        weights = self.counts[:, None] / ((self.sd / excess) ** 2 + _MODEL_FLOOR**2)
        return excess.log().T, integrals.transpose(1, 2), weights.T, elapsed

    def lateral(self, t_ref: float, first: float, labels: Tensor | None) -> tuple[Tensor, int]:
        """The lateral diffusivities and the blocks used (:func:`~anra_torch.flash.lateral.fit_lateral`)
        at ``T_ref``."""
        height, width = self.shape[1:]
        return fit_lateral(
            self.frames,
            self.offsets + first,
            self.counts,
            dx=self.dx,
            t_ref=t_ref,
            noise_sd=self.noise_sd,
            sigma=max(2.0, min(height, width) / 16),
            labels=labels,
        )


def _trimmed_rss(
    cooling: _Cooling, a: Tensor, pixels: Tensor, point: Tensor, horizon: float, profiled: bool
) -> float:
    """The sum of the best 70 % of the pixels' -2 ln(likelihood), each at its best ``tau``, at ``point`` =
    (ln of how far ``T_ref`` lies below the coolest pixel over the cooling's span, ln of the first frame's
    time in frame periods), over the bins up to ``horizon`` s; ``profiled``: each pixel's residual scale
    (at least the noise's) profiled out."""
    t_ref = cooling.low - cooling.span * math.exp(float(point[0]))
    first = cooling.dt * math.exp(float(point[1]))
    logs, integrals, weights, elapsed = cooling.series(t_ref, first, pixels)
    used = (elapsed <= max(horizon, float(elapsed[min(8, len(elapsed) - 1)])))[None, :].expand_as(weights)
    weights = torch.where(used, weights, torch.zeros_like(weights))
    grid = cooling.grid(first)
    rss = profile_rss(logs - torch.einsum("i,ipn->pn", a, integrals), weights, grid.curves)
    # -2 ln(likelihood) of the temperatures, not of ln u: the variances' logs in T, ln(u^2 / w), change
    # with T_ref too (without them a T_ref far below the frames flattens ln u and fits it at any noise)
    logs_w = torch.where(used, 2 * logs - weights.clamp_min(torch.finfo(weights.dtype).tiny).log(), 0 * logs)
    best = smooth_minimum(rss)
    if profiled:  # the scale s >= 1: n ln(rss / n) + n where rss > n
        count = used[:1].sum().to(rss)
        best = torch.where(best > count, count * (best.clamp_min(count) / count).log() + count, best)
    best = best + logs_w.sum(1)
    return float(best.sort().values[: max(1, int(0.7 * len(best)))].sum())


def _fit_globals(
    cooling: _Cooling,
    a: Tensor,
    start: tuple[float, float] | None,
    horizon: float = math.inf,
    profiled: bool = False,
) -> tuple[float, float]:
    """``T_ref`` and the first frame's time since the flash (s), by Nelder-Mead on every third pixel of
    every third row from ``start`` (or the best of a few guesses); one that runs to the search box's far end
    (a misfit, e.g. a hot layer over half the frame cooling sideways before the lateral flow is taken off,
    fitted away by the model floor's variance ``floor^2 (T - T_ref)^2``) is done again ``profiled``."""
    height, width = cooling.shape[1:]
    device = cooling.value.device
    pixels = torch.arange(height * width, device=device).view(height, width)[1::3, 1::3].flatten()

    low, high = _BOUNDS.to(_F64)

    def loss(point: Tensor) -> float:
        point = torch.maximum(torch.minimum(point, high), low)
        return _trimmed_rss(cooling, a, pixels, point, horizon, profiled)

    if start is None:
        # T_ref is the sharp direction: a fine grid along it
        below = torch.linspace(math.log(1e-3), math.log(10.0), 33, device="cpu").tolist()
        guesses = [(s, math.log(q)) for s in below for q in (0.25, 0.5, 1.0, 2.0, 4.0)]
    else:
        guesses = [
            (math.log(max((cooling.low - start[0]) / cooling.span, 1e-4)), math.log(start[1] / cooling.dt))
        ]
    points = [
        torch.maximum(torch.minimum(torch.tensor(g, dtype=_F64, device="cpu"), high), low) for g in guesses
    ]
    values = [loss(p) for p in points]
    best = points[min(range(len(points)), key=values.__getitem__)]
    point = nelder_mead(loss, best, min(values), step=0.3, tolerance=0.001, iterations=200)
    point = torch.maximum(torch.minimum(point, high), low)
    if not profiled and float(point[0]) > float(high[0]) - 0.05:
        return _fit_globals(cooling, a, None, horizon, profiled=True)
    return cooling.low - cooling.span * math.exp(float(point[0])), cooling.dt * math.exp(float(point[1]))


def _check(frames: object, dt: float, dx: float) -> Tensor:
    video, batched = as_video(frames, name="frames", min_frames=8)
    if batched:
        raise ValueError(f"frames must be one recording (T, H, W), got {tuple(video.shape)}")
    spacing_in_range(dt, "dt", "s")
    spacing_in_range(dx, "dx", "mm")
    if min(video.shape[-2:]) < 8:
        raise ValueError(f"frames must be at least 8 x 8 px for a defect map, got {tuple(video.shape[-2:])}")
    if not bool(torch.isfinite(video).all()):
        raise ValueError("frames must be finite; repair or mask the non-finite samples first")
    return video[0].to(_F64)


def _fit_pixels(
    cooling: _Cooling, a: Tensor, t_ref: float, first: float
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Each pixel's ``tau`` (:func:`~anra_torch.flash.cooling.windowed_tau`); also the residuals over the
    grid ``(P, K + 1)``, the windows' weights ``(P, N)`` and the grid's ``taus``."""
    logs, integrals, weights, elapsed = cooling.series(t_ref, first)
    return windowed_tau(logs - torch.einsum("i,ipn->pn", a, integrals), weights, elapsed, _WINDOW)


def _regions(log_tau: Tensor) -> Tensor:
    """The lateral fit's regions: the sound plate (1) and each region of another depth (2, ...), a ring
    of 3 px around each left out (0)."""
    plate = log_tau.median()
    odd = (log_tau - plate).abs() > _ODD
    labels, _ = components(odd)
    labels = labels + 1
    ring = dilate(odd, 3) & ~erode(odd, 3)
    return torch.where(ring, torch.zeros_like(labels), labels)


def defect_map(frames: Tensor, dt: float, dx: float, *, noise_sd: float | None = None) -> DefectMap:
    """Map the through-thickness time constant of a flash recording and the defects it shows.

    Args:
        frames: the cooling after the flash in C or K, the first frame after the flash first, ``(T, H, W)``.
        dt: frame period in s.
        dx: pixel size in mm.
        noise_sd: the camera's white noise sd (default: measured from the frames).

    Returns:
        :class:`DefectMap` (tensors on the frames' device, float64).

    Raises:
        ValueError: not one recording of at least 8 frames of 8 x 8 px, a spacing not positive, a
            sample not finite.

    Shape:
        ``frames`` ``(T, H, W)``; every map ``(H, W)``.
    """
    video = _check(frames, dt, dx)
    sd = float(estimate_noise_sd(video)) if noise_sd is None else float(noise_sd)
    height, width = video.shape[1:]
    cooling = _Cooling(video, dt, dx, sd)
    a = video.new_zeros(3)
    t_ref, first = _fit_globals(cooling, a, None)
    labels, horizon, last = None, math.inf, float(cooling.offsets[-1]) + first
    for _ in range(_ROUNDS):
        refit, used = cooling.lateral(t_ref, first, labels)  # too few sound pixels for a refit: a stays
        a = refit if labels is None or used != 0 else a
        t_ref, first = _fit_globals(cooling, a, (t_ref, first) if math.isinf(horizon) else None, horizon)
        tau, rss, windowed, taus = _fit_pixels(cooling, a, t_ref, first)
        log_tau = torch.log(tau.clamp(max=float(taus[-2]))).view(height, width)
        labels = _regions(log_tau)
        plate_time = math.exp(float(_plate(log_tau, last)[0]))
        if math.isinf(horizon) and last > _LONG * plate_time:  # long past the back wall: only the lateral
            horizon = max(last / _LONG**2, plate_time)  # flow changes the late frames; the globals end here
            a = a.new_zeros(3)  # measured at the T_ref the late frames pulled off
            t_ref, first = _fit_globals(cooling, a, None, horizon)  # the next lateral fit needs this T_ref
    return _finish(tau.view(height, width), rss, windowed, taus, dx, (a, t_ref, first, sd), cooling)


def _plate(log_tau: Tensor, last: float) -> tuple[Tensor, Tensor]:
    """The sound plate's ``ln tau`` and its sound pixels (:func:`~anra_torch.flash.regions.plate_level`) in a
    recording that lasts ``last`` s after the flash."""
    longest = math.log(math.pi * last)  # the back wall shows by plate / pi
    return plate_level(log_tau, _ODD, sigma=_SIGMA_LATERAL, share=_SOUND_SHARE, longest=longest)


def _significance(rss: Tensor, windowed: Tensor, plate_index: int) -> Tensor:
    """Per pixel, how many standard deviations of its own fit its ``tau`` is from the plate's."""
    best = rss.min(1).values
    dof = (windowed > 0).sum(1).clamp_min(3).to(rss)
    variance = (best / (dof - 2)).clamp_min(torch.finfo(rss.dtype).tiny)
    return ((rss[:, plate_index] - best) / variance).clamp_min(0).sqrt()


def _finish(
    tau: Tensor,
    rss: Tensor,
    windowed: Tensor,
    taus: Tensor,
    dx: float,
    fitted: tuple[Tensor, float, float, float],
    cooling: _Cooling,
) -> DefectMap:
    """Plate, significance, defects, their outlines, depths and the score from the fitted map."""
    a, t_ref, first, sd = fitted
    height, width = tau.shape
    log_tau = torch.log(tau.clamp(max=float(taus[-2])))
    last = first + (cooling.shape[0] - 1) * cooling.dt
    plate, sound = _plate(log_tau, last)
    index = int(torch.argmin((torch.log(taus[:-1]) - plate).abs()))
    z = _significance(rss, windowed, index).view(height, width)
    contrast = plate - log_tau
    scatter = 1.4826 * (contrast[sound] - contrast[sound].median()).abs().median()  # the sound plate's
    least = max(_CONTRAST, _SCATTER * float(scatter))
    candidate = (
        (contrast > _CONTRAST)
        & (contrast > _SCATTER * edge_scatter(contrast, sound, _EDGE_RINGS, _MIN_PIXELS))
        & (z > _SIGNIFICANCE)
    )
    plate_time = math.exp(float(plate))
    # the outlines and peaks from the contrast averaged over the value's smoothing (a noisy region's 95 %
    # quantile read 0.49 for d / L 0.6: python -m experiments.flash_defect_map --map-only --held-out)
    level = smooth(contrast.clamp_min(-_CONTRAST), _SIGMA_VALUE)

    def depth(outline: Tensor, peak: Tensor) -> float:
        return _depth_fraction(outline, peak, level, plate_time, (a, t_ref, first), cooling)

    outlines = outline_defects(level, candidate, z, (least, _MIN_PIXELS, dx), depth)
    score = _score(contrast, outlines.peaks)
    return DefectMap(
        depth_time=tau,
        plate_time=plate_time,
        plate_time_se=plate_time * tile_standard_error(log_tau, sound),
        back_wall_reached=last >= plate_time / math.pi,
        defect_score=score,
        defect_mask=outlines.mask,
        depth_fraction=outlines.depth_fraction,
        defects=tuple(outlines.defects),
        lateral=(float(a[0]), float(a[1]), float(a[2])),
        t_ref=t_ref,
        first_time=first,
        noise_sd=sd,
    )


def _depth_fraction(
    outline: Tensor,
    peak: Tensor,
    contrast: Tensor,
    plate_time: float,
    fitted: tuple[Tensor, float, float],
    cooling: _Cooling,
) -> float:
    """A defect's ``d / L`` at its peak (the outline's pixel whose contrast is nearest it: sideways flow
    only lowers the contrast), its ``tau`` corrected for the spread of the heat the defect reflects
    (:func:`~anra_torch.flash.spread.spread_depth_time`)."""
    a, t_ref, first = fitted
    at = int(torch.where(outline, (contrast - peak).abs(), math.inf).flatten().argmin())
    _, _, weights, elapsed = cooling.series(t_ref, first, torch.tensor([at], device=contrast.device))
    tau = plate_time * math.exp(-float(peak))
    where = (outline, divmod(at, contrast.shape[1]))
    tau = spread_depth_time(tau, plate_time, where, a, cooling.dx, (elapsed, weights[0]), _WINDOW)
    return math.sqrt(tau / plate_time)


def _score(contrast: Tensor, peaks: list[tuple[Tensor, Tensor]]) -> Tensor:
    """The defect score: over each defect found (its outline grown by 2 px) its contrast averaged over the
    value's smoothing (1 px; each pixel's own fit is noisy) over its peak; elsewhere the contrast, each
    pixel's bounded at +-:data:`_CONTRAST` (a fit can run far off in noise), averaged over the lateral
    derivatives' footprint (nothing smaller is resolved) and over twice the largest peak: a defect too
    faint to outline still ranks above the sound plate."""
    bounded = smooth(contrast.clamp(-_CONTRAST, _CONTRAST), _SIGMA_LATERAL).clamp_min(0)
    score = bounded / max([float(p) for _, p in peaks], default=1.0) * 0.5
    near = smooth(contrast.clamp_min(0), _SIGMA_VALUE)
    for outline, peak in peaks:
        region = dilate(outline, 2)
        score = torch.where(region, torch.maximum(score, near / peak), score)
        score = torch.where(outline, score.clamp_min(OUTLINE_SHARE), score)  # the mask: at least 0.6
    return score
