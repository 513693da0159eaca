"""The normal equations (:mod:`anra_torch.balance.moments`) against direct sums and least squares in NumPy.

Every expected value is computed here from the definitions in the module's docs, in NumPy float64 loops
over the term pairs: ``raw = sum w z_a z_b``, ``noise = s_ab sum w w_a w_b`` (plus Stein's
``s_UU sum dw/dU X_b`` in the ``U`` row and column), the least-squares coefficients from
:func:`numpy.linalg.lstsq` on the stacked regressors.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from anra_torch.balance import NoiseModel
from anra_torch.balance.moments import (
    Moments,
    TermNoise,
    _disjoint_groups,
    accumulate,
    extend,
    pushback,
    sandwich,
    within,
)

F64 = torch.float64
NAMES = ("U", "L", "T")


def terms(shape: tuple[int, ...] = (2, 5, 6, 7), seed: int = 0) -> dict[str, torch.Tensor]:
    """``U = 0.3 L - 0.1 T + noise`` on random ``L`` and ``T``: a balance with known coefficients."""
    g = torch.Generator().manual_seed(seed)
    lap, temp = torch.randn(shape, generator=g, dtype=F64), torch.randn(shape, generator=g, dtype=F64)
    rate = 0.3 * lap - 0.1 * temp + 0.05 * torch.randn(shape, generator=g, dtype=F64)
    return {"U": rate, "L": lap, "T": temp}


def direct(fields: dict[str, torch.Tensor], names, axes, weights=None) -> np.ndarray:
    """``sum w z_a z_b`` over ``axes`` for every pair, by NumPy, ``(..., P, P)``."""
    z = [fields[n].numpy() for n in names]
    w = np.ones_like(z[0]) if weights is None else weights.numpy()
    return np.stack([np.stack([(w * a * b).sum(axes) for b in z], -1) for a in z], -2)


def test_raw_sums_are_the_products_summed_over_the_chosen_points() -> None:
    fields = terms()
    whole = accumulate(fields, NAMES)
    np.testing.assert_allclose(whole.raw.numpy(), direct(fields, NAMES, (0, 1, 2, 3)), rtol=1e-12)
    per_video = accumulate(fields, NAMES, dims=(1, 2, 3))  # the batched matrix product path
    np.testing.assert_allclose(per_video.raw.numpy(), direct(fields, NAMES, (1, 2, 3)), rtol=1e-12)
    per_frame = accumulate(fields, NAMES, dims=(-2, -1))
    assert per_frame.raw.shape == (2, 5, 3, 3)
    np.testing.assert_allclose(per_frame.raw.numpy(), direct(fields, NAMES, (2, 3)), rtol=1e-12)
    weights = torch.rand(2, 5, 6, 7, generator=torch.Generator().manual_seed(1), dtype=F64)
    weighted = accumulate(fields, NAMES, dims=(1, 2, 3), weights=weights)  # the pairwise path
    np.testing.assert_allclose(weighted.raw.numpy(), direct(fields, NAMES, (1, 2, 3), weights), rtol=1e-12)
    assert bool((whole.noise == 0).all()) and torch.equal(whole.corrected, whole.raw)


def test_a_custom_reduction_sums_each_window() -> None:
    fields = terms((1, 4, 6, 6))
    pairs = accumulate(fields, NAMES, reduce=lambda x: x[..., :3, :].sum((1, 2, 3)))  # the top half
    np.testing.assert_allclose(
        pairs.raw.numpy(), direct({k: v[..., :3, :] for k, v in fields.items()}, NAMES, (1, 2, 3)), rtol=1e-12
    )


def test_noise_parts_are_the_covariance_times_the_weighted_counts() -> None:
    fields = terms((3, 4, 5))
    s = torch.tensor([[2.0, 0.5, 0.1], [0.5, 3.0, 0.2], [0.1, 0.2, 1.0]], dtype=F64)
    plain = accumulate(fields, NAMES, noise=TermNoise(s))
    np.testing.assert_allclose(plain.noise.numpy(), s.numpy() * 60, rtol=1e-12)  # 60 points, unit weights
    # A term whose noise scales with a map (N: T times L's noise) carries it in both of its factors.
    scale = 1.0 + torch.rand(3, 4, 5, generator=torch.Generator().manual_seed(2), dtype=F64)
    w = torch.rand(3, 4, 5, generator=torch.Generator().manual_seed(3), dtype=F64)
    mapped = accumulate(fields, NAMES, weights=w, noise=TermNoise(s, weights={"T": scale}))
    factor = {"U": np.ones((3, 4, 5)), "L": np.ones((3, 4, 5)), "T": scale.numpy()}
    expected = np.array([[s[i, j].item() * (w.numpy() * factor[a] * factor[b]).sum() for j, b in
                          enumerate(NAMES)] for i, a in enumerate(NAMES)])  # fmt: skip
    np.testing.assert_allclose(mapped.noise.numpy(), expected, rtol=1e-12)
    assert torch.equal(mapped.corrected, mapped.raw - mapped.noise)


def test_the_stein_part_enters_the_u_row_and_column_once() -> None:
    fields = terms((3, 4, 5))
    s = torch.diag(torch.tensor([2.0, 3.0, 1.0], dtype=F64))
    slope = torch.randn(3, 4, 5, generator=torch.Generator().manual_seed(4), dtype=F64)
    out = accumulate(fields, NAMES, noise=TermNoise(s, slope=slope)).noise.numpy()
    stein = np.array([(slope.numpy() * fields[n].numpy()).sum() for n in NAMES]) * 2.0  # s_UU = 2
    expected = s.numpy() * 60
    expected[0, :] += stein
    expected[:, 0] += stein
    expected[0, 0] -= stein[0]  # sum (dw/dU) U enters the U x U product once
    np.testing.assert_allclose(out, expected, rtol=1e-12)


def test_normal_equations_give_numpys_least_squares() -> None:
    fields = terms()
    moments = accumulate(fields, NAMES)
    gram, cross = moments.normal_equations(["L", "T"])
    design = np.stack([fields["L"].numpy().ravel(), fields["T"].numpy().ravel()], 1)
    expected, *_ = np.linalg.lstsq(design, fields["U"].numpy().ravel(), rcond=None)
    np.testing.assert_allclose(torch.linalg.solve(gram, cross).numpy(), expected, rtol=1e-10)
    assert abs(expected[0] - 0.3) < 0.01 and abs(expected[1] + 0.1) < 0.01  # the planted balance
    np.testing.assert_allclose(gram.numpy(), design.T @ design, rtol=1e-12)
    # Per video: one fit per leading index, each NumPy's on its own points.
    gram_b, cross_b = accumulate(fields, NAMES, dims=(1, 2, 3)).normal_equations(["L", "T"])
    for b in range(2):
        rows = np.stack([fields["L"][b].numpy().ravel(), fields["T"][b].numpy().ravel()], 1)
        ours = torch.linalg.solve(gram_b[b], cross_b[b]).numpy()
        np.testing.assert_allclose(ours, np.linalg.lstsq(rows, fields["U"][b].numpy().ravel())[0], rtol=1e-10)


def test_moments_of_disjoint_points_add_and_subsets_keep_their_order() -> None:
    fields = terms((8, 5, 5))
    first = accumulate({k: v[:3] for k, v in fields.items()}, NAMES, noise=TermNoise(torch.eye(3, dtype=F64)))
    rest = accumulate({k: v[3:] for k, v in fields.items()}, NAMES, noise=TermNoise(torch.eye(3, dtype=F64)))
    whole = accumulate(fields, NAMES, noise=TermNoise(torch.eye(3, dtype=F64)))
    summed = first + rest
    torch.testing.assert_close(summed.raw, whole.raw, rtol=1e-12, atol=0)
    torch.testing.assert_close(summed.noise, whole.noise, rtol=1e-12, atol=0)
    sub = whole.subset(["T", "U"])
    assert sub.names == ("T", "U") and sub.index(["U"]) == [1]
    assert float(sub.raw[0, 1]) == pytest.approx(float(whole.raw[2, 0]), rel=1e-15)
    assert whole.block(["L"], ["T", "U"], corrected=False).shape == (1, 2)
    with pytest.raises(
        ValueError, match=r"moments of terms \('T', 'U'\) cannot be added to \('U', 'L', 'T'\)"
    ):
        whole + sub
    halves = accumulate(fields, NAMES, dims=(1, 2)).map(lambda x: x.sum(0))  # per frame, then summed
    torch.testing.assert_close(halves.raw, whole.raw, rtol=1e-12, atol=0)
    assert isinstance(halves, Moments)


def test_extend_adds_the_new_terms_products_only() -> None:
    fields = terms((4, 5, 6))
    s = torch.tensor([[1.0, 0.2, 0.1], [0.2, 2.0, 0.3], [0.1, 0.3, 0.5]], dtype=F64)
    scale = 1.0 + torch.rand(4, 5, 6, generator=torch.Generator().manual_seed(5), dtype=F64)
    noise = TermNoise(s, weights={"T": scale})
    base = accumulate(fields, ("U", "L"), noise=TermNoise(s[:2, :2]))
    grown = extend(base, fields, ["T"], noise=noise)
    whole = accumulate(fields, NAMES, noise=noise)
    assert grown.names == NAMES
    torch.testing.assert_close(grown.raw, whole.raw, rtol=1e-12, atol=0)
    torch.testing.assert_close(grown.noise, whole.noise, rtol=1e-12, atol=0)


def test_within_is_an_orthogonal_projection_removing_the_means() -> None:
    g = torch.Generator().manual_seed(6)
    a, b = torch.randn(2, 6, 4, 5, generator=g, dtype=F64), torch.randn(2, 6, 4, 5, generator=g, dtype=F64)
    both = within(a, pixel=True, frame=True)
    torch.testing.assert_close(within(both, pixel=True, frame=True), both, rtol=0, atol=1e-14)  # idempotent
    torch.testing.assert_close(
        (both * b).sum(), (a * within(b, pixel=True, frame=True)).sum(), rtol=1e-12, atol=0
    )  # its own transpose
    assert float(both.mean(-3).abs().max()) < 1e-14 and float(both.mean((-2, -1)).abs().max()) < 1e-14
    expected = a.numpy() - a.numpy().mean(1, keepdims=True)  # per-pixel means over each video's frames
    np.testing.assert_allclose(within(a, pixel=True).numpy(), expected, atol=1e-14)
    gated = within(a, pixel=torch.tensor([True, False]))  # per video
    torch.testing.assert_close(gated[0], within(a[0], pixel=True))
    assert torch.equal(gated[1], a[1]) and torch.equal(within(a), a)


def test_pushback_is_the_transpose_of_the_linear_map() -> None:
    """``<pushback(x), v> = <x, A v>`` for a linear map ``A`` (a time difference then a weighted crop)."""
    g = torch.Generator().manual_seed(7)
    frames = torch.randn(6, 5, 5, generator=g, dtype=F64, requires_grad=True)
    weight = torch.randn(5, 3, 3, generator=g, dtype=F64)

    def apply(v: torch.Tensor) -> torch.Tensor:
        return (v[1:] - v[:-1])[:, 1:-1, 1:-1] * weight

    levers = [torch.randn(5, 3, 3, generator=g, dtype=F64) for _ in range(2)]
    backs = pushback(apply(frames), frames, levers)
    assert backs.shape == (2, 6, 5, 5)
    v = torch.randn(6, 5, 5, generator=g, dtype=F64)
    for back, lever in zip(backs, levers, strict=True):
        assert float((back * v).sum()) == pytest.approx(float((lever * apply(v)).sum()), rel=1e-12)


def test_sandwich_is_the_white_noise_covariance_of_the_coefficients() -> None:
    g = torch.Generator().manual_seed(8)
    backs = torch.randn(2, 4, 3, 3, generator=g, dtype=F64)
    inverse = torch.tensor([[2.0, 0.3], [0.3, 1.0]], dtype=F64)
    flat = backs.reshape(2, -1).numpy()
    expected = inverse.numpy() @ (0.25 * flat @ flat.T) @ inverse.numpy()  # sd 0.5: Cov = 0.25 B B^T
    np.testing.assert_allclose(sandwich(inverse, backs, NoiseModel(0.5)).numpy(), expected, rtol=1e-12)


def test_levers_apart_in_time_share_a_backward_pass_with_the_same_result() -> None:
    """With ``reach`` (a map local in time), levers zero outside spans whose reaches do not meet share one
    backward pass; each is cut out of it: the same ``A^T x`` as one pass per lever, to the bit."""
    g = torch.Generator().manual_seed(9)
    frames = torch.randn(14, 5, 5, generator=g, dtype=F64, requires_grad=True)
    weight = torch.randn(12, 3, 3, generator=g, dtype=F64)
    outputs = (frames[2:] - 2 * frames[1:-1] + frames[:-2])[:, 1:-1, 1:-1] * weight  # reach 3
    full = torch.randn(12, 3, 3, generator=g, dtype=F64)
    levers = [full]
    for start in range(0, 12, 2):  # blocks of two frames: each reach (4 frames) meets its neighbours' ones
        block = torch.zeros(12, 3, 3, dtype=F64)
        block[start : start + 2] = torch.randn(2, 3, 3, generator=g, dtype=F64)
        levers.append(block)
    levers.append(torch.zeros(12, 3, 3, dtype=F64))
    grouped = pushback(outputs, frames, levers, reach=3)
    assert torch.equal(grouped, pushback(outputs, frames, levers))
    # the blocks in 2 groups (every other one shares a pass), the full lever and the zero one alone
    assert len(_disjoint_groups(levers, 3)) == 4
