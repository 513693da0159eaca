"""The standard error of a recording read in chunks: the noise variance added up over the chunks whose
lever is pushed back (step 3 of :mod:`anra_torch.estimation.chunked`), and the totals of the sums so far."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from torch import Tensor

from anra_torch.balance import BatchNoise

__all__ = ["NoiseVariance", "gain", "totals"]


@dataclass
class NoiseVariance:
    """The noise variance of ``sum w (U - a L) L``, added up over chunks from their pushed-back levers.

    Input frame ``t`` of the lever pushed back collects the outputs ``t - L + 1 .. t``. Chained (every
    chunk sampled), a chunk passes its last ``L - 1`` frames on to the next and every frame is added
    exactly (``exact``). Sampled, a chunk's first and last ``L - 1`` frames are incomplete: its interior
    frames give the variance per frame and unit of mean output energy, which scales to the recording's
    interior; the recording's own first and last ``L - 1`` frames (first and last chunks, always sampled)
    are added exactly.
    """

    length: int
    exact: float = 0.0
    interior: float = 0.0  # variance of the sampled interior frames
    weight: float = 0.0  # their number times their chunk's mean energy per output frame
    carry: Tensor | None = None

    def add(self, sums: Any, noise: BatchNoise, *, first: bool, last: bool, chained: bool) -> None:
        """Add one chunk's ``sums.back``; ``first`` and ``last`` say whether it starts or ends the
        recording."""
        back, edge = sums.back, self.length - 1

        def variance(part: Tensor) -> float:
            return float(noise.spread(part).double().pow(2).sum()) if part.shape[1] else 0.0

        if chained:
            if self.carry is not None:
                back = back.clone()
                back[:, :edge] += self.carry
            done, self.carry = (back, None) if last or not edge else (back[:, :-edge], back[:, -edge:])
            self.exact += variance(done)
            return
        if first:
            self.exact += variance(back[:, :edge])
        if last:
            self.exact += variance(back[:, back.shape[1] - edge :])
        interior = back[:, edge : back.shape[1] - edge]
        self.interior += variance(interior)
        self.weight += interior.shape[1] * float(sums.energy.double().mean())

    def total(self, energy: float, outputs: int, frames: int, finished: bool) -> float:
        """The variance over ``frames`` input frames (``outputs`` output frames of total ``energy``)."""
        if self.weight == 0:
            return self.exact
        interior = frames - (self.length - 1) * (1 + finished)
        return self.exact + self.interior / self.weight * energy / outputs * max(interior, 0)


def gain(error: NoiseVariance) -> float:
    """The sampled noise variance per frame and unit of mean output energy (NaN when chained)."""
    return error.interior / error.weight if error.weight > 0 else math.nan


def totals(
    sums: dict[str, Tensor], variance: NoiseVariance, seen: dict[str, Any], variance_error: float
) -> tuple[float, float, float]:
    """``(a, std_error, reliability)`` of the sums so far."""
    num, den, energy = (float(sums[name].sum()) for name in ("num", "den", "energy"))
    if not den > 0:
        return math.nan, math.nan, 0.0
    a = num / den
    outputs = sums["num"].shape[0]
    noise = variance.total(energy, outputs, seen["frames"], seen["finished"])
    correction = (energy - den) * variance_error
    return a, math.hypot(math.sqrt(max(noise, 0.0)) / den, a * correction / den), den / energy
