"""Tests for ``anra features``: the JSON object against the dose functions, --out, units and masking."""

from __future__ import annotations

import importlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from commands import assert_clean, assert_one_line_error, run, run_isolated
from depth_scenes import beam_recording
from reference import A_SKIN, EA_SKIN, R_GAS, cem43_constant, omega_constant
from shared_data import DATA

from anra_torch.cli import main
from anra_torch.layers import GaussianSmoothing
from anra_torch.simulation import (
    MovingSource,
    simulate_tissue,
)
from anra_torch.tissue import depth_features
from anra_torch.tissue.dose import arrhenius_omega, cem43
from anra_torch.tissue.features import TissueFeatures
from anra_torch.video import save_npz

DT, DX = 0.1, 0.2


@pytest.fixture(scope="module")
def burn() -> torch.Tensor:
    """A source sweeping 2 mm in 2 s over tissue at 37 C, then 2 s of cooling; noise 0.02 K."""
    u0 = torch.full((40, 40), 37.0, dtype=torch.float64)
    source = MovingSource(start=(3.0, 4.0), end=(5.0, 4.0), width=0.6, power=40.0, t_off=2.0)
    clean = simulate_tissue(u0, 0.1, 0.3, dx=DX, dt=DT, n_frames=41, source=source)
    generator = torch.Generator().manual_seed(2)
    return clean + 0.02 * torch.randn(clean.shape, generator=generator, dtype=torch.float64)


@pytest.fixture(scope="module")
def files(burn: torch.Tensor, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("features")
    holed = burn.clone()
    holed[5, 10, 10] = math.nan
    holed[6:9, 0, 0] = math.inf
    return {
        "celsius": save_npz(folder / "burn.npz", burn.numpy(), dt=DT, dx=DX),
        "kelvin": save_npz(folder / "burn_k.npz", (burn + 273.15).numpy(), dt=DT, dx=DX),
        "holed": save_npz(folder / "holed.npz", holed.numpy(), dt=DT, dx=DX),
        "no_dx": save_npz(folder / "no_dx.npz", burn.numpy(), dt=DT, dx=None),
    }


def test_json_values_match_the_dose_of_the_denoised_history(
    files: dict[str, Path], burn: torch.Tensor, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "features", files["celsius"], "--json")
    assert (code, err) == (0, "")
    assert out.count("\n") == 1
    record = json.loads(out)
    assert {"cem43_minutes_max", "omega_max", "peak_temperature_max", "damaged_fraction"} <= set(record)
    assert record["units"]["cem43_minutes_max"] == "min" and record["units"]["peak_temperature_max"] == "C"
    assert record["units"]["omega_max"] == "1" and record["temperature_unit"] == "C"
    assert (record["frames"], record["height"], record["width"]) == (41, 40, 40)
    assert record["n_masked"] == 0 and record["valid"] is True and record["out"] is None
    # Independent of the feature module: smooth with the same 1 px Gaussian, then the dose functions
    # over the recorded span (the default rule, "linear").
    history = GaussianSmoothing(1.0, border="reflect")(burn)
    expected_cem = float(cem43(history, DT, rule="linear").max())
    assert record["cem43_minutes_max"] == pytest.approx(expected_cem, rel=1e-9)
    expected_omega = float(arrhenius_omega(history, DT, rule="linear").max())
    assert record["omega_max"] == pytest.approx(expected_omega, rel=1e-9)
    assert record["dose"]["rule"] == "linear" and record["dose"]["span_s"] == pytest.approx(40 * DT)
    assert record["peak_temperature_max"] == pytest.approx(float(history.max()), rel=1e-12)
    assert record["omega_max"] > 1 and 0 < record["damaged_fraction"] < 0.2


def test_a_half_precision_recording_is_analysed_like_any_other(
    files: dict[str, Path], burn: torch.Tensor, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """float16 frames (a camera's compact export) run through the same features, not an internal error."""
    half = save_npz(tmp_path / "half.npz", burn.numpy().astype(np.float16), dt=DT, dx=DX)
    code, out, err = run(capsys, "features", half, "--json")
    assert (code, err) == (0, "")
    record, full = json.loads(out), json.loads(run(capsys, "features", files["celsius"], "--json")[1])
    assert (record["frames"], record["height"], record["width"]) == (41, 40, 40)
    # float16 resolves 0.03 K at 37 C: the peak within that of the float64 recording's
    assert record["peak_temperature_max"] == pytest.approx(full["peak_temperature_max"], abs=0.05)


def test_kelvin_needs_units_k(files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "features", files["kelvin"], "--json")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("anra: error: ")
    assert "--units C" in err and "--units K" in err and "310" in err
    code, out, err = run(capsys, "features", files["kelvin"], "--json", "--units", "K")
    assert (code, err) == (0, "")
    kelvin = json.loads(out)
    _, out, _ = run(capsys, "features", files["celsius"], "--json")
    celsius = json.loads(out)
    for key in ("cem43_minutes_max", "omega_max", "peak_temperature_max"):
        assert kelvin[key] == pytest.approx(celsius[key], rel=1e-6)


def test_non_finite_values_are_masked_and_reported(
    files: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "features", files["holed"], "--json")
    assert (code, err) == (0, "")
    record = json.loads(out)
    assert record["n_masked"] == 4 and record["masked_fraction"] == pytest.approx(4 / (41 * 40 * 40))
    assert "4 non-finite samples masked" in record["message"]
    assert all(v is not None for k, v in record.items() if k.endswith("_max"))
    code, out, err = run(capsys, "features", files["holed"])
    assert code == 0 and "note: 4 non-finite samples masked" in out


def test_out_saves_every_map(
    files: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "maps"
    code, out, err = run(capsys, "features", files["celsius"], "--out", target)
    assert (code, err) == (0, "")
    assert "cem43_minutes_max" in out and f"maps: {target}.npz" in out
    saved = np.load(f"{target}.npz")
    expected = TissueFeatures()(torch.from_numpy(np.load(files["celsius"])["frames"]), DT, DX)
    for name, m in expected.maps.items():
        np.testing.assert_allclose(saved[name], m.numpy(), rtol=1e-12, atol=0)
        assert str(saved[f"units_{name}"]) == expected.units[name]
    assert float(saved["dt"]) == DT and float(saved["dx"]) == DX


def test_bad_input_is_one_line(
    files: dict[str, Path], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # No pixel size: the dose maps only, the others absent with the reason (a trace needs no dx).
    code, out, err = run(capsys, "features", files["no_dx"], "--json")
    record = json.loads(out)
    assert (code, err) == (0, "") and record["dx"] is None and record["cem43_minutes_max"] > 0
    assert "diffusivity_max" not in record and "pass dx, --dx in mm" in record["absent"]["diffusivity"]
    code, out, err = run(capsys, "features", tmp_path / "missing.npz")
    assert code == 2 and "no such file" in err
    code, out, err = run(capsys, "features", files["celsius"], "--units", "F")
    assert code == 2 and "--units" in err and "invalid choice" in err


@pytest.mark.skipif(
    not (DATA / "laser_silicone").is_dir(),
    reason="../shared/data/laser_silicone is absent",
)
@pytest.mark.slow
def test_features_read_a_flir_folder_with_resampling(capsys: pytest.CaptureFixture[str]) -> None:
    folder = DATA / "laser_silicone" / "Nov19_2"
    # Non-uniform EXIF times are resampled by default (--resample is kept, and changes nothing).
    assert main(["features", str(folder), "--dx", "0.55", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["input"]["resampled"]["from_frames"] == 25
    assert main(["features", str(folder), "--dx", "0.55", "--resample", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["frames"] == 24 and record["input"]["resampled"]["from_frames"] == 25
    assert 200 < record["peak_temperature_max"] < 220  # the ~210 C peak of this run (data README)


@pytest.mark.slow
def test_a_recording_with_a_heating_and_a_cooling_reports_the_cooling_diffusivity(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The dose is the whole recording's; the global diffusivity is the source-free phase's, the same as
    ``anra estimate`` gives, and the phases are listed. The whole recording is measured once (its noise
    and artefacts: the ANRA maps', the phases' search)."""
    u0 = torch.full((40, 40), 37.0, dtype=torch.float64)
    source = MovingSource(start=(4.0, 4.0), end=(4.0, 4.0), width=0.8, power=30.0, t_off=3.0)
    clean = simulate_tissue(u0, 0.15, 0.0, dx=DX, dt=DT, n_frames=80, source=source)
    noisy = clean + 0.01 * torch.randn(
        clean.shape, generator=torch.Generator().manual_seed(3), dtype=clean.dtype
    )
    path = save_npz(tmp_path / "spot.npz", noisy.numpy(), dt=DT, dx=DX)
    measured: list[tuple[int, ...]] = []
    for module in ("anra_torch.cli.features", "anra_torch.recording.plan", "anra_torch.estimation.estimator"):
        original = importlib.import_module(module).prepare_batch

        def counted(video: torch.Tensor, *args: object, original=original, **kwargs: object) -> object:
            measured.append(tuple(video.shape))
            return original(video, *args, **kwargs)

        monkeypatch.setattr(f"{module}.prepare_batch", counted)
    code, out, _ = run(capsys, "features", path, "--json")
    monkeypatch.undo()
    assert measured.count((1, *noisy.shape)) == 1
    record = json.loads(out)
    assert code == 0 and [p["kind"] for p in record["phases"]] == ["heating", "cooling"]
    assert record["diffusivity_phase"] == "cooling"
    code, out, _ = run(capsys, "estimate", path, "--json")
    estimate = json.loads(out)
    assert estimate["phase"] == "cooling" and record["diffusivity_global"] == pytest.approx(
        estimate["diffusivity"]
    )
    assert record["diffusivity_global"] == pytest.approx(0.15, rel=0.1)  # the simulation's, without perfusion
    assert "(the cooling phase's)" in run(capsys, "features", path)[1]


# ------------------------------------------------------------------ dose features on any frame size
@pytest.mark.parametrize(
    ("shape", "celsius", "minutes", "dx"),
    [((16, 16), 43.0, 10.0, 0.5), ((3, 5), 44.0, 5.0, 0.5), ((1, 1), 42.0, 20.0, None)],
    ids=["16x16", "3x5", "1x1-no-dx"],
)
def test_features_dose_works_on_any_frame_size(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    shape: tuple[int, int],
    celsius: float,
    minutes: float,
    dx,
) -> None:
    seconds = minutes * 60.0
    frames = np.full((round(seconds) + 1, *shape), celsius)  # 1 s apart: the record spans `seconds`
    path = save_npz(tmp_path / "v.npz", frames, dt=1.0, dx=dx)
    code, out, err = run(capsys, "features", path, "--json")
    assert (code, err) == (0, "")
    record = json.loads(out)
    assert record["cem43_minutes_max"] == pytest.approx(cem43_constant(celsius, seconds), rel=1e-12)
    assert record["omega_max"] == pytest.approx(omega_constant(celsius, seconds), rel=1e-12)
    assert record["peak_temperature_max"] == pytest.approx(celsius, rel=1e-14)
    above = seconds if celsius >= 43.0 else 0.0
    assert record["time_above_43_max"] == pytest.approx(above) and record["time_above_50_max"] == 0.0
    # The ANRA maps do not fit: absent, with the reason, and so said in the message.
    assert "diffusivity_max" not in record and "loss_rate_max" not in record and record["valid"] is False
    reason = "no pixel size" if dx is None else "frames must be at least 20 x 20 px"
    assert set(record["absent"]) == {
        "heating_rate",
        "cooling_rate",
        "rtc_attention",
        "diffusivity",
        "confidence",
        "loss_rate",
        "source",
    }
    assert all(reason in why for why in record["absent"].values()) and reason in record["message"]
    code, out, err = run(capsys, "features", path, "--out", tmp_path / "maps.npz")
    assert code == 0 and "cem43_minutes_max: " in out and "diffusivity_global: n/a" in out
    saved = np.load(tmp_path / "maps.npz")
    assert saved["cem43_minutes"].shape == shape and "diffusivity" not in saved.files


# --------------------------------------------------------------- the recorded span, the constants named
def test_features_integrate_the_recorded_span_and_name_the_constants(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = save_npz(tmp_path / "hot.npz", np.full((11, 64, 64), 60.0), dt=1.0, dx=0.5)  # 11 frames: 10 s
    code, out, err = run(capsys, "features", path, "--json")
    assert (code, err) == (0, "")
    record = json.loads(out)
    assert record["omega_max"] == pytest.approx(omega_constant(60.0, 10.0), rel=1e-12)  # 10.69
    assert record["cem43_minutes_max"] == pytest.approx(cem43_constant(60.0, 10.0), rel=1e-12)
    assert record["time_above_60_max"] == pytest.approx(10.0)
    dose = record["dose"]
    assert (dose["rule"], dose["span_s"]) == ("linear", 10.0)
    assert (dose["arrhenius"]["A_per_s"], dose["arrhenius"]["Ea_J_per_mol"]) == (A_SKIN, EA_SKIN)
    assert dose["arrhenius"]["R_gas_J_per_mol_K"] == R_GAS
    assert (dose["cem43"]["R_at_or_above_43C"], dose["cem43"]["R_below_43C"]) == (0.5, 0.25)
    assert dose["thresholds_C"] == [43.0, 50.0, 60.0] and dose["smoothing_px"] == 1.0
    # Each frame held for dt, as an option: 11 s.
    code, out, err = run(capsys, "features", path, "--json", "--rule", "hold")
    held = json.loads(out)
    assert held["omega_max"] == pytest.approx(omega_constant(60.0, 11.0), rel=1e-12)  # 11.76
    assert (held["dose"]["rule"], held["dose"]["span_s"]) == ("hold", 11.0)
    # One frame has no span: the message says what to do.
    one = save_npz(tmp_path / "one.npz", np.full((1, 64, 64), 60.0), dt=1.0, dx=0.5)
    code, out, err = run(capsys, "features", one, "--json")
    assert code == 2 and err.count("\n") == 1 and "needs at least 2, got 1" in err and "--rule hold" in err
    code, out, err = run(capsys, "features", one, "--json", "--rule", "hold")
    assert code == 0 and json.loads(out)["omega_max"] == pytest.approx(omega_constant(60.0, 1.0), rel=1e-12)


# ------------------------------------------------------------------------------------- damage in depth
@pytest.fixture(scope="module")
def depth_burn(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A 0.4 mm beam for 3 s on skin-like tissue (independent 3-D simulator), 3 s of cooling, 0.2 K noise."""
    return beam_recording(tmp_path_factory.mktemp("depth"))


@pytest.mark.slow
def test_depth_maps_json_and_npz(
    depth_burn: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "maps.npz"
    code, out, err = run(capsys, "features", depth_burn["video"], "--depth", "--out", target, "--json")
    assert (code, err) == (0, "")
    record = json.loads(out)
    depth = record["depth"]
    assert depth["absorption"].startswith("at the surface") and depth["geometry"] == "half-space"
    assert depth["diffusivity_mm2_s"] == pytest.approx(0.13, rel=0.1)
    assert depth["diffusivity_std_mm2_s"] > 0 and depth["loss_rate_per_s"] >= 0
    assert "cooling after the switch-off forecast" in depth["parameters_from"]
    assert depth["maps"] and not depth["volumetric"]
    assert record["units"]["damage_depth_mm_max"] == "mm"
    maps = np.load(target)
    h, w = depth_burn["frames"].shape[1:]
    for name in ("damage_depth_mm", "damage_depth_std_mm", "cem43_depth_mm", "cem43_depth_std_mm"):
        assert maps[name].shape == (h, w) and np.isfinite(maps[name]).all()
        assert str(maps[f"units_{name}"]) == "mm"
    z = maps["depth_mm"]
    assert z[0] == 0.0 and maps["peak_temperature_depth"].shape == maps["omega_depth"].shape == (z.size, h, w)
    profiles = {"depth_mm": "mm", "peak_temperature_depth": "C", "peak_temperature_depth_std": "K"}
    profiles |= {"omega_depth": "1", "cem43_depth_minutes": "min"}
    assert {name: str(maps[f"units_{name}"]) for name in profiles} == profiles
    # The same numbers as the library call, and close to the independent simulator's truth.
    expected = depth_features(depth_burn["frames"], depth_burn["result"].dt, depth_burn["result"].dx)
    np.testing.assert_allclose(
        maps["damage_depth_mm"], expected.maps["damage_depth_mm"][0].numpy(), rtol=1e-12
    )
    truth = depth_burn["result"].damage_depth
    assert record["damage_depth_mm_max"] == pytest.approx(truth.max(), abs=0.03)
    assert 0.1 < truth.max() < 0.4


def test_depth_without_pixel_size_says_why(depth_burn: dict, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "features", depth_burn["no_dx"], "--depth", "--json")
    assert code == 0
    record = json.loads(out)
    assert record["depth"] is None
    assert record["absent"]["damage_depth_mm"] == "no pixel size (pass dx, --dx in mm)"


def test_report_needs_depth(depth_burn: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "features", depth_burn["video"], "--report", tmp_path)
    assert code == 2
    assert "--report draws the depth maps: pass --depth with it" in err


def test_thickness_is_stated(depth_burn: dict, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "features", depth_burn["video"], "--depth", "--thickness", "8", "--json")
    assert (code, err) == (0, "")
    assert json.loads(out)["depth"]["geometry"].startswith("layer of 8 mm")


def test_depth_options_are_checked_at_their_argument(
    depth_burn: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    video = depth_burn["video"]
    for value in ("0", "-1", "nan", "inf", "thick", "1e300"):
        assert_one_line_error(
            run(capsys, "features", video, "--depth", f"--thickness={value}"),
            rf"argument --thickness: must be a positive number in mm up to 1000, got '{value}'",
        )
    assert_one_line_error(
        run(capsys, "features", video, "--thickness", "2"), r"--thickness .* pass --depth with it$"
    )
    afile = tmp_path / "afile"
    afile.write_text("notes")
    err = assert_one_line_error(
        run(capsys, "features", video, "--depth", "--report", afile),
        r"--report .*afile must be a folder \(DIR\), got an existing file",
    )
    assert "Errno" not in err and afile.read_text() == "notes"
    thin = save_npz(tmp_path / "thin.npz", depth_burn["frames"].numpy()[:, 2:26:2, 2:26:2], dt=0.1, dx=0.4)
    assert_one_line_error(
        run(capsys, "features", thin, "--depth", "--thickness", "0.001"),
        r"thin\.npz: --thickness must be deeper than the deepest depth \(.* mm\), got 0\.001$",
    )
    before = Path(video).read_bytes()
    for out in (video, str(video)[: -len(".npz")]):
        assert_one_line_error(
            run(capsys, "features", video, "--out", out), r"--out .*burn\.npz is the input .*burn\.npz"
        )
    assert Path(video).read_bytes() == before


THICKNESS = ("2", "0.05", "0", "-1", "nan", "inf", "-inf", "1e300", "1001", "1e-300", "abc", "")
"""--thickness values the depth fuzz draws from."""


@pytest.mark.slow
def test_fuzzed_depth_options_end_cleanly(depth_burn: dict, tmp_path: Path) -> None:
    """``features --depth`` with drawn --thickness, --report, --out, --dx and --rule on 12 x 12 px views of
    the beam (one with depth maps, one flagged as volumetric, one without a pixel size, a constant one):
    exit 0 or 2, one line on error naming the argument or the file, strict JSON, no infinity in a written
    map, no temporary file left, the input untouched."""
    rng = np.random.default_rng(45)
    frames, dt = depth_burn["frames"].numpy(), depth_burn["result"].dt
    coarse = frames[:, 2:26:2, 2:26:2]  # 12 x 12 px of 0.4 mm: depth maps made (1.7 s)
    videos = {
        "beam": save_npz(tmp_path / "beam.npz", coarse, dt=dt, dx=0.4),
        "centre": save_npz(tmp_path / "centre.npz", frames[:, 8:20, 8:20], dt=dt, dx=0.2),  # flagged
        "no_dx": save_npz(tmp_path / "no_dx.npz", coarse, dt=dt, dx=None),
        "flat": save_npz(tmp_path / "flat.npz", np.full_like(coarse, 37.0), dt=dt, dx=0.4),
    }
    (tmp_path / "afile").write_text("notes")
    outputs = ["maps.npz", "maps", "afile", "INPUT", ".", "/dev/null", "sub/deeper/maps.npz"]
    codes = {0: 0, 2: 0}
    for case in range(24):
        name = str(rng.choice(list(videos), p=[0.25, 0.3, 0.25, 0.2]))
        argv = ["features", str(videos[name]), "--json"]
        if rng.random() < 0.85:
            argv.append("--depth")
        if rng.random() < 0.6:
            argv.append(f"--thickness={rng.choice(THICKNESS)}")
        if rng.random() < 0.2:  # a report draws figures (about 2 s): a few
            argv += ["--report", str(tmp_path / str(rng.choice(["rep", "afile", "INPUT", "rep/inner"])))]
        if rng.random() < 0.3:
            argv += ["--out", str(tmp_path / str(rng.choice(outputs)))]
        argv = [a.replace(str(tmp_path / "INPUT"), str(videos[name])) for a in argv]
        if rng.random() < 0.2:
            argv.append(f"--dx={rng.choice(['0.4', '0', 'nan', '-1', '1e-9'])}")
        if rng.random() < 0.2:
            argv += ["--rule", str(rng.choice(["hold", "linear"]))]
        before = videos[name].read_bytes()
        code, out, err, caught = run_isolated(argv)
        label = f"case {case}: {' '.join(argv)}"
        assert_clean(label, code, out, err, caught)
        codes[code] += 1
        assert videos[name].read_bytes() == before, label
        assert not list(tmp_path.rglob(".*.tmp*")), label
        if code == 2:
            assert any(word in err for word in ("--", ".npz", "afile")), f"{label}: names nothing: {err}"
            continue
        record = json.loads(out)
        if record["out"]:
            with np.load(record["out"]) as maps:
                for key in maps.files:
                    values = maps[key]
                    if values.dtype.kind == "f":
                        assert not np.isinf(values).any(), f"{label}: {key} holds infinities"
    print(f"fuzz features --depth: {sum(codes.values())} runs, exit 0: {codes[0]}, exit 2: {codes[2]}")
    assert codes[0] >= 5 and codes[2] >= 5, codes
