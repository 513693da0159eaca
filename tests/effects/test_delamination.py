"""The delamination over a subsurface defect: its term, and the diagnosis on independent 3-D flash plates
(lateral heat flow exact per Fourier mode, finite volumes through the thickness: nothing shared with the
balance) with and without a defect."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.effects import Effect, simulate_effects
from anra_torch.effects.base import Grid
from anra_torch.effects.depth_conduction import depth_rate
from anra_torch.selection import diagnose_terms
from anra_torch.simulation.plate import FlashPlate, flash_plate_video, plate_factor

F64 = torch.float64


PLATE = {"t_heat": -0.1, "plate_time": 8.0, "T_ref": 20.0}


DEFECT = {"x": 4.0, "y": 3.0, "radius": 1.5, "strength": 1.0, "depth_time": 0.5, **PLATE, "reflected": 1.0}


@pytest.fixture(scope="module")
def defect_plate(disk_cache) -> tuple[torch.Tensor, float, float]:
    """A 3 mm plate with a defect disc (x, y, radius, depth in mm: 5, 4.5, 1.5, 0.6), simulated once per
    run for the diagnosis and the forecast tests (read only)."""

    def make() -> tuple[torch.Tensor, float, float]:
        frames, dt, dx = flash_plate_video(
            size=48, n_frames=120, plate=FlashPlate(defect=(5.0, 4.5, 1.5, 0.6)), seed=0, pad=48
        )
        return frames.to(F64), dt, dx

    return disk_cache("delamination-plate-48-defect-5-4.5-1.5-0.6", make)


def test_term_is_the_thin_layers_rate_in_the_disc() -> None:
    grid = Grid((16, 20), 0.5)
    u = torch.full((16, 20), 21.0, dtype=F64)
    term = Effect("delamination", DEFECT).term(u, 0.4, grid)
    elapsed = torch.tensor(0.5, dtype=F64)
    rate = float(depth_rate(elapsed, 8.0) - depth_rate(elapsed, 0.5))
    disc = 0.5 * (1 + math.tanh((1.5 - math.hypot(0.25, 0.25)) / 0.5))  # pixel centre (4.25, 3.25) mm
    assert float(term[6, 8]) == pytest.approx(rate * disc, rel=1e-9)
    assert abs(float(term[0, 19])) < 1e-8 * abs(rate)  # far outside


def test_plate_with_a_defect_cools_at_the_thin_layers_rate() -> None:
    """With depth_conduction, the delamination's weight ``w`` (the disc, 1 inside) blends the two plates'
    exact depth factors: ``thick^(1 - w) thin^w`` (the rates add linearly)."""
    u0 = torch.full((12, 12), 21.0, dtype=F64)
    plate = Effect("depth_conduction", {"strength": 1.0, "t_heat": -0.1, "depth_time": 8.0, "T_ref": 20.0})
    defect = Effect("delamination", {**DEFECT, "x": 3.0, "y": 3.0, "radius": 2.5})
    video = simulate_effects(u0, a=0.0, dx=0.5, dt=0.05, n_frames=31, effects=[plate, defect], substeps=8)
    t = np.arange(31) * 0.05 + 0.1
    thin = plate_factor(t, 0.5) / plate_factor(np.array(0.1), 0.5)
    thick = plate_factor(t, 8.0) / plate_factor(np.array(0.1), 8.0)
    w = 0.5 * (1 + math.tanh((2.5 - math.hypot(0.25, 0.25)) / 0.5))  # pixel (6, 6) at (3.25, 3.25) mm
    np.testing.assert_allclose(video[:, 6, 6].numpy() - 20.0, thick ** (1 - w) * thin**w, rtol=1e-6)
    assert w > 0.999  # that pixel is inside: it follows the thin layer
    w = 0.5 * (1 + math.tanh((2.5 - math.hypot(2.75, 2.75)) / 0.5))  # pixel (0, 11): 3.9 mm from the centre
    np.testing.assert_allclose(video[:, 0, 11].numpy() - 20.0, thick ** (1 - w) * thin**w, rtol=1e-6)
    assert w < 0.004  # outside: it follows the plate


@pytest.mark.slow
def test_diagnosis_finds_the_defect_on_an_independent_3d_plate(defect_plate) -> None:
    d = diagnose_terms(*defect_plate)
    assert d.names[0] == "depth_conduction" and "delamination" in d.names, d.names
    assert not {"source", "heterogeneity"} & set(d.names), d.names
    found = next(e["params"] for e in d.effects if e["name"] == "delamination")
    assert math.hypot(found["x"] - 5.0, found["y"] - 4.5) < 0.3  # mm (1.5 px)
    assert found["radius"] == pytest.approx(1.5, rel=0.2)
    assert found["depth_fraction"] == pytest.approx(0.6 / 3.0, abs=0.08)


@pytest.mark.slow
def test_no_localised_effect_on_an_intact_3d_plate() -> None:
    frames, dt, dx = flash_plate_video(size=48, n_frames=120, seed=0, pad=48)
    d = diagnose_terms(frames.to(F64), dt, dx)
    assert d.names[0] == "depth_conduction"
    assert "anisotropy" in d.names
    assert not {"source", "heterogeneity", "delamination", "periodic_source"} & set(d.names), d.names
    lateral = next(e["params"] for e in d.effects if e["name"] == "anisotropy")
    assert lateral["a_x"] == pytest.approx(7.3, rel=0.2) and lateral["a_y"] == pytest.approx(1.1, rel=0.2)


@pytest.mark.slow
def test_the_defect_and_the_anisotropy_forecast_better_within_measured_edges(defect_plate) -> None:
    """Heat leaves a flash plate's frame within seconds: forecasts bounded by the measured edge ring give
    the delamination and the anisotropy their own held-out gains (zero-flux edges gave -0.06 and -0.04,
    measured 0.73 and 0.82 within the measured edges)."""
    from anra_torch.forecast import assess_gain

    result = assess_gain(*defect_plate)
    own = dict(zip(result.diagnosis.names, result.effect_gains, strict=True))
    assert result.diagnosis.names[0] == "depth_conduction" and result.gain > 0.5, own
    assert own["delamination"] > 0.3 and own["anisotropy"] > 0.3, own


@pytest.mark.slow
def test_the_delamination_is_looked_for_in_the_regions_a_defect_map_gives(defect_plate) -> None:
    """Given candidate regions (``hints``: a flash defect map's defects, centroid, equal-area radius and
    depth fraction, in mm), the delamination's fit starts there and its centre must stay in one: found at
    the defect from a map region about it; not tried when the map shows no defect; never named away from a
    region the map gives elsewhere (a residual peak no longer decides where the defect is)."""
    effects = ["depth_conduction", "anisotropy", "delamination"]
    region = {"x": 5.3, "y": 4.2, "radius": 1.3, "depth_fraction": 0.3}  # a map's outline, off by 2 px
    d = diagnose_terms(*defect_plate, effects=effects, hints={"delamination": [region]})
    assert "delamination" in d.names and d.hints == {"delamination": (region,)}, d.names
    found = next(e["params"] for e in d.effects if e["name"] == "delamination")
    assert math.hypot(found["x"] - 5.0, found["y"] - 4.5) < 0.3  # mm (1.5 px)
    assert found["depth_fraction"] == pytest.approx(0.6 / 3.0, abs=0.08)
    intact = diagnose_terms(*defect_plate, effects=effects, hints={"delamination": []})
    assert "delamination" not in intact.names and "delamination" not in intact.scores, intact.names
    elsewhere = {"x": 2.0, "y": 7.5, "radius": 1.0, "depth_fraction": 0.5}
    d = diagnose_terms(*defect_plate, effects=effects, hints={"delamination": [elsewhere]})
    for e in d.effects:
        if e["name"] == "delamination":
            assert math.hypot(e["params"]["x"] - 2.0, e["params"]["y"] - 7.5) <= 1.0, e["params"]


def test_a_held_discs_layer_time_is_its_depth_fraction_of_the_maps_plate_time() -> None:
    """A region from a flash defect map carries the map's plate time: the held disc's layer time is
    ``(d / L)^2`` of it, not of the depth term's plate time, which on an anisotropic plate also takes up
    what the isotropic balance misses (480 s for 8.9 s put the layer at 120 s, not 2.2 s); a region
    without one keeps the depth term's."""
    from types import SimpleNamespace

    from anra_torch.effects.delamination import _held, _regions, _unpack

    region = {"x": 4.0, "y": 4.0, "radius": 1.2, "depth_fraction": 0.5}
    phi = torch.zeros(3, dtype=torch.float64)
    for hint, layer in ((region, 0.25 * 480.0), ({**region, "plate_time": 8.9}, 0.25 * 8.9)):
        system = SimpleNamespace(hints={"delamination": (hint,)}, dx=0.4)
        theta = _held(_regions(system, 480.0)[0], phi)  # type: ignore[arg-type]
        assert float(_unpack(theta, 480.0)[3]) == pytest.approx(layer, rel=1e-6)


def test_the_reflected_share_is_the_disc_averaged_by_the_spreads_gaussian() -> None:
    """``reflected_share``: the disc (radius R) averaged by the Gaussian of variance ``a t`` per axis about
    its centre at ``t = d^2 / a_z``, against a direct sum over a fine grid; 1 without lateral conduction."""
    from anra_torch.effects.delamination import reflected_share

    step = 0.01
    for radius, depth_time, lateral in ((2.6, 6.3, 2.83), (5.0, 2.0, 1.0), (1.0, 10.0, 7.3)):
        xs = np.arange(-radius, radius, step) + step / 2
        x, y = np.meshgrid(xs, xs)
        variance = lateral * depth_time
        weights = np.exp(-(x**2 + y**2) / (2 * variance)) / (2 * math.pi * variance)
        direct = weights[x**2 + y**2 <= radius**2].sum() * step**2
        assert reflected_share(radius, depth_time, lateral) == pytest.approx(direct, rel=2e-3)
    assert reflected_share(2.6, 6.3, 2.83) == pytest.approx(0.17, abs=0.01)  # the small deep disc
    assert reflected_share(2.6, 6.3, 0.0) == 1.0


def test_the_strength_is_the_defects_and_the_term_keeps_the_reflected_share() -> None:
    """The term is ``strength reflected`` times the full layer's: a fitted coefficient ``c`` reads strength
    ``c / reflected`` (a small deep defect that stops all the heat reads 1, not its share)."""
    from types import SimpleNamespace

    grid = Grid((16, 20), 0.5)
    u = torch.full((16, 20), 21.0, dtype=F64)
    full = Effect("delamination", DEFECT).term(u, 0.4, grid)
    kept = Effect("delamination", {**DEFECT, "reflected": 0.25}).term(u, 0.4, grid)
    torch.testing.assert_close(kept, 0.25 * full, rtol=1e-12, atol=0.0)
    from anra_torch.effects import EFFECTS

    context = SimpleNamespace(shape={"delamination": {**DEFECT, "reflected": 0.25}})
    params = EFFECTS["delamination"].from_coefficients({"Y": 0.2}, context)
    assert params["strength"] == pytest.approx(0.8)
    with pytest.raises(ValueError, match="reflected"):
        Effect("delamination", {**DEFECT, "reflected": 0.0})


def test_a_held_delaminations_share_is_measured_over_its_disc() -> None:
    """Held at a defect map's region, the delamination's share of dT/dt is measured over its disc:
    ``footprint`` is the disc's mean square over the balance's points (its area share, the edge 1 px
    wide); without regions every point counts (1)."""
    from types import SimpleNamespace

    from anra_torch.effects import EFFECTS

    footprint = EFFECTS["delamination"].footprint
    assert footprint is not None
    frames = torch.zeros(5, 60, 60, dtype=F64)
    system = SimpleNamespace(shape=(5, 60, 60), frames=frames, dx=0.5, margin=10, hints={"delamination": ()})
    disc = {"x": 15.0, "y": 15.0, "radius": 4.0}  # 8 px radius in the 40 x 40 px interior
    assert footprint(disc, system) == 1.0  # type: ignore[arg-type]
    system.hints = {"delamination": ({"x": 15.0, "y": 15.0, "radius": 4.0},)}
    share = footprint(disc, system)  # type: ignore[arg-type]
    from scipy.integrate import quad

    def ring(r: float) -> float:  # the squared disc with its tanh edge 1 px (0.5 mm) wide, radially
        return 2 * math.pi * r * (0.5 * (1 + math.tanh((4.0 - r) / 0.5))) ** 2

    assert share == pytest.approx(quad(ring, 0.0, 8.0)[0] / 20.0**2, rel=0.01)  # over the 20 mm interior
    assert share < math.pi * 4.0**2 / 20.0**2  # below the disc's area share: its edge squared


def test_the_bounds_hold_the_defects_strength_from_below_and_the_term_from_above() -> None:
    """A strength of at least 0.2 (after the spread), a term ``strength reflected`` of at most 5: a small deep
    disc whose term is 0.17 of the full layer's, with a reflected share 0.19, is a defect (0.89); a term
    0.29 of the layer's with a share 0.032 (a deep defect outlined over its core) is within bounds at
    strength 9; with ``reflected`` 1 the bounds are the term's, as before."""
    from anra_torch.effects import EFFECTS

    valid = EFFECTS["delamination"].valid
    p = {**DEFECT, "depth_time": 0.5}
    assert valid({**p, "strength": 0.17 / 0.19, "reflected": 0.19})
    assert valid({**p, "strength": 0.29 / 0.032, "reflected": 0.032})
    assert not valid({**p, "strength": 0.17, "reflected": 1.0})
    assert not valid({**p, "strength": 5.5, "reflected": 1.0})
    assert not valid({**p, "strength": 0.03 / 0.19, "reflected": 0.19})  # a defect of strength 0.16
