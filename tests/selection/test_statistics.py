"""The selection's statistics (:mod:`anra_torch.selection.statistics`) against chi-square tails in closed
form: ``P(chi2_2 > x) = e^(-x/2)``, ``P(chi2_4 > x) = e^(-x/2) (1 + x/2)`` and
``P(chi2_1 > x) = 2 Phi(-sqrt(x))`` (SciPy's ``log_ndtr``), far into the tail where the probabilities
underflow a float."""

from __future__ import annotations

import math

import pytest
import torch
from scipy.special import log_ndtr

from anra_torch.balance import Fit
from anra_torch.selection.statistics import chi2_of_score, log10_pvalue, search_discount, wald_score

F64 = torch.float64
LN10 = math.log(10.0)
CHI2 = [0.0, 0.5, 3.0, 20.0, 150.0, 640.0, 700.0, 2000.0, 1e5]  # past ~1290 Q underflows for dof 2


@pytest.mark.parametrize("chi2", CHI2)
def test_log10_pvalue_is_the_chi_square_tail_in_closed_form(chi2: float) -> None:
    assert log10_pvalue(chi2, 2) == pytest.approx(-chi2 / 2 / LN10, rel=1e-12, abs=1e-15)
    assert log10_pvalue(chi2, 4) == pytest.approx(
        (-chi2 / 2 + math.log1p(chi2 / 2)) / LN10, rel=1e-12, abs=1e-15
    )
    # dof 1: the tail expansion's next term is 0.75 / (chi2 / 2)^2 of Q (2e-6 at the switch, chi2 ~ 1290).
    one = (math.log(2.0) + float(log_ndtr(-math.sqrt(chi2)))) / LN10
    assert log10_pvalue(chi2, 1) == pytest.approx(one, rel=1e-5, abs=1e-12)


def test_chi2_of_score_inverts_the_tail() -> None:
    for dof in (1, 2, 3, 6):
        for score in (0.5, 2.0, 10.0, 300.0):
            assert -log10_pvalue(chi2_of_score(score, dof), dof) == pytest.approx(score, rel=1e-12)
    assert chi2_of_score(7.0, 2) == pytest.approx(2 * 7.0 * LN10, rel=1e-12)
    assert chi2_of_score(0.0, 3) == 0.0 and chi2_of_score(-1.0, 3) == 0.0


def test_the_search_discount_takes_the_penaltys_share_of_the_statistic() -> None:
    """With 2 degrees of freedom ``chi2(score) = 2 ln(10) score``: the share left is ``1 - penalty/score``."""
    assert search_discount(0.0, 2, 9.0) == 1.0
    assert search_discount(4.0, 2, 10.0) == pytest.approx(0.6, rel=1e-10)
    assert search_discount(4.0, 2, 3.0) == 0.0  # a statistic below its penalty explains nothing
    assert 0.0 < search_discount(4.0, 1, 10.0) < 1.0


def test_the_wald_score_of_a_group_of_coefficients() -> None:
    cov = torch.tensor([[4.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 9.0]], dtype=F64)
    beta = torch.tensor([0.3, -0.2, 6.0], dtype=F64)
    fit = Fit(("L", "T", "1"), beta, cov, rss=1.0)
    chi2 = float(beta[:2] @ torch.linalg.inv(cov[:2, :2]) @ beta[:2])
    assert wald_score(fit, ["L", "T"]) == pytest.approx(-log10_pvalue(chi2, 2), rel=1e-12)
    assert wald_score(fit, ["1"]) == pytest.approx(-log10_pvalue(6.0**2 / 9.0, 1), rel=1e-12)  # (6 / 3)^2
    infinite = Fit(("L", "T"), beta[:2], torch.diag(torch.tensor([1.0, math.inf], dtype=F64)), rss=1.0)
    assert wald_score(infinite, ["T"]) == 0.0  # an unresolved coefficient is not evidence
