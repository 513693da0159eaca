"""The doses of the depth march against the dose functions (both rules, blocks joined, in float64 and
float32), CEM43 across 43 C, and the noise's lag sum against the direct double sum."""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.tissue import SKIN, arrhenius_omega, cem43
from anra_torch.tissue.depth_doses import DoseAccumulator

F64 = torch.float64


def _histories(dtype: torch.dtype) -> torch.Tensor:
    """``(1, 40, 3, 4, 5)`` histories (C): random jumps of up to 50 K, a steady rise, a slow drift."""
    x = 37 + 50 * torch.rand(1, 40, 3, 4, 5, dtype=F64, generator=torch.Generator().manual_seed(0))
    x[:, :, 0] = 37 + torch.linspace(0, 40, 40, dtype=F64).view(40, 1, 1)
    x[:, :, 1] = 50 + torch.linspace(0, 0.1, 40, dtype=F64).view(40, 1, 1)
    return x.to(dtype)


@pytest.mark.parametrize("dtype", [F64, torch.float32])
def test_doses_match_the_dose_functions(dtype: torch.dtype) -> None:
    x = _histories(dtype)
    doses = DoseAccumulator(
        x, (1, 3, 4, 5), torch.tensor([0.1], dtype=F64), "linear", SKIN, 1, torch.zeros(1, 3)
    )
    for start in range(0, 40, 7):  # blocks of 7 frames, joined by their linear segments
        doses.add(x[:, start : start + 7])
    history = x[0].double().reshape(40, 60, 1)
    rtol = 1e-6 if dtype == F64 else 3e-5  # float32 exponents: 226 +- 1e-5
    for mine, function, rule in (
        (doses.omega, arrhenius_omega, "linear"),
        (doses.other("omega"), arrhenius_omega, "hold"),
        (doses.cem43, cem43, "linear"),
        (doses.other("cem43"), cem43, "hold"),
    ):
        torch.testing.assert_close(
            mine.reshape(-1), function(history, 0.1, rule=rule).reshape(-1), rtol=rtol, atol=0
        )
    torch.testing.assert_close(doses.peak, x.amax(1))


def test_cem43_across_43_c_is_exact() -> None:
    x = torch.tensor([40.0, 45.0, 41.0, 43.0, 43.0, 50.0, 30.0], dtype=F64).view(1, 7, 1, 1, 1)
    doses = DoseAccumulator(
        x, (1, 1, 1, 1), torch.tensor([1.0], dtype=F64), "linear", SKIN, 1, torch.zeros(1, 1)
    )
    doses.add(x[:, :3])
    doses.add(x[:, 3:])

    # 40 -> 45: 3/5 of the segment below 43 at ln 4 per K, 2/5 above at ln 2 per K, and so on: each
    # segment's mean rate in closed form (cem43's own is 1e-10 exact by design, this one to rounding).
    def integral(low: float, high: float) -> float:  # of R^(43 - T) dT from low to high, both on one side
        c = math.log(2.0) if low >= 43.0 else math.log(4.0)
        return (math.exp(c * (high - 43.0)) - math.exp(c * (low - 43.0))) / c

    exact = 0.0
    values = x.view(7).tolist()
    for u, v in zip(values[:-1], values[1:], strict=True):
        low, high = min(u, v), max(u, v)
        if low == high:
            exact += math.exp((low - 43.0) * (math.log(2.0) if low >= 43.0 else math.log(4.0)))
            continue
        cut = min(max(43.0, low), high)
        exact += (integral(low, cut) + integral(cut, high)) / (high - low)
    assert float(doses.cem43) == pytest.approx(exact / 60.0, rel=1e-14)
    assert float(cem43(x.view(7), 1.0, rule="linear")) == pytest.approx(exact / 60.0, rel=1e-10)


def test_noise_lag_sum_is_the_double_sum() -> None:
    """``sum_t sum_t' f'_t f'_t' rho^|t - t'|`` accumulated by the recursive filter, across blocks."""
    x = 50 + 5 * torch.sin(torch.arange(12, dtype=F64) / 2).view(1, 12, 1, 1, 1)
    rho = 0.6
    doses = DoseAccumulator(
        x, (1, 1, 1, 1), torch.tensor([0.5], dtype=F64), "hold", SKIN, 1, torch.full((1, 1), rho)
    )
    doses.add(x[:, :5])
    doses.add(x[:, 5:])
    kelvin = x.flatten() + 273.15
    theta = SKIN.activation_energy / 8.314462618
    slope = SKIN.frequency * torch.exp(-theta / kelvin) * theta / kelvin**2 * 0.5  # d(rate dt) / dT
    lags = (torch.arange(12).view(-1, 1) - torch.arange(12).view(1, -1)).abs()
    direct = (slope.view(-1, 1) * slope.view(1, -1) * rho ** lags.to(F64)).sum()
    assert float(doses.variance["omega"]) == pytest.approx(float(direct), rel=1e-7)  # exp(log_a - ...)
    assert math.isfinite(float(doses.variance["cem43"]))
