"""Subsurface temperature from the measured surface: the bioheat forward problem.

Under surface heating (contact burns, electrosurgery, far-infrared and CO2 lasers: the heat is absorbed
at the surface) the temperature below the frame is fixed by the measured surface history and the tissue's
diffusivity ``a`` and loss (perfusion) rate ``b``: with ``theta = T - T_body``::

    d theta / dt = a (d_xx + d_yy + d_zz) theta - b theta,   theta(x, y, 0, t) = measured surface,

in a half-space (or a layer of a given thickness whose bottom stays at ``T_body``), starting in equilibrium
with the first frame. A well-posed forward problem: no inversion.

How it is solved (chosen by measuring, see ``experiments/damage_depth.py``): the lateral terms matter
(under a spot 1-2.5 mm wide heat leaves sideways as well as downwards), so the frame is the boundary of a
3-D problem. With uniform ``a`` and ``b`` it separates exactly:

* laterally, the cosine modes (DCT-II) of the frame, or of the frame continued ``margin`` mm beyond its
  edges (:func:`~anra_torch.tissue.depth_window.widen`: the frame is a window, and its edges then neither
  hold the heat in nor invent it), each with its own decay ``c = a |k|^2 + b`` (``k = pi (p / H, q / W) /
  dx``, the continuous wavenumbers); a node at depth ``z`` takes the modes with ``|k| z < 9.2`` (the
  others reach it below 1e-4 of their surface amplitude);
* in depth, the second-order finite-difference operator on nodes ``0 = z_0 < z_1 < ...`` whose spacing
  grows geometrically from :data:`FIRST_STEP` (the profiles broaden with depth), down to a bottom so deep
  that no heat reaches it in the record (or a shallower layer's: the grid stops where the heat does,
  whatever the thickness);
* in time, each mode (lateral x depth eigenmode) is integrated EXACTLY between frames for a surface that
  varies linearly between them (an exponential integrator: ``phi_1``, ``phi_2``), so the frame rate sets no
  stability limit and the only errors are the depth grid's and the surface's sampling.

The march steps from frame to frame (a recurrence: each step is one vectorised update of every video's,
pixel's and mode's state), and the physical temperatures of a block of frames are formed at once.
Everything runs on the input's device in its dtype (constants built once in float64 and cached) and is
differentiable with respect to the frames, ``a`` and ``b``.

Damage in depth from the same solve: :mod:`~anra_torch.tissue.depth_damage`.

Units: mm, s, C, mm^2/s, 1/s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

from anra_torch.tissue.depth_solver import (
    BLOCK_VALUES,
    FIRST_STEP,
    bottom_depth,
    check_rate,
    dct_matrices,
    depth_nodes,
    frame_problem,
    heat_input,
    march,
    node_temperatures,
    solver_nodes,
    surface_rise,
)

__all__ = ["subsurface_temperature", "surface_heat_input"]

_F64 = torch.float64


def _nodes_with(wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The geometric grid down to the deepest ``wanted`` depth with every ``wanted`` depth inserted (grid
    nodes closer than a third of their spacing to one dropped), and where each wanted depth sits."""
    grid = depth_nodes(max(float(wanted.max()), FIRST_STEP))
    spacing = np.diff(grid, append=grid[-1] + (grid[-1] - grid[-2]))
    distance = np.abs(grid[:, None] - wanted[None, :]).min(1)
    nodes = np.unique(np.concatenate([grid[(distance > spacing / 3) | (grid == 0.0)], wanted]))
    return nodes, np.searchsorted(nodes, wanted)


def subsurface_temperature(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    depths: Sequence[float] | Tensor,
    *,
    diffusivity: float | Tensor,
    loss_rate: float | Tensor = 0.0,
    body_temperature: float | Tensor | None = None,
    thickness: float | None = None,
    units: str = "C",
) -> Tensor:
    """Temperature below every pixel at ``depths``, at every frame, from the measured surface.

    Solves ``dT/dt = a Lap T - b (T - T_body)`` under the frame with the frames as the surface temperature
    (surface heating), starting in equilibrium with the first frame.

    Args:
        frames: surface temperatures in ``units``, ``(T, H, W)`` or ``(B, T, H, W)``, finite.
        dt, dx: frame period in s and pixel size in mm (numbers or ``(B,)``).
        depths: depths in mm (>= 0; 0 is the surface itself).
        diffusivity, loss_rate: ``a`` (mm^2/s, positive), ``b`` (1/s, perfusion, >= 0); numbers or ``(B,)``.
        body_temperature: C (number or ``(B,)``); default the median of each video's first frame.
        thickness: None for a half-space; else a layer's thickness in mm, its bottom held at ``T_body``.
        units: ``"C"`` or ``"K"`` (the output is in Celsius).

    Returns:
        Temperatures in C, ``(B, T, Z, H, W)`` (``(T, Z, H, W)`` for an unbatched input), in the frames'
        dtype and device; differentiable with respect to ``frames``, ``diffusivity`` and ``loss_rate``.

    Raises:
        ValueError: bad shapes, spacings, rates, depths, non-finite frames, or units that do not fit.
        TypeError: rates that are not numbers.

    Example:
        >>> frames = torch.full((3, 4, 4), 37.0, dtype=torch.float64)
        >>> frames[1:] = 80.0  # the surface steps to 80 C
        >>> t = subsurface_temperature(frames, 0.5, 0.1, [0.0, 0.2], diffusivity=0.14)
        >>> tuple(t.shape), round(float(t[0, 1, 0, 0]), 1)
        ((3, 2, 4, 4), 37.0)
    """
    rise, batched, dt_, dx_, body = surface_rise(frames, dt, dx, units, body_temperature)
    batch, n = rise.shape[:2]
    a = check_rate(diffusivity, "diffusivity", "mm^2/s", batch, rise, positive=True)
    b = check_rate(loss_rate, "loss_rate", "1/s", batch, rise, positive=False)
    wanted = np.asarray(torch.as_tensor(depths, dtype=_F64, device="cpu").reshape(-1))
    if wanted.size == 0 or not np.isfinite(wanted).all() or (wanted < 0).any():
        raise ValueError(f"depths must be finite depths >= 0 mm, got {wanted.tolist()}")
    order = np.argsort(wanted)
    reported, where = _nodes_with(wanted[order])
    duration = float(dt_.detach().max()) * (n - 1)
    nodes = solver_nodes(reported, bottom_depth(thickness, float(reported[-1]), a, duration))
    problem = frame_problem(rise, dt_, dx_, a, b, nodes, len(reported))
    block = max(1, BLOCK_VALUES // max(1, rise[0, 0].numel() * len(reported) * batch))
    parts = [node_temperatures(rise, problem, start, states) for start, states in march(problem, block)]
    out = torch.cat(parts, 1)[:, :, torch.from_numpy(where[np.argsort(order)]).to(rise.device)]
    out = out + body.view(-1, 1, 1, 1, 1)
    return out if batched else out[0]


def surface_heat_input(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    *,
    diffusivity: float | Tensor,
    loss_rate: float | Tensor = 0.0,
    body_temperature: float | Tensor | None = None,
    thickness: float | None = None,
    units: str = "C",
) -> Tensor:
    """Heat that has entered the tissue through the surface under each pixel since the first frame.

    The surface flux the measured surface implies (the solution's ``a d theta / dz`` at ``z = 0``,
    integrated over time; heat per area over ``rho c``, in K mm): where no source acts it stays flat, so it
    is how the depth model is checked against the recording and how ``a`` and ``b`` are fitted
    (:func:`anra_torch.tissue.fit_depth_parameters`). Computed with the depth grid of :func:`depth_nodes`
    down to ``7 sqrt(a t)`` (the heat's reach over the record).

    Args:
        frames: surface temperatures in ``units``, finite, ``(T, H, W)`` or ``(B, T, H, W)``.
        dt, dx: frame period (s) and pixel size (mm).
        diffusivity, loss_rate: ``a`` (mm^2/s) and ``b`` (1/s), numbers or ``(B,)``.
        body_temperature: C; default the median of each video's first frame.
        thickness: None for a half-space, else a layer's (mm).
        units: ``"C"`` or ``"K"``.

    Returns:
        Cumulative heat input in K mm, ``(B, T, H, W)`` (0 at the first frame).

    Raises:
        ValueError: bad shapes, spacings, rates or non-finite frames.

    Shape:
        ``(B, T, H, W)`` -> ``(B, T, H, W)``.
    """
    rise, batched, dt_, dx_, _ = surface_rise(frames, dt, dx, units, body_temperature)
    batch = rise.shape[0]
    a = check_rate(diffusivity, "diffusivity", "mm^2/s", batch, rise, positive=True)
    b = check_rate(loss_rate, "loss_rate", "1/s", batch, rise, positive=False)
    duration = float(dt_.max()) * (rise.shape[1] - 1)
    reach = 7.0 * math.sqrt(float(a.detach().max()) * duration) + 0.1
    if thickness is not None:
        reach = min(reach, float(thickness) * (1.0 - 1e-9))
    reported = depth_nodes(reach)
    nodes = solver_nodes(reported, bottom_depth(thickness, float(reported[-1]), a, duration))
    heat = heat_input(frame_problem(rise, dt_, dx_, a, b, nodes, 2))
    ch, cw = dct_matrices(rise)
    out = ch.T @ heat.reshape(rise.shape) @ cw
    return out if batched else out[0]
