"""Statistics of the model selection: Wald tests and their tail probabilities, shape-search discounts."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from anra_torch.balance import Fit

__all__ = ["chi2_of_score", "log10_pvalue", "search_discount", "wald_score"]

_F64 = torch.float64


def wald_score(fit: Fit, group: Sequence[str]) -> float:
    """``-log10 p`` of the Wald test that the group's coefficients are zero."""
    idx = [fit.columns.index(c) for c in group]
    b, cov = fit.beta[idx], fit.cov[idx][:, idx]
    chi2 = float(b @ torch.linalg.pinv(cov, hermitian=True) @ b)
    if not math.isfinite(chi2):
        return 0.0
    return -log10_pvalue(chi2, len(idx))


def log10_pvalue(chi2: float, dof: int) -> float:
    """``log10 P(chi2_dof > chi2)``, accurate far into the tail (no underflow)."""
    s, x = 0.5 * dof, 0.5 * max(chi2, 0.0)
    q = float(
        torch.special.gammaincc(
            torch.tensor(s, dtype=_F64, device="cpu"), torch.tensor(x, dtype=_F64, device="cpu")
        )
    )
    if q > 1e-280:
        return math.log10(q)
    # Q(s, x) ~ x^(s-1) e^-x / Gamma(s) (1 + (s-1)/x) for large x.
    return ((s - 1.0) * math.log(x) - x - math.lgamma(s) + math.log1p((s - 1.0) / x)) / math.log(10.0)


def chi2_of_score(score: float, dof: int) -> float:
    """The chi-square statistic whose ``-log10 p`` at ``dof`` degrees of freedom is ``score`` (bisection)."""
    if score <= 0.0:
        return 0.0
    low, high = 0.0, 1.0
    while -log10_pvalue(high, dof) < score:
        high *= 2.0
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if -log10_pvalue(mid, dof) < score else (low, mid)
    return 0.5 * (low + high)


def search_discount(penalty: float, dof: int, score: float) -> float:
    """Share of an effect's statistic left after its look-elsewhere ``penalty`` (1 without a shape).

    The best of many trial shapes explains some noise too: of a statistic ``chi2(score)``, the part the
    penalty stands for, ``chi2(score) - chi2(score - penalty)``, is not counted as explained signal.
    """
    if penalty == 0.0:
        return 1.0
    full = chi2_of_score(score, dof)
    return chi2_of_score(score - penalty, dof) / full if full > 0 else 0.0
