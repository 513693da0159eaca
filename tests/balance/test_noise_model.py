"""The noise model (:mod:`anra_torch.balance.noise_model`): white and correlated kernels, the covariance of
linear statistics, the static part, the JSON record."""

from __future__ import annotations

import pytest
import torch

from anra_torch.balance.noise_model import NoiseModel

F64 = torch.float64


def test_white_noise_is_the_identity_kernel_and_known_to_well_under_a_percent() -> None:
    model = NoiseModel(0.5)
    assert model.white and not model.static and model.variance_error == 0.0 and model.variance == 0.25
    x = torch.randn(2, 6, 5, 7, dtype=F64)
    torch.testing.assert_close(model.correlate(x), x)
    torch.testing.assert_close(model.quadratic(x), 0.25 * x.reshape(2, -1) @ x.reshape(2, -1).T)


def test_the_covariance_of_a_statistic_is_that_of_noise_drawn_with_the_kernel() -> None:
    """``<b, C b>`` against the covariance matrix built entry by entry from ``rho_t`` and ``rho_s``."""
    model = NoiseModel(1.0, time_corr=(0.5, 0.2), space_length=0.8)
    assert not model.white and model.variance_error == pytest.approx(0.1)
    t, h, w = 4, 3, 3
    rho_t, rho_s = model.time_kernel(), model.space_kernel()
    mt, ms = rho_t.numel() // 2, rho_s.numel() // 2
    idx = [(a, b, c) for a in range(t) for b in range(h) for c in range(w)]
    cov = torch.zeros(len(idx), len(idx), dtype=F64)
    for i, (a, b, c) in enumerate(idx):
        for j, (d, e, f) in enumerate(idx):
            if abs(a - d) <= mt and abs(b - e) <= ms and abs(c - f) <= ms:
                cov[i, j] = rho_t[mt + a - d] * rho_s[ms + b - e] * rho_s[ms + c - f]
    backs = torch.randn(2, t, h, w, dtype=F64)
    flat = backs.reshape(2, -1)
    torch.testing.assert_close(model.quadratic(backs), flat @ cov @ flat.T)


def test_a_static_pattern_adds_the_time_sums_and_goes_with_fixed_effects() -> None:
    model = NoiseModel(1.0, static_sd=2.0)
    assert model.static and not model.white
    x = torch.randn(5, 3, 4, dtype=F64)
    torch.testing.assert_close(model.correlate(x), x + 4.0 * x.sum(-3, keepdim=True).expand_as(x))
    plain = model.without_static()
    assert not plain.static and plain.white


def test_the_record_names_every_part() -> None:
    record = NoiseModel(torch.tensor([0.3]), time_corr=(0.4,), white_sd=0.1, row_sd=0.05).describe()
    assert record == {
        "sd": pytest.approx(0.3),
        "time_correlation": [0.4],
        "space_length_px": 0.0,
        "white_sd": 0.1,
        "static_sd": 0.0,
        "column_sd": 0.0,
        "row_sd": 0.05,
        "white": False,
    }
