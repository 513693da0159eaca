"""A defect's depth corrected for the sideways spread of the heat it reflects back to the surface.

Over a defect at depth ``d`` the surface is warmer than over the sound plate by the heat the defect sends
back: the layer's image terms ``(2 / sqrt(pi a_z t)) sum_n exp(-n^2 d^2 / (a_z t))``. A defect of finite
extent sends them back from its own area only, and on their way back to the surface (about the second half
of the time since the flash, when the heat that met the defect at ``t / 2`` returns) they spread sideways.
To first order (one reflection; the lateral heat kernel is Gaussian and separates from the depth one) the
excess over the sound plate at a pixel is the layer's excess times

    L(t) = the defect's outline averaged by the Gaussian of covariance t [[a_x, a_xy], [a_xy, a_y]]

about that pixel. A small deep defect, whose ``tau = d^2 / a_z`` is long against the time its heat takes
to cross it sideways, so keeps less of its excess: its fitted ``tau`` is longer, the defect reads deeper
(a disc of 3 mm radius at ``d / L`` 0.5 under a lateral 7.3 mm^2/s reads 0.64). The surface's lateral
conduction that :mod:`~anra_torch.flash.defects` takes off removes the part the surface shows, not the
spread under it.

:func:`spread_depth_time` inverts it: the curve that model gives for a candidate ``tau`` at the defect's
peak pixel, with the same lateral term taken off and fitted over the same window with the pixel's own
weights (:func:`~anra_torch.flash.cooling.windowed_tau`), reads a longer ``tau``; the candidate that reads
the measured one is the defect's. The first-order model holds while the fit's window ends before the
layer evens out through its thickness; a window the recording's length fixes beyond that
(:func:`~anra_torch.flash.cooling.window_floor`), an outline that covers the spread, or lateral
diffusivities not measured leave ``tau`` as it is.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as nnf
from torch import Tensor

from anra_torch.flash.cooling import log_surface, window_floor, windowed_tau

__all__ = ["reflected_share", "spread_depth_time"]

_CANDIDATES = 61  # candidate tau from exp(-_RANGE) of the measured one up to it
_RANGE = 3.0
_UNCHANGED = 1e-3  # a share within this of 1 over the window: no spread to take off
_CELLS = 128  # the Gaussians' reach in cells beyond which pixels are summed in cells


def reflected_share(
    outline: Tensor, pixel: tuple[int, int], lateral: Tensor, dx: float, elapsed: Tensor
) -> Tensor:
    """``L(t)``: the share of a defect's reflected excess that reaches ``pixel`` at each time.

    The outline continues beyond the frame as its edge pixels say (a defect running out of the frame). The
    Gaussians reach 4 sd; past :data:`_CELLS` px they are summed over square cells of an odd number of
    pixels, the pixel in the central one (a large camera and a thick plate: memory bounded by the cells).

    Args:
        outline: the defect's pixels, ``(H, W)`` booleans.
        pixel: ``(row, column)``.
        lateral: ``(a_x, a_y, a_xy)`` in mm^2/s, positive definite.
        dx: pixel size in mm.
        elapsed: times since the flash in s, positive, ``(N,)``.

    Returns:
        ``(N,)`` in ``[0, 1]``, on ``elapsed``'s device and dtype.
    """
    a_x, a_y, a_xy = (float(v) for v in lateral)
    widest = 0.5 * (a_x + a_y) + math.hypot(0.5 * (a_x - a_y), a_xy)  # the tensor's larger eigenvalue
    reach = math.ceil(4 * math.sqrt(widest * float(elapsed.max())) / dx)
    half = math.ceil(reach / _CELLS) // 2  # cells of 2 half + 1 px
    cell = 2 * half + 1
    cells = math.ceil(reach / cell)  # on each side of the central cell
    radius = cells * cell + half
    padded = nnf.pad(outline.to(elapsed)[None, None], (radius,) * 4, mode="replicate")
    row, col = pixel
    patch = padded[..., row : row + 2 * radius + 1, col : col + 2 * radius + 1]
    covered = nnf.avg_pool2d(patch, cell).flatten()  # each cell's share of the outline
    steps = torch.arange(-cells, cells + 1, dtype=elapsed.dtype, device=elapsed.device) * (cell * dx)
    y, x = (v.flatten() for v in torch.meshgrid(steps, steps, indexing="ij"))
    det = a_x * a_y - a_xy**2
    quadratic = (a_y * x * x - 2 * a_xy * x * y + a_x * y * y) / det  # x^T A^-1 x
    weights = torch.exp(-0.5 * quadratic[None, :] / elapsed[:, None])  # (N, cells)
    return (weights @ covered) / weights.sum(1)


def spread_depth_time(
    tau: float,
    plate_time: float,
    defect: tuple[Tensor, tuple[int, int]],
    lateral: Tensor,
    dx: float,
    series: tuple[Tensor, Tensor],
    window: float,
) -> float:
    """The defect's ``tau = d^2 / a_z`` (s) whose spread excess reads the measured ``tau`` at its peak.

    Args:
        tau: the peak pixel's fitted ``tau`` in s.
        plate_time: the sound plate's ``L^2 / a_z`` in s (``inf``: a half-space).
        defect: its outline ``(H, W)`` booleans and its peak pixel ``(row, column)``.
        lateral: ``(a_x, a_y, a_xy)`` in mm^2/s taken off the map.
        dx: pixel size in mm.
        series: the bins' times since the flash in s ``(N,)`` and the peak pixel's bin weights (inverse
            variances of ``ln u``) ``(N,)``.
        window: the share of its ``tau`` a pixel's fit reaches.

    Returns:
        ``tau`` in s, at most the measured one; the measured one where the first-order model does not
        hold (the window ends past ``window tau``, the lateral tensor is not positive definite) or finds
        no spread.
    """
    elapsed, weights = series
    a_x, a_y, a_xy = (float(v) for v in lateral)
    floor = window_floor(elapsed)
    if not math.isfinite(tau) or floor > window * tau or min(a_x, a_y, a_x * a_y - a_xy**2) <= 0:
        return tau
    # the share beyond the window is never fitted: held at the window's end (the Gaussians stay small)
    share = reflected_share(*defect, lateral, dx, elapsed.clamp(max=window * tau))
    if float(share.min()) > 1 - _UNCHANGED:
        return tau
    exponent = torch.linspace(-_RANGE, 0.0, _CANDIDATES, dtype=elapsed.dtype, device=elapsed.device)
    candidates = tau * torch.exp(exponent)
    reads = _apparent(candidates, plate_time, share, elapsed, weights, window)
    below = torch.nonzero(reads <= tau).flatten()
    if len(below) == 0 or int(below[-1]) == _CANDIDATES - 1:
        return tau
    k = int(below[-1])  # the crossing lies between candidates k and k + 1, in ln tau
    low, high = math.log(float(reads[k])), math.log(float(reads[k + 1]))
    step = (math.log(tau) - low) / (high - low) if high > low else 0.0
    return tau * math.exp(float(exponent[k]) + step * float(exponent[k + 1] - exponent[k]))


def _apparent(
    candidates: Tensor, plate_time: float, share: Tensor, elapsed: Tensor, weights: Tensor, window: float
) -> Tensor:
    """The ``tau`` the defect map reads for each candidate ``(K,)``: the surface excess
    ``u = u_plate + L (u_layer - u_plate)`` less the lateral term the map takes off,
    ``int (u_layer - u_plate) dL / u`` (the surface's Laplacian of it times ``a`` is ``dL / dt`` times the
    layer's excess, by the lateral heat equation), fitted as a pixel is."""
    taus = torch.cat([candidates, candidates.new_full((1,), plate_time)])
    curves = torch.exp(log_surface(elapsed, taus))
    layer, plate = curves[:-1], curves[-1:]
    excess = plate + share[None, :] * (layer - plate)
    ratio = (layer - plate) / excess
    lateral = torch.zeros_like(excess)
    lateral[:, 1:] = torch.cumsum(0.5 * (ratio[:, 1:] + ratio[:, :-1]) * share.diff()[None, :], 1)
    y = excess.log() - lateral
    return windowed_tau(y, weights[None, :].expand_as(y), elapsed, window)[0]
