"""Tests for anra_torch.estimation.baselines: the paper's naive estimators (backward difference + LoG,
+/- blur).

They must be correct implementations (exact LoG, agreement with a slow NumPy/SciPy oracle, right units,
near-exact on noiseless video) and must fail on noisy video as the paper reports, so ANRA's advantage is a
measured fact rather than an artefact of a broken baseline.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import reference as ref
import torch
from scipy import ndimage

from anra_torch.estimation.baselines import BASELINES, backward_log_estimate, log_kernel
from anra_torch.estimation.estimator import ANRAEstimator
from anra_torch.simulation import gaussian_blob
from anra_torch.simulation.synthetic import paper_video

F64 = torch.float64


A_PAPER = 0.2


# ------------------------------------------------------------------------------------------ oracle
def log_kernel_oracle(sigma: float, truncate: float = 4.0) -> np.ndarray:
    """LoG as documented, by loops: sampled (r^2 - 2 s^2) / s^4 G, zero sum, x^2 + y^2 gives 4."""
    radius = max(1, math.ceil(truncate * sigma))
    size = 2 * radius + 1
    kernel = np.zeros((size, size))
    for i in range(size):
        for j in range(size):
            r2 = (i - radius) ** 2 + (j - radius) ** 2
            kernel[i, j] = (r2 - 2 * sigma**2) / sigma**4 * math.exp(-r2 / (2 * sigma**2))
    kernel -= kernel.mean()
    quadratic = sum(
        kernel[i, j] * ((i - radius) ** 2 + (j - radius) ** 2) for i in range(size) for j in range(size)
    )
    return kernel * 4.0 / quadratic


def baseline_oracle(
    video: np.ndarray, dt: float, dx: float, log_sigma: float = 1.0, blur_sigma: float | None = None
) -> float:
    """The paper's baseline for one (T, H, W) video with SciPy filters and replicated borders."""
    frames = np.asarray(video, dtype=np.float64)
    if blur_sigma is not None:
        radius = math.ceil(3 * blur_sigma)
        frames = np.stack(
            [
                ndimage.gaussian_filter(f, blur_sigma, mode="nearest", truncate=radius / blur_sigma)
                for f in frames
            ]
        )
    kernel = log_kernel_oracle(log_sigma)
    lap = np.stack([ndimage.correlate(f, kernel, mode="nearest") for f in frames]) / dx**2
    rate = (frames[1:] - frames[:-1]) / dt  # backward difference, paired with the newest frame
    lap = lap[1:]
    weights = ref.rtc(rate)
    ratio = np.where(lap == 0, 0.0, weights * rate / np.where(lap == 0, 1.0, lap))
    return float(ratio.sum(axis=(-2, -1)).mean())


def noisy_blob(seed: int = 0) -> torch.Tensor:
    t = torch.arange(6, dtype=F64) / 27.0
    clean = gaussian_blob(t, shape=(24, 28), dx=0.1, a=0.2, peak=2.0, sigma=0.5, centre=(1.23, 1.31))
    generator = torch.Generator().manual_seed(seed)
    return clean + 0.01 * torch.randn(clean.shape, generator=generator, dtype=F64)


# -------------------------------------------------------------------------------------- log_kernel
@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.0, 3.3])
def test_log_kernel_is_exact_on_quadratics(sigma: float) -> None:
    kernel = log_kernel(sigma)
    radius = math.ceil(4.0 * sigma)
    assert kernel.shape == (2 * radius + 1, 2 * radius + 1) and kernel.dtype == F64
    offsets = torch.arange(-radius, radius + 1, dtype=F64)
    y, x = torch.meshgrid(offsets, offsets, indexing="ij")
    # correlation at the centre: sum k(x, y) p(x, y) is the Laplacian of p at 0 for unit spacing
    for poly, expected in [
        (torch.ones_like(x), 0.0),
        (x, 0.0),
        (y, 0.0),
        (x**2 + y**2, 4.0),
        (x**2, 2.0),
        (y**2, 2.0),
        (x * y, 0.0),
        (x**3 + x * y**2, 0.0),
    ]:
        assert float((kernel * poly).sum()) == pytest.approx(expected, abs=1e-12)
    assert kernel.sum().abs() < 1e-14
    torch.testing.assert_close(kernel, kernel.flip(0), rtol=0, atol=0)
    torch.testing.assert_close(kernel, kernel.T, rtol=0, atol=0)


@pytest.mark.parametrize("sigma", [0.7, 1.0, 2.0])
def test_log_kernel_matches_its_documented_construction(sigma: float) -> None:
    np.testing.assert_allclose(log_kernel(sigma).numpy(), log_kernel_oracle(sigma), rtol=1e-12, atol=1e-15)


def test_log_kernel_on_an_image_is_the_calibrated_laplacian() -> None:
    import kornia

    h = 0.25
    coords = torch.arange(32, dtype=F64) * h
    y, x = torch.meshgrid(coords, coords, indexing="ij")
    image = (3 * x**2 - 2 * y**2 + 5 * x * y + x - 7)[None, None]  # Laplacian 6 - 4 = 2
    out = kornia.filters.filter2d(image, log_kernel(1.0)[None], border_type="replicate") / h**2
    interior = out[0, 0, 4:-4, 4:-4]
    torch.testing.assert_close(interior, torch.full_like(interior, 2.0), rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("sigma", [0.0, -1.0, math.nan, math.inf])
def test_log_kernel_rejects_bad_sigma(sigma: float) -> None:
    with pytest.raises(ValueError, match=r"log sigma must be a positive number of pixels"):
        log_kernel(sigma)


# ------------------------------------------------------------------------------------ the baselines
@pytest.mark.parametrize("blur_sigma", [None, 2.0], ids=["LoG", "LoG+blur"])
def test_baseline_matches_the_numpy_oracle(blur_sigma: float | None) -> None:
    video = noisy_blob()
    got = backward_log_estimate(video, 1 / 27, 0.1, blur_sigma=blur_sigma)
    assert got.shape == () and got.dtype == F64
    expected = baseline_oracle(video.numpy(), 1 / 27, 0.1, blur_sigma=blur_sigma)
    assert float(got) == pytest.approx(expected, rel=1e-9)


def test_registry_holds_the_two_paper_baselines() -> None:
    assert set(BASELINES) == {"backward+LoG", "backward+LoG+blur"}
    video = noisy_blob()[None]
    torch.testing.assert_close(
        BASELINES["backward+LoG"](video, 1 / 27, 0.1), backward_log_estimate(video, 1 / 27, 0.1)
    )
    torch.testing.assert_close(
        BASELINES["backward+LoG+blur"](video, 1 / 27, 0.1),
        backward_log_estimate(video, 1 / 27, 0.1, blur_sigma=2.0),
    )


def test_baseline_batching_and_per_video_spacing() -> None:
    videos = torch.stack([noisy_blob(0), noisy_blob(1), noisy_blob(2)])
    dts = torch.tensor([1 / 27, 1 / 30, 1 / 60], dtype=F64)
    dxs = torch.tensor([0.1, 0.2, 0.05], dtype=F64)
    batch = backward_log_estimate(videos, dts, dxs)
    assert batch.shape == (3,)
    singles = torch.stack(
        [backward_log_estimate(v, float(dt), float(dx)) for v, dt, dx in zip(videos, dts, dxs, strict=True)]
    )
    torch.testing.assert_close(batch, singles, rtol=1e-12, atol=0)


def test_baseline_scales_with_dx_squared() -> None:
    video = noisy_blob()
    base = backward_log_estimate(video, 1 / 27, 0.1)
    # RTC weights see dT/dt only, so dx enters as dx^2 exactly (dt does not: exp(|dT/dt|) has units)
    torch.testing.assert_close(backward_log_estimate(video, 1 / 27, 0.2), 4 * base, rtol=1e-12, atol=0)


@pytest.mark.parametrize("name", list(BASELINES))
def test_baselines_recover_a_without_noise(name: str, dtype: torch.dtype) -> None:
    video = paper_video(noise_sd=0.0, dtype=dtype)  # the full 224 px paper frame
    estimate = float(BASELINES[name](video.frames, video.dt, video.dx)[0])
    # measured +1.03 % (LoG) and +0.99 % (LoG+blur), both dtypes: the discretisation error of a
    # first-order backward difference paired with the newest frame
    assert abs(estimate / A_PAPER - 1) < 0.03


@pytest.fixture(scope="module")
def paper_noisy() -> tuple[torch.Tensor, float, float, float]:
    """Eight noise draws of the full paper case at 0.01, and ANRA's std_error on the first one."""
    # float32: kornia's float64 convolutions are ~8x slower on CPU
    video = paper_video(n_videos=8, seed=11, noise_sd=0.01, dtype=torch.float32)
    anra = ANRAEstimator()(video.frames[0], video.dt, video.dx)
    assert abs(float(anra.diffusivity) / A_PAPER - 1) < 0.01  # same video: ANRA is fine (measured 0.05 %)
    return video.frames, video.dt, video.dx, float(anra.std_error)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(BASELINES))
def test_baselines_fail_on_the_paper_case_as_reported(
    paper_noisy: tuple[torch.Tensor, float, float, float], name: str
) -> None:
    frames, dt, dx, anra_std_error = paper_noisy
    estimates = BASELINES[name](frames, dt, dx).double().numpy()
    errors = np.abs(estimates / A_PAPER - 1)
    # measured median |error| 309 % (LoG) and 58 % (LoG+blur); spread over seeds 1.8 and 0.12 mm^2/s,
    # against ANRA's std_error of 5.5e-5 mm^2/s: 4 and 3 orders of magnitude
    assert np.median(errors) > 0.2
    assert np.std(estimates, ddof=1) > 100 * anra_std_error


# -------------------------------------------------------------------------------------------- errors
@pytest.mark.parametrize("dt", [0.0, -1 / 27, math.nan, math.inf], ids=["zero", "negative", "nan", "inf"])
def test_baseline_rejects_bad_dt(dt: float) -> None:
    with pytest.raises(ValueError, match=r"dt must be a positive finite number in s") as info:
        backward_log_estimate(noisy_blob(), dt, 0.1)
    assert "\n" not in str(info.value)


def test_baseline_rejects_bad_dx_and_wrong_lengths() -> None:
    videos = torch.stack([noisy_blob(0), noisy_blob(1)])
    with pytest.raises(ValueError, match=r"dx must be a positive finite number in mm"):
        backward_log_estimate(videos, 1 / 27, -0.1)
    with pytest.raises(ValueError, match=r"dt must be a number or have shape \(2,\), got shape \(3,\)"):
        backward_log_estimate(videos, torch.full((3,), 1 / 27, dtype=F64), 0.1)


def test_baseline_rejects_bad_frames() -> None:
    with pytest.raises(
        ValueError, match=r"frames must have shape \(T, H, W\) or \(B, T, H, W\), got \(24, 28\)"
    ):
        backward_log_estimate(noisy_blob()[0], 1 / 27, 0.1)
    with pytest.raises(ValueError, match=r"frames needs at least 2 frames .*got 1"):
        backward_log_estimate(noisy_blob()[:1], 1 / 27, 0.1)
    with pytest.raises(TypeError, match=r"frames must hold real temperatures"):
        backward_log_estimate(noisy_blob() > 0, 1 / 27, 0.1)
