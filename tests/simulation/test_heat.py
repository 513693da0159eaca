"""The finite-difference heat simulator (:mod:`anra_torch.simulation.heat`): discrete and continuous decay,
convergence in dx and dt, py-pde, boundaries, fields of ``a``, batches, gradients, one-line errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from fields import centres, plane_wave
from tolerances import assert_rounding_close

from anra_torch.simulation import (
    BOUNDARIES,
    HeatRHS,
    Solver,
    gaussian_blob,
    simulate_heat,
)

F64 = torch.float64


TIGHT = {"solver": Solver(method="dopri5", rtol=1e-11, atol=1e-13)}
"""Adaptive solver settings whose time error is far below every tolerance used here."""


def rough_field(batch: int, height: int, width: int) -> torch.Tensor:
    """Random pixels plus one hot pixel per video: the hardest case for overshoot."""
    u = torch.rand(batch, height, width, dtype=F64)
    u[:, height // 3, width // 2] = 5.0
    return u


# --------------------------------------------------------------------------- Fourier modes
@pytest.mark.parametrize(
    ("settings", "tol"),
    [(TIGHT, 1e-10), ({"solver": Solver(method="rk4", substeps=20)}, 1e-9), ({"solver": Solver()}, 5e-8)],
    ids=["dopri5", "rk4-20-substeps", "rk4-auto"],
)
def test_fourier_mode_decays_with_discrete_eigenvalue(settings: dict, tol: float) -> None:
    # cos(k . x) is an eigenvector of the periodic 5-point Laplacian with eigenvalue
    # -(4 / dx^2) (sin^2(kx dx / 2) + sin^2(ky dx / 2)): the semi-discrete solution is exact.
    dx, a, dt, n_frames = 0.25, 0.3, 0.2, 11
    u0, kx, ky = plane_wave(24, 32, dx, m=2, n=1)
    video = simulate_heat(u0, a=a, dx=dx, dt=dt, n_frames=n_frames, boundary="periodic", **settings)
    rate = 4.0 / dx**2 * (math.sin(kx * dx / 2) ** 2 + math.sin(ky * dx / 2) ** 2)
    t = torch.arange(n_frames, dtype=F64) * dt
    expected = u0 * torch.exp(-a * rate * t)[:, None, None]
    assert video.shape == (n_frames, 24, 32)
    torch.testing.assert_close(video, expected, rtol=0, atol=tol)


def test_fourier_mode_matches_continuous_decay_to_second_order() -> None:
    # The same mode on grids 1x, 2x, 4x finer: the error against exp(-a |k|^2 t) falls 4x per step.
    a, dt, n_frames = 0.3, 0.2, 11
    t = torch.arange(n_frames, dtype=F64) * dt
    errors = []
    for refine in (1, 2, 4):
        dx = 0.5 / refine
        u0, kx, ky = plane_wave(12 * refine, 16 * refine, dx, m=2, n=1)
        video = simulate_heat(u0, a=a, dx=dx, dt=dt, n_frames=n_frames, boundary="periodic")
        exact = u0 * torch.exp(-a * (kx**2 + ky**2) * t)[:, None, None]
        errors.append((video - exact).abs().max().item())
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert errors[-1] < 1e-3
    assert all(3.8 < r < 4.2 for r in ratios), (errors, ratios)


# --------------------------------------------------------------------------- Gaussian spreading
def test_gaussian_second_moment_grows_by_2at() -> None:
    # On the lattice sum(x^2 L5 u) = 2 sum(u) for any u, so the variance grows by exactly 2 a t per
    # axis (up to the negligible tail reaching the far boundary).
    height, width, dx, a, sigma, dt = 72, 64, 0.5, 0.5, 2.0, 0.5
    u0 = gaussian_blob([0.0], shape=(height, width), dx=dx, a=a, peak=1.0, sigma=sigma, centre=(15.7, 18.2))
    video = simulate_heat(u0[0], a=a, dx=dx, dt=dt, n_frames=9, boundary="neumann")
    x, y = centres(width, dx), centres(height, dx)
    mass = video.sum((-2, -1))
    mean_x = (video * x).sum((-2, -1)) / mass
    mean_y = (video * y[:, None]).sum((-2, -1)) / mass
    var_x = (video * (x - mean_x[:, None, None]) ** 2).sum((-2, -1)) / mass
    var_y = (video * (y[:, None] - mean_y[:, None, None]) ** 2).sum((-2, -1)) / mass
    expected = sigma**2 + 2 * a * torch.arange(9, dtype=F64) * dt
    torch.testing.assert_close(var_x, expected, rtol=1e-6, atol=0)
    torch.testing.assert_close(var_y, expected, rtol=1e-6, atol=0)
    torch.testing.assert_close(mean_x, torch.full_like(mean_x, 15.7), rtol=1e-8, atol=0)


def test_convergence_in_dx_against_analytic_gaussian() -> None:
    # Semi-discrete error is O(dx^2): halving dx divides the error by ~4.
    extent, a, dt, sigma = 16.0, 0.1, 0.5, 1.0
    errors = []
    for n in (64, 128):
        dx = extent / n
        exact = gaussian_blob(torch.arange(5) * dt, shape=(n, n), dx=dx, a=a, peak=2.0, sigma=sigma)
        video = simulate_heat(exact[0], a=a, dx=dx, dt=dt, n_frames=5)
        errors.append((video - exact).abs().max().item())
    assert 3.8 < errors[0] / errors[1] < 4.2, errors


@pytest.mark.parametrize(("method", "order"), [("euler", 1), ("midpoint", 2), ("rk4", 4)])
def test_convergence_in_dt(method: str, order: int) -> None:
    u0 = gaussian_blob([0.0], shape=(32, 32), dx=0.5, a=0.1, peak=1.0, sigma=1.0)[0]
    kwargs = {"a": 0.1, "dx": 0.5, "dt": 1.0, "n_frames": 3}
    reference = simulate_heat(u0, **kwargs, **TIGHT)
    errors = [
        (simulate_heat(u0, **kwargs, solver=Solver(method=method, substeps=s)) - reference).abs().max().item()
        for s in (4, 8)
    ]
    assert errors[0] / errors[1] == pytest.approx(2.0**order, rel=0.15)


# --------------------------------------------------------------------------- independent simulator
@pytest.mark.parametrize("boundary", ["neumann", "periodic"])
def test_agrees_with_py_pde(boundary: str) -> None:
    import pde  # a test dependency (pyproject [test]); imported here because it is slow to import

    height, width, dx, a, dt, n_frames = 24, 32, 0.25, 0.15, 0.5, 5
    x, y = centres(width, dx), centres(height, dx)
    periodic = boundary == "periodic"
    if periodic:
        u0 = 1.0 + plane_wave(height, width, dx, 1, 1)[0] + 0.5 * plane_wave(height, width, dx, 2, 0)[0]
    else:  # smooth, with heat reaching the edges
        u0 = 1.0 + torch.exp(-((x[None, :] - 5.0) ** 2 + (y[:, None] - 2.0) ** 2) / 4.0)
    ours = simulate_heat(u0, a=a, dx=dx, dt=dt, n_frames=n_frames, boundary=boundary)

    # py-pde's first grid axis is x: its data are our frames transposed.
    grid = pde.CartesianGrid([(0.0, width * dx), (0.0, height * dx)], [width, height], periodic=periodic)
    bc = "periodic" if periodic else {"derivative": 0}
    equation = pde.DiffusionPDE(diffusivity=a, bc=bc)
    state = pde.ScalarField(grid, u0.numpy().T.copy())
    storage = pde.MemoryStorage()
    equation.solve(
        state,
        t_range=(n_frames - 1) * dt,
        dt=dt / 10,
        tracker=storage.tracker(dt),
        backend="numpy",
        solver="scipy",
        rtol=1e-10,
        atol=1e-12,
    )
    theirs = torch.from_numpy(np.stack([field.data.T for field in storage]))
    assert theirs.shape == ours.shape
    relative = ((ours - theirs).abs().max() / theirs.abs().max()).item()
    # Both solve the same semi-discrete system, so the agreement is far inside 1e-3.
    assert relative < 1e-6


# --------------------------------------------------------------------------- boundaries
def test_rhs_matches_numpy_padding_reference() -> None:
    # Ghost pixels written independently with np.pad: edge (neumann), constant (dirichlet), wrap.
    u = torch.rand(2, 7, 9, dtype=F64)
    modes = {"neumann": {"mode": "edge"}, "dirichlet": {"mode": "constant", "constant_values": 1.5}}
    modes["periodic"] = {"mode": "wrap"}
    assert set(modes) == set(BOUNDARIES)
    a, dx = 0.3, 0.2
    for boundary, pad in modes.items():
        value = 1.5 if boundary == "dirichlet" else 0.0
        rhs = HeatRHS(a, dx=dx, boundary=boundary, boundary_value=value)
        got = rhs(torch.tensor(0.0), u)
        p = np.pad(u.numpy(), ((0, 0), (1, 1), (1, 1)), **pad)
        lap = p[:, 1:-1, 2:] + p[:, 1:-1, :-2] + p[:, 2:, 1:-1] + p[:, :-2, 1:-1] - 4 * p[:, 1:-1, 1:-1]
        np.testing.assert_allclose(got.numpy(), a * lap / dx**2, rtol=1e-13, atol=1e-12)


def test_dirichlet_keeps_the_boundary_value() -> None:
    value, dx, a, dt = 30.0, 0.5, 0.2, 1.0
    height, width = 12, 16
    # A uniform field at the boundary value is a steady state.
    flat = torch.full((height, width), value, dtype=F64)
    steady = simulate_heat(flat, a=a, dx=dx, dt=dt, n_frames=4, boundary="dirichlet", boundary_value=value)
    torch.testing.assert_close(steady, flat.expand(4, -1, -1), rtol=0, atol=1e-12)
    # value + sin(pi (j+1)/(W+1)) sin(pi (i+1)/(H+1)) is 0 on the ghost ring: an exact eigenvector.
    j, i = torch.arange(width, dtype=F64), torch.arange(height, dtype=F64)
    mode = torch.outer(
        torch.sin(math.pi * (i + 1) / (height + 1)), torch.sin(math.pi * (j + 1) / (width + 1))
    )
    video = simulate_heat(
        value + mode,
        a=a,
        dx=dx,
        dt=dt,
        n_frames=6,
        boundary="dirichlet",
        boundary_value=value,
        **TIGHT,
    )
    sines = math.sin(math.pi / (2 * (width + 1))) ** 2 + math.sin(math.pi / (2 * (height + 1))) ** 2
    rate = 4 / dx**2 * sines
    expected = value + mode * torch.exp(-a * rate * torch.arange(6, dtype=F64) * dt)[:, None, None]
    torch.testing.assert_close(video, expected, rtol=0, atol=1e-9)
    # A hot field relaxes to the boundary value.
    hot = value + 10 * torch.rand(height, width, dtype=F64)
    late = simulate_heat(hot, a=a, dx=dx, dt=200.0, n_frames=2, boundary="dirichlet", boundary_value=value)
    assert (late[-1] - value).abs().max() < 1e-3


@pytest.mark.parametrize("boundary", ["neumann", "periodic"])
def test_zero_flux_boundaries_conserve_heat(boundary: str) -> None:
    u0 = rough_field(2, 20, 24)
    a_field = 0.05 + 0.3 * torch.rand(20, 24, dtype=F64)
    for a in (0.2, a_field):
        video = simulate_heat(u0, a=a, dx=0.3, dt=0.5, n_frames=20, boundary=boundary)
        drift = (video.sum((-2, -1)) - u0.sum((-2, -1))[:, None]).abs().max()
        assert drift < 1e-10 * u0.abs().sum((-2, -1)).min()
        assert video[:, -1].std() < 0.5 * u0.std()  # it did diffuse


@pytest.mark.parametrize("method", ["rk4", "euler", "midpoint"])
@pytest.mark.parametrize("boundary", ["neumann", "dirichlet", "periodic"])
def test_long_run_with_large_dt_obeys_maximum_principle(boundary: str, method: str) -> None:
    # dt is 40x the explicit stability limit; the automatic substeps must keep the run stable and
    # monotone: no value leaves the range of the initial field (and the boundary value).
    u0 = rough_field(2, 24, 24)
    dx, a = 0.1, torch.tensor([0.5, 1.0], dtype=F64)
    dt = 40 * 0.25 * dx**2 / 1.0
    value = 0.5 if boundary == "dirichlet" else 0.0
    video = simulate_heat(
        u0,
        a=a,
        dx=dx,
        dt=dt,
        n_frames=30,
        boundary=boundary,
        boundary_value=value,
        solver=Solver(method=method),
    )
    assert torch.isfinite(video).all()
    assert video.max() <= u0.max() + 1e-12
    assert video.min() >= u0.min() - 1e-12
    assert video[:, -1].max() < 0.5 * u0.max()  # the hot pixel spread out


# ------------------------------------------------------------- diffusivity: field, batch, gradients
@pytest.mark.parametrize("boundary", ["neumann", "dirichlet", "periodic"])
def test_uniform_field_equals_scalar_a(boundary: str) -> None:
    u0 = rough_field(2, 10, 14)
    value = 0.3 if boundary == "dirichlet" else 0.0
    kwargs = {"dx": 0.2, "dt": 0.1, "n_frames": 5, "boundary": boundary, "boundary_value": value}
    scalar = simulate_heat(u0, a=0.25, **kwargs)
    field = simulate_heat(u0, a=torch.full((10, 14), 0.25, dtype=F64), **kwargs)
    per_video_field = simulate_heat(u0, a=torch.full((2, 10, 14), 0.25, dtype=F64), **kwargs)
    torch.testing.assert_close(field, scalar, rtol=1e-13, atol=1e-13)
    torch.testing.assert_close(per_video_field, scalar, rtol=1e-13, atol=1e-13)


def test_field_a_with_two_materials_is_mirror_symmetric() -> None:
    # Two materials (left/right) and a symmetric initial field: flipping the field flips the video.
    a = torch.full((12, 16), 0.05, dtype=F64)
    a[:, 8:] = 0.4
    u0 = gaussian_blob([0.0], shape=(12, 16), dx=0.25, a=0.0, peak=1.0, sigma=0.6)[0]
    video = simulate_heat(u0, a=a, dx=0.25, dt=0.2, n_frames=6)
    flipped = simulate_heat(u0.flip(-1), a=a.flip(-1), dx=0.25, dt=0.2, n_frames=6)
    torch.testing.assert_close(flipped, video.flip(-1), rtol=0, atol=1e-14)
    # Heat spreads faster into the conductive half.
    assert video[-1, :, 8:].sum() > video[-1, :, :8].sum()


def test_batched_per_video_parameters_equal_separate_runs() -> None:
    u0 = rough_field(3, 9, 11)
    a = torch.tensor([0.1, 0.2, 0.3], dtype=F64)
    dx = torch.tensor([0.2, 0.25, 0.3], dtype=F64)
    dt = torch.tensor([0.1, 0.05, 0.2], dtype=F64)
    value = torch.tensor([0.0, 1.0, -1.0], dtype=F64)
    for boundary in BOUNDARIES:
        bv = value if boundary == "dirichlet" else 0.0
        kwargs = {"n_frames": 4, "boundary": boundary, "solver": Solver(substeps=12)}
        batched = simulate_heat(u0, a=a, dx=dx, dt=dt, boundary_value=bv, **kwargs)
        assert batched.shape == (3, 4, 9, 11)
        for i in range(3):
            bv_i = value[i].item() if boundary == "dirichlet" else 0.0
            single = simulate_heat(
                u0[i],
                a=a[i].item(),
                dx=dx[i].item(),
                dt=dt[i].item(),
                boundary_value=bv_i,
                **kwargs,
            )
            torch.testing.assert_close(batched[i], single, rtol=0, atol=1e-14)


def test_gradient_in_scalar_a_matches_finite_difference() -> None:
    u0 = rough_field(1, 8, 10)[0]
    weight = torch.rand(5, 8, 10, dtype=F64)
    kwargs = {"dx": 0.2, "dt": 0.05, "n_frames": 5, "solver": Solver(substeps=8)}

    def loss(a: torch.Tensor | float) -> torch.Tensor:
        return (simulate_heat(u0, a=a, **kwargs) * weight).sum()

    a = torch.tensor(0.2, dtype=F64, requires_grad=True)
    (grad,) = torch.autograd.grad(loss(a), a)
    h = 1e-6
    fd = (loss(0.2 + h) - loss(0.2 - h)) / (2 * h)
    assert grad.item() == pytest.approx(fd.item(), rel=1e-7)


@pytest.mark.slow
@pytest.mark.parametrize("boundary", ["neumann", "dirichlet", "periodic"])
def test_gradcheck_field_a_and_initial(boundary: str) -> None:
    # Fixed substeps: the automatic count is a step function of a (see simulate_heat's docstring).
    u0 = torch.rand(5, 6, dtype=F64, requires_grad=True)
    a = (0.1 + 0.2 * torch.rand(5, 6, dtype=F64)).requires_grad_()
    value = 0.7 if boundary == "dirichlet" else 0.0

    def run(u: torch.Tensor, field: torch.Tensor) -> torch.Tensor:
        return simulate_heat(
            u,
            a=field,
            dx=0.2,
            dt=0.02,
            n_frames=3,
            boundary=boundary,
            boundary_value=value,
            solver=Solver(substeps=4),
        )

    assert torch.autograd.gradcheck(run, (u0, a))


@pytest.mark.parametrize("a_kind", ["scalar", "field"])
def test_adjoint_gradient_matches_backprop(a_kind: str) -> None:
    u0 = rough_field(2, 8, 9).requires_grad_()
    if a_kind == "scalar":
        a = torch.tensor([0.15, 0.25], dtype=F64, requires_grad=True)
    else:
        a = (0.1 + 0.2 * torch.rand(2, 8, 9, dtype=F64)).requires_grad_()
    weight = torch.rand(2, 4, 8, 9, dtype=F64)
    # The adjoint solves the continuous adjoint ODE; it differs from backprop through RK4 by O(ds^4)
    kwargs = {"dx": 0.2, "dt": 0.05, "n_frames": 4}
    grads = []
    for adjoint in (False, True):
        out = simulate_heat(u0, a=a, solver=Solver(substeps=64, adjoint=adjoint), **kwargs)
        grads.append(torch.autograd.grad((out * weight).sum(), (u0, a)))
    for backprop, adjoint in zip(*grads, strict=True):
        torch.testing.assert_close(adjoint, backprop, rtol=1e-6, atol=1e-8)


# ----------------------------------------------------------------- shapes, dtypes, analytic helpers
def test_shapes_dtype_and_first_frame(dtype: torch.dtype) -> None:
    u0 = torch.rand(3, 10, 12, dtype=dtype)
    video = simulate_heat(u0, a=0.1, dx=0.5, dt=0.1, n_frames=4)
    assert video.shape == (3, 4, 10, 12) and video.dtype == dtype
    assert torch.equal(video[:, 0], u0)
    single = simulate_heat(u0[1], a=0.1, dx=0.5, dt=0.1, n_frames=4)
    assert single.shape == (4, 10, 12)
    assert_rounding_close(single, video[1])
    assert torch.equal(simulate_heat(u0, a=0.1, dx=0.5, dt=0.1, n_frames=1)[:, 0], u0)


def test_heat_rhs_repr_and_field_flag() -> None:
    rhs = HeatRHS(torch.ones(4, 5), dx=0.1, boundary="periodic")
    assert rhs.is_field and "field (4, 5)" in repr(rhs) and "periodic" in repr(rhs)
    assert not HeatRHS(0.2, dx=0.1).is_field


# --------------------------------------------------------------------------- errors
U0 = torch.zeros(8, 8, dtype=F64)


GOOD = {"a": 0.1, "dx": 0.1, "dt": 0.1, "n_frames": 3}


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"dx": -1.0}, r"dx must be a positive finite number in mm, got -1.0"),
        ({"dx": 0.0}, r"dx must be a positive finite number in mm"),
        ({"dx": float("nan")}, r"dx must be a positive finite number in mm"),
        ({"dx": torch.tensor([0.1, 0.2])}, r"dx must be a number or have shape \(1,\)"),
        ({"dt": -1.0}, r"dt must be a positive finite number in s, got -1.0"),
        ({"a": -0.1}, r"a must be finite and non-negative in mm\^2/s, got -0.1"),
        ({"a": float("inf")}, r"a must be finite and non-negative"),
        (
            {"a": torch.ones(5)},
            r"a must be a number, a tensor \(1,\), a field \(8, 8\).*got shape \(5,\)",
        ),
        ({"a": torch.ones(8, 7)}, r"a must be a number.*got shape \(8, 7\)"),
        (
            {"boundary": "robin"},
            r"unknown boundary 'robin'; expected one of: neumann, dirichlet, periodic",
        ),
        (
            {"solver": Solver(method="rk45")},
            r"unknown method 'rk45'; expected one of: euler, midpoint, rk4, dopri5",
        ),
        ({"n_frames": 0}, r"n_frames must be an integer >= 1, got 0"),
        ({"n_frames": 2.5}, r"n_frames must be an integer >= 1, got 2.5"),
        (
            {"solver": Solver(substeps=1), "a": 10.0},
            r"substeps=1 is unstable for rk4 at a\*dt/dx\^2=100; need at least 288",
        ),
        ({"solver": Solver(substeps=4, method="dopri5")}, r"substeps applies to fixed-step methods only"),
        ({"boundary_value": 1.0}, r"boundary_value applies to boundary='dirichlet' only"),
        (
            {"boundary": "dirichlet", "boundary_value": float("nan")},
            r"boundary_value must be finite",
        ),
        ({"solver": Solver(rtol=0.0)}, r"rtol must be a positive finite number"),
    ],
)
def test_simulate_heat_errors(changes: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        simulate_heat(U0, **{**GOOD, **changes})


@pytest.mark.parametrize(
    ("initial", "message"),
    [
        (torch.zeros(8), r"initial must have shape \(H, W\) or \(B, H, W\), got \(8,\)"),
        (
            torch.zeros(1, 2, 8, 8),
            r"initial must have shape \(H, W\) or \(B, H, W\), got \(1, 2, 8, 8\)",
        ),
        (torch.full((4, 4), float("nan")), r"initial must be finite, got 16 non-finite values"),
    ],
)
def test_simulate_heat_rejects_bad_initial(initial: torch.Tensor, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        simulate_heat(initial, **GOOD)


def test_type_errors() -> None:
    with pytest.raises(TypeError, match="initial must hold real temperatures"):
        simulate_heat(torch.zeros(4, 4, dtype=torch.complex64), **GOOD)
    with pytest.raises(TypeError, match="a must be a number or a tensor"):
        simulate_heat(U0, **{**GOOD, "a": "fast"})
