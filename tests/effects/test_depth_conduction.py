"""Conduction into depth: its rate against the plate's cosine series, the simulator against the exact depth
factor, the diagnosis on an independent (exact) flash video, and the estimate's poor-fit flag."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.balance.system import BalanceSystem
from anra_torch.effects import Effect, simulate_effects, simulate_independent
from anra_torch.effects.depth_conduction import depth_rate
from anra_torch.estimation.estimator import POOR_FIT, ANRAEstimator
from anra_torch.selection import diagnose_terms
from anra_torch.simulation.plate import plate_factor

F64 = torch.float64


PARAMS = {"strength": 1.0, "t_heat": -0.15, "depth_time": 6.0, "T_ref": 30.0}


@pytest.mark.parametrize("depth_time", [0.5, 3.0, 40.0, 200.0])
def test_rate_is_the_log_derivative_of_the_plate_series(depth_time: float) -> None:
    """Both forms of the library's rate against a central difference of the directly summed series."""
    elapsed = np.geomspace(1e-2, 30.0, 60)
    h = 1e-6 * elapsed
    numeric = -(np.log(plate_factor(elapsed + h, depth_time)) - np.log(plate_factor(elapsed - h, depth_time)))
    numeric /= 2 * h
    rate = depth_rate(torch.from_numpy(elapsed), depth_time).numpy()
    np.testing.assert_allclose(rate, numeric, rtol=1e-6, atol=1e-9 / depth_time)


def test_thick_body_cools_like_one_over_root_t() -> None:
    elapsed = torch.tensor([0.01, 0.1, 1.0], dtype=F64)
    torch.testing.assert_close(depth_rate(elapsed, 1e6), 0.5 / elapsed, rtol=1e-12, atol=0)


def test_simulated_uniform_field_follows_the_exact_depth_factor() -> None:
    u0 = torch.full((6, 6), 31.0, dtype=F64)
    depth = [Effect("depth_conduction", PARAMS)]
    video = simulate_effects(u0, a=0.1, dx=0.5, dt=0.05, n_frames=41, effects=depth, substeps=8)
    t = np.arange(41) * 0.05
    exact = plate_factor(t + 0.15, 6.0) / plate_factor(np.array(0.15), 6.0)
    np.testing.assert_allclose(video[:, 3, 3].numpy() - 30.0, exact, rtol=1e-8)  # RK4, 8 steps per frame


def test_retimed_heating_continues_the_same_cooling() -> None:
    effect = Effect("depth_conduction", PARAMS)
    u0 = torch.full((4, 4), 32.0, dtype=F64)
    whole = simulate_effects(u0, a=0.0, dx=0.5, dt=0.1, n_frames=21, effects=[effect])
    later = Effect("depth_conduction", effect.spec.retime(PARAMS, 2.0, 1.0, 1.0))
    rest = simulate_effects(whole[10], a=0.0, dx=0.5, dt=0.1, n_frames=11, effects=[later])
    torch.testing.assert_close(rest, whole[10:], rtol=1e-7, atol=0)


def _spot(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """A 2 K Gaussian flash of 3 mm sd on 30 C."""
    return 30.0 + 2.0 * torch.exp(-((x - 11.0) ** 2 + (y - 12.0) ** 2) / (2 * 3.0**2))


def _flash_video(seed: int, noise: float = 0.01) -> tuple[torch.Tensor, dict[str, float]]:
    """An exact flash on an anisotropic plate (independent spectral solution times the plate factor)."""
    params = {"strength": 1.0, "t_heat": -0.08, "depth_time": 5.0, "T_ref": 30.0}

    clean = simulate_independent(
        _spot,
        shape=(48, 48),
        a=0.5,
        dx=0.5,
        dt=0.05,
        n_frames=60,
        effects=[
            Effect("anisotropy", {"a_x": 0.9, "a_y": 0.3, "a_xy": 0.0}),
            Effect("depth_conduction", params),
        ],
    )
    rng = np.random.default_rng(seed)
    return clean + noise * torch.from_numpy(rng.standard_normal(clean.shape)), params


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_diagnosis_names_depth_conduction_and_the_anisotropy(seed: int) -> None:
    video, truth = _flash_video(seed)
    d = diagnose_terms(video, 0.05, 0.5)
    assert set(d.names) == {"depth_conduction", "anisotropy"}, (d.names, d.scores)
    found = next(e["params"] for e in d.effects if e["name"] == "depth_conduction")
    assert found["strength"] == pytest.approx(1.0, abs=0.08)
    assert found["depth_time"] == pytest.approx(truth["depth_time"], rel=0.3)
    assert found["t_heat"] == pytest.approx(truth["t_heat"], abs=0.03)
    assert found["T_ref"] == pytest.approx(30.0, abs=0.05)
    lateral = next(e["params"] for e in d.effects if e["name"] == "anisotropy")
    assert lateral["a_x"] == pytest.approx(0.9, rel=0.1) and lateral["a_y"] == pytest.approx(0.3, rel=0.15)


def test_estimate_flags_the_plain_model_on_a_flash_but_not_on_pure_diffusion() -> None:
    flash, _ = _flash_video(0)
    pure = simulate_independent(_spot, shape=(48, 48), a=0.5, dx=0.5, dt=0.05, n_frames=60)
    result = ANRAEstimator()(torch.stack([flash, pure + 0.01 * torch.randn_like(pure)]), 0.05, 0.5)
    assert float(result.explained[0]) < POOR_FIT
    assert any("explains only" in line for line in result.warnings[0])
    assert float(result.explained[1]) > 0.99 and not result.warnings[1]
    assert result.to_record(0)["explained"] == pytest.approx(float(result.explained[0]))


def test_a_vanishing_column_gets_its_real_standard_error() -> None:
    """Least squares is equilibrated: a column 1e-12 of the Laplacian's size is not cut by the
    pseudo-inverse (which gave it a zero coefficient with a zero variance: a huge Wald score)."""
    clean = simulate_independent(_spot, shape=(48, 48), a=0.5, dx=0.5, dt=0.05, n_frames=60)
    video = clean + 0.01 * torch.from_numpy(np.random.default_rng(2).standard_normal(clean.shape))
    system = BalanceSystem(video, 0.05, 0.5, 2.0, 0.01)
    rng = np.random.default_rng(3)
    system.add("tiny", 1e-12 * torch.from_numpy(rng.standard_normal(system.u.shape)), None)
    fit = system.fit(["L", "tiny"])
    beta, se = fit.coefficients()["tiny"], fit.std_errors()["tiny"]
    assert se > 1e6 and abs(beta) < 5 * se  # was ~1e-16: a zero variance
    assert math.isfinite(fit.coefficients()["L"])


def test_bad_parameters_and_partners_are_one_line_errors() -> None:
    late = {**PARAMS, "t_heat": 0.2}
    with pytest.raises(ValueError, match=r"depth_conduction.t_heat must be before the first frame \(< 0 s\)"):
        Effect("depth_conduction", late)
    source = Effect("source", {"x0": 6.0, "y0": 6.0, "x1": 8.0, "y1": 6.0, "rate": 1.0, "width": 1.0})
    with pytest.raises(ValueError, match="combines conduction into depth only with diffusion"):
        simulate_independent(
            _spot, shape=(16, 16), a=0.3, dx=0.5, dt=0.1, n_frames=3,
            effects=[Effect("depth_conduction", PARAMS), source],
        )  # fmt: skip


def test_a_given_plate_holds_the_term_without_a_search(monkeypatch: pytest.MonkeyPatch) -> None:
    """Given the plate (``hints["depth_conduction"]``: a flash defect map's ``T_ref``, plate time and
    ``t_heat``), the shape is held there, not searched: on an exact flash its strength is the true 1
    beside the anisotropy (fitted, the plate is degenerate on an isotropic balance: 480 s for 9 s)."""
    import anra_torch.effects.depth_conduction as depth

    video, params = _flash_video(0)
    system = BalanceSystem(video[4:], 0.05, 0.5, 2.0, 0.01)
    plate = {"T_ref": 30.0, "plate_time": 5.0, "t_heat": params["t_heat"] - 4 * 0.05}
    system.hints = {"depth_conduction": (plate,)}
    monkeypatch.setattr(depth, "optimise", lambda *args, **kwargs: pytest.fail("searched"))
    held = depth.SPEC.shape(system, system.fit(["L"]), None)
    assert held.params == {"t_heat": plate["t_heat"], "depth_time": 5.0, "T_ref": 30.0}
    system.add("Z", held.term, held.noise)
    fit = system.fit(["L", "D", "T_xy", "Z"]).coefficients()
    assert -fit["Z"] == pytest.approx(1.0, abs=0.03)
    assert fit["L"] + fit["D"] == pytest.approx(0.9, rel=0.05) and fit["L"] - fit["D"] == pytest.approx(
        0.3, rel=0.1
    )
