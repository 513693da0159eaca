"""Helpers shared by the effects whose regressor is a fitted shape (a source's path, a disc)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

if TYPE_CHECKING:
    from anra_torch.balance import BalanceSystem

__all__ = ["draw_circle", "edge_disc", "finish_outer", "optimise", "peak", "pixel_grid"]

_F64 = torch.float64


def pixel_grid(system: BalanceSystem) -> tuple[Tensor, Tensor]:
    """Pixel-centre coordinates (mm) of the full frame: x along columns ``(W,)``, y along rows ``(H,)``."""
    _, h, w = system.shape
    device = system.frames.device
    x = (torch.arange(w, dtype=_F64, device=device) + 0.5) * system.dx
    return x, (torch.arange(h, dtype=_F64, device=device) + 0.5) * system.dx


def finish_outer(system: BalanceSystem, rows: Tensor, cols: Tensor) -> Tensor:
    """A term whose every frame is an outer product ``rows[t] (x) cols[t]`` (a Gaussian spot), time-averaged,
    smoothed and cropped like ``U``: ``system.finish(system.filters.time.average(field))``.

    The spatial filters are separable, so they run on the two profiles and only the time average's sum of
    outer products is built at full size (the same term to rounding, without a 2D smoothing pass).

    Shape:
        ``rows`` ``(T, H)``, ``cols`` ``(T, W)`` -> ``(T - 4, h, w)``.
    """
    f = system.filters
    if f.smoother.border != "crop" or f.laplacian.border != "crop":  # padded borders do not factor
        return system.finish(f.time.average(rows[:, :, None] * cols[:, None, :]))
    partner = cast(Tensor, f.laplacian.partner.kernels)[0].to("cpu", _F64)
    u, s, vh = torch.linalg.svd(partner)  # the partner's 1D factors
    rank = int((s > 1e-13 * s[0]).sum())
    gauss = f.smoother.taps.to(rows).view(1, 1, -1)

    def filtered(profiles: Tensor, factors: Tensor) -> Tensor:  # (T, N) -> (T, rank, n)
        return F.conv1d(F.conv1d(profiles[:, None], gauss), factors.to(rows)[:, None, :])

    along_rows = filtered(rows, (u[:, :rank] * s[:rank]).T)
    along_cols = filtered(cols, vh[:rank])
    k = rows.shape[0] - f.time.length + 1
    taps = [(j, w) for j, w in enumerate(f.time.stencil.pair.tolist()) if w != 0.0]
    left = torch.cat([w * along_rows[j : j + k] for j, w in taps], 1)  # (K, taps x rank, h)
    right = torch.cat([along_cols[j : j + k] for j, w in taps], 1)  # (K, taps x rank, w)
    return left.transpose(1, 2) @ right


def edge_disc(x: Tensor, y: Tensor, cx: Any, cy: Any, radius: Any, edge: float) -> Tensor:
    """1 inside the disc of ``radius`` around ``(cx, cy)``, 0 outside, with a tanh edge ``edge`` wide (all
    mm; differentiable in the centre and radius, also at a pixel centre).

    Shape:
        ``x`` ``(W,)``, ``y`` ``(H,)`` -> ``(H, W)``.
    """
    r = torch.sqrt((x[None, :] - cx) ** 2 + (y[:, None] - cy) ** 2 + 1e-12)
    return 0.5 * (1.0 + torch.tanh((radius - r) / edge))


def draw_circle(ax: Any, x: float, y: float, radius: float, style: str) -> None:
    """A circle (mm) on a map's axes, in a matplotlib line ``style``."""
    angle = np.linspace(0.0, 2.0 * np.pi, 200)
    ax.plot(x + radius * np.cos(angle), y + radius * np.sin(angle), style)


def optimise(
    loss: Callable[[Tensor], Tensor], starts: Sequence[Tensor], *, iterations: int, runs: int
) -> Tensor:
    """L-BFGS from the ``runs`` best of ``starts`` (by loss); returns the best parameters seen."""
    with torch.no_grad():
        values = [float(loss(s)) for s in starts]
    order = sorted(range(len(starts)), key=values.__getitem__)
    best = (values[order[0]], starts[order[0]].clone())
    for index in order[:runs]:
        theta = starts[index].clone().requires_grad_(True)
        # The loss is relative to the current model's residual: one unit of chi-square is ~1e-5 of it.
        optimiser = torch.optim.LBFGS(
            [theta], lr=1.0, max_iter=iterations, tolerance_change=1e-8, line_search_fn="strong_wolfe"
        )

        def closure(theta: Tensor = theta, optimiser: torch.optim.LBFGS = optimiser) -> Tensor:
            optimiser.zero_grad()
            value = loss(theta)
            value.backward()
            nonlocal best
            if float(value.detach()) < best[0] and bool(torch.isfinite(theta).all()):
                best = (float(value.detach()), theta.detach().clone())
            return value

        optimiser.step(closure)
    return best[1]


def peak(image: Tensor, radius: int) -> tuple[float, float]:
    """Centroid (column, row) in px of the positive part of ``image`` around its maximum."""
    h, w = image.shape
    row, col = divmod(int(image.argmax()), w)
    r0, r1, c0, c1 = (
        max(row - radius, 0),
        min(row + radius + 1, h),
        max(col - radius, 0),
        min(col + radius + 1, w),
    )
    patch = image[r0:r1, c0:c1].clamp_min(0)
    total = float(patch.sum())
    if total <= 0:
        return float(col), float(row)
    rows = torch.arange(r0, r1, dtype=_F64, device=image.device)[:, None]
    cols = torch.arange(c0, c1, dtype=_F64, device=image.device)[None, :]
    return float((patch * cols).sum()) / total, float((patch * rows).sum()) / total
