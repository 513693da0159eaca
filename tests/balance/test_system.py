"""The balance of one video (:mod:`anra_torch.balance.system`): its fits against least squares in NumPy
and against an exact solution of the heat equation, extra terms, residuals.

The exact solution is ``T = x^3 + y^3 + 6 a t (x + y)`` (``Lap Lap T = 0``, so ``dT/dt = a Lap T`` holds
for all time): the 5-point Laplacian is exact on cubics, the Gaussian moves a cubic by a linear function
(whose Laplacian is zero) and the time filters are exact on a linear time course, so ``U = a L`` holds
for the filtered terms to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from anra_torch.balance import BalanceSystem, NoiseSpec

F64 = torch.float64
DT, DX, A = 0.1, 0.5, 0.3  # s, mm, mm^2/s


def cubic_heat(frames: int = 12, size: int = 20) -> torch.Tensor:
    """The exact solution above, ``(frames, size, size)``."""
    t = (torch.arange(frames, dtype=F64) * DT)[:, None, None]
    y = (torch.arange(size, dtype=F64) * DX)[None, :, None] - 4.0
    x = (torch.arange(size, dtype=F64) * DX)[None, None, :] - 5.0
    return 20.0 + 0.01 * (x**3 + y**3 + 6 * A * t * (x + y))


def noisy(seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return cubic_heat() + 0.002 * torch.randn(12, 20, 20, generator=g, dtype=F64)


def test_the_diffusivity_of_an_exact_solution_is_recovered_to_rounding() -> None:
    system = BalanceSystem(cubic_heat(), DT, DX, sigma=1.0, noise_sd=0.0)
    fit = system.fit(["L"])
    assert fit.coefficients()["L"] == pytest.approx(A, rel=1e-9)
    assert fit.rss < 1e-12 * float(system.detached["U"].pow(2).sum())
    assert system.expected_rss(fit) == 0.0  # no noise model, no expected residual
    assert system.u.shape == (8, 20 - 2 * system.margin, 20 - 2 * system.margin)  # 12 - 4 frames


@pytest.mark.parametrize("columns", [["L"], ["L", "T", "1"], ["L", "T_x", "T_y"]])
def test_without_noise_the_fit_is_numpys_least_squares(columns: list[str]) -> None:
    system = BalanceSystem(noisy(), DT, DX, sigma=1.0, noise_sd=0.0)
    fit = system.fit(columns)
    design = np.stack([system.detached[c].numpy().ravel() for c in columns], 1)
    expected, rss, *_ = np.linalg.lstsq(design, system.detached["U"].numpy().ravel(), rcond=None)
    np.testing.assert_allclose(fit.beta.numpy(), expected, rtol=1e-8)
    assert fit.rss == pytest.approx(float(rss[0]), rel=1e-8)
    assert fit.columns == tuple(columns) and list(fit.std_errors()) == columns
    residual = system.residual(fit)
    np.testing.assert_allclose(
        residual.numpy().ravel(), system.detached["U"].numpy().ravel() - design @ expected, atol=1e-9
    )


def test_a_noise_model_takes_its_expected_part_out_of_the_normal_equations() -> None:
    """The corrected ``X^T X`` is the raw sum minus ``n sd^2 <k_L, k_L> / dx^4`` (errors-in-variables)."""
    plain = BalanceSystem(noisy(), DT, DX, sigma=1.0, noise_sd=0.0)
    sd = 0.002
    corrected = BalanceSystem(noisy(), DT, DX, sigma=1.0, noise_sd=sd)
    gram_raw, cross_raw = plain.normal_equations(["L"])
    gram, cross = corrected.normal_equations(["L"])
    per_point = sd**2 * float(corrected.filters.noise_inner(["L"])[0, 0]) / DX**4
    assert float(gram_raw - gram) == pytest.approx(corrected.n * per_point, rel=1e-10)
    per_point_ul = sd**2 * float(corrected.filters.noise_inner(["U", "L"])[0, 1]) / (DT * DX**2)
    assert float(cross_raw - cross) == pytest.approx(corrected.n * per_point_ul, rel=1e-8, abs=1e-12)
    fit = corrected.fit(["L"])
    assert fit.coefficients()["L"] == pytest.approx(A, rel=0.05)  # 0.2 % noise of a 1 K field
    assert 0 < fit.std_errors()["L"] < 0.05 * A
    assert torch.equal(
        corrected.correction_covariance(["L"], torch.eye(1, dtype=F64), fit.beta), torch.zeros(1, 1)
    )


def test_an_extra_term_enters_the_fits_with_its_noise() -> None:
    """An extra term twice ``T`` with ``T``'s noise twice over gets half ``T``'s coefficient, whatever the
    noise correction."""
    system = BalanceSystem(noisy(1), DT, DX, sigma=1.0, noise_sd=0.002)
    with_t = system.fit(["L", "T"])
    system.add("twice_T", 2 * system.terms["T"], NoiseSpec("T", torch.tensor(2.0, dtype=F64)))
    with_extra = system.fit(["L", "twice_T"])
    assert with_extra.coefficients()["twice_T"] == pytest.approx(with_t.coefficients()["T"] / 2, rel=1e-9)
    assert with_extra.coefficients()["L"] == pytest.approx(with_t.coefficients()["L"], rel=1e-9)
    assert with_extra.std_errors()["twice_T"] == pytest.approx(with_t.std_errors()["T"] / 2, rel=1e-6)
    assert "twice_T" in system.moments.names and system.kernels["twice_T"] == "T"


def test_the_profile_loss_prefers_the_term_the_data_hold() -> None:
    """``e^(-b t)`` times a heat solution solves ``dT/dt = a Lap T - b T``: the plain model plus the loss
    term ``T`` leaves almost nothing above the noise; plus an unrelated field, the plain model's misfit."""
    t = (torch.arange(12, dtype=F64) * DT)[:, None, None]
    cooling = (cubic_heat() - 20.0) * torch.exp(-0.5 * t)
    system = BalanceSystem(cooling, DT, DX, sigma=1.0, noise_sd=0.0)
    held = system.profile_loss(["L", "1"], system.terms["T"].detach())  # the terms are centred on Tbar
    unrelated = torch.randn(system.u.shape, generator=torch.Generator().manual_seed(3), dtype=F64)
    other = system.profile_loss(["L", "1"], unrelated)
    assert float(held) < 1e-4 * float(other)  # measured 2e-8: the time filters' error on e^(-b t)
    fitted = system.fit(["L", "1", "T"]).coefficients()
    assert fitted["L"] == pytest.approx(A, rel=3e-3) and fitted["T"] == pytest.approx(
        -0.5, rel=3e-3
    )  # 1e-3, 4e-4


def test_rates_per_block_of_frames_get_the_same_fit_with_shared_backward_passes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Terms zero outside blocks of frames (a loss rate per block, as the depth-aware fit adds) share
    backward passes in the sandwich (the filters are local in time): the same fit as one pass per term; with
    per-pixel fixed effects (a mean over every frame) nothing is shared."""
    system = BalanceSystem(noisy(), DT, DX, sigma=1.0, noise_sd=0.002, within=("frame",))
    rates = {}
    for b, start in enumerate(range(0, 8, 2)):
        mask = torch.zeros_like(system.u)
        mask[start : start + 2] = 1.0
        rates[f"T@{b}"] = (system.detached["T"] * mask, NoiseSpec("T", mask))
    system.add_terms(rates)
    columns = ["L", *rates]
    assert system._reach(columns) == 5
    shared = system.fit(columns)
    monkeypatch.setattr(BalanceSystem, "_reach", lambda self, columns: None)
    alone = system.fit(columns)
    assert torch.equal(shared.beta, alone.beta) and torch.equal(shared.cov, alone.cov)
    monkeypatch.undo()
    assert BalanceSystem(noisy(), DT, DX, sigma=1.0, noise_sd=0.002, within=("pixel",))._reach(["L"]) is None
