"""Tests for anra_torch.simulation.integrator: the stability limits, the automatic substeps, integrate.

The limits are checked against the methods' amplification factors ``R(z)`` (not against the table they
come from), the automatic substeps against a 5-point heat simulation (stable, no new extrema), and the
minimum against the checkerboard mode, the 5-point Laplacian's most negative eigenvalue ``-8 a / dx^2``.
"""

from __future__ import annotations

import cmath
import math

import pytest
import torch

import anra_torch.effects.simulate as effects_module
import anra_torch.forecast.refine as refine_module
import anra_torch.simulation.heat as simulation_heat
import anra_torch.simulation.tissue as simulation_tissue
from anra_torch.effects import Effect, simulate_effects
from anra_torch.forecast import refine_model
from anra_torch.selection import Diagnosis
from anra_torch.simulation import (
    FIXED_STEP_METHODS,
    SAFETY,
    HeatRHS,
    Solver,
    integrate,
    simulate_heat,
    simulate_tissue,
    stable_substeps,
)

F64 = torch.float64


AMPLIFICATION = {
    "euler": lambda z: 1 + z,
    "midpoint": lambda z: 1 + z + z**2 / 2,
    "rk4": lambda z: 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24,
}
"""One step of each method on ``dy/dt = lambda y`` multiplies y by R(z), z = lambda ds."""


# ----------------------------------------------------------------------------------- the limits
@pytest.mark.parametrize("method", list(FIXED_STEP_METHODS))
def test_real_axis_limit_is_where_the_amplification_reaches_one(method: str) -> None:
    limit, R = FIXED_STEP_METHODS[method].real, AMPLIFICATION[method]
    assert limit == pytest.approx({"euler": 2.0, "midpoint": 2.0, "rk4": 2.785}[method], abs=5e-4)
    assert all(abs(R(-limit * s)) <= 1.0 for s in (0.1, 0.5, 0.9, 0.999))
    assert abs(R(-limit * 1.001)) > 1.0  # the limit is tight, not merely safe


def test_rk4_half_disc_is_inside_its_region_and_tight() -> None:
    radius, R = FIXED_STEP_METHODS["rk4"].half_disc, AMPLIFICATION["rk4"]
    angles = [math.pi / 2 + k * (math.pi / 2) / 400 for k in range(401)]  # the left half-plane
    assert max(abs(R(radius * cmath.exp(1j * a))) for a in angles) <= 1.0 + 1e-4
    assert max(abs(R(1.002 * radius * cmath.exp(1j * a))) for a in angles) > 1.0


@pytest.mark.parametrize("method", ["euler", "midpoint"])
def test_methods_without_a_half_disc_are_unstable_for_advection(method: str) -> None:
    assert FIXED_STEP_METHODS[method].half_disc is None
    assert abs(AMPLIFICATION[method](0.05j)) > 1.0  # any step on the imaginary axis grows
    with pytest.raises(ValueError, match=rf"speed must be 0 mm/s for method '{method}'.*got 1"):
        stable_substeps(0.1, 0.5, diffusivity=0.1, speed=1.0, method=method)


@pytest.mark.parametrize("method", list(FIXED_STEP_METHODS))
def test_monotone_limit_is_where_one_step_on_a_peak_overshoots(method: str) -> None:
    # One step of size 1 s on a unit peak with a ds / dx^2 = c: no negative pixel up to the monotone
    # limit (0.25 for all three), a negative one just above it.
    peak = torch.zeros(1, 15, 15, dtype=F64)
    peak[0, 7, 7] = 1.0
    monotone = FIXED_STEP_METHODS[method].monotone
    assert monotone == 0.25

    def one_step(c: float) -> torch.Tensor:
        rhs = HeatRHS(c, dx=1.0, boundary="periodic")
        return integrate(rhs, peak, n_frames=2, method=method, substeps=1)[1]

    assert float(one_step(monotone).min()) >= -1e-15
    assert float(one_step(1.04 * monotone).min()) < -1e-6


@pytest.mark.parametrize(("method", "real"), [("rk4", 2.7853), ("euler", 2.0), ("midpoint", 2.0)])
def test_minimum_follows_the_real_axis_limit(method: str, real: float) -> None:
    # dt = dx = 1: the diffusivity is the mesh Fourier number; 8 c per frame against `real` per substep.
    for k in (1, 3, 10, 288):
        c = k * real / 8.0
        assert stable_substeps(1.0, 1.0, diffusivity=c * (1 - 1e-9), method=method).minimum == k
        assert stable_substeps(1.0, 1.0, diffusivity=c * (1 + 1e-9), method=method).minimum == k + 1


def test_automatic_count_keeps_the_safety_margin_of_each_limit() -> None:
    c = 3.0  # a dt / dx^2 per frame
    count = stable_substeps(0.3, 0.1, diffusivity=0.1, method="rk4")  # 0.1 * 0.3 / 0.01 = 3
    assert count.automatic == math.ceil(c / (SAFETY * 0.25)) == 14  # the monotone limit dominates
    assert count.minimum == math.ceil(8 * c / 2.7853) == 9
    stable = stable_substeps(0.3, 0.1, diffusivity=0.1, method="rk4", policy="stable")
    assert stable.automatic == stable.minimum == math.ceil(8 * c / (SAFETY * 2.7853)) == 10
    # A loss rate adds to the real extent; advection moves the spectrum off the axis: the half-disc.
    lossy = stable_substeps(1.0, 1.0, diffusivity=0.0, decay=2.7853 * 4.5)
    assert lossy == (math.ceil(4.5 / SAFETY), 5)
    moving = stable_substeps(1.0, 0.5, diffusivity=0.0, speed=2.6155 * 0.5 * 6.5)
    assert moving == (math.ceil(6.5 / SAFETY), 7)


def test_stable_substeps_errors_are_one_line() -> None:
    cases = {
        r"dt must be a positive finite number in s, got 0": {"dt": 0.0},
        r"dx must be a positive finite number in mm, got -1": {"dx": -1.0},
        r"diffusivity must be a finite number >= 0 in mm\^2/s, got -0.1": {"diffusivity": -0.1},
        r"decay must be a finite number in 1/s, got nan": {"decay": math.nan},
        r"unknown method 'dopri5'; expected one of: euler, midpoint, rk4": {"method": "dopri5"},
        r"unknown policy 'fast'; expected one of: monotone, stable": {"policy": "fast"},
    }
    for message, change in cases.items():
        kwargs = {"dt": 0.1, "dx": 0.1, "diffusivity": 0.1, **change}
        with pytest.raises(ValueError, match=message) as err:
            stable_substeps(kwargs.pop("dt"), kwargs.pop("dx"), **kwargs)
        assert "\n" not in str(err.value)


# ---------------------------------------------------------------------- the automatic substeps
def checkerboard(n: int) -> torch.Tensor:
    """(-1)^(i + j) on n x n (n even): on a periodic grid an eigenvector of the 5-point Laplacian, -8/dx^2."""
    i = torch.arange(n)
    return ((-1.0) ** (i[:, None] + i[None, :])).to(F64)


@pytest.mark.parametrize("method", list(FIXED_STEP_METHODS))
def test_automatic_substeps_keep_a_five_point_simulation_stable_and_monotone(method: str) -> None:
    dx, a, dt = 0.1, 0.8, 0.5  # a dt / dx^2 = 40: far beyond one explicit step
    u0 = torch.rand(2, 16, 16, dtype=F64) + 0.3 * checkerboard(16)
    video = simulate_heat(
        u0, a=a, dx=dx, dt=dt, n_frames=12, boundary="periodic", solver=Solver(method=method)
    )
    assert bool(torch.isfinite(video).all())
    assert float(video.max()) <= float(u0.max()) + 1e-12  # no new extrema
    assert float(video.min()) >= float(u0.min()) - 1e-12
    # The checkerboard, the fastest mode, is damped every frame (Euler flips its sign: compare sizes).
    rough = [abs(float((frame * checkerboard(16)).mean())) for frame in video[0]]
    assert all(later <= earlier + 1e-12 for earlier, later in zip(rough, rough[1:], strict=False))
    assert rough[-1] < 1e-6 * rough[0]


@pytest.mark.parametrize("method", list(FIXED_STEP_METHODS))
def test_one_fewer_than_the_minimum_is_rejected_and_would_blow_up(method: str) -> None:
    dx, a, dt = 0.1, 0.5, 0.1  # a dt / dx^2 = 5, 8 c = 40 per frame
    count = stable_substeps(1.0, 1.0, diffusivity=a * dt / dx**2, method=method)
    u0 = checkerboard(8)
    kwargs = {"a": a, "dx": dx, "dt": dt, "n_frames": 4, "boundary": "periodic"}
    with pytest.raises(ValueError, match=rf"substeps={count.minimum - 1} is unstable") as err:
        simulate_heat(u0, **kwargs, solver=Solver(method=method, substeps=count.minimum - 1))
    assert "\n" not in str(err.value) and f"need at least {count.minimum}" in str(err.value)
    at_minimum = simulate_heat(u0, **kwargs, solver=Solver(method=method, substeps=count.minimum))
    assert float(at_minimum[-1].abs().max()) <= 1.0  # the checkerboard does not grow
    # The same run below the minimum, integrated directly: the checkerboard grows, so the minimum is tight.
    s = count.minimum - 1
    rhs = HeatRHS(a, dx=dx, boundary="periodic", time_scale=dt / s)
    below = integrate(rhs, u0.unsqueeze(0), n_frames=4, method=method, substeps=s)
    assert float(below[-1].abs().max()) > 1.0


# ------------------------------------------------------------------------------- the integrator
def test_integrate_hits_frames_exactly_and_matches_an_adaptive_method() -> None:
    dt, n = 0.25, 7  # the solver's unit is dt / n s: frames at t = 0, n, 2n, ...
    decay = 1.3

    def fixed(t: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return -decay * u * (dt / n)

    def adaptive(t: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return -decay * u * dt  # the adaptive solver's unit is one frame

    u0 = torch.tensor([1.0, -2.0], dtype=F64)
    frames = torch.arange(5, dtype=F64)[:, None]
    z = -decay * dt / n  # one RK4 step multiplies by R(z): frame k is exactly R(z)^(n k) if hit exactly
    rk4_steps = u0 * (1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24) ** (n * frames)
    rk4 = integrate(fixed, u0, n_frames=5, substeps=n)
    dopri = integrate(adaptive, u0, n_frames=5, method="dopri5", rtol=1e-10, atol=1e-12)
    assert rk4.shape == dopri.shape == (5, 2)
    assert torch.equal(rk4[0], u0)
    torch.testing.assert_close(rk4, rk4_steps, rtol=1e-13, atol=0)
    torch.testing.assert_close(dopri, u0 * torch.exp(-decay * dt * frames), rtol=1e-9, atol=0)


def test_integrate_adjoint_gives_the_gradient() -> None:
    rate = torch.tensor(0.7, dtype=F64, requires_grad=True)
    u0 = torch.ones(3, dtype=F64)

    def rhs(t: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return -rate * u * 0.1

    direct = torch.autograd.grad(integrate(rhs, u0, n_frames=3, substeps=5)[-1].sum(), rate)[0]
    out = integrate(rhs, u0, n_frames=3, substeps=5, adjoint=True, adjoint_params=(rate,))
    adjoint = torch.autograd.grad(out[-1].sum(), rate)[0]
    # The adjoint integrates its own ODE backwards with RK4: the same gradient up to RK4's error.
    assert float(direct) == pytest.approx(-3 * math.exp(-0.7), rel=1e-6)  # d/dk 3 exp(-k t) at t = 1 s
    assert float(adjoint) == pytest.approx(float(direct), rel=1e-5)


def test_integrate_errors_are_one_line() -> None:
    u0 = torch.ones(2, dtype=F64)

    def rhs(t: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return -u

    cases = {
        r"substeps must be an integer >= 1 for method 'rk4', got None": {},
        r"substeps must be an integer >= 1, got 0": {"substeps": 0},
        r"substeps applies to fixed-step methods only, got method='dopri5'": {
            "method": "dopri5",
            "substeps": 2,
        },
        r"unknown method 'rk45'; expected one of: euler, midpoint, rk4, dopri5": {"method": "rk45"},
        r"n_frames must be an integer >= 1, got 0": {"n_frames": 0, "substeps": 1},
        r"rtol must be a positive finite number": {"method": "dopri5", "rtol": 0.0},
        r"adjoint_params applies to adjoint=True only": {"substeps": 1, "adjoint_params": (u0,)},
    }
    for message, change in cases.items():
        with pytest.raises(ValueError, match=message) as err:
            integrate(rhs, u0, **{"n_frames": 3, **change})
        assert "\n" not in str(err.value)
    with pytest.raises(TypeError, match="initial must be a tensor, got list"):
        integrate(rhs, [1.0], n_frames=2, substeps=1)


# -------------------------------------------------------------- the former callers keep their counts
# (automatic, minimum) substeps per frame each caller computed before it used the integrator (its own
# rule, run on these cases at commit 8ca9d02); refine: its automatic count only (twice the effects' rule).
HEAT_COUNTS = [
    ({"a": 0.2, "dx": 0.1, "dt": 0.05}, "rk4", F64, (5, 3)),
    ({"a": 10.0, "dx": 0.1, "dt": 0.1}, "rk4", F64, (445, 288)),
    ({"a": 1.0, "dx": 0.1, "dt": 0.25}, "euler", F64, (112, 100)),
    ({"a": 1.0, "dx": 0.1, "dt": 0.25}, "midpoint", torch.float32, (112, 100)),
    ({"a": torch.tensor([0.5, 1.0], dtype=F64), "dx": 0.1, "dt": 0.01}, "rk4", F64, (5, 3)),
    (
        {"a": 0.1 + torch.linspace(0, 0.4, 36).reshape(6, 6), "dx": 0.2, "dt": 0.3},
        "rk4",
        torch.float32,
        (17, 11),
    ),
]


EFFECT_COUNTS = {
    "plain": (0.2, 0.5, 0.1, [], (1, 1)),
    "advection and loss": (
        0.1,
        0.5,
        0.5,
        [Effect("advection", {"vx": 6.0, "vy": -4.0}), Effect("linear_loss", {"b": 20.0, "T_ref": 30.0})],
        (7, 6),
    ),
    "anisotropy": (0.05, 0.1, 0.2, [Effect("anisotropy", {"a_x": 0.3, "a_y": 0.1, "a_xy": 0.05})], (19, 13)),
    "heterogeneity": (
        0.2,
        0.25,
        1 / 30,
        [Effect("heterogeneity", {"x": 1.0, "y": 1.0, "radius": 0.5, "a_inside": 0.5, "a_outside": 0.2})],
        (2, 1),
    ),
    "nonlinear": (
        0.05,
        0.1,
        0.2,
        [Effect("nonlinear_diffusion", {"a0": 0.2, "beta": 0.05, "T_ref": 30.0})],
        (26, 17),
    ),
}


FIELD_A = 0.05 + torch.linspace(0, 0.25, 36, dtype=F64).reshape(6, 6)


FIELD_B = torch.linspace(0, 2.0, 36, dtype=F64).reshape(6, 6)


TISSUE_COUNTS = [
    (0.2, 0.5, 0.5, 0.1, (1, 1)),
    (1.0, 0.0, 0.1, 0.1, (32, 32)),
    (0.1, 30.0, 0.25, 0.05, (1, 1)),
    (FIELD_A, FIELD_B, 0.1, 0.05, (5, 5)),
]


REFINE_COUNTS = {
    "plain": (0.3, 0.1, 0.1, [], 28),
    "loss and advection": (
        0.1,
        0.25,
        0.2,
        [Effect("linear_loss", {"b": 0.5, "T_ref": 30.0}), Effect("advection", {"vx": 0.8, "vy": 0.3})],
        4,
    ),
    "anisotropy": (0.05, 0.1, 0.2, [Effect("anisotropy", {"a_x": 0.3, "a_y": 0.1, "a_xy": 0.05})], 38),
}


@pytest.fixture
def substeps_used(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The substeps every caller hands to integrate (the call goes through unchanged)."""
    used: list[int] = []

    def spy(*args: object, **kwargs: object) -> torch.Tensor:
        used.append(kwargs["substeps"])  # type: ignore[arg-type]
        return integrate(*args, **kwargs)  # type: ignore[arg-type]

    for module in (simulation_heat, simulation_tissue, effects_module, refine_module):
        monkeypatch.setattr(module, "integrate", spy)
    return used


def assert_minimum(run: object, minimum: int) -> None:
    """``run(substeps)`` rejects ``minimum - 1`` naming ``minimum`` and accepts ``minimum``."""
    if minimum > 1:
        with pytest.raises(
            ValueError, match=rf"substeps={minimum - 1} is unstable .*need at least {minimum}\b"
        ):
            run(minimum - 1)  # type: ignore[operator]
    run(minimum)  # type: ignore[operator]


@pytest.mark.parametrize(("spacing", "method", "dtype", "counts"), HEAT_COUNTS)
def test_simulate_heat_keeps_its_substeps(substeps_used, spacing, method, dtype, counts) -> None:
    u0 = torch.rand(2, 6, 6, dtype=dtype)
    simulate_heat(u0, **spacing, n_frames=2, solver=Solver(method=method))
    assert substeps_used == [counts[0]]
    assert_minimum(
        lambda s: simulate_heat(u0, **spacing, n_frames=2, solver=Solver(method=method, substeps=s)),
        counts[1],
    )


@pytest.mark.parametrize("name", list(EFFECT_COUNTS))
def test_simulate_effects_keeps_its_substeps(substeps_used, name: str) -> None:
    a, dx, dt, effects, counts = EFFECT_COUNTS[name]
    u0 = torch.linspace(30.0, 38.0, 64, dtype=F64).reshape(8, 8)  # the range sets the rates
    simulate_effects(u0, a=a, dx=dx, dt=dt, n_frames=2, effects=effects)
    assert substeps_used == [counts[0]]
    assert_minimum(
        lambda s: simulate_effects(u0, a=a, dx=dx, dt=dt, n_frames=2, effects=effects, substeps=s), counts[1]
    )


@pytest.mark.parametrize(("a", "b", "dx", "dt", "counts"), TISSUE_COUNTS)
def test_simulate_tissue_keeps_its_substeps(substeps_used, a, b, dx, dt, counts) -> None:
    u0 = torch.full((6, 6), 40.0, dtype=F64)
    simulate_tissue(u0, a, b, dx=dx, dt=dt, n_frames=2)
    assert substeps_used == [counts[0]]
    assert_minimum(lambda s: simulate_tissue(u0, a, b, dx=dx, dt=dt, n_frames=2, substeps=s), counts[1])


@pytest.mark.parametrize("name", list(REFINE_COUNTS))
def test_refine_model_keeps_its_substeps(substeps_used, name: str) -> None:
    a, dx, dt, effects, automatic = REFINE_COUNTS[name]
    r2 = ((torch.arange(12, dtype=F64) - 6.0) ** 2) / 8
    u0 = 30.0 + 8.0 * torch.exp(-r2[:, None] - r2[None, :])
    frames = simulate_effects(u0, a=a, dx=dx, dt=dt, n_frames=5, effects=effects)
    records = [{"name": e.name, "params": dict(e.params), "score": 1.0} for e in effects]
    diagnosis = Diagnosis(
        base=a,
        base_std_error=0.0,
        effects=records,
        a_plain=a,
        scores={},
        thresholds={},
        coefficients={},
        std_errors={},
        noise_sd=0.01,
        smoothing=0.0,  # compare the raw frames: the first frame's range sets the rates
        mean=35.0,
        fit_ratio=1.0,
        residual_map=torch.zeros(8, 8, dtype=F64),
        margin=2,
    )
    substeps_used.clear()  # the simulation of the frames above went through the spy too
    refine_model(frames, dt, dx, diagnosis, iterations=1)
    assert substeps_used and set(substeps_used) == {automatic}
