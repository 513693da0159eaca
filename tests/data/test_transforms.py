"""Dataset transforms: region of interest (frames and per-pixel labels), resampling in time (exact on fields
linear in time), phase selection against a simulation's known switch-off, chaining and pickling."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from tolerances import assert_rounding_close

from anra_torch.data import Compose, RegionOfInterest, Resample, SelectPhase, ThermalVideoDataset
from anra_torch.recording import find_phases
from anra_torch.simulation import MovingSource, simulate_tissue
from anra_torch.video import Video, save_npz

F64 = torch.float64


def linear_in_time(t: torch.Tensor, h: int = 6, w: int = 7) -> torch.Tensor:
    """Frames ``30 + 2 t + pattern(y, x)``: every interpolation exact on linear data reproduces them."""
    pattern = torch.arange(h * w, dtype=F64).reshape(h, w) / 10
    return 30.0 + 2.0 * t.view(-1, 1, 1) + pattern


@pytest.fixture(scope="module")
def heated() -> dict:
    """A tissue heated by a spot for 3 s (switch-off known), then cooling, 10 Hz for 8 s."""
    dt, t_off = 0.1, 3.0
    source = MovingSource(start=(2.4, 2.4), end=(2.4, 2.4), width=0.6, power=20.0, t_on=0.0, t_off=t_off)
    u0 = torch.full((24, 24), 37.0, dtype=F64)
    frames = simulate_tissue(u0, 0.12, 0.2, dx=0.2, dt=dt, n_frames=81, source=source)
    frames = frames + 0.01 * torch.randn(frames.shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    return {"video": Video(frames=frames, dt=dt, dx=0.2), "switch_off": round(t_off / dt)}


def test_region_of_interest_cuts_frames_and_per_pixel_labels() -> None:
    frames = torch.randn(5, 10, 12, dtype=F64)
    labels = {
        "burn": torch.rand(10, 12) > 0.5,
        "stack": torch.randn(3, 10, 12),
        "grade": 2.0,
        "curve": torch.ones(5),
    }
    video = Video(frames=frames, dt=0.1, dx=0.2, meta={"labels": labels})
    for roi in ("3,2,6,5", (3, 2, 6, 5), [3, 2, 6, 5]):
        out = RegionOfInterest(roi)(video)
        assert torch.equal(out.frames, frames[:, 2:7, 3:9]) and out.meta["roi"] == [3, 2, 6, 5]
        assert torch.equal(out.meta["labels"]["burn"], labels["burn"][2:7, 3:9])
        assert torch.equal(out.meta["labels"]["stack"], labels["stack"][:, 2:7, 3:9])
        assert out.meta["labels"]["grade"] == 2.0 and out.meta["labels"]["curve"] is labels["curve"]
    with pytest.raises(
        ValueError, match=r"<memory>: roi 8,2,6,5 \(x0,y0,W,H px\) does not fit in the 12 x 10 px"
    ):
        RegionOfInterest("8,2,6,5")(video)
    with pytest.raises(ValueError, match=r"roi must be X0,Y0,W,H in px \(four integers\), got '1,2'"):
        RegionOfInterest("1,2")
    with pytest.raises(ValueError, match=r"roi needs X0, Y0 >= 0 and W, H >= 1 px, got '0,0,0,4'"):
        RegionOfInterest((0, 0, 0, 4))


@pytest.mark.parametrize("method", ["linear", "cubic"])
def test_resample_to_a_new_step_is_exact_on_a_linear_history(method: str) -> None:
    t = torch.arange(11, dtype=F64) * 0.2
    video = Video(frames=linear_in_time(t), dt=0.2, dx=0.1)  # uniform, no timestamps
    out = Resample(dt=0.05, method=method)(video)
    grid = torch.arange(41, dtype=F64) * 0.05
    assert out.dt == 0.05 and out.frames.shape == (41, 6, 7) and out.meta["resampled"]["from_frames"] == 11
    assert_rounding_close(out.t, grid)
    assert_rounding_close(out.frames, linear_in_time(grid))


def test_resample_makes_non_uniform_timestamps_uniform() -> None:
    t = torch.tensor([0.0, 0.1, 0.3, 0.4, 0.6, 0.7, 0.9, 1.0], dtype=F64)
    video = Video(frames=linear_in_time(t), dt=0.1, dx=0.1, t=t)
    assert not video.uniform
    out = Resample()(video)
    assert out.uniform and out.meta["resampled"]["step_max"] == pytest.approx(0.2)
    assert_rounding_close(out.frames, linear_in_time(out.t))
    plain = Video(frames=linear_in_time(t[:4]), dt=0.1, dx=0.1)
    assert Resample()(plain) is plain and Resample(dt=0.1)(plain) is plain
    with pytest.raises(ValueError, match=r"dt must be a positive number in s or None, got 0"):
        Resample(dt=0)
    with pytest.raises(ValueError, match=r"method must be one of cubic, linear, got 'spline'"):
        Resample(method="spline")


def test_select_phase_finds_the_cooling_after_the_known_switch_off(heated: dict) -> None:
    video, switch_off = heated["video"], heated["switch_off"]
    cooling = SelectPhase("cooling")(video)
    phase = cooling.meta["phase"]
    assert phase["kind"] == "cooling" and abs(phase["start_frame"] - switch_off) <= 2
    assert phase["stop_frame"] == 81 and torch.equal(cooling.frames, video.frames[phase["start_frame"] :])
    spot = cooling.frames[:, 10:14, 10:14].mean((1, 2))
    assert bool((spot[1:] < spot[:-1]).all())  # a source-free phase: the spot only cools
    # The preferred phase of a heating-then-cooling recording is its cooling (source-free first).
    assert SelectPhase()(video).meta["phase"] == phase
    heating = SelectPhase("heating")(video).meta["phase"]
    assert heating["start_frame"] <= 2 and abs(heating["stop_frame"] - 1 - switch_off) <= 2
    assert [(p.name, p.start, p.stop) for p in find_phases(video.frames, dt=video.dt)] == [
        ("heating", heating["start_frame"], heating["stop_frame"]),
        ("cooling", phase["start_frame"], phase["stop_frame"]),
    ]


def test_select_phase_names_what_it_found_when_the_kind_is_missing(heated: dict) -> None:
    warming = Video(frames=heated["video"].frames[:25], dt=0.1, dx=0.2)
    with pytest.raises(ValueError, match=r"<memory>: no cooling phase of at least 8 frames; found heating"):
        SelectPhase("cooling")(warming)
    with pytest.raises(ValueError, match=r"phase must be one of preferred, baseline, .*, got 'peak'"):
        SelectPhase("peak")
    with pytest.raises(ValueError, match=r"min_frames must be an integer >= 2, got 1"):
        SelectPhase(min_frames=1)


def test_transforms_chain_pickle_and_keep_frames_on_disk(heated: dict, tmp_path: Path) -> None:
    video = heated["video"]
    save_npz(tmp_path / "heated.npz", video.frames.numpy(), dt=video.dt, dx=video.dx)
    chain = Compose(SelectPhase("cooling"), RegionOfInterest("4,4,16,16"))
    dataset = ThermalVideoDataset(tmp_path, transform=pickle.loads(pickle.dumps(chain)))
    out = dataset[0]
    start = out.meta["phase"]["start_frame"]
    assert torch.equal(out.frames, video.frames[start:, 4:20, 4:20])
    lazy = ThermalVideoDataset(tmp_path, on_disk_above=0, transform=SelectPhase("cooling"))[0]
    assert lazy.on_disk and lazy.meta["phase"]["start_frame"] == start
    assert np.array_equal(np.asarray(lazy.loaded().frames), video.frames[start:].numpy())
    with pytest.raises(TypeError, match=r"steps must be callable \(Video -> Video\), got int"):
        Compose(SelectPhase(), 3)  # type: ignore[arg-type]
