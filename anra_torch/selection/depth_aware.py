"""The lateral diffusivity of a surface that also loses heat into depth: ``a`` with a loss rate per frame.

A surface heated and left to cool over a thick body (a liquid, a composite plate, skin) loses most of its
heat downwards. Where the depth problem separates from the lateral one (a body homogeneous in depth, heat
laid down with one depth profile), the surface obeys

    dT/dt = a Lap T - r(t) (T - T_ref(t)),

with a rate ``r(t)`` that no one frame's pixels tell apart (``1 / (2 t)`` after a flash on a half-space,
falling as the body evens out; any convective or radiative loss adds to it). The plain balance,
``dT/dt = a Lap T``, then reads the hot spot's faster cooling as lateral spreading.
:func:`depth_aware_diffusivity` fits ``a`` with a free rate and level in every frame
(``r_k`` times that frame's ``T``, and per-frame fixed effects for ``r_k T_ref``), through the same
balance core as the diagnosis (:class:`~anra_torch.balance.BalanceSystem`: matched filters, the
measured noise model, errors-in-variables moments and the sandwich standard error).

The model's own check is its consistency: smoothing both sides of a linear PDE keeps it exact, so where the
model describes the frames its ``a`` does not depend on the smoothing. :attr:`DepthAwareFit.consistent`
compares ``a`` over the smoothing candidates.

Checked against 3-D conduction it shares no code with (``experiments/depth_references.py``, asserted on in
``tests/test_depth_aware.py``): on the exact surface of a Gaussian spreading in a half-space (a separable
depth problem) ``a`` is 1.8 % high where the plain estimate is 74 % high; on an explicit 3-D slab heated by
a beam for 120 s, 59 % high over the cooling's first frames (the heat still sits under the beam: the depth
problem does not separate; plain: 147 %), and 8 % high from 60 s after the switch-off on. Consistency over
the smoothings does not reveal that bias.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from anra_torch.balance import BalanceSystem, Fit, NoiseSpec, find_artefacts, measure_noise
from anra_torch.checks import own_tensor, positive
from anra_torch.selection.diagnose import SMOOTHING, minimum_frame_size

__all__ = [
    "MAX_RATES",
    "NOISE_SHARE",
    "RATE_VALUES",
    "SCALE_CONSISTENCY",
    "DepthAwareFit",
    "depth_aware_diffusivity",
]

SCALE_CONSISTENCY = 1.5
"""Largest ratio of the highest to the lowest ``a`` over the smoothing candidates of a consistent fit."""

MAX_RATES = 32
"""Most loss rates fitted (consecutive blocks of frames share one in a longer run: the depth rate changes
slowly once the first frames are past, and each rate adds a term to the balance)."""

RATE_VALUES = 2**25
"""Budget of rates times pixel values: each rate holds a term and a noise weight the size of the balance's,
so a run of 4M pixel values (the largest ``anra estimate`` reads whole) gets 8 rates, about 0.5 GB."""

NOISE_SHARE = 0.05
"""Largest share of ``Lap T``'s sum of squares that may be the measured noise's at a smoothing used: the
errors-in-variables correction is then small. Above it the fit leans on the noise model, and frames
resampled from samples seconds apart carry noise that is no longer white in time (a 3-D slab sampled 5-60 s
apart read 0.012 mm^2/s for 0.126 at 1 px, where a quarter of ``Lap T`` was noise; 0.13-0.16 at 2-8 px)."""


@dataclass(frozen=True)
class DepthAwareFit:
    """``a`` of ``dT/dt = a Lap T - r_k (T - T_ref,k)`` (one rate and level per frame).

    Attributes:
        diffusivity: ``a`` in mm^2/s at :attr:`smoothing_px`, of the candidates whose ``Lap T`` is at most
            :data:`NOISE_SHARE` noise (else the least noisy one) the one with the smallest standard error.
        std_error: its standard error (noise only; the spread over smoothings shows the model's error).
        smoothing_px: Gaussian sigma of the fit, px.
        rates: the rate ``r`` in 1/s (positive: heat lost) of each block of frames: one per frame the time
            derivative is centred on, or blocks of consecutive frames in a longer or larger run (at most
            :data:`MAX_RATES`, and :data:`RATE_VALUES` over the balance's size).
        rate_frames: the first frame (index in the run) of each rate's block.
        by_smoothing: ``a`` (mm^2/s) at each of those smoothing candidates (px).
        plain_by_smoothing: the plain ``dT/dt = a Lap T`` (with the same per-frame levels) at each of them:
            where depth matters it moves with the smoothing too.
    """

    diffusivity: float
    std_error: float
    smoothing_px: float
    rates: tuple[float, ...]
    rate_frames: tuple[int, ...]
    by_smoothing: dict[float, float]
    plain_by_smoothing: dict[float, float]

    @property
    def consistent(self) -> bool:
        """Whether ``a`` is positive at every smoothing and within :data:`SCALE_CONSISTENCY` of itself, at two
        smoothings or more (one cannot be checked)."""
        values = list(self.by_smoothing.values())
        return len(values) > 1 and min(values) > 0 and max(values) <= SCALE_CONSISTENCY * min(values)

    def to_record(self) -> dict[str, Any]:
        """A JSON-ready record (``diffusivity``, ``std_error`` mm^2/s; ``smoothing_px`` px; ``rates`` 1/s and
        ``rate_frames``; ``by_smoothing`` and ``plain_by_smoothing`` ``{"<px>": mm^2/s}``; ``consistent``)."""
        return {
            "diffusivity": self.diffusivity,
            "std_error": self.std_error,
            "smoothing_px": self.smoothing_px,
            "rates": list(self.rates),
            "rate_frames": list(self.rate_frames),
            "by_smoothing": {f"{s:g}": a for s, a in self.by_smoothing.items()},
            "plain_by_smoothing": {f"{s:g}": a for s, a in self.plain_by_smoothing.items()},
            "consistent": self.consistent,
        }


def depth_aware_diffusivity(
    frames: Tensor, dt: float, dx: float, *, smoothing: Sequence[float] = SMOOTHING
) -> DepthAwareFit:
    """Fit the lateral diffusivity with a uniform loss rate and level free in every frame.

    Args:
        frames: one source-free run of frames (cooling, baseline), ``(T, H, W)`` temperatures.
        dt: frame period in s.
        dx: pixel size in mm.
        smoothing: Gaussian sigma candidates in px (those the frames are large enough for are used).

    Returns:
        :class:`DepthAwareFit`.

    Raises:
        ValueError: not ``(T, H, W)``, fewer than 6 frames (two rates to tell apart from ``a``), frames too
            small for every smoothing, non-finite values, or no change at all.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    dt, dx = positive(dt, "dt", "s"), positive(dx, "dx", "mm")
    video, sigmas = _checked(frames, smoothing)
    video, artefacts = find_artefacts(video)
    if float(video.amax() - video.amin()) == 0.0:
        raise ValueError("frames are constant: no change to fit")
    noise = measure_noise(video, static_pattern=artefacts.fixed_pattern)
    within = tuple(dict.fromkeys(("frame", *artefacts.within)))
    kept: tuple[float, BalanceSystem] | None = None  # the least noisy, in case no smoothing is quiet enough
    fits, plains, shares, blocks = {}, {}, {}, {}
    for sigma in sigmas:
        system = BalanceSystem(video, dt, dx, sigma, float(noise.sd), noise=noise, within=within)
        index = system.moments.names.index("L")
        shares[sigma] = float(system.moments.noise[index, index] / system.moments.raw[index, index])
        if shares[sigma] <= NOISE_SHARE:  # the rates are fitted only where Lap T is mostly signal
            fits[sigma], plains[sigma], blocks[sigma] = _fit_rates(system)
        elif not fits and (kept is None or shares[sigma] < shares[kept[0]]):
            kept = (sigma, system)
    if not fits and kept is not None:  # every smoothing's Lap T is more than NOISE_SHARE noise
        sigma, system = kept
        fits[sigma], plains[sigma], blocks[sigma] = _fit_rates(system)
    best = min(fits, key=lambda s: float(fits[s].cov[0, 0]))
    fit = fits[best]
    return DepthAwareFit(
        diffusivity=float(fit.beta[0]),
        std_error=math.sqrt(max(float(fit.cov[0, 0]), 0.0)),
        smoothing_px=best,
        rates=tuple(-float(b) for b in fit.beta[1:]),
        rate_frames=tuple(block.start + 2 for block in blocks[best]),
        by_smoothing={s: float(f.beta[0]) for s, f in fits.items()},
        plain_by_smoothing={s: plains[s] for s in fits},
    )


def _checked(frames: Tensor, smoothing: Sequence[float]) -> tuple[Tensor, list[float]]:
    """The frames as float64 ``(T, H, W)``, checked, and the smoothings they are large enough for."""
    video = own_tensor(frames, torch.float64)
    if video.ndim != 3 or video.shape[0] < 6:
        raise ValueError(f"frames must have shape (T, H, W) with T >= 6, got {tuple(video.shape)}")
    if not bool(torch.isfinite(video).all()):
        raise ValueError("frames must be finite for the depth-aware fit; repair or crop non-finite pixels")
    sigmas = [float(s) for s in smoothing if min(video.shape[1:]) >= minimum_frame_size(float(s))]
    if not sigmas:
        need = minimum_frame_size(smoothing)
        raise ValueError(
            f"frames must be at least {need} x {need} px for the depth-aware fit, "
            f"got {video.shape[1]} x {video.shape[2]}"
        )
    return video, sigmas


def _fit_rates(system: BalanceSystem) -> tuple[Fit, float, list[slice]]:
    """``a`` with a rate per block of frames (``r_b`` times ``T`` masked to the block), the plain ``a`` in
    the same balance, and the blocks."""
    plain = float(system.fit(["L"]).beta[0])
    blocks = _blocks(system.u.shape[0], system.u.numel())
    rates = {}
    for b, block in enumerate(blocks):
        mask = torch.zeros_like(system.u)
        mask[block] = 1.0
        rates[f"T@{b}"] = (system.detached["T"] * mask, NoiseSpec("T", mask))
    system.add_terms(rates)
    return system.fit(["L", *rates]), plain, blocks


def _blocks(k: int, values: int) -> list[slice]:
    """The derivative frames ``0 .. k - 1`` in consecutive blocks of near-equal length: one frame each when
    ``k`` allows, at most :data:`MAX_RATES` and :data:`RATE_VALUES` / ``values`` (at least 4) blocks."""
    n = min(k, MAX_RATES, max(4, RATE_VALUES // max(values, 1)))
    edges = [round(i * k / n) for i in range(n + 1)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
