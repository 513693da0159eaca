"""Random skin-like scenes for :func:`anra_torch.simulation.bioheat_reference.simulate_bioheat`.

The validation scenes of the depth model (``experiments/damage_depth.py``, ``tests/test_tissue_depth.py``):
skin-like tissue (``a`` 0.10-0.20 mm^2/s, perfusion 0-0.01 1/s), a far-infrared laser spot, a sweeping tip
or a contact burn (surface heating) or a near-infrared spot (volumetric), exposures of 0.5-60 s and
surface peaks of 60-95 C, so that equal peaks come with very different depths. Units: mm, s, C.
"""

from __future__ import annotations

import math

import numpy as np

from anra_torch.simulation.bioheat_reference import flux_centre
from anra_torch.simulation.bioheat_setup import BioheatScene, Contact, SurfaceFlux, Tissue

__all__ = ["KINDS", "flux_peak", "random_scene"]

KINDS = ("spot", "sweep", "contact", "near_infrared")
"""Scene kinds :func:`random_scene` draws: a far-infrared laser spot, a sweeping tip, a contact burn
(surface heating), and a near-infrared spot (volumetric, outside the depth model)."""


def flux_peak(source: SurfaceFlux, tissue: Tissue, points: np.ndarray, times: np.ndarray) -> float:
    """Largest surface rise (K) of ``source`` on a half-space at ``points`` ``(P, 2)`` and ``times`` ``(S,)``:
    the Green's function ``exp(-|p - c|^2 / (2 s2)) w^2 / s2 / sqrt(pi a u) e^{-b u}``, ``s2 = w^2 + 2 a u``,
    integrated over the elapsed time ``u = v^2`` by Gauss-Legendre (no loss to air, no edges)."""
    a, b, w2 = tissue.diffusivity, tissue.perfusion, source.width**2
    nodes, weights = np.polynomial.legendre.leggauss(200)
    best = 0.0
    for t in times:
        lo, hi = math.sqrt(max(t - source.t_off, 0.0)), math.sqrt(max(t - source.t_on, 0.0))
        if hi <= lo:
            continue
        v = lo + (hi - lo) * 0.5 * (nodes + 1.0)
        u = v**2
        c = np.array([flux_centre(source, t - e) for e in u])  # (N, 2)
        s2 = w2 + 2.0 * a * u
        d2 = ((points[:, None, :] - c[None]) ** 2).sum(-1)
        kernel = np.exp(-d2 / (2.0 * s2)) * w2 / s2 * np.exp(-b * u) * 2.0 / math.sqrt(math.pi * a)
        best = max(best, float((kernel * weights).sum(-1).max()) * 0.5 * (hi - lo) * source.power)
    return best


def random_scene(seed: int, *, kind: str | None = None) -> BioheatScene:
    """A skin-like scene: ``a`` 0.10-0.20 mm^2/s, perfusion 0-0.01 1/s, an exposure from t = 1 s of 0.5-60 s
    (half the draws log-uniform over it, half uniform over 10-60 s: long exposures make the deep burns), a
    surface peak of 60-95 C (the source's power set for it), then 4-20 s of cooling; a camera of 48 x 48
    px at 5-30 Hz (5 or 10 Hz beyond 10 s of exposure) whose view holds the heat's lateral spread (pixels of
    at most 0.25 mm: a long record's heat crosses the view's edges), and tissue beyond the view by the heat's
    reach ``sqrt(4 a duration)`` (at least 2 mm), so that the block's walls hold no heat in.

    Args:
        seed: random seed.
        kind: one of :data:`KINDS`; default cycles through the first three with ``seed``.

    Shape:
        No arrays.
    """
    kind = kind or KINDS[seed % 3]
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; expected one of: {', '.join(KINDS)}")
    rng = np.random.default_rng(seed)
    tissue = Tissue(diffusivity=rng.uniform(0.10, 0.20), perfusion=rng.uniform(0.0, 0.01))
    if rng.uniform() < 0.5:
        exposure = math.exp(rng.uniform(math.log(0.5), math.log(60.0)))
    else:
        exposure = rng.uniform(10.0, 60.0)
    rate = float(rng.choice([5.0, 10.0] if exposure > 10.0 else [5.0, 10.0, 15.0, 30.0]))
    exposure = round(exposure * rate) / rate
    t_on, cooling = 1.0, round(min(max(exposure, 4.0), 20.0) * rate) / rate
    duration = t_on + exposure + cooling
    spread = math.sqrt(4.0 * tissue.diffusivity * duration)  # the heat's lateral reach, mm
    target = rng.uniform(60.0, 95.0)
    width = rng.uniform(0.25, 1.0)  # a beam's sigma: 1/e^2 diameters of 1-4 mm
    radius = rng.uniform(1.0, 3.0)  # a probe's
    size = 2.0 * radius if kind == "contact" else 4.0 * width
    dx = round(min(max((3.0 + size + 2.0 * spread) / 48, 0.1), 0.25), 3)
    centre = (24 * dx, 24 * dx)
    if kind == "contact":
        source: SurfaceFlux | Contact = Contact(centre, radius, target + 1.0, t_on, t_on + exposure)
    else:
        half = 0.5 * rng.uniform(1.0, 4.0) if kind == "sweep" else 0.0
        start, end = (centre[0] - half, centre[1]), (centre[0] + half, centre[1])
        absorption = rng.uniform(0.5, 2.0) if kind == "near_infrared" else None
        unit = SurfaceFlux(start, end, width, 1.0, t_on, t_on + exposure)
        path = np.linspace(0.0, 1.0, 21)[:, None] * (np.subtract(end, start))[None] + np.array(start)
        times = t_on + exposure * np.linspace(0.05, 1.0, 40) if half else np.array([t_on + exposure])
        power = (target - tissue.body_temperature) / flux_peak(unit, tissue, path, times)
        source = SurfaceFlux(start, end, width, power, t_on, t_on + exposure, absorption)
    # The block's walls (no flux) stand where no heat reaches within the record: beyond the view by the heat's
    # reach, at least 2 mm (2 mm held the heat of 50-70 s records in, biasing the fitted a 1-5 % high).
    margin = max(2.0, spread)
    return BioheatScene(tissue, (source,), duration, (48, 48), dx, rate, margin, label=kind)
