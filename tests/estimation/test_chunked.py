"""Chunked estimation: the whole video's sums from time chunks, a standard error equal to the exact one,
precision on demand, and one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tolerances import assert_rounding_close

from anra_torch.estimation.chunked import Chunking, estimate_chunked
from anra_torch.estimation.estimator import ANRAEstimator
from anra_torch.simulation import gaussian_blob
from anra_torch.video.lazy import LazyFrames as NpyFrames

DT, DX, NOISE = 1 / 27, 0.1, 0.01


def _video(frames: int, side: int = 44, seed: int = 0) -> torch.Tensor:
    t = torch.arange(frames, dtype=torch.float64) * DT
    generator = torch.Generator().manual_seed(seed)
    clean = gaussian_blob(t, shape=(side - 4, side), dx=DX, a=0.2, peak=3.0, sigma=1.0)
    return clean + NOISE * torch.randn(clean.shape, generator=generator, dtype=torch.float64)


@pytest.mark.parametrize("chunk", [1, 3, 7, 40])
def test_chunks_give_the_whole_videos_sums_to_rounding(chunk: int) -> None:
    """Chunks of 1, 3 and 7 output frames cut through the 5-frame filter's halo; 40 is one chunk."""
    video = _video(37)
    est = ANRAEstimator(smoothing=1.0, noise_sd=NOISE, strict=False)
    whole = est(video, DT, DX)
    chunked = estimate_chunked(
        video, DT, DX, estimator=est, chunking=Chunking(chunk_frames=chunk, error_every=1)
    )
    result = chunked.result
    assert_rounding_close(result.per_frame, whole.per_frame, ops=64)
    assert_rounding_close(result.diffusivity, whole.diffusivity, ops=64)
    assert_rounding_close(result.reliability, whole.reliability, ops=64)
    assert_rounding_close(result.frame_times, whole.frame_times)
    # The exact adjoint, chained over the chunks; linearised at the pilot's a instead of the video's own.
    assert float(result.std_error) == pytest.approx(float(whole.std_error), rel=1e-3)
    assert chunked.frames_used == 37 and bool(result.valid)


def test_sampled_standard_error_matches_the_exact_one() -> None:
    """The lever pushed back on every 4th chunk's interior, scaled by the energy, against every frame's."""
    video = _video(300, side=64, seed=1).float()
    est = ANRAEstimator(smoothing=2.0, strict=False)
    exact = estimate_chunked(
        video, DT, DX, estimator=est, chunking=Chunking(chunk_frames=16, error_every=1)
    ).result
    sampled = estimate_chunked(
        video, DT, DX, estimator=est, chunking=Chunking(chunk_frames=16, error_every=4)
    ).result
    whole = est(video, DT, DX)
    # The noise level is measured on the pilot's 48 frames, not on all 300: a 0.3 % difference here.
    assert float(exact.std_error) == pytest.approx(float(whole.std_error), rel=0.01)
    assert float(sampled.std_error) == pytest.approx(float(exact.std_error), rel=0.05)
    assert float(sampled.diffusivity) == float(exact.diffusivity)


def test_default_estimator_chooses_a_smoothing_near_the_whole_videos() -> None:
    video = _video(120, side=64, seed=2).float()
    whole = ANRAEstimator(strict=False)(video, DT, DX)
    chunked = estimate_chunked(video, DT, DX).result
    assert float(chunked.diffusivity) == pytest.approx(0.2, rel=0.01)
    # A pilot of 3 x 16 frames may pick a neighbouring candidate: the standard error stays within 25 %.
    assert float(chunked.std_error) == pytest.approx(float(whole.std_error), rel=0.25)
    assert chunked.noise[0]["sd"] == pytest.approx(NOISE, rel=0.05)


def test_precision_stops_reading_once_reached() -> None:
    video = _video(200, side=48, seed=3).float()
    full = estimate_chunked(video, DT, DX, chunking=Chunking(chunk_frames=10))
    target = 2 * float(full.result.std_error / full.result.diffusivity)
    early = estimate_chunked(video, DT, DX, precision=target, chunking=Chunking(chunk_frames=10))
    assert early.frames_used < full.frames_used == 200
    relative = float(early.result.std_error / early.result.diffusivity)
    assert relative <= target * 1.001
    assert early.result.per_frame.shape[0] == early.frames_used - 4


def test_reads_an_npy_file_chunk_by_chunk(tmp_path) -> None:
    video = _video(60, side=48, seed=4).float()
    path = tmp_path / "v.npy"
    np.save(path, video.numpy())
    from_file = estimate_chunked(NpyFrames(path), DT, DX, chunking=Chunking(chunk_frames=12)).result
    in_memory = estimate_chunked(video, DT, DX, chunking=Chunking(chunk_frames=12)).result
    assert float(from_file.diffusivity) == float(in_memory.diffusivity)


def test_a_dead_element_is_masked_and_constant_frames_are_flagged() -> None:
    video = _video(60, side=48, seed=5).float()
    video[:, 20, 20] = 7.0  # stuck
    result = estimate_chunked(video, DT, DX, chunking=Chunking(chunk_frames=12)).result
    assert float(result.diffusivity) == pytest.approx(0.2, rel=0.02)
    assert int(result.n_masked) == 60
    flat = estimate_chunked(torch.zeros(30, 48, 48), DT, DX).result
    assert not bool(flat.valid) and "constant" in flat.messages[0]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"precision": 0.0}, "precision must be a relative standard error in (0, 1), got 0.0"),
        ({"chunking": Chunking(chunk_frames=0)}, "chunk_frames must be an integer >= 1 (frames), got 0"),
        ({"chunking": Chunking(error_every=0)}, "error_every must be an integer >= 1 (chunks), got 0"),
        ({"chunking": Chunking(pilot_side=0)}, "pilot_side must be an integer >= 1 (px), got 0"),
        ({"chunking": Chunking(pilot_frames=2.5)}, "pilot_frames must be an integer >= 1 (frames), got 2.5"),
        (
            {"chunking": Chunking(pilot_blocks=True)},
            "pilot_blocks must be an integer >= 1 (blocks), got True",
        ),
        ({"estimator": ANRAEstimator(mode="ratio")}, "needs an estimator with mode='lsq'"),
        ({"estimator": ANRAEstimator(window=5)}, "use window=None, got 5"),
        ({"dtype": torch.int32}, "dtype must be torch.float32 or torch.float64, got torch.int32"),
    ],
)
def test_bad_arguments_get_one_line_errors(kwargs, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        estimate_chunked(_video(20).float(), DT, DX, **kwargs)


def test_too_few_frames_and_a_wrong_shape_are_refused() -> None:
    with pytest.raises(ValueError, match="need at least 5 frames for the time filter, got 3"):
        estimate_chunked(torch.zeros(3, 40, 40), DT, DX)
    with pytest.raises(ValueError, match=r"frames must have shape \(T, H, W\), got \(40, 40\)"):
        estimate_chunked(torch.zeros(40, 40), DT, DX)


def test_spikes_are_repaired_in_every_chunk_and_counted_once() -> None:
    """30 single-sample spikes of 50 K, some on chunk edges: all repaired, counted once, a as unspiked."""
    video = _video(120, side=64, seed=6).float()
    clean = estimate_chunked(video, DT, DX, chunking=Chunking(chunk_frames=12)).result
    generator = torch.Generator().manual_seed(1)
    rows, cols = (
        torch.randint(0, 60, (30,), generator=generator),
        torch.randint(0, 64, (30,), generator=generator),
    )
    frames = torch.randperm(120, generator=generator)[:30]
    frames[:3] = torch.tensor([12, 15, 24])  # a chunk's first frame, the last of its halo, the next's first
    video[frames, rows, cols] += 50.0
    result = estimate_chunked(video, DT, DX, chunking=Chunking(chunk_frames=12)).result
    assert result.artefacts[0]["spikes"] == 30
    assert abs(float(result.diffusivity) - float(clean.diffusivity)) < 0.2 * float(clean.std_error)


def test_the_computation_dtype_is_the_callers_not_the_files() -> None:
    """float32 frames computed in float64 (``anra batch --float64``) give what float64 frames give."""
    video = _video(40).float()
    asked = estimate_chunked(video, DT, DX, dtype=torch.float64).result
    stored = estimate_chunked(video.double(), DT, DX).result
    single = estimate_chunked(video, DT, DX).result
    assert float(asked.diffusivity) == float(stored.diffusivity)
    assert float(asked.std_error) == float(stored.std_error)
    assert float(single.diffusivity) != float(stored.diffusivity)  # float32 differs in its last digits
