"""The public API computes on its input's device and dtype: with the default device switched to ``meta``
and every input on the CPU, each entry point runs and gives the same numbers as with the CPU default.

A tensor created without a device would land on ``meta`` (no data) and the computation would fail or mix
devices; a kernel built once on the default device, or a constant tensor, likewise. The commands take
``--device`` and refuse a device that is not there with one line.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import pytest
import torch

from anra_torch import ANRAEstimator, StreamingEstimator, TissueFeatures, diagnose_terms, simulate_heat
from anra_torch.cli import main
from anra_torch.effects import Effect, hidden_effect_video, simulate_effects
from anra_torch.estimation import Chunking, estimate_chunked
from anra_torch.forecast import fit_source_map
from anra_torch.simulation import gaussian_blob


@contextmanager
def default_device(device: str) -> Iterator[None]:
    before = torch.get_default_device()
    torch.set_default_device(device)
    try:
        yield
    finally:
        torch.set_default_device(before)


def on_meta_default(run: Callable[[], object]) -> object:
    """``run()`` with the default device set to ``meta`` (inputs made beforehand, on the CPU)."""
    with default_device("meta"):
        return run()


def tensors(value: object) -> list[torch.Tensor]:
    """Every tensor and number in a result (dataclass fields, dicts, tuples), in order."""
    if isinstance(value, torch.Tensor):
        return [value.detach()]
    if isinstance(value, int | float) and not isinstance(value, bool):
        return [torch.tensor(float(value), dtype=torch.float64, device="cpu")]
    if isinstance(value, dict):
        return [t for k in sorted(value, key=str) for t in tensors(value[k])]
    if isinstance(value, list | tuple):
        return [t for v in value for t in tensors(v)]
    if hasattr(value, "__dataclass_fields__"):
        return [t for name in value.__dataclass_fields__ for t in tensors(getattr(value, name))]
    return []


def assert_same(meta: object, cpu: object) -> None:
    got, want = tensors(meta), tensors(cpu)
    assert len(got) == len(want) > 0
    for g, w in zip(got, want, strict=True):
        assert g.device.type == "cpu", "a result on the default device instead of the input's"
        torch.testing.assert_close(g, w, rtol=0, atol=0, equal_nan=True)


@pytest.fixture
def video(dtype: torch.dtype) -> torch.Tensor:
    t = torch.arange(12, dtype=torch.float64, device="cpu") / 27.0
    clean = gaussian_blob(t, shape=(40, 44), dx=0.1, a=0.2, peak=3.0, sigma=0.6)
    noise = 0.01 * torch.randn(clean.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    return (clean + noise).to(dtype)


def test_estimator_batched_with_field(video: torch.Tensor) -> None:
    batch = torch.stack([video, video.flip(-1)])
    dt = torch.tensor([1 / 27, 1 / 25], dtype=video.dtype, device="cpu")

    def run() -> object:
        return ANRAEstimator(smoothing=(1.0, 2.0), window=9, strict=False)(batch, dt, 0.1)

    assert_same(on_meta_default(run), run())


def test_estimator_masked_and_ratio(video: torch.Tensor) -> None:
    frames = video.clone()
    frames[3, 5, 7] = torch.nan
    frames[:, 20, 20] = 1.0  # a dead element

    def run() -> object:
        lsq = ANRAEstimator(strict=False)(frames, 1 / 27, 0.1)
        return lsq, ANRAEstimator(mode="ratio", strict=False)(frames, 1 / 27, 0.1)

    assert_same(on_meta_default(run), run())


def test_estimator_gradients(video: torch.Tensor) -> None:
    def run() -> object:
        frames = video.clone().requires_grad_(True)
        result = ANRAEstimator(smoothing=1.0, strict=False)(frames, 1 / 27, 0.1)
        (grad,) = torch.autograd.grad(result.diffusivity, frames)
        return result.diffusivity, grad

    assert_same(on_meta_default(run), run())


def test_streaming_and_chunked(video: torch.Tensor) -> None:
    def run() -> object:
        stream = StreamingEstimator(dt=1 / 27, dx=0.1, smoothing=1.0)
        for frame in video:
            last = stream.push(frame)
        chunked = estimate_chunked(video, 1 / 27, 0.1, chunking=Chunking(chunk_frames=4, pilot_frames=8))
        return last, chunked.result, chunked.gain

    assert_same(on_meta_default(run), run())


def test_tissue_features(dtype: torch.dtype) -> None:
    t = torch.arange(16, dtype=torch.float64, device="cpu") * 0.5
    heated = 37.0 + gaussian_blob(t, shape=(28, 30), dx=0.1, a=0.01, peak=25.0, sigma=0.5)
    frames = heated.to(dtype)

    def run() -> object:
        out = TissueFeatures()(frames, dt=0.5, dx=0.1)
        return out.maps, out.summary

    assert_same(on_meta_default(run), run())


@pytest.mark.slow
def test_diagnose_terms() -> None:
    video = hidden_effect_video(["advection"], seed=1, size=40, duration=1.0)
    frames = video.frames.to("cpu")

    def run() -> object:
        d = diagnose_terms(frames, video.dt, video.dx)
        return d.names, d.effects, d.base, d.coefficients

    meta, cpu = on_meta_default(run), run()
    assert meta[0] == cpu[0] == ["advection"]
    assert_same(meta[1:], cpu[1:])


def test_simulation_and_source_map(dtype: torch.dtype) -> None:
    initial = torch.zeros(24, 24, dtype=dtype, device="cpu")
    initial[10:14, 10:14] = 1.0
    q = torch.zeros(24, 24, dtype=dtype, device="cpu")
    q[8:16, 8:16] = 1.0
    advection = Effect("advection", {"vx": 0.3, "vy": -0.2})

    def run() -> object:
        heat = simulate_heat(initial, a=0.2, dx=0.1, dt=0.01, n_frames=6)
        effects = simulate_effects(initial, a=0.2, dx=0.1, dt=0.01, n_frames=6, effects=[advection])
        forced = simulate_effects(initial + 20.0, a=0.1, dx=0.5, dt=0.1, n_frames=20, forcing=q)
        model = fit_source_map(forced, 0.1, 0.5, scale_px=0)
        return heat, effects, model.a, model.forcing

    assert_same(on_meta_default(run), run())


# ------------------------------------------------------------------------------------------- commands
@pytest.fixture
def recording(tmp_path) -> str:  # noqa: ANN001 - pytest's tmp_path
    t = np.arange(30) / 27.0
    clean = gaussian_blob(torch.from_numpy(t), shape=(40, 40), dx=0.1, a=0.2, peak=3.0, sigma=0.6).numpy()
    noisy = clean + 0.01 * np.random.default_rng(0).standard_normal(clean.shape)
    path = tmp_path / "spot.npz"
    np.savez(path, frames=noisy.astype(np.float32), dt=1 / 27, dx=0.1)
    return str(path)


@pytest.mark.parametrize("command", ["estimate", "diagnose", "features", "batch"])
def test_commands_take_a_device(command: str, recording: str, tmp_path, capsys) -> None:  # noqa: ANN001
    args = {
        "estimate": ["estimate", recording, "--json"],
        "diagnose": ["diagnose", recording, "--json"],
        "features": ["features", recording, "--out", str(tmp_path / "maps.npz")],
        "batch": ["batch", str(tmp_path), "--out", str(tmp_path / "rows.csv"), "--no-progress"],
    }[command]
    assert main([*args, "--device", "cpu"]) in (0, None)
    if command == "estimate":
        record = json.loads(capsys.readouterr().out)
        assert math.isclose(record["diffusivity"], 0.2, rel_tol=0.05)
    capsys.readouterr()
    absent = "cuda:7" if torch.cuda.is_available() else "cuda"  # no such device here
    assert main([*args, "--device", absent]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--device" in err[0] and "not available" in err[0]


def test_device_names_are_checked(recording: str, capsys) -> None:  # noqa: ANN001
    assert main(["estimate", recording, "--device", "tpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--device" in err[0] and "'tpu'" in err[0]
