"""A cup of touching leaves round the axis, split at its tips (segmentation._split_petals,
_reach_profile, _reach_lobes; step 11 of the segmentation).

A rosette's inner leaves rise from the crown edge on edge, and the level sets of the
skeleton do not part them until near their tips: the segmentation finds the cup as one
leaf. Its rim still has one lobe per leaf. The fixtures are clouds made in memory: a cone
rising from the crown whose rim is cut into lobes (each lobe one true leaf, known by its
azimuth), found as one leaf, and leaflets fanned out from the end of a stalk.
"""

import math

import numpy as np
import pytest

from conftest import assert_cup_split_into, split_one_cup
from plantsim.evaluation import segmentation

CROWN_TOP_Z_M = 0.02
CROWN_RADIUS_M = 0.004
SPACING_M = 0.001
CELL_M = 2 * SPACING_M  # the working voxel of a clean cloud, two spacings


def _cone_cup(seed, *, n_petals=8, tip_m=0.05, notch_m=0.045, elevation_deg=55.0):
    """Points of a cone rising ``elevation_deg`` from the crown's top edge, whose rim is cut
    into ``n_petals`` lobes: each reaches ``tip_m`` up the cone at its middle and
    ``notch_m`` where it meets the next. Returns the points and each point's petal."""
    rng = np.random.default_rng(seed)
    el = math.radians(elevation_deg)
    n = int(2 * math.pi * (CROWN_RADIUS_M + tip_m * math.cos(el)) * tip_m / SPACING_M ** 2)
    slant = tip_m * np.sqrt(rng.uniform(0.0, 1.0, n))  # even over the cone's area
    phi = rng.uniform(0.0, 2 * math.pi, n)
    width = 2 * math.pi / n_petals
    off = (phi - 0.3 + 0.5 * width) % width - 0.5 * width  # from the middle of its petal
    keep = slant <= notch_m + (tip_m - notch_m) * np.cos(math.pi * off / width)
    slant, phi = slant[keep], phi[keep]
    r = CROWN_RADIUS_M + slant * math.cos(el)
    pts = np.column_stack([r * np.cos(phi), r * np.sin(phi), CROWN_TOP_Z_M + slant * math.sin(el)])
    petal = np.floor(((phi - 0.3 + 0.5 * width) % (2 * math.pi)) / width).astype(np.int64) % n_petals
    return pts, petal


def _split(pts, *, min_leaf_m=0.01):
    return split_one_cup(segmentation._split_petals, pts, junction=np.array([0.0, 0.0, CROWN_TOP_Z_M]), cell_m=CELL_M,
                         spacing_m=SPACING_M, min_leaf_m=min_leaf_m)


@pytest.mark.parametrize("seed, n_petals", [(0, 8), (1, 5), (2, 12)])
def test_a_cup_found_as_one_leaf_is_split_into_its_true_leaves_at_their_tips(seed, n_petals):
    # Lobes 5 mm deep on a cup 50 mm tall: the level sets, 8 mm apart, hold each lobe's
    # tip and the next one's in one piece.
    pts, petal = _cone_cup(seed, n_petals=n_petals)
    # The cuts are good to about an azimuth bin, a voxel at the cup's median radius: a
    # 12-petal cup's petals are 6 bins wide (77-83 % over seeds 0-5; 8 petals 86-88 %,
    # 5 petals 90-93 %). Each is no leaflet: a leaf of its own, as long as a leaf.
    midribs = assert_cup_split_into(_split(pts), petal, n_petals, min_share=0.75,
                                    junction=[0.0, 0.0, CROWN_TOP_Z_M])
    for rib in midribs:
        assert np.linalg.norm(np.diff(rib, axis=0), axis=1).sum() > 0.03


def test_lobes_within_the_samplings_roughness_or_shorter_than_a_leaf_are_no_leaves():
    # 1 mm deep: under two spacings, the roughness a bin's farthest point has anyway.
    pts, _ = _cone_cup(3, notch_m=0.049)
    assert _split(pts)[4] == 0
    # Deep enough, but no lobe reaches a leaf's length from the junction.
    pts, _ = _cone_cup(3)
    assert _split(pts, min_leaf_m=0.06)[4] == 0


def test_a_few_points_far_from_the_cup_make_no_leaf_of_their_own():
    # Eight stray points 0.25 m above the cup, at the azimuth of a notch between two
    # lobes: their reach is a lobe of its own, a leaf's length from the junction, but
    # eight points are no surface 0.25 m long (step 8's rule: a point a spacing).
    pts, petal = _cone_cup(5)
    notch = 0.3 + math.pi / 8
    stray = np.column_stack([np.full(8, 0.03 * math.cos(notch)), np.full(8, 0.03 * math.sin(notch)),
                             np.linspace(0.27, 0.28, 8)])
    label, midribs, groups, _, added = _split(np.vstack([pts, stray]))
    assert added == 7 and len(midribs) == 8
    assert len(set(label[-8:].tolist())) == 1  # they went with one petal


def test_leaflets_at_the_end_of_a_stalk_are_not_leaves_of_their_own():
    # A stalk out from the axis to 40 mm, three leaflets fanned from its end, the side
    # ones square to it: round the axis they span over 100 deg and their rim has three
    # lobes, but only the middle one's part starts at the stalk.
    rng = np.random.default_rng(4)
    end = np.array([0.04, 0.0, 0.03])
    stalk = np.column_stack([rng.uniform(0.005, 0.04, 400), rng.uniform(-0.0015, 0.0015, 400),
                             np.full(400, 0.03)])
    leaflets = []
    for angle in (-90.0, 0.0, 90.0):
        a = math.radians(angle)
        along, across = np.array([math.cos(a), math.sin(a), 0.0]), np.array([-math.sin(a), math.cos(a), 0.0])
        u, s = rng.uniform(0.0, 0.05, 6000), rng.uniform(-0.5, 0.5, 6000)
        keep = np.abs(s) <= 0.5 * np.sqrt(np.clip(1 - (2 * u / 0.05 - 1) ** 2, 0, 1))
        leaflets.append(end + u[keep, None] * along + 0.02 * s[keep, None] * across)
    pts = np.vstack([stalk] + leaflets)
    prof = segmentation._reach_profile(np.arctan2(pts[:, 1], pts[:, 0]),
                                       np.linalg.norm(pts - [0.0, 0.0, CROWN_TOP_Z_M], axis=1), 360)
    peaks, _ = segmentation._reach_lobes(prof, prominence=2 * SPACING_M, min_reach=0.01)
    assert len(peaks) == 3  # the lobes are there; the rule that reads them as leaflets is what holds
    label, midribs, groups, _, added = _split(pts)
    assert added == 0 and len(midribs) == 1 and np.all(label == 0)


def test_the_reach_profile_bridges_short_gaps_and_keeps_long_ones():
    phi = np.radians([0.5, 1.5, 5.5, 30.5])  # bins 0, 1, 5 and 30 of 360
    prof = segmentation._reach_profile(phi, np.array([0.01, 0.02, 0.06, 0.03]), 360)
    # 3 empty bins between bins 1 and 5 take the line between them; 24 stay empty.
    assert prof[:6] == pytest.approx([0.01, 0.02, 0.03, 0.04, 0.05, 0.06])
    assert np.all(prof[6:30] == 0) and prof[30] == pytest.approx(0.03)


def test_lobes_are_read_round_the_circle_with_their_sectors():
    # Three lobes round 72 bins, peaks at bins 70, 22 and 46 and valleys at 10, 34 and 58,
    # one lobe either side of bin 0, where the profile is unrolled.
    bins = np.arange(72)
    knots = [(-14, 0.035), (-2, 0.060), (10, 0.040), (22, 0.062), (34, 0.030), (46, 0.058), (58, 0.035),
             (70, 0.060), (82, 0.040)]
    prof = np.interp(bins, [k for k, _ in knots], [v for _, v in knots])
    peaks, ends = segmentation._reach_lobes(prof, prominence=0.005, min_reach=0.01)
    # In order round from the lowest valley, each with the valley that ends its sector.
    assert list(zip(peaks.tolist(), ends.tolist())) == [(46, 58), (70, 10), (22, 34)]
    # Prominence is over the higher of the two valleys: a lobe whose valley on one side
    # lies within the prominence of its peak is no lobe.
    knots[6] = (58, 0.054)  # 4 mm below the lobe at 46, 6 mm below the one at 70
    shallow = np.interp(bins, [k for k, _ in knots], [v for _, v in knots])
    assert sorted(segmentation._reach_lobes(shallow, prominence=0.005, min_reach=0.01)[0].tolist()) == [22, 70]
    # Lobes short of a leaf's length, or one lobe alone, are none.
    assert len(segmentation._reach_lobes(prof, prominence=0.005, min_reach=0.061)[0]) == 0
    assert len(segmentation._reach_lobes(prof, prominence=0.03, min_reach=0.01)[0]) == 0


def test_a_noisy_scans_reach_is_its_noises_and_is_not_read():
    # The same points segmented whole (a crown under the cup), once as a clean scan and
    # once given a range noise along beams through the axis: only the clean one is split.
    pts, _ = _cone_cup(0)
    rng = np.random.default_rng(9)
    theta = rng.uniform(0.0, 2 * math.pi, 3000)
    crown = np.column_stack([CROWN_RADIUS_M * np.cos(theta), CROWN_RADIUS_M * np.sin(theta),
                             rng.uniform(0.0, CROWN_TOP_Z_M, 3000)])
    pts = np.vstack([crown, pts])
    assert segmentation.segment_organs(pts).petal_split_leaves > 0
    radial = np.column_stack([pts[:, :2] / np.linalg.norm(pts[:, :2], axis=1)[:, None], np.zeros(len(pts))])
    noisy = segmentation.segment_organs(pts, range_noise_m=0.01 * radial)
    assert noisy.petal_split_leaves == 0
