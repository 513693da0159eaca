"""The standard flash-thermography contrasts against closed forms: TSR's log-log slope -1/2 over a half-space
and its second log-derivative's peak at a plate's back wall (``L^2 / (pi a_z)``), PPT's phase of a sampled
exponential and of a cosine, PCT against NumPy's SVD of the same standardised matrix."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from anra_torch.flash import pct, ppt, tsr

F64 = torch.float64


def _plate_surface(t: np.ndarray, thickness: float, a_z: float = 0.45) -> np.ndarray:
    """An insulated plate's surface excess after a unit flash (cosine series, 400 terms)."""
    n = np.arange(1, 401)
    return (1 + 2 * np.exp(-np.outer(t, n**2) * math.pi**2 * a_z / thickness**2).sum(1)) / thickness


def test_tsr_slope_is_minus_a_half_over_a_half_space(dtype: torch.dtype) -> None:
    """``T = T_ref + q / sqrt(t)``, the flash brighter at some pixels: ``ln`` excess is linear in ``ln t``
    with slope -1/2 (and curvature 0) at every pixel, whatever the flash did there."""
    t = torch.logspace(-2, 1, 80, dtype=F64)
    energy = torch.tensor([[1.0, 2.0, 0.5], [3.0, 1.5, 0.8]], dtype=F64)
    frames = (20.0 + energy[None] / t.sqrt()[:, None, None]).to(dtype)
    result = tsr(frames, t, baseline=20.0)
    eps = torch.finfo(dtype).eps
    scale = 1e3 * eps**0.5 if dtype == torch.float32 else 1e-9  # float32: the logs' rounding through the fit
    torch.testing.assert_close(result.first, torch.full_like(result.first, -0.5), rtol=0, atol=scale)
    torch.testing.assert_close(result.second, torch.zeros_like(result.second), rtol=0, atol=scale)
    assert result.first.dtype == dtype and result.samples.eq(80).all()


def test_tsr_slope_of_a_plate_before_its_back_wall() -> None:
    thickness = 2.0
    back_wall = thickness**2 / (math.pi * 0.45)
    t = np.geomspace(back_wall / 3000, back_wall / 30, 60)
    frames = torch.from_numpy(20.0 + _plate_surface(t, thickness))[:, None, None]
    result = tsr(frames, torch.from_numpy(t), degree=5, baseline=20.0)
    torch.testing.assert_close(result.first[:, 0, 0], torch.full((60,), -0.5, dtype=F64), rtol=0, atol=1e-8)


@pytest.mark.parametrize("thickness", [1.0, 2.0, 3.8])
def test_tsr_second_derivative_peaks_at_the_back_wall(thickness: float) -> None:
    """The exact second log-derivative of the plate factor peaks at ``L^2 / (pi a_z)`` (the cosine series
    differentiated on a fine grid here); TSR's degree-9 polynomial over a decade either side finds it within
    1 % (measured 0.6-0.9 %)."""
    back_wall = thickness**2 / (math.pi * 0.45)
    fine = np.geomspace(back_wall / 10, back_wall * 10, 20001)
    exact = np.gradient(np.gradient(np.log(_plate_surface(fine, thickness)), np.log(fine)), np.log(fine))
    assert fine[exact.argmax()] == pytest.approx(back_wall, rel=2e-3)  # the closed form itself
    t = np.geomspace(back_wall / 10, back_wall * 10, 400)
    frames = torch.from_numpy(20.0 + _plate_surface(t, thickness))[:, None, None].expand(400, 2, 2)
    second = tsr(frames, torch.from_numpy(t), degree=9, baseline=20.0).second[:, 0, 0]
    inner = slice(100, 300)  # a fitted polynomial's derivatives swing at the window's ends
    assert t[inner][int(second[inner].argmax())] == pytest.approx(back_wall, rel=0.01)


def test_tsr_leaves_out_samples_below_the_baseline() -> None:
    t = torch.linspace(0.1, 5.0, 40, dtype=F64)
    frames = (20.0 + 2.0 / t.sqrt())[:, None, None].repeat(1, 1, 2)
    frames[5, 0, 1] = 19.0  # a dropout below the temperature before the flash
    result = tsr(frames, t, baseline=20.0)
    assert result.samples.tolist() == [[40, 39]]
    torch.testing.assert_close(result.first[:, 0, 1], torch.full((40,), -0.5, dtype=F64), rtol=0, atol=1e-8)


def test_ppt_phase_of_a_sampled_exponential_and_of_a_cosine() -> None:
    """``sum_n q^n w^n = (1 - q^N) / (1 - q w)``, ``w = exp(-2 pi i k / N)``: the phase is
    ``-arg(1 - q w)``; a cosine at bin ``k`` with phase ``phi`` has phase ``phi`` there."""
    n, dt, tau = 256, 0.01, 0.3
    time = torch.arange(n, dtype=F64) * dt
    q = math.exp(-dt / tau)
    decay = torch.exp(-time / tau)
    phi = 0.7
    wave = torch.cos(2 * math.pi * 3 * time / (n * dt) + phi)
    frames = torch.stack([decay, 5.0 * decay + 20.0, wave], -1)[:, None, :]  # (T, 1, 3)
    result = ppt(frames, dt, frequencies=6)
    k = torch.arange(1, 7, dtype=F64)
    expected = -torch.angle(1 - q * torch.exp(torch.complex(torch.zeros(6, dtype=F64), -2 * math.pi * k / n)))
    torch.testing.assert_close(result.phase[:, 0, 0], expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(result.phase[:, 0, 1], expected, rtol=0, atol=1e-12)  # scale and offset
    assert float(result.phase[2, 0, 2]) == pytest.approx(phi, abs=1e-12)
    torch.testing.assert_close(result.frequencies, k / (n * dt))


def test_pct_is_the_svd_of_the_standardised_matrix() -> None:
    rng = np.random.default_rng(1)
    t = np.linspace(0.1, 2.0, 50)
    base = 1 / np.sqrt(t)
    defect = np.zeros((12, 14))
    defect[3:6, 4:9] = 1.0
    video = (
        base[:, None, None] * (1 + 0.3 * rng.random((12, 14)))[None] + np.exp(-1 / t)[:, None, None] * defect
    )
    video += 0.01 * rng.standard_normal(video.shape)
    result = pct(torch.from_numpy(video), components=3)
    matrix = video.reshape(50, -1)
    matrix = (matrix - matrix.mean(0)) / matrix.std(0, ddof=1)
    u, s, vh = np.linalg.svd(matrix, full_matrices=False)
    for i in range(3):
        reference = vh[i] * np.sign(((vh[i] - vh[i].mean()) ** 3).sum())  # positive skew
        np.testing.assert_allclose(result.maps[i].numpy().ravel(), reference, atol=1e-8)
        np.testing.assert_allclose(np.abs(result.time_components[i].numpy()), np.abs(u[:, i]), atol=1e-8)
    np.testing.assert_allclose(result.variance.numpy(), s[:3] ** 2 / (s**2).sum(), rtol=1e-10)
    second = result.maps[1].numpy()
    assert second[defect > 0].mean() > second[defect == 0].mean()  # the defect reads positive


def test_batched_equals_unbatched_and_stays_on_the_input_device() -> None:
    t = torch.linspace(0.05, 3.0, 30, dtype=F64)
    frames = 20.0 + (1.0 + torch.rand(6, 7, dtype=F64))[None] / t.sqrt()[:, None, None]
    batch = torch.stack([frames, 1.01 * frames + 0.1 * torch.rand(6, 7, dtype=F64)])
    one = tsr(batch[1], t, baseline=20.0)
    torch.testing.assert_close(tsr(batch, t, baseline=20.0).second[1], one.second)
    torch.testing.assert_close(pct(batch, components=2).maps[1], pct(batch[1], components=2).maps)
    torch.testing.assert_close(
        ppt(batch, 0.1, frequencies=3).phase[1], ppt(batch[1], 0.1, frequencies=3).phase
    )
    torch.set_default_device("meta")  # any tensor made without the input's device lands here and fails
    try:
        assert tsr(batch, t, baseline=20.0).first.device.type == "cpu"
        assert pct(batch, components=2).maps.device.type == "cpu"
        assert ppt(batch, 0.1, frequencies=3).phase.device.type == "cpu"
    finally:
        torch.set_default_device(None)


def test_errors() -> None:
    frames = torch.ones(10, 4, 4) + torch.linspace(1, 0, 10)[:, None, None]
    t = torch.linspace(0.1, 1.0, 10)
    with pytest.raises(ValueError, match=r"times must have shape \(10,\)"):
        tsr(frames, t[:5])
    with pytest.raises(ValueError, match="times must be positive seconds since the flash"):
        tsr(frames, t - 0.5)
    with pytest.raises(ValueError, match="more than degree = 7 samples above the baseline"):
        tsr(frames, t, baseline=1.5)
    with pytest.raises(ValueError, match="frames must have shape"):
        tsr(torch.ones(4, 4), t)
    with pytest.raises(ValueError, match="standardise must be one of|unknown standardise"):
        pct(frames, standardise="mean")
    with pytest.raises(ValueError, match="components must be at most"):
        pct(frames, components=11)
    with pytest.raises(ValueError, match="frequencies must be at most N / 2 = 5"):
        ppt(frames, 0.1, frequencies=6)
    with pytest.raises(ValueError, match="dt must be a positive number in s"):
        ppt(frames, 0.0)
    with pytest.raises(ValueError, match="frames must be finite"):
        ppt(frames * float("nan"), 0.1)


def test_pct_of_a_constant_video_is_an_error_and_beyond_its_rank_zero() -> None:
    """A video in which nothing varies has no component (never a NaN variance); a rank-one video's second
    and third components are zero with no variance, its first holds all of it."""
    flat = torch.full((8, 4, 5), 20.0, dtype=F64)
    for standardise in ("pixel", "frame", "none"):
        with pytest.raises(ValueError, match=rf"^frames do not vary after standardise='{standardise}'"):
            pct(flat, standardise=standardise)
    varying = 20.0 + torch.rand(8, 4, 5, dtype=F64)
    with pytest.raises(ValueError, match=r"^frames of video 1 do not vary after standardise='pixel'"):
        pct(torch.stack([varying, flat]), components=2)
    with pytest.raises(ValueError, match=r"standardise='frame' needs at least 2 pixels per frame, got 1 x 1"):
        pct(varying[:, :1, :1], components=1, standardise="frame")
    rank_one = torch.linspace(1.0, 2.0, 8, dtype=F64)[:, None, None] * (1 + torch.rand(4, 5, dtype=F64))
    result = pct(rank_one, components=3, standardise="none")
    torch.testing.assert_close(result.variance, torch.tensor([1.0, 0.0, 0.0], dtype=F64), rtol=0, atol=1e-12)
    assert bool((result.maps[1:] == 0).all()) and bool((result.time_components[1:] == 0).all())
    torch.testing.assert_close(result.maps[0].norm(), torch.tensor(1.0, dtype=F64))


def degenerate(rng: np.random.Generator, kind: str, shape: tuple[int, int, int]) -> torch.Tensor:
    """A video that breaks a contrast's assumptions: constant, one pixel constant, frames all alike, rank
    one, values near float32's limits, or a batch with a constant video."""
    t, h, w = shape
    base = 20 + torch.from_numpy(rng.random(shape))
    if kind == "constant":
        return torch.full(shape, float(rng.choice([0.0, 20.0, -5.0, 1e30])), dtype=F64)
    if kind == "frames_alike":
        return base[:1].expand(shape).clone()
    if kind == "pixel_constant":
        base[:, 0, 0] = 5.0
        return base
    if kind == "rank_one":
        return 20 + torch.linspace(1, 2, t, dtype=F64)[:, None, None] * base[0]
    if kind == "huge":
        return base * 1e30
    if kind == "tiny":
        return base * 1e-30
    if kind == "batch_constant":
        return torch.stack([base, torch.full(shape, 3.0, dtype=F64)])
    return base


KINDS = ("constant", "frames_alike", "pixel_constant", "rank_one", "huge", "tiny", "batch_constant", "plain")


def test_fuzzed_degenerate_videos_give_finite_contrasts_or_one_line_errors() -> None:
    """tsr, pct and ppt on degenerate videos (float32 and float64, down to 1 x 1 px and two frames), with
    drawn times (repeated, reversed, 1e-300 to 1e300 s), baselines (non-finite, huge, maps), dt, degrees,
    components and standardisations: every output finite, or a one-line ValueError; no warning."""
    rng = np.random.default_rng(45)
    errors = 0
    for case in range(600):
        kind = str(rng.choice(KINDS))
        shape = (int(rng.choice([2, 3, 5, 9, 16])), int(rng.choice([1, 2, 5])), int(rng.choice([1, 3, 6])))
        video = degenerate(rng, kind, shape).to(torch.float32 if rng.random() < 0.5 else F64)
        name = str(rng.choice(["tsr", "pct", "ppt"]))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                if name == "tsr":
                    scale = float(rng.choice([1e-300, 1e-3, 1.0, 1e3, 1e300]))
                    times = torch.arange(1, shape[0] + 1, dtype=F64) * scale
                    times = times.flip(0) if rng.random() < 0.2 else times
                    times = torch.ones(shape[0], dtype=F64) if rng.random() < 0.2 else times
                    baseline = float(rng.choice([0.0, 19.0, 25.0, math.nan, math.inf, -math.inf, 1e300]))
                    if rng.random() < 0.2:
                        baseline = torch.full(shape[1:], baseline, dtype=F64)
                    r = tsr(video, times, degree=int(rng.choice([1, 2, 3, 7])), baseline=baseline)
                    outputs = (r.coefficients, r.log_excess, r.first, r.second)
                elif name == "pct":
                    standardise = str(rng.choice(["pixel", "frame", "none"]))
                    r = pct(video, components=int(rng.choice([1, 2, 6])), standardise=standardise)
                    outputs = (r.maps, r.time_components, r.variance)
                else:
                    dt = float(rng.choice([1e-300, 0.01, 1.0, 1e300]))
                    used = int(rng.choice([2, shape[0]]))
                    r = ppt(video, dt, frequencies=int(rng.choice([1, 2, 4])), frames_used=used)
                    outputs = (r.phase, r.amplitude, r.frequencies)
        except ValueError as err:
            assert "\n" not in str(err), f"case {case} ({name} {kind}): {err}"
            errors += 1
            continue
        for out in outputs:
            assert bool(torch.isfinite(out).all()), f"case {case}: {name} of {kind} {shape} {video.dtype}"
    print(f"fuzz flash: 600 calls, finite results: {600 - errors}, one-line ValueError: {errors}")
    assert 50 < errors < 550
