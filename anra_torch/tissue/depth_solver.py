"""The engine of the depth model: depth grid, depth operator, lateral cosine modes, exact march in time.

Shared by :mod:`~anra_torch.tissue.depth`, :mod:`~anra_torch.tissue.depth_damage` and
:mod:`~anra_torch.tissue.depth_fit`; the method: ``docs/architecture.md``, "The depth model". Operators
are built once in float64 on the CPU, cached, then moved to the frames' device and dtype.
Units: mm, s, K, mm^2/s, 1/s.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import as_spacing, as_video, number
from anra_torch.tissue.dose import to_celsius

__all__ = [
    "BLOCK_VALUES",
    "DEEP_GROWTH",
    "FIRST_STEP",
    "GROWTH",
    "ModalProblem",
    "bottom_depth",
    "check_rate",
    "dct_matrices",
    "depth_nodes",
    "depth_operator",
    "frame_problem",
    "free_surface_operator",
    "heat_input",
    "march",
    "modal_problem",
    "node_temperatures",
    "solver_nodes",
    "state_at",
    "surface_rise",
    "wavenumbers",
]

FIRST_STEP = 0.01
"""Spacing (mm) of the depth nodes at the surface."""
GROWTH = 1.03
"""Ratio of consecutive depth spacings down to the deepest node reported (3 % per node: a damage front at
depth ``z`` is resolved to about ``0.03 z``)."""
DEEP_GROWTH = 1.25
"""Ratio of consecutive spacings below the reported nodes, down to a bottom no heat reaches."""
_F64 = torch.float64
_BLOCK = 2**22  # values of a closed-form sum over frames held at once
BLOCK_VALUES = 2**22
"""Temperatures formed per block of frames of the march (32 MiB in float64)."""


def depth_nodes(max_depth: float, *, first: float = FIRST_STEP, growth: float = GROWTH) -> np.ndarray:
    """Depths in mm of the reported nodes: 0, then spacings ``first * growth^j`` until ``max_depth`` is
    passed.

    Args:
        max_depth: deepest depth to cover in mm, positive.
        first: spacing at the surface in mm, positive.
        growth: ratio of consecutive spacings, >= 1.

    Returns:
        Node depths in mm as a float64 NumPy array, 0 first.

    Raises:
        ValueError: a value that is not finite, not positive or a ``growth`` below 1.
        TypeError: a value that is not a number.

    Shape:
        ``(Z,)``.

    Example:
        >>> depth_nodes(0.05, first=0.01, growth=1.0)
        array([0.  , 0.01, 0.02, 0.03, 0.04, 0.05])
    """
    max_depth = number(max_depth, "max_depth", "mm", positive=True)
    first = number(first, "first", "mm", positive=True)
    growth = number(growth, "growth", "1", minimum=1.0)
    if growth == 1.0:
        n = math.ceil(max_depth / first - 1e-9)
    else:
        n = math.ceil(math.log1p(max_depth / first * (growth - 1.0)) / math.log(growth) - 1e-9)
    steps = first * growth ** np.arange(n)
    return np.concatenate([[0.0], np.cumsum(steps)])


def solver_nodes(reported: np.ndarray, bottom: float) -> tuple[float, ...]:
    """The reported nodes continued down to ``bottom``, the last node, which is held at the body
    temperature; below the reported nodes each spacing grows by :data:`DEEP_GROWTH`."""
    nodes, step = list(reported), reported[-1] - reported[-2]
    while nodes[-1] < bottom:
        step *= DEEP_GROWTH
        nodes.append(nodes[-1] + step)
    if len(nodes) > len(reported) + 1 and bottom - nodes[-2] < 0.5 * (nodes[-2] - nodes[-3]):
        nodes.pop(-2)  # the last step would be too short next to its neighbour: merge it
    nodes[-1] = bottom  # exactly: a layer's bottom is held at the body temperature
    return tuple(float(z) for z in nodes)


@lru_cache(maxsize=64)
def depth_operator(nodes: tuple[float, ...], reported: int) -> dict[str, Tensor]:
    """The depth operator on ``nodes``, surface first and bottom last, diagonalised: float64 on the CPU.

    On the interior nodes ``u_t = A u + f g``, ``A = D^-1/2 Q diag(lambda) Q^T D^1/2``, ``g`` the surface.
    Keys: ``lam`` ``(M,)``, the eigenvalues in 1/mm^2; ``forcing`` ``(M,)``, the modal ``f``; ``heat``
    ``(M,)``, each mode's trapezoid integral over depth in mm; ``to_nodes`` ``(reported - 1, M)``, modes to
    the reported interior nodes; ``surface_weight``, the surface node's trapezoid weight in mm."""
    z = np.asarray(nodes)
    h = np.diff(z)
    w = 0.5 * (h[:-1] + h[1:])
    inverse = 1.0 / h
    scale = 1.0 / np.sqrt(w)
    symmetric = np.diag(-(inverse[:-1] + inverse[1:]) * scale**2)
    off = inverse[1:-1] * scale[:-1] * scale[1:]
    symmetric += np.diag(off, 1) + np.diag(off, -1)
    lam, q = np.linalg.eigh(symmetric)
    forcing = np.zeros(len(w))
    forcing[0] = inverse[0] / w[0]
    arrays = {
        "lam": lam,
        "forcing": q.T @ (np.sqrt(w) * forcing),
        "to_nodes": (scale[:, None] * q)[: reported - 1],
        "heat": q.T @ np.sqrt(w),
        "surface_weight": np.array(0.5 * h[0]),
    }
    return {k: torch.from_numpy(v) for k, v in arrays.items()}


@lru_cache(maxsize=64)
def free_surface_operator(nodes: tuple[float, ...], beta: float) -> dict[str, Tensor]:
    """The depth operator of the cooling after the switch-off, diagonalised: float64 on the CPU.

    No source acts: the surface node is free and loses ``a beta theta`` to the air, ``beta = h / k`` in
    1/mm; interior nodes as in :func:`depth_operator`, the bottom held at 0. Keys: ``lam`` ``(M,)`` in
    1/mm^2; ``to_modes`` ``(M, M)``, node values, surface first, to modal coefficients; ``surface``
    ``(M,)``, modes to the surface node."""
    z = np.asarray(nodes)
    h = np.diff(z)
    w = np.concatenate([[0.5 * h[0]], 0.5 * (h[:-1] + h[1:])])
    inverse = 1.0 / h
    diagonal = -(inverse[:-1] + inverse[1:])
    diagonal = np.concatenate([[-inverse[0] - beta], diagonal])
    scale = 1.0 / np.sqrt(w)
    symmetric = np.diag(diagonal * scale**2)
    off = inverse[:-1] * scale[:-1] * scale[1:]
    symmetric += np.diag(off, 1) + np.diag(off, -1)
    lam, q = np.linalg.eigh(symmetric)
    arrays = {"lam": lam, "to_modes": q.T * np.sqrt(w)[None, :], "surface": q[0] * scale[0]}
    return {k: torch.from_numpy(v) for k, v in arrays.items()}


@lru_cache(maxsize=16)
def dct_matrix(n: int) -> Tensor:
    """Orthonormal DCT-II matrix ``(n, n)``, float64 on the CPU: ``C[p, i] = s_p cos(pi p (i + 1/2) / n)``."""
    p, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    c = np.cos(np.pi * p * (i + 0.5) / n) * math.sqrt(2.0 / n)
    c[0] /= math.sqrt(2.0)
    return torch.from_numpy(c)


# ------------------------------------------------------------------------------------------ the march
@dataclass(frozen=True)
class ModalProblem:
    """One batch's forward problem in lateral modes, on the frames' device and dtype.

    ``spectrum`` ``(B, T, K)``: the surface rise in K in ``K`` lateral cosine modes; ``dt``, ``a``, ``b``
    ``(B,)`` in s, mm^2/s, 1/s; ``operator``: :func:`depth_operator`'s tensors; ``decay`` ``(B, K, M)``:
    ``-mu = a |k|^2 + b - a lambda`` in 1/s of every lateral x depth mode; ``depths``: the reported nodes in
    mm; ``step``: the largest pixel in mm when the modes are the frame's cosine modes, else 0, and a node at
    depth ``z`` then takes only the modes with ``|k| < MODE_REACH / z``."""

    spectrum: Tensor
    dt: Tensor
    a: Tensor
    b: Tensor
    operator: dict[str, Tensor]
    decay: Tensor
    depths: tuple[float, ...] = ()
    step: float = 0.0


def modal_problem(
    spectrum: Tensor, k2: Tensor, dt: Tensor, a: Tensor, b: Tensor, nodes: tuple, reported: int
) -> ModalProblem:
    """:class:`ModalProblem` of the lateral modes ``spectrum`` ``(B, T, K)`` with squared wavenumbers
    ``k2`` ``(B, K)`` in 1/mm^2, on the depth ``nodes``."""
    operator = {
        k: v.to(device=spectrum.device, dtype=spectrum.dtype)
        for k, v in depth_operator(nodes, reported).items()
    }
    lateral = a[:, None] * k2 + b[:, None]
    decay = lateral[..., None] - a[:, None, None] * operator["lam"]
    return ModalProblem(spectrum, dt, a, b, operator, decay, tuple(nodes[:reported]))


def wavenumbers(h: int, w: int, dx: Tensor) -> Tensor:
    """``|k|^2`` in 1/mm^2 of the cosine modes of an ``h x w`` frame, ``(B, H W)`` for ``dx`` ``(B,)``."""
    like = {"device": dx.device, "dtype": dx.dtype}
    ky = (math.pi / h) * torch.arange(h, **like)[None, :] / dx[:, None]
    kx = (math.pi / w) * torch.arange(w, **like)[None, :] / dx[:, None]
    return (ky[:, :, None] ** 2 + kx[:, None, :] ** 2).flatten(1)


def dct_matrices(rise: Tensor) -> tuple[Tensor, Tensor]:
    """The frame's DCT matrices on ``rise``'s device and dtype."""
    like = {"device": rise.device, "dtype": rise.dtype}
    return dct_matrix(rise.shape[-2]).to(**like), dct_matrix(rise.shape[-1]).to(**like)


def frame_problem(
    rise: Tensor,
    dt: Tensor,
    dx: Tensor,
    a: Tensor,
    b: Tensor,
    nodes: tuple,
    reported: int,
    *,
    lateral: bool = True,
) -> ModalProblem:
    """:class:`ModalProblem` of every cosine mode of the surface rise ``rise`` ``(B, T, H, W)`` in K.
    With ``lateral=False`` every mode has ``k = 0``: each pixel's column on its own, in 1-D."""
    ch, cw = dct_matrices(rise)
    spectrum = (ch @ rise @ cw.T).flatten(2)
    k2 = wavenumbers(*rise.shape[-2:], dx)
    problem = modal_problem(spectrum, k2 if lateral else torch.zeros_like(k2), dt, a, b, nodes, reported)
    return replace(problem, step=float(dx.detach().max()) if lateral else 0.0)


def phi_functions(z: Tensor) -> tuple[Tensor, Tensor]:
    """``phi_1(z) = (e^z - 1) / z`` and ``phi_2(z) = (e^z - 1 - z) / z^2`` for ``z <= 0``; series near 0."""
    small = z.abs() < 1e-3
    safe = torch.where(small, -1.0, z)
    e = torch.expm1(safe)
    phi1 = torch.where(small, 1.0 + z / 2 + z**2 / 6, e / safe)
    phi2 = torch.where(small, 0.5 + z / 6 + z**2 / 24, (e - safe) / safe**2)
    return phi1, phi2


def march(problem: ModalProblem, block: int) -> Iterator[tuple[int, Tensor]]:
    """The modal states of every frame, ``block`` frames at a time, stepped exactly between frames.

    Each mode obeys ``w' = mu w + a f_m g(t)`` with the surface ``g`` linear between frames:
    ``w <- e^(mu dt) w + a f_m dt ((phi_1 - phi_2) g_n + phi_2 g_(n+1))``. The first frame's state is the
    steady one, ``w = a f_m g_0 / (-mu)``: the tissue in equilibrium with the first frame.

    Yields:
        ``(start, states)``: the states of frames ``start .. start + L - 1``, ``(B, L, K, M)``.
    """
    p = problem
    z = -p.decay * p.dt.view(-1, 1, 1)
    phi1, phi2 = phi_functions(z)
    gain = (p.a * p.dt).view(-1, 1, 1) * p.operator["forcing"]
    step, old, new = torch.exp(z), gain * (phi1 - phi2), gain * phi2
    g = p.spectrum.unsqueeze(-1)  # (B, T, K, 1)
    state = p.a.view(-1, 1, 1) * p.operator["forcing"] * g[:, 0] / p.decay
    states, start = [state], 0
    # The recurrence runs frame by frame (each step vectorised over videos, pixels and modes): a
    # parallel scan over time would hold every frame's modes at once.
    for n in range(1, g.shape[1]):
        state = step * state + old * g[:, n - 1] + new * g[:, n]
        states.append(state)
        if len(states) == block:
            yield start, torch.stack(states, 1)
            start, states = start + block, []
    if states:
        yield start, torch.stack(states, 1)


def state_at(problem: ModalProblem, last: Tensor, *, start: Tensor | None = None) -> Tensor:
    """The modal state ``(B, K, M)`` of :func:`march` at frame ``last`` ``(B,)`` of each video, in closed
    form: ``w_N = E^N w_0 + old . sum_L E^L g_(N-1-L) + new . sum_L E^L g_(N-L)``. ``start`` ``(B, K)`` is
    the first frame's surface whose steady state is ``w_0``; default the spectrum's first frame."""
    p = problem
    z = -p.decay * p.dt.view(-1, 1, 1)
    phi1, phi2 = phi_functions(z)
    gain = (p.a * p.dt).view(-1, 1, 1) * p.operator["forcing"]
    first = p.spectrum[:, 0] if start is None else start
    steady = p.a.view(-1, 1, 1) * p.operator["forcing"] * first.unsqueeze(-1) / p.decay
    n = int(last.max()) + 1
    lag = torch.arange(n, device=z.device)
    totals = [torch.zeros_like(z), torch.zeros_like(z)]
    chunk = min(n, max(1, _BLOCK // max(1, z.numel())))
    powers = torch.exp(z.unsqueeze(-1) * lag[:chunk].to(z.dtype))  # (B, K, M, L): E^L, one chunk
    across = torch.exp(z * chunk).unsqueeze(-1)  # E^chunk: from one chunk to the next
    for at in range(0, n, chunk):
        here = powers[..., : min(chunk, n - at)]
        frame = last.view(-1, 1) - lag[at : at + chunk].view(1, -1)  # (B, L): frame N - L, this chunk's
        valid = (frame >= 1).to(z.dtype).unsqueeze(-1)  # lags L < N
        index = frame.clamp_min(0).unsqueeze(-1).expand(-1, -1, p.spectrum.shape[2])
        newer = p.spectrum.gather(1, index) * valid  # g_(N-L), (B, L, K)
        older = p.spectrum.gather(1, (index - 1).clamp_min(0)) * valid  # g_(N-1-L)
        for i, g in enumerate((older, newer)):
            totals[i] = totals[i] + torch.einsum("bkml,blk->bkm", here, g)
        # in place where no gradient is taken: a fresh (B, K, M, L) block per chunk costs page faults
        powers = powers * across if torch.is_grad_enabled() else powers.mul_(across)
    decayed = torch.exp(z * last.view(-1, 1, 1).to(z.dtype)) * steady
    return decayed + gain * (phi1 - phi2) * totals[0] + gain * phi2 * totals[1]


def node_temperatures(rise: Tensor, problem: ModalProblem, start: int, states: Tensor) -> Tensor:
    """Temperature rise in K at the reported nodes, surface first, ``(B, L, Z, H, W)``, from a block of
    :func:`march` states of every cosine mode of ``rise`` ``(B, T, H, W)``; a node sums the modes that
    reach it."""
    h, w = rise.shape[-2:]
    ch, cw = dct_matrices(rise)
    inner = torch.matmul(problem.operator["to_nodes"], states.transpose(-1, -2))  # (B, L, Z - 1, K)
    grid = inner.view(*inner.shape[:3], h, w)
    parts = [rise[:, start : start + states.shape[1]].unsqueeze(2)]
    for low, high, p, q in _bands(problem.depths[1:], h, w, problem.step):
        parts.append(ch[:p].T @ grid[:, :, low:high, :p, :q] @ cw[:q])
    return torch.cat(parts, 2)


MODE_REACH = 9.2
"""A lateral mode ``k`` reaches depth ``z`` at most as ``exp(-|k| z)`` (the steady state): a node takes the
modes with ``|k| z < MODE_REACH`` (the others below 1e-4 of their surface amplitude there)."""


@lru_cache(maxsize=64)
def _bands(depths: tuple[float, ...], h: int, w: int, step: float) -> tuple[tuple[int, int, int, int], ...]:
    """Groups ``[low, high)`` of consecutive interior nodes, each with the ``p x q`` lowest cosine modes
    its nodes take; all of them when ``step`` is 0."""
    out: list[list[int]] = []
    for j, z in enumerate(depths):
        p, q = h, w
        if step > 0 and z > 0:
            reach = MODE_REACH / z * step / math.pi  # |k| < reach pi / step, k = pi p / (n step)
            p, q = min(h, math.ceil(reach * h) + 1), min(w, math.ceil(reach * w) + 1)
        if out and out[-1][2:] == [p, q]:
            out[-1][1] = j + 1
        else:
            out.append([j, j + 1, p, q])
    return tuple(tuple(band) for band in out)


# ------------------------------------------------------------------------------------------ inputs
def check_rate(value: object, name: str, unit: str, batch: int, like: Tensor, *, positive: bool) -> Tensor:
    """A per-video rate, ``a``, ``b`` or a standard error, as ``(B,)`` on ``like``'s device and dtype,
    gradients kept.

    Raises:
        TypeError: not a number or tensor.
        ValueError: not one value or ``(B,)``; not finite; not positive if ``positive``, else negative.
    """
    if isinstance(value, Tensor):
        x = value.to(device=like.device, dtype=like.dtype).reshape(-1)
    else:
        try:
            x = torch.as_tensor(value, dtype=like.dtype, device=like.device).reshape(-1)
        except (TypeError, ValueError, RuntimeError) as err:
            raise TypeError(
                f"{name} must be a number in {unit} or a tensor of shape ({batch},), got {value!r}"
            ) from err
    if x.numel() == 1:
        x = x.expand(batch)
    if x.numel() != batch:
        raise ValueError(f"{name} must be a number or have shape ({batch},), got shape {tuple(x.shape)}")
    bad = ~torch.isfinite(x.detach()) | ((x.detach() <= 0) if positive else (x.detach() < 0))
    if bool(bad.any()):
        need = "positive" if positive else "non-negative"
        raise ValueError(f"{name} must be {need} and finite in {unit}, got {x.detach().tolist()}")
    return x


def surface_rise(
    frames: object, dt: object, dx: object, units: str, body_temperature: object
) -> tuple[Tensor, bool, Tensor, Tensor, Tensor]:
    """The checked inputs of a depth solve: the surface rise over the body temperature in K
    ``(B, T, H, W)``, whether the input was batched, ``dt`` in s and ``dx`` in mm ``(B,)``, and the body
    temperature in C ``(B,)``.

    Raises:
        ValueError: bad shape, spacings or body temperature; under 2 frames; non-finite frames; units that
            do not fit the values.
        TypeError: frames not a real tensor or array, a body temperature not a number.
    """
    video, batched = as_video(frames, min_frames=2)
    to_celsius(video, units)  # checks the unit against the values (float64 copy, discarded)
    if not bool(torch.isfinite(video.detach()).all()):
        bad = int((~torch.isfinite(video.detach())).sum())
        raise ValueError(
            f"frames must be finite for the depth solve, got {bad} non-finite values; fill them first "
            "(TissueFeatures fills each pixel's gaps with its mean)"
        )
    celsius = video + (273.15 * -1.0 if units == "K" else 0.0)
    b = video.shape[0]
    dt_ = as_spacing(dt, name="dt", unit="s", batch=b, like=celsius)
    dx_ = as_spacing(dx, name="dx", unit="mm", batch=b, like=celsius)
    if body_temperature is None:
        body = celsius.detach()[:, 0].flatten(1).median(1).values
    else:
        body = check_rate(body_temperature, "body_temperature", "C", b, celsius, positive=False).detach()
    return celsius - body.view(-1, 1, 1, 1), batched, dt_, dx_, body


def bottom_depth(thickness: object, deepest: float, a: Tensor, duration: float) -> float:
    """The bottom node in mm: ``7 sqrt(a t)`` below the deepest reported node, where no heat arrives over
    the record ``t = duration``, rounded up to whole mm; a layer's ``thickness`` where that is shallower.

    Raises:
        ValueError: a ``thickness`` that is not positive or not deeper than ``deepest``.
        TypeError: a ``thickness`` that is not a number.
    """
    free = float(math.ceil(deepest + 7.0 * math.sqrt(float(a.detach().max()) * duration) + 0.1))
    if thickness is not None:
        thickness = number(thickness, "thickness", "mm", positive=True)
        if thickness <= deepest:
            raise ValueError(
                f"thickness must be deeper than the deepest depth ({deepest:g} mm), got {thickness:g}"
            )
        return min(thickness, free)
    return free


# ------------------------------------------------------------------------------------------ heat input
def heat_input(problem: ModalProblem) -> Tensor:
    """Cumulative heat in K mm that entered through the surface in each lateral mode, ``(B, T, K)``, 0 at
    the first frame."""
    p = problem
    a = p.a.view(-1, 1, 1)
    eta, lam, forcing = p.operator["heat"], p.operator["lam"], p.operator["forcing"]
    g = p.spectrum  # (B, T, K)
    steps, previous = [g.new_zeros(g.shape[0], 1, g.shape[2])], None
    for start, states in march(p, 64):
        if previous is not None:
            states, start = torch.cat([previous, states], 1), start - 1
        previous = states[:, -1:]
        n = states.shape[1] - 1
        if n < 1:
            continue
        integral_g = 0.5 * (g[:, start : start + n] + g[:, start + 1 : start + n + 1]) * p.dt.view(-1, 1, 1)
        change = states[:, 1:] - states[:, :-1] - (a * integral_g).unsqueeze(-1) * forcing
        integral_w = change / -p.decay.unsqueeze(1)
        steps.append(a * (integral_w @ (eta * lam) + (eta @ forcing) * integral_g))
    return torch.cat(steps, 1).cumsum(1)
