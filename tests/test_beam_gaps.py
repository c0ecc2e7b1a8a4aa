"""How far apart a rig's beams pass at a point (evaluate.beam_gaps_m), and the plant height
read between the highest beam that hits the top and the next, which passes over it
(traits.robust_height's ``beam_gaps_m``; issue 13: the ideal 3-leaf rosette's top, a leaf's
tip, read 2.3 % low on the default rig because the beams passed 1.5 mm below it)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from plantsim.evaluation import traits
from plantsim.evaluation.evaluate import beam_gaps_m
from plantsim.rig.geometry import RigGeometry

STEP_DEG = 0.3515625  # the URG-04LX's angle between beams (360 / 1024)
STEP_RAD = math.radians(STEP_DEG)


def _cloud(points, angles_rad):
    return SimpleNamespace(points_turntable=np.asarray(points, dtype=np.float64),
                           turntable_angle_rad=np.asarray(angles_rad, dtype=np.float64))


def test_beam_gaps_by_hand_on_the_default_rig():
    # The LiDAR 0.35 m from the axis, 0.15 m up, its fan upright through the axis.
    T = RigGeometry().T_base_lidar()
    cloud = _cloud([[0.0, 0.0, 0.15],       # on the axis, level with the LiDAR: R dtheta
                    [0.0, 0.0, 0.50],       # on the axis, 45 deg up: R = 0.35 sqrt 2, over cos 45
                    [0.10, 0.0, 0.15],      # 0.1 m nearer the LiDAR, level
                    [0.0, -0.10, 0.15]],    # the same point after the table turned 90 deg
                   [0.0, 0.0, 0.0, math.pi / 2])
    gaps = beam_gaps_m(cloud, T, STEP_DEG)
    assert gaps == pytest.approx([0.35 * STEP_RAD, 0.70 * STEP_RAD, 0.25 * STEP_RAD, 0.25 * STEP_RAD],
                                 rel=1e-12)


def test_a_fan_leaned_about_its_boresight_spreads_its_beams_up_the_vertical():
    # Rolled by 60 deg, the level beam's neighbours lie R dtheta away along a line 60 deg
    # from the vertical: the vertical meets them twice as far up. Rolled flat, they bound
    # no top from above: NaN, not a huge number.
    at_axis = _cloud([[0.0, 0.0, 0.15]], [0.0])
    assert beam_gaps_m(at_axis, RigGeometry(roll_deg=60).T_base_lidar(), STEP_DEG) == pytest.approx(
        [2 * 0.35 * STEP_RAD], rel=1e-9)
    assert np.isnan(beam_gaps_m(at_axis, RigGeometry(roll_deg=90).T_base_lidar(), STEP_DEG)).all()
    with pytest.raises(ValueError, match="angle_increment_deg must be a number > 0"):
        beam_gaps_m(at_axis, RigGeometry().T_base_lidar(), 0.0)


def _blade_between_beams(top_m, gap_m, *, width_m=0.004, column_m=0.0005, base_m=0.05):
    """A vertical blade, 40 mm out from the axis, up to ``top_m``, sampled as a fan does:
    rows at multiples of ``gap_m`` (the beams), columns ``column_m`` apart (the turns)."""
    z = np.arange(math.ceil(base_m / gap_m), math.floor(top_m / gap_m) + 1) * gap_m
    y = np.arange(-width_m / 2, width_m / 2 + 1e-12, column_m)
    yy, zz = np.meshgrid(y, z)
    return np.column_stack([np.full(yy.size, 0.04), yy.ravel(), zz.ravel()])


def test_the_top_read_between_the_beams_is_unbiased_and_within_half_a_gap():
    # The true top anywhere between two beams: the highest hit reads it up to a whole gap
    # low, half a gap low on average; half the gap added, the error is within half a
    # gap either way and about 0 on average.
    gap = 0.002
    raw, between = [], []
    for u in np.linspace(0.0, 1.0, 40, endpoint=False) + 0.0125:
        top = 0.1 + u * gap
        pts = _blade_between_beams(top, gap)
        gaps = np.full(len(pts), gap)
        raw.append(traits.robust_height(pts, cell=0.001, min_points=2) - top)
        between.append(traits.robust_height(pts, cell=0.001, min_points=2, beam_gaps_m=gaps) - top)
    raw, between = np.array(raw), np.array(between)
    assert np.all(raw <= 1e-12) and raw.mean() == pytest.approx(-gap / 2, abs=0.05 * gap)
    assert np.abs(between).max() <= gap / 2 + 1e-12
    assert abs(between.mean()) <= 0.05 * gap
    assert np.abs(between).mean() < 0.6 * np.abs(raw).mean()


def test_the_gap_is_the_top_voxels_own_and_unknown_gaps_add_nothing():
    gap = 0.002
    pts = _blade_between_beams(0.1005, gap)
    top = pts[:, 2] == pts[:, 2].max()
    gaps = np.full(len(pts), 0.010)
    gaps[top] = gap  # only the top voxel's points' gaps count
    h0 = traits.robust_height(pts, cell=0.001, min_points=2)
    assert traits.robust_height(pts, cell=0.001, min_points=2, beam_gaps_m=gaps) == pytest.approx(h0 + gap / 2)
    unknown = np.where(top, np.nan, gap)
    assert traits.robust_height(pts, cell=0.001, min_points=2, beam_gaps_m=unknown) == h0
    for bad, match in ((np.full(len(pts) - 1, gap), "one gap a point"),
                       (np.full(len(pts), -gap), "metres >= 0"),
                       (np.full(len(pts), np.inf), "metres >= 0")):
        with pytest.raises(ValueError, match=match):
            traits.robust_height(pts, cell=0.001, min_points=2, beam_gaps_m=bad)


def test_extract_traits_says_what_it_added_to_the_height():
    gap = 0.002
    pts = _blade_between_beams(0.1005, gap, width_m=0.02)
    plain = traits.extract_traits(pts)
    read = traits.extract_traits(pts, beam_gaps_m=np.full(len(pts), gap))
    assert math.isnan(plain.height_beam_gap_m) and read.height_beam_gap_m == pytest.approx(gap)
    assert read.height_m == pytest.approx(plain.height_m + gap / 2, abs=1e-12)
    assert all(h1 == pytest.approx(h0 + gap / 2, abs=1e-12)
               for h0, h1 in zip(plain.heights_over_grids_m, read.heights_over_grids_m))
    (note,) = [n for n in read.notes if "between the beams" in n]
    assert note.startswith(f"height: {1e3 * read.height_m:.1f} mm, half the 2 mm between the beams")
    assert not any("between the beams" in n for n in plain.notes)
    assert read.to_dict()["height_beam_gap_m"] == pytest.approx(gap)
