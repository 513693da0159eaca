"""The defect map against exact plates: every pixel its own insulated plate (the cosine series, 400 terms),
the layer above a defect a thinner plate; an anisotropic lateral spread of a non-uniform flash (an exact
Gaussian times the depth factor); a recording that ends before the back wall shows."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.flash import DefectMap, defect_map
from anra_torch.simulation import Defect, PlateSetup, ReferencePlate, reference_plate_video

TAU = 4.0  # s: the plate's L^2 / a_z
DX = 0.3  # mm


def _plate(
    *,
    size: int = 40,
    frames: int = 240,
    dt: float = 0.025,
    defects: tuple[tuple[float, float, float, float], ...] = (),
    lateral: tuple[float, float] | None = None,
    seed: int = 0,
    spot: tuple[float, float] = (0.35, 0.6),
) -> tuple[torch.Tensor, float, np.ndarray, np.ndarray]:
    """Frames (first at ``dt`` after the flash, T_ref 20, 20 mK noise), the truth's defect mask and
    depth fractions. ``defects``: discs ``(x, y, radius, d / L)`` in mm; ``lateral``: ``(a_x, a_y)`` of a
    flash 0.7 + a Gaussian spot of 4 mm at ``spot`` (fractions of the frame; without ``lateral`` the flash
    is uniform and nothing flows sideways)."""
    t = dt * np.arange(1, frames + 1)
    yy, xx = (np.mgrid[0:size, 0:size] + 0.5) * DX
    fraction = np.full((size, size), np.nan)
    for x, y, radius, f in defects:
        fraction[(xx - x) ** 2 + (yy - y) ** 2 <= radius**2] = f
    taus = np.where(np.isnan(fraction), TAU, np.nan_to_num(fraction) ** 2 * TAU)
    # The series once per distinct plate (the sound one and one per defect depth), given to its pixels.
    plates, which = np.unique(taus, return_inverse=True)
    n = np.arange(1, 401)
    s = t[:, None, None] / plates[None, :, None]
    depth = ((1 + 2 * np.exp(-(n**2) * math.pi**2 * s).sum(-1)) / np.sqrt(plates))[
        :, which.reshape(taus.shape)
    ]
    spread = 1.0
    if lateral is not None:
        vx, vy = (16 + 2 * a * t[:, None, None] for a in lateral)
        r2 = (xx - spot[0] * size * DX) ** 2 / vx + (yy - spot[1] * size * DX) ** 2 / vy
        spread = 0.7 + 0.5 * 16 / np.sqrt(vx * vy) * np.exp(-r2 / 2)
    noise = 0.02 * np.random.default_rng(seed).standard_normal(depth.shape)
    return torch.from_numpy(20 + 3 * spread * depth + noise), dt, ~np.isnan(fraction), fraction


def _independent(
    size: int, n_frames: int, thickness: float, duration: float, seed: int, defect: Defect
) -> tuple[ReferencePlate, DefectMap]:
    """A plate of the independent finite-volume simulator (nothing shared with the map), ``size`` x ``size``
    px at 0.4 mm with one defect, and its defect map."""
    plate = reference_plate_video(
        PlateSetup(
            shape=(size, size),
            dx=0.4,
            n_frames=n_frames,
            thickness=thickness,
            duration=duration,
            seed=seed,
            defects=(defect,),
        )
    )
    return plate, defect_map(plate.frames, plate.dt, plate.dx)


@pytest.fixture(scope="module")
def defective() -> tuple[object, np.ndarray, np.ndarray]:
    """An ellipse-free plate with a disc at d / L 0.5 inside the frame and one at 0.3 running out of it."""
    frames, dt, mask, fraction = _plate(defects=((7.0, 5.0, 2.5, 0.5), (-0.5, 8.0, 3.0, 0.3)))
    return defect_map(frames, dt, DX), mask, fraction


@pytest.mark.slow
def test_plate_time_defects_outlines_and_depths_on_an_exact_plate(defective) -> None:
    found, mask, fraction = defective
    assert abs(found.plate_time / TAU - 1) < 0.03
    assert 0 < found.plate_time_se < 0.05 * TAU
    assert found.back_wall_reached
    assert abs(found.t_ref - 20) < 0.03 and abs(found.first_time / 0.025 - 1) < 0.3
    assert found.lateral == (0.0, 0.0, 0.0)  # nothing flows sideways: no lateral fit is physical
    got = found.defect_mask.numpy()
    assert (got & mask).sum() / (got | mask).sum() > 0.8
    inside = sorted(found.defects, key=lambda d: d.x)
    assert len(inside) == 2
    edge, middle = inside
    assert edge.touches_edge and not middle.touches_edge
    assert abs(middle.x - 7.0) < 0.3 and abs(middle.y - 5.0) < 0.3
    assert abs(middle.area / (math.pi * 2.5**2) - 1) < 0.2
    assert abs(middle.depth_fraction - 0.5) < 0.05 and abs(edge.depth_fraction - 0.3) < 0.05
    depth = found.depth_fraction.numpy()
    assert np.isnan(depth[~got]).all()
    assert np.nanmax(np.abs(depth[mask & got] - fraction[mask & got])) < 0.08


@pytest.mark.slow
def test_the_score_ranks_every_defect_pixel_above_the_sound_ones(defective) -> None:
    found, mask, _ = defective
    score = found.defect_score.numpy()
    # ROC AUC by ranks (Mann-Whitney)
    ranks = score.ravel().argsort().argsort() + 1.0
    positives = mask.ravel()
    auc = (ranks[positives].sum() - positives.sum() * (positives.sum() + 1) / 2) / (
        positives.sum() * (~positives).sum()
    )
    assert auc > 0.99
    assert score[found.defect_mask.numpy()].min() >= 0.5 - 1e-9  # the outline: half the peak
    assert score.max() <= 1.0 + 1e-9 or found.defects


@pytest.mark.slow
def test_a_non_uniform_flash_spreading_anisotropically_is_no_defect() -> None:
    frames, dt, _, _ = _plate(lateral=(7.3, 1.1), seed=1)
    found = defect_map(frames, dt, DX)
    a_x, a_y, a_xy = found.lateral
    assert abs(a_x / 7.3 - 1) < 0.1 and abs(a_y / 1.1 - 1) < 0.25 and abs(a_xy) < 0.5  # a_y: 1.29 at seed 1
    assert found.defects == () and not found.defect_mask.any()
    assert abs(found.plate_time / TAU - 1) < 0.03


@pytest.mark.slow
def test_a_recording_that_ends_before_the_back_wall_says_so() -> None:
    frames, dt, _, _ = _plate(size=24, frames=200, dt=0.005, seed=2)  # ends at TAU / 4
    found = defect_map(frames, dt, DX)
    assert not found.back_wall_reached
    assert found.defects == ()
    assert abs(found.t_ref - 20) < 0.03
    assert found.plate_time > 0.8 * TAU


def test_tensors_are_made_where_the_frames_live() -> None:
    frames, dt, _, _ = _plate(size=16, frames=60, dt=0.05, seed=3)
    torch.set_default_device("meta")  # any tensor made without the input's device lands here and fails
    try:
        found = defect_map(frames.float(), dt, DX)
    finally:
        torch.set_default_device(None)
    assert found.depth_time.device.type == "cpu" and found.depth_time.dtype == torch.float64


def test_errors() -> None:
    frames = torch.ones(20, 10, 10) + torch.linspace(1, 0, 20)[:, None, None]
    with pytest.raises(ValueError, match=r"frames must be one recording \(T, H, W\)"):
        defect_map(frames[None].repeat(2, 1, 1, 1), 0.1, DX)
    with pytest.raises(ValueError, match="at least 8 x 8 px"):
        defect_map(frames[:, :6, :6], 0.1, DX)
    bad = frames.clone()
    bad[3, 2, 2] = math.nan
    with pytest.raises(ValueError, match="frames must be finite"):
        defect_map(bad, 0.1, DX)
    with pytest.raises(ValueError, match="dt"):
        defect_map(frames, -0.1, DX)


@pytest.mark.slow
def test_a_recording_long_past_the_back_wall_keeps_t_ref() -> None:
    frames, dt, _, _ = _plate(size=32, frames=240, dt=0.05, lateral=(7.3, 1.1), seed=5)  # to 3 TAU
    found = defect_map(frames, dt, DX)  # its late frames, only lateral flow, sent T_ref to -58 C
    assert abs(found.t_ref - 20) < 0.05 and abs(found.plate_time / TAU - 1) < 0.1
    assert found.defects == () and found.back_wall_reached


@pytest.mark.slow
def test_the_outline_reaches_the_edge_where_single_pixels_are_not_significant() -> None:
    # a deep disc (contrast ln 2) at 55 mK: its edge pixels' own fits fall under 3 sd, its contrast does not
    frames, dt, mask, _ = _plate(size=32, defects=((5.0, 5.0, 2.5, 0.7),), seed=3)
    frames = frames + 0.05 * torch.from_numpy(np.random.default_rng(5).standard_normal(frames.shape))
    found = defect_map(frames, dt, DX)
    got = found.defect_mask.numpy()
    assert (got & mask).sum() / (got | mask).sum() > 0.9  # 0.84 when the outline stopped at z = 3
    assert len(found.defects) == 1 and abs(found.defects[0].depth_fraction - 0.7) < 0.05


@pytest.mark.parametrize("seed", [3, 4])
def test_a_noisy_defect_reads_its_depth_from_its_averaged_contrast(seed: int) -> None:
    # d / L 0.6 at 0.3 K (10 % of the flash's rise): the 95 % quantile of the pixels' own contrasts read
    # the disc shallower (0.52 with seed 3); averaged over the value's smoothing, 0.55 and 0.57
    frames, dt, mask, _ = _plate(size=32, defects=((5.0, 5.0, 2.5, 0.6),), seed=seed)
    noise = np.random.default_rng(seed + 10).standard_normal(frames.shape)
    found = defect_map(frames + 0.3 * torch.from_numpy(noise), dt, DX)
    got = found.defect_mask.numpy()
    assert (got & mask).sum() / (got | mask).sum() > 0.85
    assert len(found.defects) == 1 and abs(found.defects[0].depth_fraction - 0.6) < 0.06


@pytest.mark.slow
def test_a_defect_too_faint_to_outline_still_ranks_above_the_sound_plate() -> None:
    # d / L 0.93 (contrast 0.15, under the 0.2 a defect pixel needs) at 0.4 K: no defect is outlined
    frames, dt, mask, _ = _plate(size=32, defects=((4.8, 4.8, 2.5, 0.93),), seed=4)
    frames = frames + 0.4 * torch.from_numpy(np.random.default_rng(6).standard_normal(frames.shape))
    found = defect_map(frames, dt, DX)
    assert found.defects == ()
    score = found.defect_score.numpy().ravel()
    ranks = score.argsort().argsort() + 1.0
    positives = mask.ravel()
    auc = (ranks[positives].sum() - positives.sum() * (positives.sum() + 1) / 2) / (
        positives.sum() * (~positives).sum()
    )
    assert auc > 0.95  # 0.72 when each pixel's contrast was the score on its own


@pytest.mark.slow
def test_a_shallow_disc_on_the_independent_plate_is_one_defect_at_its_depth() -> None:
    # finite volumes (nothing shared with the map): its contrast spreads sideways past the disc, in two
    # significant parts; both inside one outline, one defect, its depth read at the peak
    _, found = _independent(
        32, 200, 2.0, 8.0, 3, Defect("ellipse", centre=(6.4, 6.4), size=(2.5, 2.5), depth=0.5)
    )
    assert len(found.defects) == 1  # 2 when each significant part was a defect
    (disc,) = found.defects
    assert abs(disc.x - 6.4) < 0.5 and abs(disc.y - 6.4) < 0.5
    assert abs(disc.depth_fraction - 0.25) < 0.05


@pytest.mark.slow
def test_a_large_defect_in_a_thick_plate_leaves_the_lateral_fit_physical() -> None:
    # 4.5 mm, a 9 x 7 mm ellipse at d / L 0.6 in the middle: the late blocks of the lateral fit turned a_y
    # negative; the map then took nothing off and read the flash's spreading as a defect at the side
    plate, found = _independent(
        48, 300, 4.5, 50.0, 26, Defect("ellipse", centre=(9.5, 10.5), size=(4.5, 3.5), depth=2.7)
    )
    assert abs(found.lateral[0] / 7.3 - 1) < 0.15 and found.lateral[1] > 0  # zeros before
    assert abs(found.plate_time / plate.plate_time - 1) < 0.1  # +20 % before
    for defect in found.defects:  # one at the side before
        assert plate.defect_mask[int(defect.y / plate.dx), int(defect.x / plate.dx)]


@pytest.mark.slow
def test_a_bright_spot_by_the_corner_is_no_defect_before_the_back_wall() -> None:
    # the one-sided local quadratic's curvature is biased beside the spot, the edge's scatter was measured on
    # the pixels that looked sound, and the refits on the few sound pixels of a noisy map lost a_x, a_y
    frames, dt, _, _ = _plate(lateral=(7.3, 1.1), frames=200, dt=0.005, seed=3, spot=(0.1, 0.1))  # to TAU / 4
    found = defect_map(frames, dt, DX)
    assert found.defects == () and not found.defect_mask.any()  # 3.3 % of the frame before
    assert abs(found.lateral[0] / 7.3 - 1) < 0.1


@pytest.mark.slow
def test_a_defect_covering_nearly_half_the_frame_is_the_defect_not_the_plate() -> None:
    # 2 mm, a 12 x 9 mm rectangle at d / L 0.5 in a 16 mm frame: the hot layer's sideways cooling, not yet
    # taken off, sent T_ref to -138 C (the model floor's variance grows with T - T_ref), and the median
    # took the defect's tau for the plate's (plate time -92 %, nothing outlined)
    plate, found = _independent(
        40, 200, 2.0, 9.0, 8, Defect("rectangle", centre=(8.0, 8.0), size=(6.0, 4.6), depth=1.0)
    )
    # +23 %: the thin sound ring beside the hot layer is warmed sideways by more than the fit takes off
    assert abs(found.plate_time / plate.plate_time - 1) < 0.3
    mask = found.defect_mask.numpy()
    assert (mask & plate.defect_mask).sum() / (mask | plate.defect_mask).sum() > 0.6
    assert len(found.defects) == 1 and abs(found.defects[0].depth_fraction - 0.5) < 0.1


@pytest.mark.slow
def test_a_small_deep_disc_reads_its_depth_with_the_spread_of_its_heat_taken_off() -> None:
    # 4 mm, a disc of 3 mm radius at d / L 0.5 (finite volumes, nothing shared with the map): the heat it
    # reflects spreads sideways on its way back (lateral 7.3 mm^2/s), and its peak read 0.64
    _, found = _independent(
        48, 300, 4.0, 40.0, 29, Defect("ellipse", centre=(9.0, 10.0), size=(3.0, 3.0), depth=2.0)
    )
    assert len(found.defects) == 1 and abs(found.defects[0].depth_fraction - 0.5) < 0.05
