"""Thermal dose: CEM43, Arrhenius Omega and time above a threshold against closed forms and scipy quad."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import integrate

from anra_torch.tissue.dose import (
    SKIN,
    ArrheniusConstants,
    arrhenius_omega,
    cem43,
    count_masked,
    dose_maps,
    time_above,
)

R_GAS = 8.314462618


def _omega_rate(celsius: float, a: float = 3.1e98, ea: float = 6.28e5) -> float:
    """Henriques-Moritz damage rate (1/s), written from the formula."""
    return a * math.exp(-ea / (R_GAS * (celsius + 273.15)))


def _cem_rate(celsius: float) -> float:
    return (0.5 if celsius >= 43.0 else 0.25) ** (43.0 - celsius)


def _quad_linear(rate, samples: np.ndarray, dt: float, breaks: tuple[float, ...] = ()) -> float:
    """Integral of rate(T(t)) for the piecewise-linear interpolant, segment by segment with quad."""
    total = 0.0
    for k in range(len(samples) - 1):
        t0, t1 = samples[k], samples[k + 1]

        def f(s: float, t0: float = t0, t1: float = t1) -> float:
            return rate(t0 + (t1 - t0) * s)

        points = [(b - t0) / (t1 - t0) for b in breaks if t1 != t0 and 0 < (b - t0) / (t1 - t0) < 1]
        value, _ = integrate.quad(f, 0.0, 1.0, points=points or None, epsabs=0.0, epsrel=1e-13, limit=200)
        total += value * dt
    return total


# ------------------------------------------------------------------------------------ CEM43
@pytest.mark.parametrize(
    ("celsius", "minutes", "expected"), [(43.0, 10.0, 10.0), (44.0, 5.0, 10.0), (42.0, 20.0, 5.0)]
)
@pytest.mark.parametrize("dt", [1.0, 0.25])
def test_cem43_constant_histories_are_exact(
    celsius: float, minutes: float, expected: float, dt: float
) -> None:
    n = round(minutes * 60 / dt)
    assert float(cem43(torch.full((n,), celsius), dt)) == pytest.approx(expected, rel=1e-12)
    # The interpolant of n + 1 samples lasts n dt.
    linear = cem43(torch.full((n + 1,), celsius, dtype=torch.float64), dt, rule="linear")
    assert float(linear) == pytest.approx(expected, rel=1e-12)


def test_cem43_step_history_is_the_sapareto_dewey_sum() -> None:
    # 2 min at 37 C, 5 min at 44 C, 3 min at 41 C, sampled at 2 Hz.
    history = torch.cat([torch.full((240,), 37.0), torch.full((600,), 44.0), torch.full((360,), 41.0)])
    expected = (120 * 0.25**6 + 300 * 2.0 + 180 * 0.25**2) / 60.0
    assert float(cem43(history, 0.5)) == pytest.approx(expected, rel=1e-12)


def test_cem43_linear_matches_quad() -> None:
    rng = np.random.default_rng(3)
    samples = 41.0 + 4.0 * np.sin(np.linspace(0, 7, 40)) + rng.normal(0, 0.5, 40)
    samples[10] = 43.0  # a sample exactly at the breakpoint
    samples[11] = 43.0  # and a flat segment on it
    expected = _quad_linear(_cem_rate, samples, 0.3, breaks=(43.0,)) / 60.0
    got = float(cem43(torch.tensor(samples), 0.3, rule="linear"))
    assert got == pytest.approx(expected, rel=1e-10)


def test_cem43_kelvin_equals_celsius() -> None:
    history = torch.linspace(37.0, 55.0, 50, dtype=torch.float64)
    for rule in ("hold", "linear"):
        kelvin = cem43(history + 273.15, 0.1, units="K", rule=rule)
        assert float(kelvin) == pytest.approx(float(cem43(history, 0.1, rule=rule)), rel=1e-10)


# --------------------------------------------------------------------------------------- Omega
def test_omega_hold_is_the_arrhenius_sum() -> None:
    history = torch.tensor([37.0, 55.0, 61.5, 66.0, 58.0, 45.0], dtype=torch.float64)
    expected = sum(_omega_rate(float(t)) for t in history) * 0.2
    assert float(arrhenius_omega(history, 0.2)) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("jump", [False, True])
def test_omega_linear_matches_quad(jump: bool) -> None:
    rng = np.random.default_rng(5)
    samples = 50.0 + 12.0 * np.sin(np.linspace(0, 3, 30)) + rng.normal(0, 1.0, 30)
    if jump:  # one frame from body temperature to 95 C: the segment needs many Gauss-Legendre pieces
        samples[7], samples[8] = 37.0, 95.0
    expected = _quad_linear(_omega_rate, samples, 0.05)
    got = float(arrhenius_omega(torch.tensor(samples), 0.05, rule="linear"))
    assert got == pytest.approx(expected, rel=1e-6)
    assert abs(got / expected - 1) < 1e-9  # measured: far inside the 1e-6 acceptance


@pytest.mark.parametrize("step", [0.0, 1e-12, 1e-7, 1e-4, 0.3])
def test_omega_linear_is_exact_on_flat_and_nearly_flat_segments(step: float) -> None:
    # The closed form divides by each segment's rise: flat and nearly flat ones take its limit smoothly.
    samples = np.array([55.0, 55.0 + step, 55.0 + 2 * step, 61.0, 61.0 + step])
    expected = _quad_linear(_omega_rate, samples, 0.5)
    got = float(arrhenius_omega(torch.tensor(samples), 0.5, rule="linear"))
    assert got == pytest.approx(expected, rel=1e-10)


def test_omega_linear_matches_quad_for_other_constants_and_beyond_the_series_reach() -> None:
    # Pig skin (Ea / R_gas = 31 000 K) up to 150 C needs more terms of the closed form's series; a small
    # activation energy (600 K) puts body temperature beyond its reach: composite Gauss-Legendre there.
    rng = np.random.default_rng(7)
    samples = 60.0 + 40.0 * np.sin(np.linspace(0, 4, 25)) + rng.normal(0, 2.0, 25)
    for a, ea in ((7.39e39, 2.577e5), (2.0, 5.0e3)):
        constants = ArrheniusConstants(frequency=a, activation_energy=ea)
        expected = _quad_linear(lambda t, a=a, ea=ea: _omega_rate(t, a, ea), samples, 0.1)
        got = float(arrhenius_omega(torch.tensor(samples), 0.1, constants=constants, rule="linear"))
        assert got == pytest.approx(expected, rel=1e-10)


def test_gradients_flow_through_the_linear_doses_also_on_flat_segments() -> None:
    history = torch.tensor([37.0, 52.0, 52.0, 61.5, 44.0, 42.5, 43.0], dtype=torch.float64)
    history.requires_grad_()
    for fn in (arrhenius_omega, cem43):
        assert torch.autograd.gradcheck(lambda v, fn=fn: fn(v, 0.2, rule="linear"), (history,))


def test_omega_constants_are_configurable() -> None:
    pig = ArrheniusConstants(frequency=7.39e39, activation_energy=2.577e5)
    history = torch.full((11,), 55.0, dtype=torch.float64)
    expected = 10 * _omega_rate(55.0, 7.39e39, 2.577e5)
    assert float(arrhenius_omega(history, 1.0, constants=pig, rule="linear")) == pytest.approx(
        expected, rel=1e-12
    )
    assert SKIN.frequency == 3.1e98 and SKIN.activation_energy == 6.28e5
    with pytest.raises(ValueError, match="activation_energy must be a positive"):
        ArrheniusConstants(frequency=1.0, activation_energy=-1.0)


def test_omega_reaches_one_near_sixty_celsius_in_a_second() -> None:
    # ln A = Ea / (R T) at T = 333.06 K: one second there is Omega = 1.
    kelvin = 6.28e5 / (R_GAS * math.log(3.1e98))
    history = torch.full((1,), kelvin, dtype=torch.float64)
    assert float(arrhenius_omega(history, 1.0, units="K")) == pytest.approx(1.0, rel=1e-12)


# ---------------------------------------------------------------------------------- time above
def test_time_above_triangle_pulse() -> None:
    # 37 -> 67 C linearly over 30 s and back over 30 s: above 52 C for 2 * 15 s.
    history = torch.cat([torch.linspace(37, 67, 31), torch.linspace(66, 37, 30)]).double()
    assert float(time_above(history, 1.0, 52.0, rule="linear")) == pytest.approx(30.0, rel=1e-12)
    # hold: samples 52..67..52 -> 16 + 15 frames
    assert float(time_above(history, 1.0, 52.0)) == pytest.approx(31.0, rel=1e-12)


def test_time_above_a_flat_segment_at_the_threshold_counts() -> None:
    history = torch.tensor([43.0, 43.0, 43.0, 42.0], dtype=torch.float64)
    assert float(time_above(history, 1.0, 43.0, rule="linear")) == 2.0
    assert float(time_above(history, 1.0, 43.0 + 1e-9, rule="linear")) == 0.0


def test_cem43_linear_across_43_on_a_tiny_rise_is_the_rate_there() -> None:
    # A segment crossing 43 C over 2e-9 K: its mean rate is 1 (R^0) to rounding.
    history = torch.tensor([43.0 - 1e-9, 43.0 + 1e-9], dtype=torch.float64)
    assert float(cem43(history, 60.0, rule="linear")) == pytest.approx(1.0, rel=1e-8)


# --------------------------------------------------------------------------- shapes and masks
def test_video_shapes_and_per_video_dt(dtype: torch.dtype) -> None:
    video = 37.0 + 20.0 * torch.rand(2, 9, 4, 5, dtype=dtype)
    dt = torch.tensor([0.1, 0.3])
    for fn in (cem43, arrhenius_omega, lambda v, d, **k: time_above(v, d, 50.0, **k)):
        for rule in ("hold", "linear"):
            batched = fn(video, dt, rule=rule)
            assert batched.shape == (2, 4, 5) and batched.dtype == torch.float64
            for b in range(2):
                single = fn(video[b], float(dt[b]), rule=rule)
                torch.testing.assert_close(batched[b], single, rtol=1e-12, atol=0)
            pixel = fn(video[1, :, 2, 3], float(dt[1]), rule=rule)
            torch.testing.assert_close(batched[1, 2, 3], pixel, rtol=1e-12, atol=0)


def test_non_finite_samples_add_nothing_and_are_counted() -> None:
    history = torch.tensor([40.0, 45.0, float("nan"), 50.0, float("inf"), 44.0], dtype=torch.float64)
    clean_hold = torch.tensor([40.0, 45.0, 50.0, 44.0], dtype=torch.float64)
    assert float(cem43(history, 1.0)) == pytest.approx(float(cem43(clean_hold, 1.0)), rel=1e-14)
    # linear: only the segment 40 -> 45 has two finite ends
    first = torch.tensor([40.0, 45.0], dtype=torch.float64)
    assert float(arrhenius_omega(history, 1.0, rule="linear")) == pytest.approx(
        float(arrhenius_omega(first, 1.0, rule="linear")), rel=1e-14
    )
    assert int(count_masked(history)) == 2
    assert torch.isfinite(cem43(history, 1.0, rule="linear"))


@pytest.mark.parametrize("rule", ["hold", "linear"])
def test_dose_maps_equal_the_dose_functions(rule: str) -> None:
    # One pass for every dose (TissueFeatures' route) gives what each function gives alone, masks included.
    video = 37.0 + 25.0 * torch.rand(
        2, 12, 3, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(2)
    )
    video[0, 5, 1, 2] = float("nan")
    dt = torch.tensor([0.1, 0.25], dtype=torch.float64)
    maps = dose_maps(video, dt, thresholds=(43.0, 50.0), rule=rule)
    assert list(maps) == ["time_above_43", "time_above_50", "cem43_minutes", "omega"]
    torch.testing.assert_close(maps["omega"], arrhenius_omega(video, dt, rule=rule), rtol=1e-12, atol=0)
    torch.testing.assert_close(maps["cem43_minutes"], cem43(video, dt, rule=rule), rtol=1e-12, atol=0)
    for t in (43.0, 50.0):
        torch.testing.assert_close(
            maps[f"time_above_{t:g}"], time_above(video, dt, t, rule=rule), rtol=1e-12, atol=0
        )
    # The same samples masked through ``finite`` instead of NaN (their values ignored).
    filled = torch.nan_to_num(video, nan=99.0)
    masked = dose_maps(filled, dt, thresholds=(43.0, 50.0), rule=rule, finite=torch.isfinite(video))
    for name, value in maps.items():
        torch.testing.assert_close(masked[name], value, rtol=1e-12, atol=0)


# ------------------------------------------------------------------------------------ bad input
def test_celsius_range_declared_wrongly_names_units() -> None:
    kelvin_video = torch.linspace(290.0, 330.0, 20)
    with pytest.raises(ValueError, match=r"units='C' \(--units C\).*290-330.*only makes sense in K"):
        cem43(kelvin_video, 1.0)
    with pytest.raises(ValueError, match=r"units='K' \(--units K\).*below absolute zero"):
        arrhenius_omega(torch.tensor([37.0, -5.0]), 1.0, units="K")
    with pytest.raises(ValueError, match=r"units='K'.*only makes sense in C"):
        arrhenius_omega(torch.tensor([37.0, 45.0]), 1.0, units="K")
    with pytest.raises(ValueError, match=r"units='C'.*below absolute zero"):
        time_above(torch.tensor([37.0, -300.0]), 1.0, 43.0)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="rule must be one of 'hold', 'linear', got 'simpson'"):
        cem43(torch.zeros(3) + 40, 1.0, rule="simpson")
    with pytest.raises(ValueError, match="dt must be a positive finite number in s"):
        cem43(torch.zeros(3) + 40, 0.0)
    with pytest.raises(ValueError, match=r"temperatures must have shape \(T,\), \(T, H, W\)"):
        cem43(torch.zeros(3, 4) + 40, 1.0)
    with pytest.raises(ValueError, match="needs at least 2 frames"):
        cem43(torch.zeros(1) + 40, 1.0, rule="linear")
    with pytest.raises(TypeError, match="constants must be ArrheniusConstants"):
        arrhenius_omega(torch.zeros(3) + 40, 1.0, constants=(1.0, 2.0))
    with pytest.raises(ValueError, match="threshold must be a finite temperature"):
        time_above(torch.zeros(3) + 40, 1.0, float("nan"))
