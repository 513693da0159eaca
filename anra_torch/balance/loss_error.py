"""The standard error of the windowed loss rate of :func:`anra_torch.balance.fit_loss_windows`, propagated
from the white sensor noise through the filters, without noise copies.

The error is exact in time and local in space: exact for a lever constant over the window and, for the
Laplacian's noise, linear over it; above the exact value where the lever varies faster. The derivation:
``docs/architecture.md``, section "The loss rate's standard error"; measured in ``docs/results/tissue.md``.
"""

from __future__ import annotations

import weakref

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.balance.filters import MatchedFilters

__all__ = ["loss_rate_error"]

_FIELDS = ("uL", "zL", "mL", "uR", "zR", "mR")  # pushed time derivative, rise, average of each lever
_KIND = {"u": "P", "z": "P", "m": "L"}  # their spatial filter: the Gaussian's (P) or the Laplacian's (L)
_CORRELATIONS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_BLOCK_VALUES = 1 << 18  # values per block of the per-pixel work (1 MiB of float32: stays in the cache)


def loss_rate_error(
    filters: MatchedFilters,
    levers: tuple[Tensor, Tensor],
    coefficients: dict[str, Tensor],
    noise_sd: Tensor,
    window: int,
) -> Tensor:
    """Standard error of each window's loss rate, ``(B, H, W)``, in the coefficients' units.

    Args:
        filters: the filters the terms were made with (``U``, ``L``, ``T``; padding borders).
        levers: the Laplacian and the rise on each pixel's cooling frames (0 elsewhere), ``(B, K, H, W)``.
        coefficients: for each pushed field of :data:`_FIELDS` (``u``, ``z``, ``m`` of the ``L`` and ``R``
            levers), its weight in the window's change of ``b``, ``(B, H, W)``: ``c / dt`` for ``u``,
            ``c b`` for ``z``, ``-c a / dx^2`` for ``m``, with ``c`` the change of ``b`` per unit change of
            the window's sum of residual times that lever.
        noise_sd: white noise sd of the frames, ``(B,)``.
        window: side of the windows (px, odd).

    Shape:
        Levers ``(B, K, H, W)``; coefficients and output ``(B, H, W)``.
    """
    # Float32 sums over the frames (relative error ~1e-6); combined in float64, where the two levers'
    # coefficients may nearly cancel (by at most 1 / 0.05: the fit's conditioning bound).
    lap, rise = (lever.to(torch.float32) for lever in levers)
    # Per-pixel sums over the frames in blocks of rows whose temporaries stay in the cache.
    rows = max(1, _BLOCK_VALUES // max(lap.shape[0] * lap.shape[1] * lap.shape[-1], 1))
    blocks = [
        _time_products(filters, {"L": lap[..., r : r + rows, :], "R": rise[..., r : r + rows, :]})
        for r in range(0, lap.shape[-2], rows)
    ]
    products = {key: torch.cat([block[key] for block in blocks], -2) for key in blocks[0]}
    sums = _window_sums(filters, products, window)
    variance = _combine({k: v.to(torch.float64) for k, v in sums.items()}, coefficients)
    variance = variance + _slope_part(filters, {"L": lap, "R": rise}, coefficients, window)
    total = variance.clamp_min(0.0)
    return noise_sd.view(-1, 1, 1) * total.sqrt() / _window_count(lap.shape[-2:], window, lap.device)


def _combine(sums: dict[tuple[str, str], Tensor], coefficients: dict[str, Tensor]) -> Tensor:
    """``sum_fg C_f C_g S_fg`` over the (unordered) pairs of fields; the name's last letter is the lever."""
    total = None
    for (f, g), value in sums.items():
        weight = coefficients[_field(f)] * coefficients[_field(g)] * (1.0 if f == g else 2.0)
        total = weight * value if total is None else total + weight * value
    assert total is not None
    return total


def _field(name: str) -> str:
    """``"mL"`` for a field or for its slopes ``"ymL"``, ``"xmL"``."""
    return name[-2:]


def _lag(a: list[float], b: list[float], m: int) -> float:
    """``sum_s a_s b_{s + m}`` of two tap lists."""
    return sum(a[s] * b[s + m] for s in range(len(a)) if 0 <= s + m < len(b))


class _Lags:
    """``X(i, j, m) = sum_k G_i(k) G_j(k + m)`` of named series ``(B, K, H, W)``, computed once each."""

    def __init__(self, series: dict[str, Tensor]) -> None:
        self.series, self.cache = series, {}
        self.frames = next(iter(series.values())).shape[1]

    def __call__(self, i: str, j: str, m: int) -> Tensor:
        if m < 0:
            return self(j, i, -m)
        if (i, j, m) not in self.cache:
            a, b = self.series[i], self.series[j]
            self.cache[i, j, m] = (a[:, : self.frames - m] * b[:, m:]).sum(1)
        return self.cache[i, j, m]

    def pushed(self, i: str, x: list[float], j: str, y: list[float]) -> Tensor:
        """``sum_t (x G_i)(t) (y G_j)(t)``, ``x G`` the series pushed back through the taps ``x``:
        ``sum_m tau_xy(-m) X(i, j, m)``, ``tau_xy(m) = sum_s x_s y_{s + m}``."""
        terms = [(_lag(x, y, -m), m) for m in range(1 - len(x), len(y))]
        out = [w * self(i, j, m) for w, m in terms if w != 0.0]
        return sum(out[1:], out[0]) if out else torch.zeros_like(self.series[i][:, 0])


def _time_products(filters: MatchedFilters, levers: dict[str, Tensor]) -> dict[tuple[str, str], Tensor]:
    """``sum_t f(t) g(t)`` per pixel for every pair of :data:`_FIELDS`, ``(B, H, W)`` each.

    ``u`` is the lever pushed back through the time derivative's taps (per unit ``dt``), ``m`` through the
    average's ``s``, and ``z = m - S s`` (``S = sum_k G``) adds the first averaged frame's part of the rise.
    """
    taps = {"u": filters.time.taps.tolist(), "m": filters.time.pair.tolist()}
    lags = _Lags(levers)
    frames = lags.frames
    total = {i: g.sum(1) for i, g in levers.items()}
    # sum_t s_t (x G_i)(t): the first frames' share of the rise's noise
    first = {
        (i, x): sum(_lag(taps[x], taps["m"], k) * g[:, k] for k in range(min(len(taps["m"]), frames)))
        for i, g in levers.items()
        for x in ("u", "m")
    }
    square = sum(v * v for v in taps["m"])
    products = {}
    for n, f in enumerate(_FIELDS):
        for g in _FIELDS[n:]:
            (kf, i), (kg, j) = f, g
            xf, xg = ("m" if kf == "z" else kf), ("m" if kg == "z" else kg)
            value = lags.pushed(i, taps[xf], j, taps[xg])
            if kf == "z":
                value = value - total[i] * first[j, xg]
            if kg == "z":
                value = value - total[j] * first[i, xf]
            if kf == "z" and kg == "z":
                value = value + total[i] * total[j] * square
            products[f, g] = value
    return products


def _box(x: Tensor, dim: int, half: int) -> Tensor:
    """Sum over ``[i - half, i + half]`` clipped to the axis, along ``dim`` (from the running sum)."""
    n, width = x.shape[dim], 2 * half + 1
    total = x.cumsum(dim)  # total[i] = sum_{j <= i}
    if n <= width:
        index = torch.arange(n, device=x.device)
        upper = total.index_select(dim, (index + half).clamp(max=n - 1))
        lower = total.index_select(dim, (index - half - 1).clamp(min=0)) * (index > half).to(x.dtype).view(
            [-1 if d == dim % x.ndim else 1 for d in range(x.ndim)]
        )
        return upper - lower
    out = torch.empty_like(x)
    inner = n - width
    out.narrow(dim, 0, half + 1).copy_(total.narrow(dim, half, half + 1))  # windows that start at the edge
    torch.sub(
        total.narrow(dim, width, inner), total.narrow(dim, 0, inner), out=out.narrow(dim, half + 1, inner)
    )
    torch.sub(
        total.narrow(dim, n - 1, 1), total.narrow(dim, inner, half), out=out.narrow(dim, n - half, half)
    )
    return out


def _slope_part(
    filters: MatchedFilters, levers: dict[str, Tensor], coefficients: dict[str, Tensor], window: int
) -> Tensor:
    """What the constant-lever sums miss of the Laplacian's noise for a lever that varies linearly over the
    window: ``sum_t beta^T K beta``, ``beta`` the window's least-squares slope of ``gamma_L`` (per px, frame
    by frame, through the time average) and ``K = -1/2 sum_{q, q' in W} (q' - q)(q' - q)^T R_LL(q - q')``
    (diagonal in the frame's interior; its x-y part, non-zero only where the window is clipped, is left
    out)."""
    half = window // 2
    some = next(iter(levers.values()))
    h, w = some.shape[-2:]
    ys = torch.arange(h, dtype=some.dtype, device=some.device).view(-1, 1)
    xs = torch.arange(w, dtype=some.dtype, device=some.device).view(1, -1)
    count = _box(_box(torch.ones_like(ys * xs), -2, half), -1, half)
    centre = {"y": _box(_box(ys.expand(h, w), -2, half), -1, half) / count}
    centre["x"] = _box(_box(xs.expand(h, w), -2, half), -1, half) / count
    spread = {a: _box(_box(pos * pos.expand(h, w), -2, half), -1, half) / count - centre[a] ** 2
              for a, pos in (("y", ys), ("x", xs))}  # fmt: skip
    taps = filters.time.pair.tolist()
    slopes = {}
    for name, lever in levers.items():
        along = {"y": [], "x": []}
        frames = max(1, _BLOCK_VALUES // max(lever.shape[0] * h * w, 1))
        for k in range(0, lever.shape[1], frames):  # frame by frame (blocks that stay in the cache)
            part = lever[:, k : k + frames]
            rows = _box(part, -1, half)  # along x first: shared by both slopes
            total = _box(rows, -2, half)
            along["y"].append((_box(rows * ys, -2, half) - centre["y"] * total) / (spread["y"] * count))
            along["x"].append(
                (_box(_box(part * xs, -1, half), -2, half) - centre["x"] * total) / (spread["x"] * count)
            )
        slopes |= {a + name: torch.cat(parts, 1) for a, parts in along.items()}
    rows = max(1, _BLOCK_VALUES // max(some.shape[0] * some.shape[1] * w, 1))
    products: dict[str, list[Tensor]] = {}
    for r in range(0, h, rows):  # pushed through the time average and multiplied, in blocks of rows
        pushed = {key: _push(value[..., r : r + rows, :], taps) for key, value in slopes.items()}
        for i, j in (("L", "L"), ("L", "R"), ("R", "R")):
            for a in "yx":
                products.setdefault(a + i + j, []).append((pushed[a + i] * pushed[a + j]).sum(1))
    moments = _slope_moments(filters, window, (h, w))
    out = None
    for i, j in (("L", "L"), ("L", "R"), ("R", "R")):
        weight = coefficients[f"m{i}"] * coefficients[f"m{j}"] * (1.0 if i == j else 2.0)
        for a in "yx":
            term = torch.cat(products[a + i + j], -2).to(torch.float64) * moments[a + a].to(weight)
            out = weight * term if out is None else out + weight * term
    assert out is not None
    return out


def _push(series: Tensor, taps: list[float]) -> Tensor:
    """``sum_k G(k) taps(t - k)``: a series ``(B, K, H, W)`` pushed back through a time filter,
    ``(B, K + L - 1, H, W)``."""
    b, k = series.shape[:2]
    out = series.new_zeros(b, k + len(taps) - 1, *series.shape[2:])
    for j, tap in enumerate(taps):
        if tap != 0.0:
            out[:, j : j + k].add_(series, alpha=tap)
    return out


def _slope_moments(filters: MatchedFilters, window: int, shape: tuple[int, int]) -> dict[str, Tensor]:
    """``K_ab = -1/2 sum_{q, q' in W_p} (q' - q)_a (q' - q)_b R_LL(q - q')`` per window centre ``p`` (the
    window clipped to the frame), ``(H, W)`` each for ``ab`` in ``yy`` and ``xx``."""
    h, w = shape
    out = {}
    for a in "yx":
        for b in a:
            powers = ((a == "y") + (b == "y"), (a == "x") + (b == "x"))
            total = torch.zeros(h, w, dtype=torch.float64, device="cpu")
            for along_y, along_x in _correlation_factors(filters, window)["LL"]:
                wy = (_axis_weights(along_y, h, window, powers[0]) * _inside(h, window)).sum(1)
                wx = (_axis_weights(along_x, w, window, powers[1]) * _inside(w, window)).sum(1)
                total = total + wy[:, None] * wx[None, :]
            out[a + b] = -0.5 * total
    return out


def _correlation_factors(filters: MatchedFilters, window: int) -> dict[str, list[tuple[Tensor, Tensor]]]:
    """The spatial noise correlation of each pair of spatial filters (``PP``, ``PL``, ``LL``, unit ``dx``)
    at lags up to ``window - 1``, as a short sum of separable factors ``(along y, along x)`` (CPU float64)."""
    cached = _CORRELATIONS.setdefault(filters, {})
    if window not in cached:
        responses = filters.impulse_responses(("T", "L")).sum(1)  # spatial kernels: the averages sum to 1
        side, reach = responses.shape[-1], window - 1
        factors = {}
        for name, (p, q) in {"PP": (0, 0), "PL": (0, 1), "LL": (1, 1)}.items():
            padded = F.pad(responses[q], (reach, reach, reach, reach))[None, None]
            corr = F.conv2d(padded, responses[p].reshape(1, 1, side, side))[0, 0]  # sum_x k_p(x) k_q(x + lag)
            u, sv, vh = torch.linalg.svd(corr)
            rank = int((sv > 1e-12 * sv[0]).sum()) if sv[0] > 0 else 0
            factors[name] = [(u[:, r] * sv[r], vh[r]) for r in range(rank)]
        cached[window] = factors
    return cached[window]


def _inside(size: int, window: int) -> Tensor:
    """``[p, o]``: whether the pixel at offset ``o`` from a window centre ``p`` is in the frame,
    ``(size, window)`` float64."""
    h = window // 2
    position = torch.arange(size, device="cpu")[:, None] + torch.arange(-h, h + 1, device="cpu")[None, :]
    return ((position >= 0) & (position < size)).to(torch.float64)


def _axis_weights(factor: Tensor, size: int, window: int, power: int) -> Tensor:
    """``sum_{|o'| <= h, 0 <= p + o' < size} factor(o - o') (o' - o)^power`` for each window centre ``p`` and
    offset ``o`` of a pixel in its window: the correlation (``power`` 0) or its moment that pixel meets from
    the window's pixels inside the frame, ``(size, window)``."""
    h = window // 2
    offsets = torch.arange(-h, h + 1, dtype=torch.float64, device="cpu")
    lags = offsets[None, :] - offsets[:, None]  # [o, o']: o' - o
    spread = factor[(-lags).long() + (window - 1)] * lags**power  # factor(o - o') (o' - o)^power
    return _inside(size, window) @ spread.T  # (size, w): [p, o]


def _pair_kind(f: str, g: str) -> str:
    """``PP``, ``PL`` or ``LL``: the spatial filters whose noise two pushed fields carry."""
    kinds = {_KIND[_field(f)[0]], _KIND[_field(g)[0]]}
    return "PP" if kinds == {"P"} else "LL" if kinds == {"L"} else "PL"


def _powers(f: str, g: str) -> tuple[int, int]:
    """Powers ``(along y, along x)`` of the lag in the window sum: 0 for fields, their slopes' axes else."""
    axes = [name[0] for name in (f, g) if len(name) == 3]
    return axes.count("y"), axes.count("x")


def _window_sums(
    filters: MatchedFilters, products: dict[tuple[str, str], Tensor], window: int
) -> dict[tuple[str, str], Tensor]:
    """``sum_{q in W_p} P(q) sum_{q' in W_p} R(q - q') (q' - q)^powers`` for each product map ``P``
    ``(B, H, W)``, with the correlation ``R`` of its pair of spatial filters and the window ``W_p`` clipped to
    the frame."""
    h, w = next(iter(products.values())).shape[-2:]
    half = window // 2
    factors = _correlation_factors(filters, window)
    groups: dict[tuple[str, tuple[int, int]], list] = {}
    for key in products:
        groups.setdefault((_pair_kind(*key), _powers(*key)), []).append(key)
    out = {}
    for (kind, (py, px)), keys in groups.items():
        stacked = F.pad(torch.stack([products[k] for k in keys], 1), (half, half, half, half))
        total = torch.zeros_like(stacked[..., half : half + h, half : half + w])
        for along_y, along_x in factors[kind]:
            wy = _axis_weights(along_y, h, window, py).to(stacked)
            wx = _axis_weights(along_x, w, window, px).to(stacked)
            rows = sum(wx[:, o] * stacked[..., o : o + w] for o in range(window))  # (B, n, H + 2 half, W)
            total = total + sum(wy[:, o, None] * rows[..., o : o + h, :] for o in range(window))
        out |= {k: total[:, n] for n, k in enumerate(keys)}
    return out


def _window_count(shape: tuple[int, int], window: int, device: torch.device) -> Tensor:
    """Pixels of each window inside the frame, ``(H, W)`` float64."""
    h = window // 2
    counts = []
    for size in shape:
        position = torch.arange(size, device=device)
        inside = (position + h).clamp(max=size - 1) - (position - h).clamp(min=0) + 1
        counts.append(inside.to(torch.float64))
    return counts[0][:, None] * counts[1][None, :]
