"""What the beams through the turntable's axis say about a noisy stem standing on it: where
it ends (segmentation.beam_stem_top) and where the leaves stand in front of it.

A 2D LiDAR whose scan plane holds the turntable's axis sends every beam across the axis: a
beam meets a stem standing there, or a leaf in front of it, or passes the axis. The scenes
are ray-cast exactly (a cylinder and flat plates), with Gaussian range noise along each beam.
"""

import math
import re

import numpy as np
import pytest

from conftest import turntable_first_hits
from plantsim.evaluation import segmentation, traits


def _first_hits(rng, *, stem_r=0.007, stem_h=0.3, sigma=0.012, beside_m=0.0, plates=(), n_angles=360,
                lidar=(0.35, 0.15), elev_deg=(-25.0, 50.0, 0.35)):
    """The first hits (:func:`conftest.turntable_first_hits`) on a cylinder on the axis
    (radius ``stem_r``, from 0 to ``stem_h``) and on plates; points and noise vectors."""
    return turntable_first_hits(rng, [(0.0, 0.0, stem_r, stem_h)], plates=plates, sigma=sigma, n_angles=n_angles,
                                lidar=lidar, beside_m=beside_m, elev_deg=elev_deg)


# A leaf leaving a 0.3 m stem near its top and rising steeply beside the axis, one
# spreading out above it, and a lower leaf standing out to one side.
STEEP = ((0.005, -0.01, 0.28), (0.025, 0.0, 0.17), (0.0, 0.02, 0.0))
SPREAD = ((0.03, -0.015, 0.45), (0.1, 0.0, 0.02), (0.0, 0.03, 0.0))
LOW = ((0.008, -0.02, 0.10), (0.10, 0.0, 0.03), (0.0, 0.04, 0.0))


@pytest.mark.parametrize("seed", [0, 1])
def test_the_beams_read_a_noisy_stems_top_where_a_steep_leaf_rises_above_it(seed):
    # A 14 mm stem under 12 mm of range noise fills a column 3-4 cm wide, and the
    # leaf rising from its top within that column looks like more stem to the walk up
    # the skeleton: it read 0.40-0.43 m. The beams through the axis meet the stem (or a
    # leaf in front of it) up to 0.3 m at every turn, and pass the axis above it.
    rng = np.random.default_rng(seed)
    pts, noise = _first_hits(rng, plates=[STEEP, SPREAD, LOW])
    top = segmentation.beam_stem_top(pts, noise, base_z=0.0, slice_m=0.01, max_miss_m=0.001)
    assert top == pytest.approx(0.30, abs=0.01)
    t = traits.extract_traits(pts, range_noise_m=noise)
    assert t.stems[0].diameter_from == "beams"  # no ring fits: read where the beams meet it
    assert t.stem_height_m == pytest.approx(0.30, rel=0.03)
    assert t.stems[0].height_m == t.stem_height_m and t.stems[0].height_from == "beams"
    assert t.leaf_count == 2
    # The traits say where the top came from and where the walk would have put it.
    (note,) = [n for n in t.notes if "stop meeting it" in n]
    up_mm, walk_mm = (float(x) for x in re.search(r"it, (\d+) mm up, .* went on to (\d+) mm", note).groups())
    assert up_mm == pytest.approx(300, abs=10) and walk_mm >= 380
    # Without the range noise nothing is read from the beams.
    assert not [n for n in traits.extract_traits(pts).notes if "stop meeting it" in n]


def test_the_beams_read_nothing_where_they_cannot_tell():
    rng = np.random.default_rng(3)
    kw = dict(base_z=0.0, slice_m=0.01, max_miss_m=0.001)
    pts, noise = _first_hits(rng, plates=[STEEP, LOW])
    assert math.isfinite(segmentation.beam_stem_top(pts, noise, **kw))
    # No noise: the beams' directions are unknown.
    assert math.isnan(segmentation.beam_stem_top(pts, np.zeros_like(noise), **kw))
    # A LiDAR 20 mm beside the axis: its beams miss a stem on it.
    pts_beside, noise_beside = _first_hits(rng, beside_m=0.02, plates=[STEEP, LOW])
    assert math.isnan(segmentation.beam_stem_top(pts_beside, noise_beside, **kw))
    # A 4 mm stem under 12 mm noise leaves a fifth of its cells open at its base already.
    pts_thin, noise_thin = _first_hits(rng, stem_r=0.002, plates=[STEEP, LOW])
    assert math.isnan(segmentation.beam_stem_top(pts_thin, noise_thin, **kw))
    # No stem on the axis at all.
    pts_none, noise_none = _first_hits(rng, stem_r=1e-9, plates=[STEEP, SPREAD, LOW])
    assert math.isnan(segmentation.beam_stem_top(pts_none, noise_none, **kw))
    with pytest.raises(ValueError, match="slice_m"):
        segmentation.beam_stem_top(pts, noise, base_z=0.0, slice_m=0.0, max_miss_m=0.001)


def _rising_leaf(insertion_z, azimuth_deg, width=0.04):
    """A leaf 40 mm wide leaving the stem's surface at ``insertion_z`` and rising along it
    for 120 mm to 45 mm from the axis, then out to 150 mm (a maize leaf's lower part lies
    in a noisy stem's column): two plates, 126 + 116 = 242 mm along its midrib."""
    a = math.radians(azimuth_deg)
    out, side = np.array([math.cos(a), math.sin(a), 0.0]), np.array([-math.sin(a), math.cos(a), 0.0])
    start = 0.007 * out + np.array([0.0, 0.0, insertion_z]) - 0.5 * width * side
    rise = 0.038 * out + np.array([0.0, 0.0, 0.12])
    return [(start, rise, width * side), (start + rise, 0.105 * out + np.array([0.0, 0.0, 0.05]), width * side)]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_leaf_rising_in_a_noisy_stems_column_is_read_from_its_insertion(seed):
    # Under 12 mm of range noise a 14 mm stem fills a column 3-4 cm wide, and the lower
    # 120 mm of each leaf rising along it lies in that column: the skeleton's leaf began
    # where it left the column, 120-130 mm above its insertion, and read 116-161 mm long
    # for 242. In front of the stem the leaf's cells of turn angle and height hold points
    # nearer the sensor than the stem's (their median, although each point is 12 mm noisy):
    # the leaf is given those points and its midrib starts 15-25 mm above the insertion.
    # Its width is read with the noise's spread across it taken out.
    rng = np.random.default_rng(seed)
    pts, noise = _first_hits(rng, stem_h=0.4, plates=_rising_leaf(0.12, 0.0) + _rising_leaf(0.25, 180.0))
    t = traits.extract_traits(pts, range_noise_m=noise)
    seg = traits.segment_for_traits(pts, range_noise_m=noise)
    assert t.leaf_count == 2
    assert any("2 leaves' bases in the column read from the beams" in n for n in t.notes)
    bases = sorted(float(m[0, 2]) for m in seg.leaf_midribs)
    assert bases[0] == pytest.approx(0.12, abs=0.035) and bases[1] == pytest.approx(0.25, abs=0.035)
    for leaf in t.leaves:
        assert leaf.length_m == pytest.approx(0.242, rel=0.15)
        assert leaf.width_m == pytest.approx(0.040, rel=0.25)
        assert leaf.area_m2 == pytest.approx(0.242 * 0.040, rel=0.30)


def _refusal(t):
    """The trait note saying the beams could not end the stem, and the top it quotes, mm."""
    notes = [n for n in t.notes if "cannot end it" in n]
    if not notes:
        return None, math.nan
    (note,) = notes
    return note, float(re.search(r"its top, (\d+) mm up", note).group(1))


def test_the_traits_say_why_the_beams_do_not_end_a_noisy_stem():
    # Where the beams cannot end a noisy stem, its top is where the walk up its column
    # stopped, and a leaf rising in the column carries the walk on: the traits say so,
    # and why, instead of quoting the walk's top as if the beams had read it.
    rng = np.random.default_rng(4)
    pts, noise = _first_hits(rng, plates=[STEEP, LOW])
    assert _refusal(traits.extract_traits(pts, range_noise_m=noise))[0] is None  # the beams end it
    note, top_mm = _refusal(traits.extract_traits(pts))
    assert "no range noise is given" in note
    # A 4 mm stem under 12 mm of noise: a fifth of its cells are open at its base.
    pts_thin, noise_thin = _first_hits(rng, stem_r=0.002, plates=[STEEP, LOW])
    t = traits.extract_traits(pts_thin, range_noise_m=noise_thin)
    note, top_mm = _refusal(t)
    open_pct = float(re.search(r"the beams pass the axis in (\d+) % of the cells", note).group(1))
    assert 15 <= open_pct <= 35
    assert top_mm == pytest.approx(1e3 * t.stem_height_m, abs=1.0)
    assert t.stems[0].height_from == "walk"
    # A stem 40 mm tall (a rosette's crown) spans too few slices of two voxels to read
    # its own share of open cells above its lowest.
    pts_short, noise_short = _first_hits(rng, stem_h=0.04)
    note, _ = _refusal(traits.extract_traits(pts_short, range_noise_m=noise_short))
    assert re.search(r"the plant spans [1-6] slices of \d+ mm, too few", note)


def _cup_round_a_crown(n=8, width=0.014, incl_deg=50.0, length=0.05, crown_r=0.004, crown_h=0.02):
    """A rosette's inner leaves round its crown: ``n`` plates ``width`` wide leaving the
    crown's surface at its top and rising outward at ``incl_deg``, edge on edge round it
    out to ``n width / 2 pi`` from the axis (18 mm)."""
    plates = []
    for k in range(n):
        a = 2.0 * math.pi * k / n
        out, side = np.array([math.cos(a), math.sin(a), 0.0]), np.array([-math.sin(a), math.cos(a), 0.0])
        rise = math.radians(incl_deg)
        plates.append((crown_r * out + np.array([0.0, 0.0, crown_h]) - 0.5 * width * side, width * side,
                       length * (math.cos(rise) * out + np.array([0.0, 0.0, math.sin(rise)]))))
    return plates


def _cup_top(pts, noise):
    """cup_stem_top as segment_organs reads it: slices of half a voxel, runs of a voxel."""
    voxel = segmentation.kept_points(pts)[1].voxel_m
    return segmentation.cup_stem_top(pts, noise, base_z=0.0, slice_m=segmentation.CUP_SLICE_VOXELS * voxel,
                                     run_m=segmentation.CUP_RUN_VOXELS * voxel, max_miss_m=0.001)


@pytest.mark.parametrize("sigma", [0.005, 0.010])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_crowns_top_is_where_the_beams_meet_the_leaves_standing_round_it(seed, sigma):
    # An 8 mm crown 20 mm tall under 5-10 mm of range noise leaves 12-19 % of its cells
    # open (the beams passing the axis cannot end it: beam_stem_top), and the walk up
    # its noisy column went on up the leaves standing round it (51-55 mm). Above its top the beams
    # meet those leaves, in front of the axis in every turn angle, and farther out as
    # they widen: the median over the turn of where each cell's beams return reads the
    # crown's radius, then the cup's.
    rng = np.random.default_rng(seed)
    pts, noise = _first_hits(rng, stem_r=0.004, stem_h=0.02, sigma=sigma, plates=_cup_round_a_crown())
    assert _cup_top(pts, noise) == pytest.approx(0.020, abs=0.004)
    assert math.isnan(segmentation.beam_stem_top(pts, noise, base_z=0.0, slice_m=0.01, max_miss_m=0.001))
    t = traits.extract_traits(pts, range_noise_m=noise)
    (stem,) = t.stems
    assert stem.height_from == "beams" and stem.height_m == pytest.approx(0.020, abs=0.004)
    (note,) = [n for n in t.notes if "standing round it" in n]
    assert "segmentation.cup_stem_top" in note
    # Without the noise the beams' directions are unknown: the walk's top stands.
    assert traits.extract_traits(pts).stems[0].height_from == "walk"


@pytest.mark.parametrize("seed", [0, 1])
def test_no_cup_is_read_where_leaves_stand_in_front_of_a_stem_in_a_few_turn_angles(seed):
    # A maize's leaves rise beside its stem in a few turn angles: the median over the turn
    # still reads the stem there. A stem does not double its width going up.
    rng = np.random.default_rng(seed)
    for kw in (dict(plates=[STEEP, SPREAD, LOW]), dict(stem_r=0.002, plates=[STEEP, LOW]), dict(plates=[]),
               dict(stem_h=0.4, plates=_rising_leaf(0.12, 0.0) + _rising_leaf(0.25, 180.0))):
        pts, noise = _first_hits(rng, **kw)
        assert math.isnan(_cup_top(pts, noise)), kw
    # A cup with no crown under it: no stem is seen in front of the axis.
    pts, noise = _first_hits(rng, stem_r=1e-9, plates=_cup_round_a_crown())
    assert math.isnan(_cup_top(pts, noise))
    with pytest.raises(ValueError, match="run_m"):
        segmentation.cup_stem_top(pts, noise, base_z=0.0, slice_m=0.002, run_m=0.0, max_miss_m=0.001)


def _beam_diameter(pts, noise, top_z):
    """beam_stem_diameter as extract_traits reads it: slices of half a voxel."""
    scale = segmentation.kept_points(pts)[1]
    return segmentation.beam_stem_diameter(pts, noise, base_z=0.0, top_z=top_z,
                                           slice_m=segmentation.CUP_SLICE_VOXELS * scale.voxel_m, max_miss_m=0.001)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_noisy_stems_diameter_is_read_where_the_beams_through_the_axis_meet_it(seed):
    # Under 12 mm of range noise a 14 mm stem's slices are discs of noise 3-4 cm wide: no
    # ring fits, and the column's width was all that was said (an upper bound). Every beam
    # crosses the axis and returns from the stem's front, a radius in front of the axis,
    # whatever the turn angle; leaves standing in front of it in some turn angles read
    # farther out, and the mode over the turn leaves them out.
    rng = np.random.default_rng(seed)
    for stem_h, plates in ((0.3, [STEEP, SPREAD, LOW]), (0.4, _rising_leaf(0.12, 0.0) + _rising_leaf(0.25, 180.0))):
        pts, noise = _first_hits(rng, stem_h=stem_h, plates=plates)
        assert _beam_diameter(pts, noise, stem_h) == pytest.approx(0.014, rel=0.12)
        t = traits.extract_traits(pts, range_noise_m=noise)
        (stem,) = t.stems
        assert stem.diameter_from == "beams" and stem.diameter_resolved
        assert stem.diameter_m == pytest.approx(0.014, rel=0.12) and t.stem_diameter_m == stem.diameter_m
        (note,) = [n for n in t.notes if "beam_stem_diameter" in n]
        column_mm = float(re.search(r"its noisy column, (\d+) mm wide", note).group(1))
        assert column_mm >= 25
    # A 7 mm stem, whose cells hold a few points each.
    pts, noise = _first_hits(rng, stem_r=0.0035, plates=[STEEP, LOW])
    assert _beam_diameter(pts, noise, 0.3) == pytest.approx(0.007, rel=0.25)


def test_no_diameter_is_read_where_the_beams_cannot_meet_a_stem_on_the_axis():
    rng = np.random.default_rng(5)
    pts, noise = _first_hits(rng, plates=[STEEP, LOW])
    assert math.isfinite(_beam_diameter(pts, noise, 0.3))
    # No noise given: the beams' directions are not known, and the noisy column's width
    # is all that is said (an upper bound).
    assert math.isnan(_beam_diameter(pts, np.zeros_like(noise), 0.3))
    stem = traits.extract_traits(pts).stems[0]
    assert stem.diameter_from == "column" and not stem.diameter_resolved and stem.diameter_m > 0.020
    # A LiDAR 20 mm beside the axis: its beams miss the stem standing on it.
    pts_beside, noise_beside = _first_hits(rng, beside_m=0.02, plates=[STEEP, LOW])
    assert math.isnan(_beam_diameter(pts_beside, noise_beside, 0.3))
    # No stem on the axis, only leaves round it; a top within three slices of the base.
    pts_none, noise_none = _first_hits(rng, stem_r=1e-9, plates=_cup_round_a_crown())
    assert math.isnan(_beam_diameter(pts_none, noise_none, 0.02))
    assert math.isnan(_beam_diameter(pts, noise, 0.004))
    with pytest.raises(ValueError, match="top_z"):
        segmentation.beam_stem_diameter(pts, noise, base_z=0.0, top_z=math.nan, slice_m=0.003, max_miss_m=0.001)
