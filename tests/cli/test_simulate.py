"""``anra simulate`` (:mod:`anra_torch.cli.simulate`): readable files, presets, flags, ``--effect`` with the
truth in the file, ``--param`` overrides, ``--crop``, one-line errors.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from commands import run

from anra_torch.cli import PRESETS
from anra_torch.effects import EFFECTS, Sensor, effects_from_json, hidden_effect_video
from anra_torch.simulation.synthetic import paper_video

SMALL = ("--size", "48", "--duration", "1")
"""A 48 x 48 px, 31-frame scene: fast."""


def truth(path: Path) -> tuple:
    with np.load(path) as data:
        return effects_from_json(str(data["effects"]))


def test_effect_writes_frames_and_truth_of_hidden_effect_video(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "video.npz"
    code, out, err = run(
        capsys,
        "simulate",
        "--effect",
        "advection,linear_loss",
        "--seed",
        3,
        "--noise",
        0.05,
        *SMALL,
        "-o",
        path,
    )
    assert (code, err) == (0, "")
    assert out.startswith(f"wrote {path}: 31 frames of 48 x 48 px") and "effects: advection vx=" in out
    expected = hidden_effect_video(
        ["advection", "linear_loss"], seed=3, size=48, duration=1.0, sensor=Sensor(noise_sd=0.05)
    )
    with np.load(path) as data:
        assert {"frames", "dt", "dx", "t", "a_true", "noise_sd", "seed", "effects", "preset"} == set(
            data.files
        )
        np.testing.assert_array_equal(data["frames"], expected.frames.numpy())
        assert float(data["noise_sd"]) == 0.05 and int(data["seed"]) == 3 and str(data["preset"]) == "hidden"
        assert float(data["a_true"]) == 0.15 and float(data["dx"]) == 0.5
        records = json.loads(str(data["effects"]))
    assert [r["name"] for r in records] == ["advection", "linear_loss"]
    assert set(records[0]["params"]) == {"vx", "vy"} and records[0]["units"]["vx"] == "mm/s"
    assert truth(path) == expected.effects


def test_param_fixes_one_value_and_the_rest_come_from_the_seed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drawn, fixed = tmp_path / "drawn.npz", tmp_path / "fixed.npz"
    assert (
        run(capsys, "simulate", "--effect", "source", "--effect", "anisotropy", *SMALL, "-o", drawn)[0] == 0
    )
    code, _, _ = run(
        capsys,
        *("simulate", "--effect", "source,anisotropy", *SMALL),
        *("--param", "source.rate=2.5", "--param", "anisotropy.a_xy=0.01", "-o", fixed),
    )
    assert code == 0
    (src0, aniso0), (src1, aniso1) = truth(drawn), truth(fixed)
    assert src1.params == {**src0.params, "rate": 2.5}
    assert aniso1.params == {**aniso0.params, "a_xy": 0.01}
    assert aniso1.derived()["ratio"] != aniso0.derived()["ratio"]  # derived values follow the parameters


@pytest.mark.slow
def test_estimate_reads_the_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pure, lossy = tmp_path / "pure.npz", tmp_path / "lossy.npz"
    assert run(capsys, "simulate", "--preset", "hidden", "--size", "64", "-o", pure)[0] == 0
    assert truth(pure) == ()
    assert run(capsys, "simulate", "--effect", "linear_loss", "--size", "64", "-o", lossy)[0] == 0
    for path in (pure, lossy):
        code, out, err = run(capsys, "estimate", path, "--json")
        assert (code, err) == (0, "")
        summary = json.loads(out)
        assert summary["a_true"] == 0.15 and summary["frames"] == 91 and summary["valid"] is True
    # Pure heat transfer: the estimator recovers the truth.
    assert json.loads(run(capsys, "estimate", pure, "--json")[1])["diffusivity"] == pytest.approx(
        0.15, rel=0.05
    )


def test_crop_shifts_the_positions_in_the_truth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    full, crop = tmp_path / "full.npz", tmp_path / "crop.npz"
    argv = ("simulate", "--effect", "heterogeneity,source", *SMALL)
    assert run(capsys, *argv, "-o", full)[0] == 0
    assert run(capsys, *argv, "--crop", "32", "-o", crop)[0] == 0
    (het0, src0), (het1, src1) = truth(full), truth(crop)
    shift = 8 * 0.5  # (48 - 32) / 2 px at 0.5 mm
    assert het1.params["x"] == pytest.approx(het0.params["x"] - shift)
    assert het1.params["y"] == pytest.approx(het0.params["y"] - shift)
    assert src1.params["x1"] == pytest.approx(src0.params["x1"] - shift)
    assert het1.params["radius"] == het0.params["radius"] and src1.params["rate"] == src0.params["rate"]
    with np.load(full) as a, np.load(crop) as b:
        np.testing.assert_array_equal(b["frames"], a["frames"][:, 8:40, 8:40])
        np.testing.assert_array_equal(b["a_map"], a["a_map"][8:40, 8:40])


def test_presets_without_effects_are_unchanged(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "blobs.npz"
    assert run(capsys, "simulate", "--preset", "blobs", "--frames", "5", "-o", path)[0] == 0
    with np.load(path) as data:
        assert set(data.files) == {"frames", "dt", "dx", "t", "a_true", "noise_sd", "seed", "preset"}
        assert str(data["preset"]) == "blobs"
    assert "hidden" in PRESETS and PRESETS["hidden"].effects and not PRESETS["paper"].effects


def test_help_lists_effects_and_their_parameters(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "simulate", "--help")
    assert code == 0
    text = " ".join(out.split())
    assert "--effect NAME[,NAME...]" in text and "--param NAME.KEY=VALUE" in text
    for name, spec in EFFECTS.items():
        assert f"{name} ({', '.join(spec.params)})" in text
    assert "drawn at random from --seed" in text


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ("--effect", "perfusion"),
            r"argument --effect: unknown effect 'perfusion'; expected one of: linear_loss",
        ),
        (("--effect", "source", "--param", "source-rate"), r"argument --param: must be NAME.KEY=VALUE"),
        (
            ("--effect", "source", "--param", "source.rate=fast"),
            r"must be NAME.KEY=VALUE with a finite number",
        ),
        (("--effect", "source", "--param", "advection.vx=1"), r"effect 'advection' is not simulated; add it"),
        (("--param", "source.rate=1"), r"effect 'source' is not simulated"),
        (("--effect", "source", "--param", "source.speed=1"), r"effect 'source' has no parameter 'speed'"),
        (("--effect", "anisotropy,heterogeneity"), r"both replace the diffusion term"),
        (("--effect", "source,source"), r"effect 'source' is given 2 times"),
        (
            ("--effect", "source", "--preset", "paper"),
            r"--effect needs a scene with effects \(--preset hidden\)",
        ),
        (
            ("--effect", "anisotropy", "--param", "anisotropy.a_xy=1"),
            r"anisotropy tensor \[\[a_x, a_xy\], \[a_xy, a_y\]\] must be positive definite",
        ),
        (("--effect", "source", "--frames", "1"), r"at least 2 frames"),
        (("--effect", "source", "--crop", "200"), r"--crop must be at most the frame size 96 px"),
    ],
)
def test_errors_are_one_line(
    argv: tuple[str, ...], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "simulate", *argv, "-o", tmp_path / "x.npz")
    assert code == 2 and out == ""
    assert err.startswith("anra: error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert re.search(message, err), err
    assert not (tmp_path / "x.npz").exists()


# ------------------------------------------------------------------------------------------- simulate
def test_simulate_writes_a_readable_npz(paper96: Path) -> None:
    with np.load(paper96) as data:
        assert set(data.files) == {"frames", "dt", "dx", "t", "a_true", "noise_sd", "seed", "preset"}
        assert data["frames"].shape == (28, 96, 96)
        assert float(data["dt"]) == pytest.approx(1 / 27) and float(data["dx"]) == pytest.approx(10 / 224)
        np.testing.assert_allclose(data["t"], np.arange(28) / 27)
        assert float(data["a_true"]) == 0.2 and str(data["preset"]) == "paper"
        # The crop is the centre of the paper's full video, noise included.
        full = paper_video(noise_sd=0.01, seed=0).frames[0, :, 64:160, 64:160].numpy()
        np.testing.assert_array_equal(data["frames"], full)


def test_simulate_flags(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(
        capsys,
        *("simulate", "--a", "0.1", "--noise", "0", "--fps", "10", "--frames", "9", "--size", "40"),
        *("--dx", "0.25", "-o", tmp_path / "p"),
    )
    assert code == 0 and f"wrote {tmp_path / 'p.npz'}: 9 frames of 40 x 40 px" in out
    with np.load(tmp_path / "p.npz") as data:
        assert (float(data["a_true"]), float(data["dx"]), float(data["dt"])) == (0.1, 0.25, 0.1)
        clean = paper_video(noise_sd=0.0, fps=10, duration=0.8, size=40, a=0.1).clean.numpy()
        np.testing.assert_allclose(data["frames"], clean, rtol=0, atol=1e-12)


def test_simulate_blobs_preset_with_duration_and_crop(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = (
        "simulate",
        "--preset",
        "blobs",
        "--duration",
        "0.5",
        "--fps",
        "20",
        "--crop",
        "32",
        "--seed",
        "3",
    )
    code, _, _ = run(capsys, *argv, "-o", tmp_path / "b.npz")
    assert code == 0
    with np.load(tmp_path / "b.npz") as data:
        assert data["frames"].shape == (11, 32, 32)
        assert (float(data["a_true"]), float(data["dx"]), int(data["seed"])) == (0.15, 0.5, 3)


def test_an_output_that_is_a_device_or_a_folder_is_refused(tmp_path: Path, capsys) -> None:
    for out, kind in (("/dev/null", "a character device"), (tmp_path, "a folder")):
        code, stdout, err = run(capsys, "simulate", *SMALL, "-o", out)
        assert code == 2 and err.count("\n") == 1, err
        assert f"-o {out} must be a file path, got {kind}" in err
    assert not Path("/dev/null.npz").exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("preset", "least"), [("blobs", 49), ("hidden", 16)])
def test_a_size_below_the_scenes_minimum_names_size(preset: str, least: int, tmp_path: Path, capsys) -> None:
    code, _, err = run(capsys, "simulate", "--preset", preset, "--size", least - 1, "-o", tmp_path / "x.npz")
    assert code == 2 and f"--size must be at least {least} px for --preset {preset}" in err, err
    assert "sigma_range_px" not in err and not (tmp_path / "x.npz").exists()
    code, out, _ = run(
        capsys, "simulate", "--preset", preset, "--size", least, "--frames", "3", "-o", tmp_path / "x"
    )
    assert code == 0 and (tmp_path / "x.npz").exists()
    assert run(capsys, "simulate", "--help")[1].count(f"{preset} {least}") == 1  # "at least ... blobs 49"
