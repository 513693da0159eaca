"""Subsurface temperature from the measured surface: the bioheat forward problem under surface heating.

With ``theta = T - T_body``, the tissue below the frame obeys Pennes' equation
``d theta / dt = a (d_xx + d_yy + d_zz) theta - b theta``, where ``a`` is the diffusivity and ``b`` the
loss rate by perfusion. The measured frames are its surface temperature, and the tissue starts in
equilibrium with the first frame, in a half-space or in a layer whose bottom stays at ``T_body``: a
well-posed forward problem, no inversion. The solve runs on the frames' device and dtype and is
differentiable with respect to the frames, ``a`` and ``b``. How it is solved: ``docs/architecture.md``,
"The depth model". Damage in depth from the same solve: :mod:`~anra_torch.tissue.depth_damage`.

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
    """The geometric grid down to the deepest ``wanted`` depth with every ``wanted`` depth inserted, and
    the index of each wanted depth. Grid nodes closer to a wanted depth than a third of their spacing are
    dropped."""
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

    Solves ``dT/dt = a Lap T - b (T - T_body)`` with the frames as the surface, from equilibrium.

    Args:
        frames: finite surface temperatures in ``units``.
        dt, dx: frame period in s and pixel size in mm, numbers or ``(B,)``.
        depths: depths in mm, each >= 0; 0 is the surface itself.
        diffusivity, loss_rate: ``a > 0`` in mm^2/s and the perfusion ``b >= 0`` in 1/s, numbers or ``(B,)``.
        body_temperature: C, a number or ``(B,)``; default the median of each video's first frame.
        thickness: None for a half-space; else a layer's thickness in mm, its bottom held at ``T_body``.
        units: ``"C"`` or ``"K"``; the output is in Celsius either way.

    Returns:
        Temperatures in C, in the frames' dtype and device; differentiable in ``frames``, ``a`` and ``b``.

    Raises:
        ValueError: bad shapes, fewer than 2 frames, bad spacings, rates, depths or thickness, non-finite
            frames, or units that do not fit the values.
        TypeError: frames that are not a real tensor or array, rates that are not numbers.

    Shape:
        ``(B, T, H, W)`` -> ``(B, T, Z, H, W)``, ``Z = len(depths)``; ``(T, H, W)`` -> ``(T, Z, H, W)``.

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

    The time integral of the surface flux ``a d theta / dz`` at ``z = 0`` that the measured surface
    implies: heat per area over ``rho c``, in K mm. Where no source acts it stays flat.

    Args:
        frames: finite surface temperatures in ``units``.
        dt: frame period in s, a number or ``(B,)``.
        dx: pixel size in mm, a number or ``(B,)``.
        diffusivity: ``a`` in mm^2/s, positive; a number or ``(B,)``.
        loss_rate: ``b`` in 1/s, >= 0; a number or ``(B,)``.
        body_temperature: ``T_body`` in C; default the median of each video's first frame.
        thickness: None for a half-space, else a layer's thickness in mm.
        units: ``"C"`` or ``"K"``.

    Returns:
        Cumulative heat input in K mm, 0 at the first frame.

    Raises:
        ValueError: bad shapes, fewer than 2 frames, bad spacings, rates or thickness, non-finite frames,
            or units that do not fit the values.
        TypeError: frames that are not a real tensor or array, rates that are not numbers.

    Shape:
        ``(B, T, H, W)`` -> ``(B, T, H, W)``; ``(T, H, W)`` -> ``(T, H, W)``.
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
