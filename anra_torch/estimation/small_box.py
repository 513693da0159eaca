"""Models for regions too small for the balance's filters, or whose conduction is faster than a frame.

A FLIR box export of 9 x 15 px, or an 8 x 8 px crop, leaves no interior for a 26 px smoothing filter; and
when heat crosses the region within a frame (``a dt / dx^2 >> 1``) the interior is, at every frame, the
steady state for its edges and the diffusivity cannot be read from it. Three models work there, all on
the interior with the MEASURED edge pixels as a Dirichlet boundary that follows the recording:

- ``plain``: ``dT/dt = a Lap T``, ``a`` by least squares on a moving average in time (the same average on
  both sides of the PDE keeps it exact), central time differences and the 5-point Laplacian;
- ``loss``: ``dT/dt = a Lap T - b (T - T_ref) + c`` (a linear loss to the body and the air, a net heat
  input ``c``), fitted the same way;
- ``quasi_steady``: ``T = harmonic(edges) + S(x, y)``, the limit of ``dT/dt = a Lap T + q(x, y)`` when
  conduction is faster than a frame: the interior is the steady state for its measured edges plus the
  source's stationary particular solution ``S`` (the fit frames' mean of ``T - harmonic(edges)``).

:func:`fit_small_box` fits one model on a run of frames; :func:`forecast_small_box` forecasts the frames
after a start frame with it. Units: ``dt`` in s, ``dx`` in mm, ``a`` in mm^2/s, ``b`` in 1/s, ``c`` in
data units per s.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from anra_torch.checks import diffusivity_warnings, own_tensor

__all__ = [
    "MODELS",
    "SmallBoxModel",
    "edge_explained",
    "fit_small_box",
    "forecast_small_box",
    "harmonic_interior",
    "small_box_estimate",
]

MODELS = ("plain", "loss", "quasi_steady")
"""The small-region models, in order of complexity."""

SMOOTH_FRAMES = 11
"""Frames of the moving average in time applied to both sides of the PDE before the least squares."""

BLOCK_FRAMES = SMOOTH_FRAMES + 2
"""Frames per block of the standard error: the moving average and the central difference correlate a
residual with those up to this many frames away, and no further."""

MIN_BLOCKS = 4
"""Fewest blocks from which a standard error is given (fewer: None, the precision unknown)."""

UNRESOLVED = 0.5
"""Share of the interior's change explained by the steady state for its edges above which conduction is
taken as faster than a frame (the diffusivity unresolved)."""

_F64 = torch.float64
_STABLE = 0.4  # explicit Euler: substep * (4 a / dx^2 + b) below this


@dataclass(frozen=True)
class SmallBoxModel:
    """One fitted small-region model.

    Attributes:
        kind: one of :data:`MODELS`.
        a: diffusivity in mm^2/s (``plain``, ``loss``; 0 for ``quasi_steady``).
        a_std_error: its standard error in mm^2/s, clustered over blocks of :data:`BLOCK_FRAMES` frames
            (the averaged residuals are correlated within a block); None for ``quasi_steady`` or fewer than
            :data:`MIN_BLOCKS` blocks.
        b: linear loss rate in 1/s (``loss``; else 0).
        c: net heat input in data units per s (``loss``; else 0).
        t_ref: the loss' reference temperature, data units (the fit frames' mean).
        source: ``S(x, y)`` of ``quasi_steady``, data units (else None).

    Shape:
        ``source`` ``(H - 2, W - 2)``.
    """

    kind: str
    a: float = 0.0
    b: float = 0.0
    c: float = 0.0
    t_ref: float = 0.0
    source: Tensor | None = None
    a_std_error: float | None = None

    @property
    def significant(self) -> bool | None:
        """Whether ``a`` differs from 0 by more than 3 standard errors (None: no standard error). A box that
        hardly changes over its frames (a baseline) gives an ``a`` near 0 that says nothing about the
        material."""
        if self.a_std_error is None:
            return None
        return abs(self.a) > 3.0 * self.a_std_error

    def params(self) -> dict[str, float]:
        """The model's parameters in physical units (``S`` by its extremes)."""
        if self.kind == "quasi_steady":
            assert self.source is not None
            return {"S_max": float(self.source.max()), "S_min": float(self.source.min())}
        if self.kind == "plain":
            return {"a": self.a}
        return {"a": self.a, "b": self.b, "c": self.c, "T_ref": self.t_ref}


def _laplacian5(u: Tensor, dx: float) -> Tensor:
    """5-point Laplacian on the interior. Shape ``(..., H, W)`` -> ``(..., H - 2, W - 2)``."""
    centre = u[..., 1:-1, 1:-1]
    return (u[..., 1:-1, 2:] + u[..., 1:-1, :-2] + u[..., 2:, 1:-1] + u[..., :-2, 1:-1] - 4 * centre) / dx**2


def _moving_average(x: Tensor, n: int) -> Tensor:
    """Mean over ``n`` consecutive frames (valid part: ``T - n + 1`` frames)."""
    n = min(n, x.shape[0])
    return x.unfold(0, n, 1).mean(-1)


def fit_small_box(frames: Tensor, dt: float, dx: float, kind: str) -> SmallBoxModel:
    """Fit the small-region model ``kind`` on ``frames`` (all of them are fit frames).

    Args:
        frames: temperatures, at least 3 x 3 px.
        dt: frame period in s.
        dx: pixel size in mm.
        kind: one of :data:`MODELS`.

    Shape:
        ``frames`` ``(T, H, W)`` with ``T >= 3`` (``quasi_steady``: ``T >= 1``).
    """
    if kind not in MODELS:
        raise ValueError(f"kind must be one of {', '.join(MODELS)}, got {kind!r}")
    video = own_tensor(frames, _F64)
    if video.ndim != 3 or min(video.shape[1:]) < 3:
        raise ValueError(f"frames must have shape (T, H, W) with H, W >= 3, got {tuple(video.shape)}")
    bad = int((~torch.isfinite(video)).sum())
    if bad:
        raise ValueError(f"frames must be finite for the small-box models, got {bad} non-finite values")
    if kind == "quasi_steady":
        return SmallBoxModel(kind, source=(video[:, 1:-1, 1:-1] - harmonic_interior(video)).mean(0))
    if video.shape[0] < 3:
        raise ValueError(f"frames must hold at least 3 frames to fit a time derivative, got {video.shape[0]}")
    u = _moving_average(video, SMOOTH_FRAMES)
    if u.shape[0] < 3:
        u = video
    dudt = ((u[2:] - u[:-2]) / (2 * dt))[:, 1:-1, 1:-1].reshape(-1)
    lap = _laplacian5(u[1:-1], dx).reshape(-1)
    t_ref = float(u.mean())
    columns = [lap]
    if kind == "loss":
        columns += [-(u[1:-1, 1:-1, 1:-1].reshape(-1) - t_ref), torch.ones_like(dudt)]
    design = torch.stack(columns, 1)
    beta = torch.linalg.lstsq(design, dudt[:, None], driver="gelsd").solution[:, 0]
    se = _block_std_error(design, dudt - design @ beta, frames=u.shape[0] - 2)
    if kind == "plain":
        return SmallBoxModel(kind, a=float(beta[0]), t_ref=t_ref, a_std_error=se)
    return SmallBoxModel(
        kind, a=float(beta[0]), b=float(beta[1]), c=float(beta[2]), t_ref=t_ref, a_std_error=se
    )


def _block_std_error(design: Tensor, residual: Tensor, frames: int) -> float | None:
    """Standard error of the first coefficient of a least-squares fit whose rows are ``frames`` frames of
    equal size, clustered over blocks of :data:`BLOCK_FRAMES` consecutive frames (the sandwich
    ``G^-1 (sum_b s_b s_b^T) G^-1`` with ``s_b`` a block's score ``X_b^T e_b``, times ``B / (B - 1)``):
    residuals smoothed in time are correlated within a block, and the 5-point Laplacian correlates them
    across pixels, both inside the block's sum; neighbouring blocks' cross products enter with the Bartlett
    weight 1/2. Conservative: a time difference of averaged frames correlates neighbouring blocks'
    scores negatively, so on a still noisy box ``a / se`` spreads by 0.53 and on a resolved decaying mode
    the standard error is 5x the spread over seeds (``tests/test_recording.py -k small_box_standard_error``).
    None with fewer than :data:`MIN_BLOCKS` blocks.

    Shape:
        ``design`` ``(N, P)``, ``residual`` ``(N,)`` with ``N = frames * pixels``.
    """
    blocks = frames // BLOCK_FRAMES
    if blocks < MIN_BLOCKS:
        return None
    rows = design.shape[0] // frames
    used = blocks * BLOCK_FRAMES * rows
    scores = (design[:used] * residual[:used, None]).reshape(blocks, BLOCK_FRAMES * rows, -1).sum(1)
    gram_inv = torch.linalg.pinv(design.T @ design)
    # Neighbouring blocks share the residuals' correlation across their border: their cross products too.
    meat = scores.T @ scores + 0.5 * (scores[1:].T @ scores[:-1] + scores[:-1].T @ scores[1:])
    cov = gram_inv @ meat @ gram_inv * (blocks / (blocks - 1))
    return float(cov[0, 0].clamp_min(0).sqrt())


def forecast_small_box(
    model: SmallBoxModel, frames: Tensor, dt: float, dx: float, start: int, n: int
) -> Tensor:
    """Forecast the ``n`` frames after ``frames[start]``, the edges following the measured frames.

    ``plain`` and ``loss`` step explicit Euler (substeps within the stability limit; a negative ``a`` or
    ``b``, ill-posed forward, is taken as 0) from the measured ``frames[start]``, the edges linearly
    interpolated between measured frames; ``quasi_steady`` is at every frame the steady state for the
    measured edges plus ``S``.

    Shape:
        ``frames`` ``(T, H, W)`` -> ``(n, H, W)`` (edges as measured).
    """
    video = own_tensor(frames, _F64)
    if model.kind == "quasi_steady":
        out = video[start + 1 : start + 1 + n].clone()
        out[:, 1:-1, 1:-1] = harmonic_interior(out) + model.source
        return out
    a, b = max(model.a, 0.0), max(model.b, 0.0)
    substeps = max(1, math.ceil(dt * (4 * a / dx**2 + b) / _STABLE))
    if substeps > 100_000:
        raise ValueError(
            f"the fitted rates need {substeps} explicit substeps per frame (a = {a:.3g} mm^2/s, "
            f"b = {b:.3g} 1/s); conduction is faster than a frame: use the quasi_steady model"
        )
    h = dt / substeps
    u = video[start].clone()
    out = torch.empty((n, *u.shape), dtype=_F64, device=u.device)
    for k in range(n):
        for s in range(substeps):
            w = (s + 1) / substeps
            edge = (1 - w) * video[start + k] + w * video[start + k + 1]
            u[1:-1, 1:-1] += h * (a * _laplacian5(u, dx) - b * (u[1:-1, 1:-1] - model.t_ref) + model.c)
            u[0], u[-1], u[:, 0], u[:, -1] = edge[0], edge[-1], edge[:, 0], edge[:, -1]
        out[k] = u
    return out


@functools.lru_cache(maxsize=16)
def _sine_basis(n: int) -> tuple[Tensor, Tensor]:
    """Orthonormal DST-I basis of ``n`` interior points and the 5-point second difference's eigenvalues."""
    k = torch.arange(1, n + 1, dtype=_F64, device="cpu")  # data on the CPU, moved by the caller
    basis = math.sqrt(2 / (n + 1)) * torch.sin(math.pi * k[:, None] * k[None, :] / (n + 1))
    return basis, -4 * torch.sin(math.pi * k / (2 * (n + 1))) ** 2


def harmonic_interior(frames: Tensor) -> Tensor:
    """Each frame's steady state for its measured edges: the interior solving the 5-point Laplace equation.

    Solved exactly in the sine basis (Dirichlet edges), so any box size costs two small matrix products.

    Shape:
        ``(T, H, W)`` -> ``(T, H - 2, W - 2)``.
    """
    video = own_tensor(frames, _F64)
    edges = video.clone()
    edges[:, 1:-1, 1:-1] = 0.0
    rhs = -_laplacian5(edges, 1.0)  # the edges' pull on the interior
    (sy, ly), (sx, lx) = (tuple(v.to(rhs.device) for v in _sine_basis(n)) for n in rhs.shape[-2:])
    spectrum = sy @ rhs @ sx / (ly[:, None] + lx[None, :])
    return sy @ spectrum @ sx


def edge_explained(frames: Tensor) -> float:
    """Fraction of the interior's variance over time that the steady state for its edges explains (1: the
    interior follows its edges within a frame; conduction is not resolved).

    Both are first averaged over :data:`SMOOTH_FRAMES` frames (when there are at least twice as many), as
    the small-box models are fitted: the steady state is linear in the frames, so the average keeps it
    exact while the noise, which no steady state explains, falls. Frame by frame, noise alone took the
    share of a box that follows its edges under a half, and its diffusivity was reported as a number near
    zero instead of flagged.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    video = own_tensor(frames, _F64)
    if video.shape[0] >= 2 * SMOOTH_FRAMES:
        video = _moving_average(video, SMOOTH_FRAMES)
    inner = video[:, 1:-1, 1:-1] - video[:, 1:-1, 1:-1].mean(0)
    harmonic = harmonic_interior(video)
    harmonic = harmonic - harmonic.mean(0)
    total = float(inner.pow(2).sum())
    return 1.0 - float((inner - harmonic).pow(2).sum()) / total if total > 0 else 1.0


def unresolved_bound(frames: Tensor, dt: float, dx: float) -> float | None:
    """When conduction crosses the region within a frame (:func:`edge_explained` at least
    :data:`UNRESOLVED`), the lower bound on ``a`` in mm^2/s that implies: the slowest mode of the box,
    ``1 / (a pi^2 (1/Lx^2 + 1/Ly^2))``, relaxes within ``dt``; else None (the diffusivity is resolved).

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    if edge_explained(frames) < UNRESOLVED:
        return None
    h, w = frames.shape[-2:]
    return 1.0 / (dt * math.pi**2 * (1 / ((w - 1) * dx) ** 2 + 1 / ((h - 1) * dx) ** 2))


def small_box_estimate(frames: Tensor, dt: float, dx: float) -> dict[str, Any]:
    """The estimate record of a region too small for the balance's filters, as ``anra estimate`` and
    ``anra batch`` report it: the ``plain`` fit's ``a`` and standard error, valid only when it is resolved.

    Not valid, with the reason in ``message``: fewer than 3 x 3 px or 3 frames; conduction crossing the
    region within a frame (``a`` None, and ``diffusivity_lower_bound``, :func:`unresolved_bound`); ``a``
    within 3 standard errors of 0 (the region hardly changes: a baseline); ``a`` significantly negative or
    outside every known material (:func:`~anra_torch.checks.diffusivity_warnings`).

    Returns:
        ``{"diffusivity", "std_error"}`` in mm^2/s (None where not measured), ``"valid"``, ``"message"``.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    video = own_tensor(frames, _F64)
    h, w = video.shape[1:]
    if min(h, w) < 3 or video.shape[0] < 3:
        return {"diffusivity": None, "std_error": None, "valid": False, "message": "too small: need 3 x 3 px"}
    plain = fit_small_box(video, dt, dx, "plain")
    a, se = plain.a, plain.a_std_error
    bound = unresolved_bound(video, dt, dx)
    if bound is not None:
        message = (
            f"unresolved: conduction crosses the {h} x {w} px region within a frame (a > {bound:.3g} mm^2/s)"
        )
        return {
            "diffusivity": None,
            "std_error": None,
            "valid": False,
            "message": message,
            "diffusivity_lower_bound": bound,
        }
    if plain.significant is False:
        message = (
            f"not resolved: a = {a:.3g} +- {se:.2g} mm^2/s is within 3 standard errors of 0 (the "
            f"{h} x {w} px region hardly changes over these frames)"
        )
        return {"diffusivity": a, "std_error": se, "valid": False, "message": message}
    z = None if se is None or se == 0 else a / se
    flagged = diffusivity_warnings(a, dt=dt, dx=dx, z=z)
    if flagged:
        message = "not resolved by the small-box fit: " + "; ".join(flagged)
        return {"diffusivity": a, "std_error": se, "valid": False, "message": message}
    how = "no standard error (too few frames)" if se is None else "standard error over blocks of frames"
    return {
        "diffusivity": a,
        "std_error": se,
        "valid": True,
        "message": f"small-box fit (5-point Laplacian, measured edges); {how}",
    }
