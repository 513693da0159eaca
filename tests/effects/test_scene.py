"""Random ground-truth videos (:mod:`anra_torch.effects.scene`): deterministic draws recorded as the truth,
detectable parameters, physical videos, ``.npz`` round trips and crops.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
import torch

from anra_torch.effects import (
    EFFECTS,
    Effect,
    Geometry,
    HiddenEffectVideo,
    Sensor,
    effects_from_json,
    hidden_effect_video,
    simulate_effects,
)
from anra_torch.effects.scene import draw_scene
from anra_torch.simulation import simulate_heat
from anra_torch.video import load_video

F64 = torch.float64


def test_scene_temperature_is_the_first_frame() -> None:
    scene = draw_scene((), seed=11, size=48)
    centres = (torch.arange(48, dtype=F64) + 0.5) * scene.dx
    torch.testing.assert_close(scene.temperature(centres[None, :], centres[:, None]), scene.initial)


def test_hidden_video_is_deterministic_and_records_the_truth() -> None:
    names = ["linear_loss", "advection", "source"]
    first = hidden_effect_video(names, seed=7, size=48, duration=1.0)
    again = hidden_effect_video(names, seed=7, size=48, duration=1.0)
    other = hidden_effect_video(names, seed=8, size=48, duration=1.0)
    assert isinstance(first, HiddenEffectVideo)
    torch.testing.assert_close(first.frames, again.frames, rtol=0, atol=0)
    assert first.effects == again.effects and first.effects != other.effects
    assert [e.name for e in first.effects] == names
    assert first.frames.shape == (31, 48, 48) and first.times[-1] == pytest.approx(1.0)
    # The truth is what was simulated.
    u0 = first.clean[0]
    redo = simulate_effects(u0, a=0.15, dx=0.5, dt=1 / 30, n_frames=31, effects=first.effects)
    torch.testing.assert_close(first.clean, redo, rtol=0, atol=1e-12)
    # Noise: white, sd = 1 % of the peak initial rise over the background.
    rise = float(u0.max()) - 30.0
    assert 5.0 <= rise <= 40.0 and first.noise_sd == pytest.approx(0.01 * rise)
    assert float((first.frames - first.clean).std()) == pytest.approx(first.noise_sd, rel=0.02)
    pure = hidden_effect_video((), seed=7, size=48, duration=1.0, sensor=Sensor(noise_frac=0.0))
    assert pure.effects == () and pure.a == 0.15 and pure.a_map is None
    torch.testing.assert_close(pure.frames, simulate_heat(u0, a=0.15, dx=0.5, dt=1 / 30, n_frames=31))


@pytest.mark.slow
def test_hidden_video_time_error_is_negligible() -> None:
    video = hidden_effect_video(
        ["linear_loss", "source", "advection", "anisotropy"], seed=0, size=48, sensor=Sensor(noise_frac=0.0)
    )
    fine = simulate_effects(
        video.clean[0], a=0.15, dx=0.5, dt=1 / 30, n_frames=91, effects=video.effects, substeps=8
    )
    rise = float(video.clean[0].max()) - 30.0
    assert float((video.clean - fine).abs().max()) < 1e-6 * rise


def test_params_override_only_what_they_name() -> None:
    base = hidden_effect_video(["advection", "heterogeneity"], seed=3, size=48, duration=0.5)
    fixed = hidden_effect_video(
        ["advection", "heterogeneity"], seed=3, size=48, duration=0.5, params={"advection": {"vx": 0.25}}
    )
    assert fixed.effects[0].params == {"vx": 0.25, "vy": base.effects[0].params["vy"]}
    assert fixed.effects[1] == base.effects[1]
    with pytest.raises(ValueError, match="params given for effect 'source', which is not among the effects"):
        hidden_effect_video(["advection"], seed=3, size=48, params={"source": {"rate": 1.0}})
    with pytest.raises(ValueError, match="unknown effect 'perfusion'; expected one of: linear_loss"):
        hidden_effect_video(["perfusion"], seed=3)
    with pytest.raises(ValueError, match="both replace the diffusion term"):
        hidden_effect_video(["anisotropy", "nonlinear_diffusion"], seed=3, size=48)
    with pytest.raises(ValueError, match="effect 'source' is given 2 times"):
        hidden_effect_video(["source", "source"], seed=3, size=48)


def test_sampled_parameters_are_in_their_detectable_ranges() -> None:
    for seed in range(6):
        rng = np.random.default_rng(seed)
        g = Geometry((96, 96), 0.5, 3.0, 0.15, rise=12.0, background=30.0, hotspots=((20.0, 25.0, 2.0),))
        loss = EFFECTS["linear_loss"].sample(rng, g)
        assert 0.3 <= math.exp(-loss["b"] * 3.0) <= 0.8 and 30.0 - 2.4 <= loss["T_ref"] <= 30.0
        src = EFFECTS["source"].sample(rng, g)
        assert 0.2 <= src["rate"] * 3.0 / 12.0 <= 1.0 and 1.0 <= src["width"] <= 2.5
        ends = np.array([src["x0"], src["y0"], src["x1"], src["y1"]])
        assert bool(((ends >= 3 * src["width"]) & (ends <= 48.0 - 3 * src["width"])).all())
        assert math.hypot(src["x1"] - src["x0"], src["y1"] - src["y0"]) <= 10.0
        flow = EFFECTS["advection"].sample(rng, g)
        assert 2.0 <= math.hypot(flow["vx"], flow["vy"]) * 3.0 / 0.5 <= 10.0
        aniso = Effect("anisotropy", EFFECTS["anisotropy"].sample(rng, g))
        assert 1.5 <= aniso.derived()["ratio"] <= 4.0
        assert EFFECTS["anisotropy"].reference_a(aniso.params) == pytest.approx(0.15)
        het = EFFECTS["heterogeneity"].sample(rng, g)
        contrast = het["a_inside"] / het["a_outside"]
        assert (0.3 <= contrast <= 0.6 or 1.7 <= contrast <= 3.0) and het["a_outside"] == 0.15
        assert (
            4.0 <= het["radius"] <= 10.0
            and math.hypot(het["x"] - 20.0, het["y"] - 25.0) <= 0.5 * het["radius"]
        )
        law = EFFECTS["nonlinear_diffusion"].sample(rng, g)
        assert 0.3 <= law["beta"] * 12.0 <= 1.0 and law["a0"] == 0.15 and law["T_ref"] == 30.0


@pytest.mark.slow
@pytest.mark.parametrize("name", list(EFFECTS))
def test_hidden_videos_stay_physical_and_show_the_effect(
    hidden_video: Callable[..., HiddenEffectVideo], name: str
) -> None:
    """Each effect's four scenes against the same scenes without it (those pure scenes are simulated once per
    test run, not once per effect)."""
    for seed in range(4):
        video = hidden_effect_video([name], seed=seed, sensor=Sensor(noise_frac=0.0))
        pure = hidden_video((), seed=seed, sensor=Sensor(noise_frac=0.0))
        rise = float(pure.clean[0].max()) - 30.0
        assert bool(video.clean.isfinite().all())
        assert 30.0 - 0.2 * rise - 1e-6 <= float(video.clean.min())
        assert float(video.clean.max()) <= 30.0 + 2.0 * rise
        # Clearly present at the default noise (1 % of the rise): the matched-filter signal-to-noise ratio
        # of the effect, ||with - without|| / noise sd over every pixel of every frame, is far above 1.
        snr = float((video.clean - pure.clean).square().sum().sqrt()) / (0.01 * rise)
        assert snr > 50.0, snr
        if name == "heterogeneity":
            assert video.a_map is not None and video.a_map.shape == (96, 96)


def test_hidden_video_npz_round_trip_and_crop(tmp_path) -> None:  # noqa: ANN001
    video = hidden_effect_video(
        ["source", "heterogeneity"], seed=2, size=48, duration=0.5, sensor=Sensor(dtype=torch.float32)
    )
    assert video.frames.dtype == torch.float32 and video.a_map is not None
    path = video.to_npz(tmp_path / "truth")
    assert path.name == "truth.npz"
    with np.load(path) as data:
        assert {"frames", "dt", "dx", "t", "a_true", "noise_sd", "seed", "effects", "a_map"} <= set(
            data.files
        )
        assert effects_from_json(str(data["effects"])) == video.effects
        np.testing.assert_array_equal(data["frames"], video.frames.numpy())
        assert float(data["a_true"]) == video.a == video.effects[1].params["a_outside"]
    loaded = load_video(path)
    assert loaded.dt == pytest.approx(1 / 30) and loaded.dx == 0.5
    assert effects_from_json(loaded.meta["effects"]) == video.effects
    # Cropping shifts the positions in the truth to the window.
    window = video.crop(4, 8, 32, 30)
    assert window.frames.shape == (16, 32, 30) and window.a_map.shape == (32, 30)
    src, het = window.effects
    assert src.params["x0"] == pytest.approx(video.effects[0].params["x0"] - 4.0)
    assert src.params["y1"] == pytest.approx(video.effects[0].params["y1"] - 2.0)
    assert het.params["x"] == pytest.approx(video.effects[1].params["x"] - 4.0)
    assert het.params["radius"] == video.effects[1].params["radius"]
    with pytest.raises(ValueError, match="crop window .* must lie inside the 48 x 48 px frame"):
        video.crop(40, 0, 16, 16)
