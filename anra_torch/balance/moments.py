"""The balance's normal equations: sums of weighted products of its terms, minus their noise parts.

:class:`Moments` holds the weighted sums of products ``sum w z_a z_b`` of the terms ``z = (U, X_1, ...)``
of a least-squares fit ``U = sum_j beta_j X_j`` over a set of output points, and their expected noise
parts, subtracted as the errors-in-variables correction; :class:`TermNoise` gives the terms' noise per
point. Moments of disjoint sets of points add, so a long recording accumulates chunk by chunk;
:func:`sandwich` gives the standard errors. The derivation, the Stein term for weights computed from the
noisy ``U`` included: ``docs/architecture.md``, section "The estimator".
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["Moments", "TermNoise", "accumulate", "extend", "pushback", "sandwich", "within"]

Reduce = Callable[[Tensor], Tensor]
"""Sums a product map over the points of one statistic, e.g. over each frame's pixels."""


@dataclass(frozen=True)
class TermNoise:
    """The noise of the terms in a balance, per output point.

    Attributes:
        covariance: ``s_ab``, the noise covariance per point of terms ``a`` and ``b`` (in the order of the
            names given to :func:`accumulate`), ``(P, P)`` or per video ``(B, P, P)``.
        weights: for a term whose noise varies over the points (``N``: ``T`` times ``L``'s noise; a
            fitted shape), its weight map broadcastable to the terms; absent terms have weight 1.
        slope: ``dw/dU`` of weights computed from ``U`` (Stein correction), or None.
    """

    covariance: Tensor
    weights: Mapping[str, Tensor] | None = None
    slope: Tensor | None = None


@dataclass(frozen=True)
class Moments:
    """Sufficient statistics of a balance over a set of points.

    Attributes:
        names: the terms, ``U`` first by convention.
        raw: ``sum w z_a z_b``, ``(..., P, P)``.
        noise: its expected noise part, ``(..., P, P)`` (zeros without a noise model).

    Shape:
        Leading dims ``...`` index the statistics (videos, frames, windows).
    """

    names: tuple[str, ...]
    raw: Tensor
    noise: Tensor

    @property
    def corrected(self) -> Tensor:
        """``raw - noise``: the products of the noise-free terms, in expectation."""
        return self.raw - self.noise

    def index(self, names: Sequence[str]) -> list[int]:
        """Positions of ``names`` in :attr:`names`."""
        return [self.names.index(n) for n in names]

    def block(self, rows: Sequence[str], cols: Sequence[str], *, corrected: bool = True) -> Tensor:
        """The ``rows x cols`` block, ``(..., len(rows), len(cols))``."""
        source = self.corrected if corrected else self.raw
        r, c = self.index(rows), self.index(cols)
        return source[..., r, :][..., :, c]

    def normal_equations(self, columns: Sequence[str], target: str = "U") -> tuple[Tensor, Tensor]:
        """``(X^T X, X^T U)`` of the fit of ``target`` on ``columns``, noise parts removed.

        Shape:
            ``(..., k, k)`` and ``(..., k)``.
        """
        return self.block(columns, columns), self.block(columns, [target])[..., 0]

    def subset(self, names: Sequence[str]) -> Moments:
        """The statistics of ``names`` only, in that order."""
        index = self.index(names)
        return Moments(
            tuple(names), self.raw[..., index, :][..., :, index], self.noise[..., index, :][..., :, index]
        )

    def map(self, fn: Reduce) -> Moments:
        """The same statistics with ``fn`` applied over the leading dims (e.g. a sum over frames).

        ``fn`` acts on tensors whose last two dims are ``(P, P)``.
        """
        return Moments(self.names, fn(self.raw), fn(self.noise))

    def __add__(self, other: Moments) -> Moments:
        if other.names != self.names:
            raise ValueError(f"moments of terms {other.names} cannot be added to {self.names}")
        return Moments(self.names, self.raw + other.raw, self.noise + other.noise)


def _constant(x: Tensor, dims: Sequence[int]) -> Tensor | None:
    """``x`` with the ``dims`` it is constant over (broadcast there: stride 0) taken once and dropped, or None
    where it varies over one of them."""
    if any(x.stride(d) != 0 and x.shape[d] != 1 for d in dims):
        return None
    for d in sorted((d % x.ndim for d in dims), reverse=True):
        x = x.select(d, 0)
    return x


def _sum_over(dims: Sequence[int] | None) -> Reduce:
    return (lambda x: x.sum()) if dims is None else (lambda x: x.sum(tuple(dims)))


def _raw(
    terms: Sequence[Tensor], weights: Tensor | None, reduce: Reduce, dims: Sequence[int] | None
) -> Tensor:
    """``reduce(w z_a z_b)`` for every pair, ``(..., P, P)``."""
    p = len(terms)
    if (  # more than three terms: their products' sums are cheaper as one matrix product
        weights is None
        and p > 3
        and dims is not None
        and sorted(d % terms[0].ndim for d in dims) == list(range(terms[0].ndim - len(dims), terms[0].ndim))
    ):
        # Trailing dims summed: one batched matrix product of the flattened terms.
        lead = terms[0].shape[: terms[0].ndim - len(dims)]
        flat = torch.stack([t.expand_as(terms[0]).reshape(*lead, -1) for t in terms], -1)
        return flat.transpose(-1, -2) @ flat
    products = {}
    for i in range(p):
        for j in range(i, p):
            product = terms[i] * terms[j] if weights is None else weights * terms[i] * terms[j]
            products[i, j] = products[j, i] = reduce(product)
    return torch.stack([torch.stack([products[i, j] for j in range(p)], -1) for i in range(p)], -2)


def _noise(
    names: Sequence[str], terms: Sequence[Tensor], weights: Tensor | None, reduce: Reduce, noise: TermNoise
) -> Tensor:
    """``s_ab reduce(w w_a w_b)`` (plus the Stein part) for every pair, ``(..., P, P)``."""
    p = len(names)
    extra = dict(noise.weights or {})
    ones = torch.ones_like(terms[0]) if weights is None else weights
    counts: dict[tuple, Tensor] = {}

    def count(a: str, b: str) -> Tensor:
        key = tuple(sorted(n for n in (a, b) if n in extra))
        if key not in counts:
            field = ones
            for n in (a, b):
                if n in extra:
                    field = field * extra[n]
            counts[key] = reduce(field.expand_as(terms[0]))
        return counts[key]

    table = torch.stack([torch.stack([count(a, b) for b in names], -1) for a in names], -2)
    cov = noise.covariance
    cov = cov.reshape(*cov.shape[:-2], *([1] * (table.ndim - cov.ndim)), p, p) if cov.ndim > 2 else cov
    out = table * cov
    if noise.slope is not None and "U" in names:
        u = names.index("U")
        stein = torch.stack([reduce(noise.slope * t) for t in terms], -1) * cov[..., u, u : u + 1]
        out = out.clone()
        out[..., u, :] += stein
        out[..., :, u] += stein
        out[..., u, u] -= stein[..., u]
    return out


def accumulate(
    terms: Mapping[str, Tensor],
    names: Sequence[str],
    *,
    dims: Sequence[int] | None = None,
    reduce: Reduce | None = None,
    weights: Tensor | None = None,
    noise: TermNoise | None = None,
) -> Moments:
    """The :class:`Moments` of the named terms over the points that ``dims`` or ``reduce`` sums.

    Args:
        terms: term maps by name, all broadcastable to the first one's shape.
        names: the terms to include, in order (``U`` first by convention).
        dims: dims summed (default all), unless ``reduce`` is given.
        reduce: a custom sum over the points of each statistic (e.g. a box window).
        weights: per-point weights ``w`` (default 1).
        noise: the terms' noise model; None leaves the noise parts zero (no errors-in-variables).

    Returns:
        :class:`Moments` with leading dims those that ``dims``/``reduce`` keep.

    Shape:
        Terms ``(..., h, w)`` alike; output ``(*kept, P, P)``.
    """
    names = tuple(names)
    fields = [terms[n] for n in names]
    fields = [f.expand_as(fields[0]) if f.shape != fields[0].shape else f for f in fields]
    # Weights constant over the summed points (a frame's uniform weights) factor out of every sum.
    constant = None
    if weights is not None and reduce is None and dims is not None and weights.shape == fields[0].shape:
        constant = _constant(weights, dims)
    slope = None if noise is None or noise.slope is None else _constant(noise.slope, dims or ())
    if constant is not None and (
        noise is None or noise.slope is None or (slope is not None and not bool(slope.any()))
    ):
        quiet = None if noise is None else TermNoise(noise.covariance, noise.weights)
        plain = accumulate(terms, names, dims=dims, noise=quiet)
        return Moments(names, plain.raw * constant[..., None, None], plain.noise * constant[..., None, None])
    summed = reduce if reduce is not None else _sum_over(dims)
    raw = _raw(
        fields, weights, summed, None if reduce is not None else (dims or tuple(range(fields[0].ndim)))
    )
    if noise is None:
        return Moments(names, raw, torch.zeros_like(raw))
    return Moments(names, raw, _noise(names, fields, weights, summed, noise).to(raw.dtype))


def extend(
    moments: Moments,
    terms: Mapping[str, Tensor],
    names: Sequence[str],
    *,
    noise: TermNoise | None = None,
) -> Moments:
    """``moments`` with more terms: only the products involving the new ones are computed.

    For sums over all points (the leading dims of ``moments`` empty) with unit weights: a fitted shape
    added to a fixed bank, or a trial shape while it is fitted (differentiable in the new terms and in
    their noise weights).

    Args:
        moments: moments of ``moments.names`` over every point of ``terms``.
        terms: every term by name (old and new), broadcastable to ``terms[moments.names[0]]``.
        names: the new terms.
        noise: the noise model over ``(*moments.names, *names)`` (``covariance`` of that size).

    Shape:
        Output ``(P + E, P + E)``.
    """
    old, new = list(moments.names), list(names)
    every = old + new
    like = terms[old[0]]
    fields = {n: terms[n] if terms[n].shape == like.shape else terms[n].expand_as(like) for n in every}
    weights = dict(noise.weights or {}) if noise is not None else {}
    p = len(every)

    def noise_part(a: str, b: str) -> Tensor:
        if noise is None:
            return moments.raw.new_zeros(())
        field = like.new_ones(())
        for n in (a, b):
            if n in weights:
                field = field * weights[n]
        count = field.expand_as(like).sum() if field.ndim else field * like.numel()
        return noise.covariance[every.index(a), every.index(b)] * count

    raw = [[None] * p for _ in range(p)]
    part = [[None] * p for _ in range(p)]
    for i, a in enumerate(every):
        for j, b in enumerate(every):
            if i < len(old) and j < len(old):
                raw[i][j], part[i][j] = moments.raw[i, j], moments.noise[i, j]
            elif j >= i:
                raw[i][j] = raw[j][i] = (fields[a] * fields[b]).sum()
                part[i][j] = part[j][i] = noise_part(a, b)
    return Moments(
        tuple(every),
        torch.stack([torch.stack(list(row)) for row in raw]),
        torch.stack(
            [
                torch.stack(
                    [torch.as_tensor(v, dtype=moments.raw.dtype, device=moments.raw.device) for v in row]
                )
                for row in part
            ]
        ),
    )


def within(term: Tensor, *, pixel: bool | Tensor = False, frame: bool | Tensor = False) -> Tensor:
    """``term`` without each pixel's mean over time (``pixel``) and/or each frame's mean over space
    (``frame``): per-pixel and per-frame fixed effects (a static pattern, a global offset path).

    A projection: its own transpose, so a lever for a statistic of the transformed terms is transformed
    the same way before it is pushed back.

    Args:
        term: a term ``(..., K, h, w)``.
        pixel: remove per-pixel means; a bool, or ``(B,)`` bools for a batch ``(B, K, h, w)``.
        frame: remove per-frame means; likewise.

    Shape:
        ``(..., K, h, w)`` -> the same.
    """
    for flag, dims in ((pixel, (-3,)), (frame, (-2, -1))):
        if isinstance(flag, Tensor):
            if bool(flag.any()):
                gate = flag.to(term.dtype).view(-1, *([1] * (term.ndim - 1)))
                term = term - gate * term.mean(dims, keepdim=True)
        elif flag:
            term = term - term.mean(dims, keepdim=True)
    return term


def pushback(
    outputs: Tensor, frames: Tensor, levers: Sequence[Tensor], *, reach: int | None = None
) -> Tensor:
    """``A^T x`` for each lever ``x``, where ``A`` is the (linearised) map from ``frames`` to ``outputs``.

    Through the autograd graph that built ``outputs`` from ``frames``: the transposed filters, exactly.
    With ``reach`` (``A`` local in time: output frame ``k`` made from frames ``k .. k + reach - 1`` only),
    levers that are zero outside spans of frames whose reaches do not meet share one backward pass, each
    then cut out of it (``A^T`` is linear: the same numbers, a pass per group instead of per lever).

    Shape:
        ``outputs`` like each lever, frames first; ``frames`` any; output ``(len(levers), *frames.shape)``.
    """
    groups = (
        _disjoint_groups(levers, reach) if reach is not None else [[(i, None)] for i in range(len(levers))]
    )
    backs = frames.new_zeros((len(levers), *frames.shape))
    for group in groups:
        lever = levers[group[0][0]] if len(group) == 1 else sum(levers[i] for i, _ in group)
        # the gradient of <outputs, lever>: the same A^T x, without grad_outputs (whose check imports sympy)
        (back,) = torch.autograd.grad((outputs * lever).sum(), frames, retain_graph=True)
        for i, span in group:
            if span is None or len(group) == 1:
                backs[i] = back
            else:
                backs[i, span] = back[span]
    return backs


def _disjoint_groups(levers: Sequence[Tensor], reach: int) -> list[list[tuple[int, slice | None]]]:
    """The levers in groups whose frames' reaches (``first .. last + reach - 1`` of the nonzero output
    frames) do not meet, each lever with its reach; an all-zero lever alone."""
    spans: list[tuple[int, slice | None]] = []
    for i, lever in enumerate(levers):
        lever = lever.detach()
        if bool(lever[0].ne(0).any()) and bool(lever[-1].ne(0).any()):  # every frame's reach (no scan)
            spans.append((i, slice(0, lever.shape[0] - 1 + reach)))
            continue
        nonzero = torch.nonzero(lever.reshape(lever.shape[0], -1).ne(0).any(1)).flatten()
        spans.append((i, slice(int(nonzero[0]), int(nonzero[-1]) + reach) if nonzero.numel() else None))
    groups: list[list[tuple[int, slice | None]]] = []
    ends: list[int] = []
    for i, span in sorted(spans, key=lambda item: -1 if item[1] is None else item[1].start):
        for g, end in enumerate(ends):
            if span is not None and groups[g][0][1] is not None and end <= span.start:
                groups[g].append((i, span))
                ends[g] = span.stop
                break
        else:
            groups.append([(i, span)])
            ends.append(-1 if span is None else span.stop)
    return groups


def sandwich(inverse: Tensor, backs: Tensor, noise: object) -> Tensor:
    """Covariance ``G^-1 M G^-1`` of coefficients ``G^-1 X^T U`` with ``M = Cov(A^T X)`` from the noise model.

    Args:
        inverse: ``G^-1``, ``(k, k)``.
        backs: the regressors pushed back onto the frames, ``A^T x_j``, ``(k, *frames)``.
        noise: a noise model with ``quadratic(backs) -> (k, k)``
            (:class:`~anra_torch.balance.NoiseModel`).

    Shape:
        Output ``(k, k)``.
    """
    return inverse @ noise.quadratic(backs) @ inverse  # type: ignore[attr-defined]
