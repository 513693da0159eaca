"""collate and VideoBatch: stacking, NaN padding with its mask and count, centre crops, labels, and
VideoBatch.apply giving each video's own numbers (estimator and tissue features against each video alone)."""

from __future__ import annotations

import math

import pytest
import torch
from tolerances import assert_rounding_close

from anra_torch.data import VideoBatch, collate
from anra_torch.estimation import ANRAEstimator
from anra_torch.tissue import TissueFeatures
from anra_torch.video import Video

DT, DX = 0.2, 0.2  # s, mm


def diffusing_gaussian(
    t: int, h: int, w: int, a: float, *, noise: float = 0.02, seed: int = 0
) -> torch.Tensor:
    """The exact 2D solution of dT/dt = a Lap T from a Gaussian of sigma 1 mm, 25 K over 37 C, plus noise."""
    time = torch.arange(t, dtype=torch.float64).view(-1, 1, 1) * DT
    y = (torch.arange(h, dtype=torch.float64).view(1, -1, 1) - (h - 1) / 2) * DX
    x = (torch.arange(w, dtype=torch.float64).view(1, 1, -1) - (w - 1) / 2) * DX
    s2 = 1.0 + 2 * a * time
    clean = 37.0 + 25.0 / s2 * torch.exp(-(x**2 + y**2) / (2 * s2))
    generator = torch.Generator().manual_seed(seed)
    return clean + noise * torch.randn(clean.shape, generator=generator, dtype=torch.float64)


def video(t: int, h: int, w: int, diffusivity: float, seed: int = 0, **labels: object) -> Video:
    frames = diffusing_gaussian(t, h, w, diffusivity, seed=seed)
    return Video(frames=frames, dt=DT, dx=DX, meta={"labels": dict(labels)})


@pytest.fixture(scope="module")
def mixed() -> list[Video]:
    return [
        video(30, 32, 36, 0.10, seed=1, a=0.10, name="first", burn=torch.ones(32, 36, dtype=torch.bool)),
        video(25, 24, 40, 0.15, seed=2, a=0.15, name="second", burn=torch.ones(24, 40, dtype=torch.bool)),
        video(30, 32, 36, 0.20, seed=3, name="third", burn=torch.ones(32, 36, dtype=torch.bool)),
    ]


def test_videos_of_one_shape_are_stacked_as_they_are() -> None:
    videos = [video(12, 24, 24, a, seed=k) for k, a in enumerate((0.1, 0.2))]
    batch = collate(videos)
    assert batch.mode == "same" and isinstance(batch, VideoBatch) and len(batch) == 2
    assert torch.equal(batch.frames, torch.stack([v.frames for v in videos]))
    assert bool(batch.mask.all()) and batch.padding.tolist() == [0, 0]
    assert torch.equal(batch.t, torch.arange(12, dtype=torch.float64).expand(2, 12) * DT)
    assert batch.dt.tolist() == [DT, DT] and batch.dx.tolist() == [DX, DX]


def test_padding_is_nan_with_its_mask_and_count(mixed: list[Video]) -> None:
    batch = collate(mixed)
    assert batch.mode == "pad" and tuple(batch.frames.shape) == (3, 30, 32, 40)
    assert batch.sizes.tolist() == [[30, 32, 36], [25, 24, 40], [30, 32, 36]]
    assert batch.padding.tolist() == [30 * 32 * 40 - 30 * 32 * 36, 30 * 32 * 40 - 25 * 24 * 40, 30 * 32 * 4]
    assert torch.equal(batch.mask, torch.isfinite(batch.frames))  # the videos have no NaN of their own
    assert int((~batch.mask).sum(dim=(1, 2, 3)).sub(batch.padding).abs().sum()) == 0
    for k, v in enumerate(mixed):
        t, h, w = v.frames.shape
        assert torch.equal(batch.frames[k, :t, :h, :w], v.frames)
        assert bool(batch.t[k, t:].isnan().all()) and torch.equal(
            batch.t[k, :t], torch.arange(t, dtype=torch.float64) * DT
        )
    assert torch.equal(
        batch.pixel_mask[1], torch.zeros(32, 40, dtype=torch.bool).index_fill(0, torch.arange(24), True)
    )


def test_labels_numbers_text_and_per_pixel_maps(mixed: list[Video]) -> None:
    batch = collate(mixed)
    a = batch.labels["a"]
    assert a.dtype == torch.float64 and a[:2].tolist() == [0.10, 0.15] and math.isnan(float(a[2]))
    assert batch.labels["name"] == ("first", "second", "third")
    burn = batch.labels["burn"]
    assert burn.dtype == torch.bool and tuple(burn.shape) == (3, 32, 40)
    assert torch.equal(burn, batch.pixel_mask)  # a map of ones, padded with False where the frame is not


def test_crop_keeps_the_first_frames_and_the_centre(mixed: list[Video]) -> None:
    batch = collate(mixed, mode="crop")
    assert batch.mode == "crop" and tuple(batch.frames.shape) == (3, 25, 24, 36)
    assert bool(batch.mask.all()) and batch.padding.tolist() == [0, 0, 0]
    # Centre offsets by hand: (36 - 36) // 2 = 0 and (32 - 24) // 2 = 4 rows; (40 - 36) // 2 = 2 columns.
    assert torch.equal(batch.frames[0], mixed[0].frames[:25, 4:28, 0:36])
    assert torch.equal(batch.frames[1], mixed[1].frames[:25, 0:24, 2:38])
    assert tuple(batch.labels["burn"].shape) == (3, 24, 36) and bool(batch.labels["burn"].all())
    assert batch.meta[0]["roi"] == [0, 4, 36, 24] and batch.meta[1]["roi"] == [2, 0, 36, 24]


def test_apply_gives_each_video_its_own_estimate_and_count(mixed: list[Video]) -> None:
    videos = list(mixed)
    holed = videos[1].frames.clone()
    holed[3, 5, 7] = holed[10, 20, 30] = float("nan")  # two samples of the video's own are masked
    videos[1] = Video(frames=holed, dt=DT, dx=DX)
    batch = collate(videos)
    estimator = ANRAEstimator(strict=False)
    result = batch.apply(estimator)
    for k, v in enumerate(videos):
        alone = estimator(v.frames, v.dt, v.dx)
        assert_rounding_close(result.diffusivity[k], alone.diffusivity, ops=1000)
        assert_rounding_close(result.std_error[k], alone.std_error, ops=1000)
        assert int(result.n_masked[k]) == int(alone.n_masked) == (2 if k == 1 else 0)
        assert result.messages[k] == alone.messages[0]
    assert bool(result.per_frame[1, 21:].isnan().all())  # 25 - 5 + 1 = 21 frames of its own
    # The exact solution's diffusivity comes back within 2 %: the spacing travels with each video.
    torch.testing.assert_close(
        result.diffusivity, torch.tensor([0.10, 0.15, 0.20], dtype=torch.float64), rtol=0.02, atol=0
    )
    # Straight in, the padding is masked and counted: n_masked is the padding plus the video's own.
    direct = estimator(batch.frames, batch.dt, batch.dx)
    assert direct.n_masked.tolist() == (batch.padding + torch.tensor([0, 2, 0])).tolist()


def test_apply_gives_each_video_its_own_tissue_maps(mixed: list[Video]) -> None:
    batch = collate(mixed)
    features = TissueFeatures()
    out = batch.apply(features)
    for k, v in enumerate(mixed):
        alone = features(v.frames, v.dt, v.dx)
        _, h, w = v.frames.shape
        assert set(out.maps) == set(alone.maps)
        for name, m in alone.maps.items():
            assert_rounding_close(out.maps[name][k, :h, :w], m, ops=1000)
            assert bool(out.maps[name][k, h:].isnan().all()) and bool(out.maps[name][k, :, w:].isnan().all())
        assert int(out.summary["n_masked"][k]) == 0 and out.messages[k] == alone.messages[0]
    assert tuple(out.stack().shape) == (3, len(features.map_names), 32, 40)


def test_apply_on_one_shape_is_one_call() -> None:
    batch = collate([video(12, 24, 24, a, seed=k) for k, a in enumerate((0.1, 0.2))])
    calls = []

    def layer(frames: torch.Tensor, dt: torch.Tensor, dx: torch.Tensor) -> torch.Tensor:
        calls.append(tuple(frames.shape))
        return frames.mean(1)

    assert torch.equal(batch.apply(layer), batch.frames.mean(1)) and calls == [(2, 12, 24, 24)]


def test_apply_names_the_videos_a_layer_refuses() -> None:
    small = Video(frames=diffusing_gaussian(12, 12, 16, 0.1), dt=DT, dx=DX)
    batch = collate([video(12, 24, 24, 0.1), small])
    with pytest.raises(ValueError, match=r"^<memory>: frames must be at least 20 x 20 px"):
        batch.apply(ANRAEstimator())


def test_dtype_device_and_pinning() -> None:
    counts = Video(frames=torch.arange(6 * 4 * 4).reshape(6, 4, 4), dt=0.1, dx=None)
    assert collate([counts]).frames.dtype == torch.get_default_dtype() and collate([counts]).dx is None
    single = Video(frames=torch.zeros(6, 4, 4, dtype=torch.float32), dt=0.1, dx=None)
    double = Video(frames=torch.zeros(6, 4, 5, dtype=torch.float64), dt=0.1, dx=None)
    assert collate([single, single]).frames.dtype == torch.float32
    batch = collate([single, double])
    assert batch.frames.dtype == torch.float64
    moved = batch.to("meta", torch.float32)
    assert moved.frames.device.type == "meta" and moved.frames.dtype == torch.float32
    assert moved.dt.dtype == torch.float64 and moved.mask.device.type == "meta"


def test_a_batch_is_made_on_the_videos_device_whatever_the_default() -> None:
    videos = [video(8, 20, 20, 0.1, seed=0, grade=1.0), video(6, 20, 24, 0.2, seed=1, grade=2.0)]
    torch.set_default_device("meta")  # a tensor made without a device would land here
    try:
        batch, cropped = collate(videos), collate(videos, mode="crop")
        made = [batch.frames, batch.dt, batch.dx, batch.t, batch.sizes, batch.labels["grade"], batch.mask]
        made += [batch.padding, cropped.frames, *batch.apply(lambda f, dt, dx: (f.mean(1), dt))]
    finally:
        torch.set_default_device(None)
    assert {x.device.type for x in made} == {"cpu"}
    assert torch.equal(batch.frames[0, :8, :, :20], videos[0].frames) and batch.padding.tolist() == [640, 960]


def test_errors_are_one_line() -> None:
    one, other = video(8, 20, 20, 0.1), video(8, 20, 24, 0.1)
    with pytest.raises(ValueError, match=r"mode must be one of pad, crop, same, got 'stretch'"):
        collate([one], mode="stretch")
    with pytest.raises(ValueError, match=r"one shape with mode='same', got \(8, 20, 20\), \(8, 20, 24\)"):
        collate([one, other], mode="same")
    with pytest.raises(TypeError, match=r"non-empty sequence of Video, got list"):
        collate([])
    with pytest.raises(TypeError, match=r"got an item of Tensor"):
        collate([one, one.frames])
    with pytest.raises(TypeError, match=r"dtype must be a floating dtype, got torch.int64"):
        collate([one], dtype=torch.int64)
    unknown = Video(frames=one.frames, dt=DT, dx=None)
    with pytest.raises(ValueError, match=r"dx: <memory> have no pixel size while the other videos have one"):
        collate([one, unknown])
    odd = Video(frames=one.frames, dt=DT, dx=DX, meta={"labels": {"curve": torch.zeros(3)}})
    even = Video(frames=other.frames, dt=DT, dx=DX, meta={"labels": {"curve": torch.zeros(4)}})
    with pytest.raises(ValueError, match=r"label 'curve': tensors of different shapes \(\(3,\), \(4,\)\)"):
        collate([odd, even])
