"""Tests for anra_torch.balance.estimate_noise_sd: accuracy on smooth fields, robustness, masks."""

from __future__ import annotations

import pytest
import torch

from anra_torch.balance.noise import estimate_noise_sd

F64 = torch.float64


def smooth_video(
    b: int, t: int, h: int, w: int, *, amplitude: float = 3.8, sigma_px: float = 10.0
) -> torch.Tensor:
    """A spreading, drifting Gaussian hot spot on a tilted background, like the paper's clean frames."""
    y = torch.arange(h, dtype=F64)[:, None]
    x = torch.arange(w, dtype=F64)[None, :]
    frames = []
    for k in range(t):
        s2 = sigma_px**2 + 2.0 * k
        cx, cy = w / 2 + 0.3 * k, h / 2 - 0.2 * k
        blob = amplitude * torch.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s2)) * sigma_px**2 / s2
        frames.append(blob + 0.02 * amplitude * (x / w - 0.5 * y / h) + 0.01 * amplitude * k / t)
    return torch.stack(frames).expand(b, t, h, w).clone()


@pytest.mark.parametrize("sd", [0.01, 1.0])
def test_recovers_white_noise_on_smooth_field(sd: float, dtype: torch.dtype) -> None:
    clean = smooth_video(2, 16, 48, 48)
    frames = (clean + sd * torch.randn_like(clean)).to(dtype)
    estimate = estimate_noise_sd(frames)
    assert estimate.shape == (2,) and estimate.dtype == dtype
    torch.testing.assert_close(estimate.double(), torch.full((2,), sd, dtype=F64), rtol=0.03, atol=0)


def test_unaffected_by_a_strong_smooth_signal(dtype: torch.dtype) -> None:
    noise = torch.randn(1, 16, 48, 48, dtype=F64)
    signal = smooth_video(1, 16, 48, 48, amplitude=1e4, sigma_px=8.0)  # 10^4 x the noise sd
    alone = estimate_noise_sd(noise.to(dtype))
    with_signal = estimate_noise_sd((signal + noise).to(dtype))
    assert float(with_signal) == pytest.approx(1.0, rel=0.05)
    assert float(with_signal) == pytest.approx(float(alone), rel=0.05)


def test_ignores_non_finite_pixels(dtype: torch.dtype) -> None:
    clean = smooth_video(1, 12, 40, 40)
    frames = (clean + 0.05 * torch.randn_like(clean)).to(dtype)
    frames[:, :, 5:15, 20:30] = float("nan")  # a dead region
    frames[:, 3, 30, 7] = float("inf")  # and a hot pixel
    frames[:, :, 33, 33] = float("nan")
    estimate = estimate_noise_sd(frames)
    assert bool(torch.isfinite(estimate).all())
    assert float(estimate) == pytest.approx(0.05, rel=0.03)


def test_mask_excludes_corrupted_pixels(dtype: torch.dtype) -> None:
    clean = smooth_video(1, 12, 40, 40)
    frames = (clean + 0.05 * torch.randn_like(clean)).to(dtype)
    bad = torch.zeros_like(frames, dtype=torch.bool)
    bad[..., :, :16] = True  # 40 % of the sensor returns garbage
    frames[bad] = 100.0 * torch.rand(int(bad.sum()), dtype=dtype)
    assert float(estimate_noise_sd(frames)) > 0.1  # without the mask the garbage dominates
    masked = estimate_noise_sd(frames, mask=~bad)
    assert float(masked) == pytest.approx(0.05, rel=0.03)


def test_batched_and_unbatched(dtype: torch.dtype) -> None:
    sds = torch.tensor([0.01, 0.1, 1.0], dtype=F64)
    clean = smooth_video(3, 12, 40, 40)
    frames = (clean + sds[:, None, None, None] * torch.randn_like(clean)).to(dtype)
    estimate = estimate_noise_sd(frames)
    assert estimate.shape == (3,)
    torch.testing.assert_close(estimate.double(), sds, rtol=0.03, atol=0)
    single = estimate_noise_sd(frames[1])
    assert single.shape == ()
    torch.testing.assert_close(single, estimate[1])


def test_short_videos_use_the_spatial_axes(dtype: torch.dtype) -> None:
    clean = smooth_video(1, 3, 64, 64)  # too few frames for the temporal fourth difference
    frames = (clean + 0.2 * torch.randn_like(clean)).to(dtype)
    assert float(estimate_noise_sd(frames)) == pytest.approx(0.2, rel=0.03)


def test_errors() -> None:
    with pytest.raises(ValueError, match=r"frames must be at least 5 long along some axis.*\(1, 4, 4, 4\)"):
        estimate_noise_sd(torch.zeros(4, 4, 4))
    with pytest.raises(
        ValueError, match=r"frames must have shape \(T, H, W\) or \(B, T, H, W\), got \(64, 64\)"
    ):
        estimate_noise_sd(torch.zeros(64, 64))
