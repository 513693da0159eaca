"""The loss rate's standard error without noise copies (:mod:`anra_torch.balance.loss_error`), against the
functional it stands for: the window's first-order change of ``b`` under white frame noise, written here
from the filters themselves (``MatchedFilters.terms`` of a noise video, the levers, the window means).

Its exact variance comes from autograd (the squared weights of the functional, window by window); the
Monte Carlo route (seeded noise videos through the same functional) is the reference on a realistic scene.
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from anra_torch.balance import MatchedFilters, loss
from anra_torch.balance.loss_error import loss_rate_error
from anra_torch.simulation import MovingSource, simulate_tissue

F64 = torch.float64
WINDOW = 9
FIELDS = ("uL", "zL", "mL", "uR", "zR", "mR")


def features_filters() -> MatchedFilters:
    """The filters of :class:`~anra_torch.tissue.TissueFeatures`."""
    return MatchedFilters(
        2.0, laplacian_size=3, laplacian_family="holoborodko", border="replicate", smoothing_border="reflect"
    )


def change(filters: MatchedFilters, levers: dict, coefficients: dict, noise: torch.Tensor) -> torch.Tensor:
    """The first-order change of each window's ``b`` under ``noise`` ``(1, T, H, W)``: ``sum_f C_f`` times
    the window mean of the lever times the noise of the field's term (``u``: ``U``, ``z``: the rise of
    ``T``, ``m``: ``L``; unit ``dt`` and ``dx``, the coefficients carry the units), ``(1, H, W)``."""
    terms = filters.terms(noise, 1.0, 1.0, ("U", "L", "T"))
    noise_of = {"u": terms["U"], "z": terms["T"] - terms["T"][:, :1], "m": terms["L"]}
    total = torch.zeros_like(noise[:, 0])
    for name in FIELDS:
        product = (levers[name[1]] * noise_of[name[0]]).sum(1, keepdim=True)
        mean = F.avg_pool2d(product, WINDOW, stride=1, padding=WINDOW // 2, count_include_pad=False)
        total = total + coefficients[name] * mean[:, 0]
    return total


def exact_sd(filters: MatchedFilters, levers: dict, coefficients: dict, pixels: list) -> torch.Tensor:
    """The functional's exact sd per unit noise at ``pixels``: the norm of its weights (autograd)."""
    frames = levers["L"].shape[1] + filters.time.length - 1
    noise = torch.zeros(1, frames, *levers["L"].shape[-2:], dtype=F64, requires_grad=True)
    with torch.enable_grad():
        out = change(filters, levers, coefficients, noise)
        sds = [torch.autograd.grad(out[0, y, x], noise, retain_graph=True)[0].norm() for y, x in pixels]
    return torch.stack(sds)


def analytic_sd(filters: MatchedFilters, levers: dict, coefficients: dict) -> torch.Tensor:
    return loss_rate_error(
        filters, (levers["L"], levers["R"]), coefficients, torch.ones(1, dtype=F64), WINDOW
    )[0]


def interior(size: int, filters: MatchedFilters, step: int = 1) -> list:
    """Window centres whose window and filters stay clear of the frame's padded border."""
    margin = filters.reach + WINDOW // 2 + 1
    return [(y, x) for y in range(margin, size - margin, step) for x in range(margin, size - margin, step)]


def random_coefficients(size: int, seed: int, zero: tuple[str, ...] = ()) -> dict:
    """Smooth random coefficient maps ``(1, H, W)`` (they vary from window to window, as a fit's do)."""
    g = torch.Generator().manual_seed(seed)
    out = {}
    for name in FIELDS:
        coarse = torch.randn(1, 1, 4, 4, generator=g, dtype=F64)
        smooth = F.interpolate(coarse, size=(size, size), mode="bilinear", align_corners=True)[:, 0]
        out[name] = torch.zeros_like(smooth) if name in zero else 1.0 + 0.5 * smooth
    return out


def test_exact_for_levers_constant_over_the_window() -> None:
    # Each pixel's lever constant in space (any time course, cooling from different frames in two halves of
    # the frame): the local sums are the exact ones.
    filters, size, k = features_filters(), 40, 14
    g = torch.Generator().manual_seed(0)
    course = torch.randn(2, k, 1, 1, generator=g, dtype=F64)
    levers = {name: course[i].expand(k, size, size)[None].clone() for i, name in enumerate("LR")}
    coefficients = random_coefficients(size, 1)
    pixels = interior(size, filters, step=3)
    got = analytic_sd(filters, levers, coefficients)
    want = exact_sd(filters, levers, coefficients, pixels)
    torch.testing.assert_close(torch.stack([got[y, x] for y, x in pixels]), want, rtol=1e-5, atol=0)


def test_exact_for_a_laplacian_lever_linear_over_the_window() -> None:
    # The Laplacian's noise alone (only the m fields weigh) and a lever linear in x and y: the slope part
    # restores what the constant-lever sums miss of its sign-changing correlation.
    filters, size, k = features_filters(), 40, 12
    g = torch.Generator().manual_seed(2)
    t = torch.randn(3, k, 1, 1, generator=g, dtype=F64)
    y = torch.arange(size, dtype=F64).view(1, -1, 1)
    x = torch.arange(size, dtype=F64).view(1, 1, -1)
    levers = {"L": (t[0] + 0.3 * t[1] * x - 0.2 * t[2] * y)[None], "R": (t[1] + 0.1 * t[0] * y + 0 * x)[None]}
    coefficients = random_coefficients(size, 3, zero=("uL", "zL", "uR", "zR"))
    pixels = interior(size, filters, step=3)
    got = analytic_sd(filters, levers, coefficients)
    want = exact_sd(filters, levers, coefficients, pixels)
    torch.testing.assert_close(torch.stack([got[y, x] for y, x in pixels]), want, rtol=1e-5, atol=0)


def heated_fit(size: int = 32, frames: int = 30) -> tuple[dict, dict]:
    """The levers and coefficients :func:`fit_loss_windows` hands over on a spot heated for 2 s, then
    cooling (a = 0.1, b = 0.3, 0.05 K noise): each pixel's Laplacian and rise on its frames after its peak,
    and each window's weights from its fit (in units of 1/s; ``dt`` 0.1 s, ``dx`` 0.2 mm)."""
    u0 = torch.full((size, size), 37.0, dtype=F64)
    c = size * 0.2 / 2
    source = MovingSource(start=(c, c), end=(c, c), width=0.8, power=10.0, t_off=2.0)
    clean = simulate_tissue(u0, 0.1, 0.3, dx=0.2, dt=0.1, n_frames=frames, source=source)
    video = clean + 0.05 * torch.randn(clean.shape, generator=torch.Generator().manual_seed(4), dtype=F64)
    filters = features_filters()
    terms = filters.terms(video[None], 0.1, 0.2, ("U", "L", "T"))
    one = torch.ones(1, dtype=F64)
    handed = {}

    def capture(filters, levers, coefficients, noise_sd, window):  # noqa: ANN001, ANN202
        handed.update(levers=dict(zip("LR", levers, strict=True)), coefficients=coefficients)
        return torch.zeros_like(levers[0][:, 0])

    original = loss.loss_rate_error
    loss.loss_rate_error = capture
    try:
        loss.fit_loss_windows(filters, terms, torch.zeros(1, size, size, dtype=F64), 0.05 * one, 0.1 * one,
                              0.2 * one, window=WINDOW)  # fmt: skip
    finally:
        loss.loss_rate_error = original
    return handed["levers"], handed["coefficients"]


def test_agrees_with_the_monte_carlo_route_on_a_heated_spot() -> None:
    # 200 seeded noise videos through the same functional: each window's sd to ~5 %. The analytic sd is
    # exact in time and takes each pixel's lever as constant over the noise correlation length: on the
    # spot, whose Laplacian turns over within a window, it stays above the Monte Carlo sd (conservative).
    filters, size = features_filters(), 32
    levers, coefficients = heated_fit(size)
    frames = levers["L"].shape[1] + filters.time.length - 1
    g = torch.Generator().manual_seed(6)
    total = torch.zeros(size, size, dtype=F64)
    for _ in range(200):
        noise = torch.randn(1, frames, size, size, generator=g, dtype=F64)
        total += change(filters, levers, coefficients, noise)[0] ** 2
    monte_carlo = (total / 200).sqrt()
    got = analytic_sd(filters, levers, coefficients)
    ratio = torch.stack([got[y, x] / monte_carlo[y, x] for y, x in interior(size, filters)])
    assert 1.0 <= float(ratio.median()) <= 1.45  # measured 1.31
    assert 0.95 <= float(ratio.min()) and float(ratio.max()) <= 1.8  # measured 1.05 and 1.57
    assert bool(torch.isfinite(got).all()) and bool((got >= 0).all())  # every window, border ones included


def test_the_error_scales_with_the_noise_and_works_on_a_batch() -> None:
    filters, size = features_filters(), 24
    levers, coefficients = heated_fit(size, frames=16)
    one = analytic_sd(filters, levers, coefficients)
    both = loss_rate_error(
        filters,
        (levers["L"].expand(2, -1, -1, -1), levers["R"].expand(2, -1, -1, -1)),
        {k: v.expand(2, -1, -1) for k, v in coefficients.items()},
        torch.tensor([1.0, 3.0], dtype=F64),
        WINDOW,
    )
    torch.testing.assert_close(both[0], one, rtol=1e-12, atol=0)
    torch.testing.assert_close(both[1], 3.0 * one, rtol=1e-12, atol=0)


@pytest.mark.parametrize("size", [5, 11])
def test_frames_smaller_than_the_window_give_finite_errors(size: int) -> None:
    filters = features_filters()
    g = torch.Generator().manual_seed(8)
    levers = {name: torch.randn(1, 6, size, size, generator=g, dtype=F64) for name in "LR"}
    got = analytic_sd(filters, levers, random_coefficients(size, 9))
    assert got.shape == (size, size) and bool(torch.isfinite(got).all())
