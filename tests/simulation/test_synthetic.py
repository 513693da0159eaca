"""Tests for anra_torch.simulation.synthetic: the paper's case, random blobs, npz export."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.simulation.synthetic import FWHM_PER_SIGMA, Blobs, SyntheticVideo, blobs_video, paper_video


@pytest.fixture(scope="module")
def paper() -> SyntheticVideo:
    """The default paper case with two noise draws (about 0.1 s to build)."""
    return paper_video(n_videos=2)


def half_max_width(profile: np.ndarray) -> float:
    """Width (samples) between the linearly interpolated half-maximum crossings of one peak."""
    half = profile.max() / 2
    above = np.flatnonzero(profile >= half)
    lo, hi = above[0], above[-1]
    left = lo - 1 + (half - profile[lo - 1]) / (profile[lo] - profile[lo - 1])
    right = hi + (profile[hi] - half) / (profile[hi] - profile[hi + 1])
    return float(right - left)


# --------------------------------------------------------------------------- paper_video
def test_paper_video_shape_and_spacing(paper: SyntheticVideo) -> None:
    assert paper.frames.shape == (2, 28, 224, 224)
    assert paper.clean.shape == (28, 224, 224)
    assert paper.frames.dtype == paper.clean.dtype == torch.float64
    assert paper.dx == 10.0 / 224 and paper.dt == 1.0 / 27 and paper.a == 0.2
    torch.testing.assert_close(paper.times, torch.arange(28, dtype=torch.float64) / 27, rtol=0, atol=0)
    assert paper.times[-1].item() == pytest.approx(1.0, abs=1e-15)


def test_paper_video_initial_diameter_is_50_px_fwhm(paper: SyntheticVideo) -> None:
    frame = paper.clean[0].numpy()
    # The frame centre (5 mm) falls between pixels 111 and 112; row 111 is a scaled Gaussian in x.
    row = frame[111]
    cols = np.arange(224) + 0.5  # pixel-centre x in px
    inside = row > 0.05 * row.max()
    # The log of a Gaussian is a parabola: its curvature gives sigma exactly.
    curvature = np.polyfit(cols[inside], np.log(row[inside]), 2)[0]
    sigma_px = math.sqrt(-1 / (2 * curvature))
    assert FWHM_PER_SIGMA * sigma_px == pytest.approx(50.0, abs=1e-6)
    assert half_max_width(row) == pytest.approx(50.0, abs=0.05)
    assert half_max_width(frame[:, 111]) == pytest.approx(50.0, abs=0.05)
    # Peak 3.8 at the centre; the nearest pixel centres are half a pixel off in x and y.
    assert frame.max() == pytest.approx(3.8 * math.exp(-0.25 / sigma_px**2), rel=1e-9)


def test_paper_video_noise_is_white_with_the_requested_sd(paper: SyntheticVideo) -> None:
    noise = paper.frames - paper.clean
    assert noise.std().item() == pytest.approx(0.01, rel=0.02)
    assert abs(noise.mean().item()) < 5 * 0.01 / math.sqrt(noise.numel())

    # Independent across frames, videos and neighbouring pixels.
    def corr(u: torch.Tensor, v: torch.Tensor) -> float:
        return torch.corrcoef(torch.stack([u.flatten(), v.flatten()]))[0, 1].item()

    assert abs(corr(noise[:, 1:], noise[:, :-1])) < 0.01
    assert abs(corr(noise[0], noise[1])) < 0.01
    assert abs(corr(noise[..., 1:], noise[..., :-1])) < 0.01


def test_paper_video_seeds_are_reproducible_and_distinct() -> None:
    first = paper_video(n_videos=2, seed=3, size=48)
    again = paper_video(n_videos=2, seed=3, size=48)
    other = paper_video(n_videos=2, seed=4, size=48)
    assert torch.equal(first.frames, again.frames)
    assert torch.equal(first.clean, other.clean)
    assert not torch.equal(first.frames, other.frames)
    assert not torch.equal(first.frames[0], first.frames[1])
    assert paper_video(noise_sd=0.0, size=48).frames[0].equal(first.clean)


@pytest.mark.parametrize("crop", [64, 63, 224])
def test_paper_video_crop_takes_the_central_pixels(paper: SyntheticVideo, crop: int) -> None:
    video = paper_video(n_videos=2, crop=crop)
    start = (224 - crop) // 2
    window = (..., slice(start, start + crop), slice(start, start + crop))
    assert video.frames.shape == (2, 28, crop, crop)
    assert torch.equal(video.frames, paper.frames[window])
    assert torch.equal(video.clean, paper.clean[window])
    assert video.dx == paper.dx
    if crop == 64:  # centred, and heat crosses the edges of the crop
        torch.testing.assert_close(video.clean, video.clean.flip(-1).flip(-2), rtol=1e-13, atol=0)
        assert video.clean[0, 0].max() > 0.1 * 3.8


def test_paper_video_float32_and_options() -> None:
    video = paper_video(size=32, fps=10.0, duration=0.5, dtype=torch.float32)
    assert video.frames.shape == (1, 6, 32, 32) and video.frames.dtype == torch.float32
    assert video.times.dtype == torch.float32 and video.dt == 0.1


# --------------------------------------------------------------------------- blobs_video
def test_blobs_video_shapes_and_determinism() -> None:
    video = blobs_video(n_videos=3, seed=1)
    assert video.frames.shape == video.clean.shape == (3, 40, 96, 96)
    assert video.dt == 1 / 30 and video.dx == 0.5 and video.a == 0.15
    assert torch.equal(video.frames, blobs_video(n_videos=3, seed=1).frames)
    other = blobs_video(n_videos=3, seed=2)
    assert not torch.equal(video.clean, other.clean)
    assert not torch.equal(video.clean[0], video.clean[1])  # each video has its own geometry
    noise = video.frames - video.clean
    assert noise.std().item() == pytest.approx(0.02, rel=0.02)


def test_blobs_video_blobs_stay_inside_on_the_background() -> None:
    video = blobs_video(n_videos=4, seed=5, blobs=Blobs(n_blobs=4), n_frames=10, fps=2.0)
    excess = video.clean - 30.0
    assert excess.min() >= 0
    peak0 = excess[:, 0].amax((-2, -1))
    assert (peak0 >= 3.0).all() and (peak0 <= 4 * 10.0).all()
    # Centres at least 2 sd inside: little heat has left the frame after 4.5 s.
    mass = excess.sum((-2, -1))
    assert (mass[:, -1] / mass[:, 0] > 0.95).all()
    assert (mass[:, -1] / mass[:, 0] <= 1 + 1e-12).all()


# --------------------------------------------------------------------------- export, errors
@pytest.mark.parametrize("n_videos", [1, 2])
def test_to_npz_round_trip(tmp_path, n_videos: int) -> None:
    video = paper_video(n_videos=n_videos, size=24, crop=16)
    path = tmp_path / "video.npz"
    video.to_npz(path)
    with np.load(path) as data:
        assert set(data.files) == {"frames", "dt", "dx", "t", "a_true"}
        expected = video.frames[0] if n_videos == 1 else video.frames
        np.testing.assert_array_equal(data["frames"], expected.numpy())
        assert data["frames"].shape == ((28, 16, 16) if n_videos == 1 else (2, 28, 16, 16))
        assert float(data["dt"]) == video.dt and float(data["dx"]) == video.dx
        assert float(data["a_true"]) == 0.2
        np.testing.assert_array_equal(data["t"], video.times.numpy())


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: paper_video(crop=300), r"crop must be at most size=224 px, got 300"),
        (lambda: paper_video(crop=0), r"crop must be an integer >= 1, got 0"),
        (lambda: paper_video(n_videos=0), r"n_videos must be an integer >= 1, got 0"),
        (
            lambda: paper_video(noise_sd=-0.1),
            r"noise_sd must be a finite number >= 0 in units of temperature",
        ),
        (lambda: paper_video(fps=0.0), r"fps must be a positive finite number in Hz, got 0.0"),
        (
            lambda: blobs_video(blobs=Blobs(sigma_range_px=(4.0, 30.0))),
            r"sigma_range_px must stay below size / 4 = 24 px",
        ),
        (
            lambda: blobs_video(blobs=Blobs(peak_range=(5.0, 1.0))),
            r"peak_range must be a finite pair with low <= high",
        ),
        (lambda: blobs_video(dx=-0.5), r"dx must be a positive finite number in mm, got -0.5"),
    ],
)
def test_errors(make, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make()
