"""Traits from pipeline scans of procedural plants against their exact truth (issue 13).

The issue's targets: from an ideal 0.5-degree scan, height within 2 %, leaf count
within 20 %, leaf area within 20 %; from a realistic 1-degree scan (URG-04LX noise
model), 5 %, 40 % and 35 %. Plants: maize (9 leaves), wheat (4 tillers, 16 leaves,
stems 4 mm), rosettes of 12 and 30 overlapping leaves (touching leaves), a bean-like dicot
(8 trifoliate leaves: 24 laminae on petioles), and the issue's smallest leaf count,
three leaves: a maize, a rosette and a bean with simple leaves. Each scan runs once per
module (cached). Leaves are counted as a botanist counts them (and as Pheno4D labels a
tomato's): a compound leaf once, so the dicot has 8 leaves; its 24 laminae are the
lamina count, tested apart.

Asserted: every target the current segmentation meets (``scripts/traits_accuracy.py``
prints the whole table). Targets not met yet are strict ``xfail``s, so a fix that
reaches one turns the test red until it is promoted to a plain assertion:
ideal rosette leaf area
(-33 % / -53 %: most of it hidden from the default rig; the true leaves measured alone read
-27 % / -39 %, scripts/traits_area_bound.py: no segmentation meets these, the reason their
xfails give); the dicot's realistic lamina count (11 for 24); realistic
wheat area (+156 %: its leaves' widths under noise as wide as they are; +244 % before its
tillers were found in their turn angles, their culms and ears read as leaves; its true
leaves measured alone, each point labelled by the face its beam hit, read +187 %: the
per-leaf measures, not the segmentation) and realistic
rosettes (6 leaves for 12; one leaf for 30, area -82 %, which a note says is a ring of merged
leaves, tested below, where its true leaves measured alone read -6 %: the
segmentation's miss; the 12-leaf one's area, -40 % while its crown's noisy column held its inner leaves
up to 69 mm, reads -11 % since the beams end the crown where they meet the
leaves standing round it, segmentation.cup_stem_top). The ideal 3-leaf rosette's
height is met (-0.3 %) since half the gap between the beams at the top is added
(traits.robust_height's ``beam_gaps_m``, as ``plantsim traits`` reads them from the
sidecar): the top is a leaf's tip, and the URG's beams, 0.35 deg apart, pass 2.7 mm
apart there, the highest hit 1.5 mm below it (-2.3 % before). The realistic
3-leaf rosette's leaves, one leaf in the noise round the axis, are split by azimuth
(segmentation._split_at_axis): 3 on every grid, each matched to its true leaf. The point
spacing the segmentation scales by is the median over the surface's area, measured on
every point kept (segmentation.estimate_scale): as a 90th percentile over the points, on
the points the outlier removal kept, it measured the stem of a small plant, which holds
most of its points (97 % of the ideal bean's within 6 mm of the axis), and found no leaf
on the bean, 4 on the 3-leaf maize and rosette (the maize's stem, broken at its base,
read as a leaf).
The ideal 30-leaf rosette's count is met (25 for 30, 17-31 over the grids; 21 before)
since a cup of touching leaves is split where their smooth surfaces meet at a crease
(segmentation._split_smooth_surfaces), which also reads the dicot's top leaf, a cup of
leaflets, as two leaves on 5 of the 9 grids (tested below).
``scripts/traits_separability.py`` says how far the realistic noise itself mixes the organs.
Every plant is scanned on the default rig, which warns about the maize (their tops seen
61-62 deg up) and the rosettes (flat, seen edge-on); ``scripts/traits_accuracy.py
--fit-rig`` scans those on the rig ``--fit-rig`` picks (docs/traits.md: 9 misses for 10).

Each scan's traits are read given its range noise, each point's beam direction times the
noise's sigma, as ``plantsim traits`` reads it from the scan's sidecar (zeros for the
ideal sensor): the plant's top is read with its points moved along their beams, and a
branch that a noisy stem's hits make is given back to the stem (the realistic bean's
area read +77 % without it, +19 % with it).

Traits are measured on the LAS file's 0.01 mm grid, and the organs segmented on 9
shifted voxel grids, the grid of the median leaf count kept (``TraitSettings.shifted_grids``):
a scan's traits and its file's are the same, and each trait carries its spread over
the grids (tested at the end).

Counts can meet their target with leaves split and merged, so the ideal maize and wheat
and the realistic dicot are also matched leaf by leaf to their true leaves (IoU of points
> 0.5, :mod:`plantsim.evaluation.organ_match`); the realistic maize and wheat meet their
count with 2 and 4 leaves matched (each point's truth the face its beam hit: the nearest
face is where the noise put it, and matched the maize's 0).
"""

import functools
import logging
import math

import numpy as np
import pytest

from plantsim.cloud.export import read_cloud, write_cloud
from plantsim.evaluation import traits
from plantsim.evaluation.evaluate import scan_beam_gaps, scan_range_noise
from plantsim.evaluation.organ_match import match_procedural_leaves, procedural_leaf_labels
from plantsim.plant.mesh import plant_from_arrays
from plantsim.plant.procedural import make_dicot, make_maize, make_rosette, make_wheat
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan

PLANTS = {
    "maize": lambda: make_maize(seed=0),
    "wheat": lambda: make_wheat(seed=0),
    "rosette12": lambda: make_rosette(seed=1, n_leaves=12),
    "rosette30": lambda: make_rosette(seed=2, n_leaves=30),
    "dicot": lambda: make_dicot(seed=0),  # 8 trifoliate leaves: 24 laminae, 3 on each petiole
    # The smallest leaf count: three leaves, on three species shapes.
    "maize3": lambda: make_maize(seed=2, n_leaves=3),
    "rosette3": lambda: make_rosette(seed=0, n_leaves=3),
    "bean3": lambda: make_dicot(seed=1, n_leaves=3, leaflets=1),  # three simple leaves
}
IDEAL = (True, 0.5)
REALISTIC = (False, 1.0)
NOT_YET = "issue 13 target not met by the current segmentation (see the module docstring)"
# Leaf areas the per-leaf measures miss on the true leaves too, each measured alone (each
# point labelled by its nearest face, on a realistic scan by the face its beam hit):
# scripts/traits_area_bound.py.
NOT_BY_SEGMENTATION = ("issue 13 target not met, and the true leaves measured alone miss it too "
                       "(scripts/traits_area_bound.py; see the module docstring)")
SMALL = ["maize3", "rosette3", "bean3"]
# Per scan, each plant point's range noise along its beam (what `plantsim traits` reads
# from a scan's sidecar), filled as the scans run; and how far up the vertical through each
# the fan's next beam passes (its beam gap, read from the sidecar too).
_RANGE_NOISE: dict = {}
_BEAM_GAPS: dict = {}


@functools.lru_cache(maxsize=None)
def _plant_cloud(name: str, ideal: bool, step_deg: float):
    plant = PLANTS[name]()
    logging.getLogger("plantsim").setLevel(logging.ERROR)
    try:
        result = run_scan(RunConfig(ideal=ideal, scan=StepScan(step_deg=step_deg)),
                          plant=plant_from_arrays(plant.vertices_m, plant.faces))
        _RANGE_NOISE[(name, ideal, step_deg)] = scan_range_noise(result)[0]
        _BEAM_GAPS[(name, ideal, step_deg)] = scan_beam_gaps(result)
        return result.cloud.plant_only(), plant.traits
    finally:
        logging.getLogger("plantsim").setLevel(logging.NOTSET)


def _cloud(name: str, ideal: bool, step_deg: float):
    cloud, truth = _plant_cloud(name, ideal, step_deg)
    return cloud.points_turntable, truth


@functools.lru_cache(maxsize=None)
def _scan(name: str, ideal: bool, step_deg: float):
    # Given the scan's range noise, as `plantsim traits` reads it from the scan's sidecar
    # (zeros for the ideal sensor: nothing moves, no branch is the stem's noise).
    points, truth = _cloud(name, ideal, step_deg)
    key = (name, ideal, step_deg)
    return traits.extract_traits(points, range_noise_m=_RANGE_NOISE[key], beam_gaps_m=_BEAM_GAPS[key]), truth


def _rel(estimate, truth):
    return abs(estimate - truth) / truth


def _true_leaf_count(truth):
    """The truth's leaves, a compound leaf (laminae on one petiole) counted once."""
    return traits.traits_from_truth(truth).leaf_count


def _miss(*ids, reason=NOT_YET):
    return [pytest.param(*i, marks=pytest.mark.xfail(strict=True, reason=reason)) for i in ids]


def _small(*missed):
    """The 3-leaf plants, those in ``missed`` as strict xfails."""
    return [n for n in SMALL if n not in missed] + _miss(*((n,) for n in missed))


@pytest.mark.parametrize("name", ["maize", "wheat", "rosette12", "rosette30", "dicot"] + _small())
def test_height_from_an_ideal_half_degree_scan_within_two_percent(name):
    est, truth = _scan(name, *IDEAL)
    assert _rel(est.height_m, truth["height_m"]) <= 0.02


@pytest.mark.parametrize("name", ["maize", "wheat", "rosette12", "rosette30", "dicot"] + _small())
def test_height_from_a_realistic_one_degree_scan_within_five_percent(name):
    est, truth = _scan(name, *REALISTIC)
    assert _rel(est.height_m, truth["height_m"]) <= 0.05


def test_the_ideal_3_leaf_rosettes_top_is_read_between_the_beams():
    # Its top is a leaf's tip, and the beams at it pass 2.7 mm apart: the highest that hits
    # it reads 2.3 % low. Half the gap added, the height is within 0.5 %.
    est, truth = _scan("rosette3", *IDEAL)
    points, _ = _cloud("rosette3", *IDEAL)
    sampled = traits.extract_traits(points, range_noise_m=_RANGE_NOISE[("rosette3", *IDEAL)])
    assert math.isnan(sampled.height_beam_gap_m) and _rel(sampled.height_m, truth["height_m"]) > 0.02
    assert 0.0025 < est.height_beam_gap_m < 0.003
    assert est.height_m - sampled.height_m == pytest.approx(est.height_beam_gap_m / 2, abs=1e-9)
    assert _rel(est.height_m, truth["height_m"]) <= 0.005


@pytest.mark.parametrize("name", list(PLANTS))
def test_a_realistic_height_given_the_range_noise_is_within_five_percent_on_every_grid(name):
    # Given each point's range noise (as `plantsim traits` reads it from the sidecar), the
    # points that can reach the top move along their beams first (traits.beam_median_points):
    # every shifted grid reads within 3.3 % (scripts/traits_accuracy.py). With the points as
    # measured the 3-leaf maize read 3.4-8.7 % low over the grids, and a voxel count alone
    # cannot tell a top from the band its noise spreads it into.
    points, truth = _cloud(name, *REALISTIC)
    noise = _RANGE_NOISE[(name, *REALISTIC)]
    assert noise.shape == points.shape
    assert np.linalg.norm(noise, axis=1).min() >= 0.01  # at least the URG-04LX's 10 mm floor
    est = traits.extract_traits(points, range_noise_m=noise)
    assert len(est.heights_over_grids_m) == 9 and est.heights_over_grids_m[0] == est.height_m
    assert max(_rel(h, truth["height_m"]) for h in est.heights_over_grids_m) <= 0.05


@pytest.mark.parametrize("name", ["maize", "wheat", "rosette12", "rosette30", "dicot"] + _small())
def test_leaf_count_from_an_ideal_scan_within_twenty_percent(name):
    est, truth = _scan(name, *IDEAL)
    assert _rel(est.leaf_count, _true_leaf_count(truth)) <= 0.20


@pytest.mark.parametrize("name", ["maize", "wheat", "dicot"]
                         + _miss(("rosette12",), ("rosette30",), reason=NOT_BY_SEGMENTATION) + _small())
def test_leaf_area_from_an_ideal_scan_within_twenty_percent(name):
    est, truth = _scan(name, *IDEAL)
    assert _rel(est.leaf_area_m2, truth["leaf_area_m2"]) <= 0.20


# The maize (11 for 9) and the wheat (10 for 16) meet the count by number mostly: 2 and
# 4 of their found leaves match a true leaf (scripts/traits_accuracy.py, docs/traits.md);
# so does the dicot (11 for 8: no leaflets grouped, its leaves split in two or three).
@pytest.mark.parametrize("name", ["maize", "wheat", "dicot"] + _miss(("rosette12",), ("rosette30",))
                         + _small())
def test_leaf_count_from_a_realistic_scan_within_forty_percent(name):
    est, truth = _scan(name, *REALISTIC)
    assert _rel(est.leaf_count, _true_leaf_count(truth)) <= 0.40


# The laminae, each leaflet counted: the dicot's 24 (the other plants' laminae are their
# leaves). Held to the leaf count's targets: 21 ideal (19 before its top leaf's leaflets,
# a cup, were split at their creases, segmentation._split_smooth_surfaces), 11 realistic,
# not met.
@pytest.mark.parametrize("setting, target", [
    (IDEAL, 0.20),
    pytest.param(REALISTIC, 0.40, marks=pytest.mark.xfail(strict=True, reason=NOT_YET))])
def test_the_dicots_lamina_count(setting, target):
    est, truth = _scan("dicot", *setting)
    assert traits.traits_from_truth(truth).lamina_count == len(truth["leaves"]) == 24
    assert _rel(est.lamina_count, 24) <= target


def test_an_ideal_dicots_leaves_are_its_true_compound_leaves():
    # Leaflets hanging from one stalk out of the stem's column are one leaf: the 21
    # laminae found make 9 leaves, each all of one true leaf's points (one petiole's
    # laminae), each true leaf found. The top leaf, whose leaflets stand round the stem's
    # top as a cup, is read as two (a leaflet apart) on 5 of the 9 shifted grids since
    # cups are split at their creases (segmentation._split_smooth_surfaces): 8 on every
    # grid before, with 19 laminae.
    est, truth = _scan("dicot", *IDEAL)
    assert _true_leaf_count(truth) == 8 and est.leaf_count == 9
    assert set(est.leaf_counts_over_grids) <= {8, 9}
    assert est.lamina_count > est.leaf_count
    assert [lf.group for lf in est.leaves] and {lf.group for lf in est.leaves} == set(range(9))
    points, _ = _cloud("dicot", *IDEAL)
    seg = traits.segment_for_traits(points)
    true_lamina = procedural_leaf_labels(seg.points, PLANTS["dicot"]())
    petiole = np.array([lf["petiole"] for lf in truth["leaves"]])
    groups = traits.leaf_groups_of(seg)
    owners = []
    for g in range(9):
        member = np.isin(seg.leaf_label, [i for i, x in enumerate(groups) if x == g])
        hit = true_lamina[member]
        owners.append(set(petiole[hit[hit >= 0]].tolist()))
    assert all(len(o) == 1 for o in owners), owners
    assert sorted(set(min(o) for o in owners)) == list(range(8))


@pytest.mark.parametrize("name", ["maize", "dicot", "rosette12"] + _miss(("wheat",), reason=NOT_BY_SEGMENTATION)
                         + _miss(("rosette30",)) + _small())
def test_leaf_area_from_a_realistic_scan_within_thirty_five_percent(name):
    est, truth = _scan(name, *REALISTIC)
    assert _rel(est.leaf_area_m2, truth["leaf_area_m2"]) <= 0.35


def _grids_given_noise(points, noise):
    """The segmentation's 9 grids as extract_traits makes them, given the range noise."""
    return traits._segment_above(traits.on_file_grid(points), traits.TraitSettings(), noise).grids


@functools.lru_cache(maxsize=None)
def _fitted_maize_scan():
    """The realistic 1-degree scan of the 9-leaf maize on the rig fit_rig picks for it:
    (points, range noise)."""
    from plantsim.rig.fit import fit_rig

    plant = PLANTS["maize"]()
    placed = plant_from_arrays(plant.vertices_m, plant.faces)
    config = RunConfig(ideal=False, scan=StepScan(step_deg=1.0))
    rig, _ = fit_rig(placed, config.rig, config.lidar)
    logging.getLogger("plantsim").setLevel(logging.ERROR)
    try:
        result = run_scan(config.replace(rig=rig), plant=placed)
    finally:
        logging.getLogger("plantsim").setLevel(logging.NOTSET)
    return result.cloud.plant_only().points_turntable, scan_range_noise(result)[0]


def test_the_branches_a_noisy_stem_spreads_are_given_back_to_it():
    # The 3-leaf bean's 7 mm stem under 10 mm of range noise is a disc 2 cm wide whose
    # lobes the skeleton reads as leaves: 4 "leaves" for 3, 25 % of their points on a
    # true leaf, area +77 %. Given each point's beam (the scan's range noise), a branch
    # 90 % of whose points could be the stem's hits carried along their beams, and that
    # ends within the stem's noise disc, goes back to the stem
    # (segmentation.stem_noise_points): 2 leaves (2 or 3 over the grids), 42 % of their
    # points on a true leaf, and 95 % of the true leaves' points kept.
    points, _ = _cloud("bean3", *REALISTIC)
    noise = _RANGE_NOISE[("bean3", *REALISTIC)]
    truth_of = functools.partial(procedural_leaf_labels, plant=PLANTS["bean3"]())
    plain = traits.segment_for_traits(points)
    given = traits.segment_for_traits(points, range_noise_m=noise)
    assert plain.stem_noise_branches == 0 and given.stem_noise_branches >= 1

    def precision_recall(seg):
        on_leaf, labelled = truth_of(seg.points) >= 0, seg.leaf_label >= 0
        return on_leaf[labelled].mean(), labelled[on_leaf].mean()

    (p0, r0), (p1, r1) = precision_recall(plain), precision_recall(given)
    assert p1 > p0 + 0.1 and r1 >= r0 - 0.06, (p0, r0, p1, r1)
    est, truth = _scan("bean3", *REALISTIC)
    assert set(est.leaf_counts_over_grids) <= {2, 3}
    assert sum("the stem's own hits" in n for n in est.notes) == 1
    # The maize's leaves lie along its stem for much of their sheath: up to 89 % of a
    # leaf's points within the stem's noise on this rig, 94 % on the one fit_rig picks
    # for it (0.47 m out, 0.30 m up), where the share alone gave one of its 10 leaves to the stem.
    # They reach out of the noise disc: none goes to the stem, on any grid.
    maize, _ = _scan("maize", *REALISTIC)
    assert not any("the stem's own hits" in n for n in maize.notes)
    points, _ = _cloud("maize", *REALISTIC)
    fitted = _fitted_maize_scan()
    for pts, noise in ((points, _RANGE_NOISE[("maize", *REALISTIC)]), fitted):
        assert [g.stem_noise_branches for g in _grids_given_noise(pts, noise)] == [0] * 9


def test_the_realistic_30_leaf_rosettes_one_leaf_is_said_to_be_a_ring_of_leaves():
    # Its leaves blur into one (the count target above is not met); the output says so.
    est, _ = _scan("rosette30", *REALISTIC)
    assert est.leaf_count == 1
    assert sum("surrounds the plant's centre" in n and "lower bound" in n for n in est.notes) == 1
    # Single leaves each span a sector: none is said to be a ring.
    for name, settings in (("maize", (IDEAL, REALISTIC)), ("wheat", (IDEAL, REALISTIC)),
                           ("dicot", (IDEAL, REALISTIC))):
        for setting in settings:
            est, _ = _scan(name, *setting)
            assert not any("surrounds" in n for n in est.notes), (name, setting)
    # The 12-leaf rosette's inner leaves, which its crown's noisy column held until the
    # beams ended the crown below them (segmentation.cup_stem_top), are one of its 6
    # leaves (for 12), said to be a ring round the crown; the other five span sectors.
    est, _ = _scan("rosette12", *REALISTIC)
    assert sum("surrounds its stem" in n and "lower bound" in n for n in est.notes) == 1


def test_stems_found_from_the_base_up_with_their_diameter():
    est, truth = _scan("wheat", *IDEAL)
    assert est.stem_count == len(truth["stems"]) == 4
    assert _rel(est.stem_diameter_m, truth["stem_diameter_m"]) <= 0.10
    est, truth = _scan("maize", *IDEAL)
    assert est.stem_count == 1
    assert _rel(est.stem_diameter_m, truth["stem_diameter_m"]) <= 0.10
    assert est.stems[0].diameter_from == "rings"
    # A rosette's crown is 2 cm tall under leaves rising steeply from its top: one
    # stem on the axis, not the leaves' columns (4 stems 15-27 mm wide before).
    for name in ("rosette12", "rosette30"):
        est, truth = _scan(name, *IDEAL)
        (stem,) = est.stems
        assert np.hypot(*stem.center_xy_m) < 0.002, name
        assert _rel(stem.diameter_m, truth["stem_diameter_m"]) <= 0.10, name


def test_a_noisy_wheats_tillers_are_found_in_their_turn_angles_each_with_its_height():
    # Under 10-12 mm of range noise a 4 mm culm 40-60 mm from the axis is a streak along
    # the beams, no column in the base slices: one stem of four was found (the one on the
    # axis, 47 mm wide), and the tillers' culms and ears were read as leaves. Their turn
    # angles are as scanned (segmentation.find_beam_stems, track_beam_stem).
    est, truth = _scan("wheat", *REALISTIC)
    assert est.stem_count == len(truth["stems"]) == 4
    assert sum(st.found_in_beams for st in est.stems) == 3
    c = traits.compare_traits(est, traits.traits_from_truth(truth))
    heights = [e for e in c.errors if e.trait.endswith("].height_m")]
    assert len(heights) == 4 and all(e.relative_error <= 0.05 for e in heights), heights
    for st in est.stems:
        if st.found_in_beams:  # to a step (1 mm at 60 mm) and the beam's footprint
            assert st.diameter_resolved and st.diameter_m < 0.010
    # The plant's diameter: theirs, not the axis culm's noisy column (47 mm; 16.7 with it).
    assert est.stem_diameter_m < 0.010
    # Their culms no longer make leaves: every leaf found is mostly one true leaf (each
    # point's truth the face its beam hit; 79-100 % of each leaf's points are a leaf's).
    points, _ = _cloud("wheat", *REALISTIC)
    seg = traits.segment_for_traits(points, range_noise_m=_RANGE_NOISE[("wheat", *REALISTIC)])
    labels = procedural_leaf_labels(seg.points, PLANTS["wheat"](), range_noise_m=seg.range_noise_m)
    for i in range(len(seg.leaf_midribs)):
        assert np.mean(labels[seg.leaf_label == i] >= 0) > 0.5, i


@pytest.mark.parametrize("name", ["maize", "wheat"])
def test_the_widest_leaf_from_an_ideal_scan_within_three_percent(name):
    # A cross-section's 2nd-98th percentile extent read the leaves 6 % narrow (48.2 mm
    # for 51.1 on the maize, 9.9 for 10.5 on the wheat) and their areas 11-12 % small;
    # read as a uniformly sampled strip's width (segmentation.uniform_width), 50.5 and 10.5.
    est, truth = _scan(name, *IDEAL)
    assert _rel(est.leaf_width_m, truth["leaf_width_m"]) <= 0.03


@pytest.mark.parametrize("name", [
    # The maize's stem reads 0.25 to 0.51 m for 0.42 over the 9 shifted grids
    # (PlantTraits.stem_heights_over_grids_m): 0.42 on three, 0.25 on three, 0.31, 0.36
    # and 0.51. On the origin's grid (0.25) the stem's level sets split into two
    # half-rings at 0.15 m, and the walk takes the one nearer its axis, which ends.
    pytest.param("maize", marks=pytest.mark.xfail(strict=True, reason=(
        "the maize's stem walk reads 0.25-0.51 m for 0.42 over the shifted grids: it follows a "
        "leaf up the whorl or stops at a leaf's junction"))),
    "wheat", "bean3",
    # The 3-leaf maize's stem walk broke at its base (0.013 m for 0.42) while the point
    # spacing was a percentile over the points, most of them on the stem.
    "maize3"])
def test_stem_height_from_an_ideal_scan_within_five_percent(name):
    # The stem's top, not where a leaf wrapped round it split its level sets (0.24 m
    # for 0.42 m on the maize before the walk went on through both halves).
    est, truth = _scan(name, *IDEAL)
    stem_height = max(st["height_m"] for st in truth["stems"])
    assert _rel(est.stem_height_m, stem_height) <= 0.05, name


@pytest.mark.parametrize("name", ["maize", "maize3"])
def test_a_noisy_maize_stem_ends_where_the_beams_stop_meeting_it(name):
    # A noisy stem's column is its measured width (the noise is in it), and its axis
    # follows only pieces that fit in that column: the walk stopped at 0.60 m on a
    # 0.42 m stem before, having bent off up the top leaf, and at 0.50 m (0.48 m on the
    # 3-leaf maize) still, up the leaves rising in the column. The beams through the axis
    # meet the stem up to its top and pass the axis above it (segmentation.beam_stem_top):
    # 0.429 and 0.421 m, on every grid.
    est, truth = _scan(name, *REALISTIC)
    assert _rel(est.stem_height_m, truth["stems"][0]["height_m"]) <= 0.05
    assert max(est.stem_heights_over_grids_m) - min(est.stem_heights_over_grids_m) <= 0.01


def test_a_noisy_rosettes_crown_ends_where_the_beams_meet_the_leaves_standing_round_it():
    # The 12-leaf rosette's 20 mm crown under 10 mm of range noise is a column holding its
    # inner leaves' bases, and the walk went on up them to 69 mm: 49 % of the leaves'
    # points were "stem" (1 % now). Above the crown the beams through the axis meet the
    # inner leaves all round it, farther out than the crown (segmentation.cup_stem_top).
    est, truth = _scan("rosette12", *REALISTIC)
    (stem,) = est.stems
    assert stem.height_from == "beams"
    assert stem.height_m == pytest.approx(truth["stems"][0]["height_m"], abs=0.005)
    assert any("leaves standing round it" in n for n in est.notes)
    seg = traits.segment_for_traits(*_cloud("rosette12", *REALISTIC)[:1],
                                    range_noise_m=_RANGE_NOISE[("rosette12",) + REALISTIC])
    on_leaf = procedural_leaf_labels(seg.points, PLANTS["rosette12"]()) >= 0
    assert (seg.stem_label[on_leaf] >= 0).mean() <= 0.10


@pytest.mark.parametrize("name", ["maize", "dicot", "rosette12", "maize3", "bean3"])
def test_a_noisy_stems_diameter_is_read_from_the_beams_through_the_axis(name):
    # Under the URG's 10-12 mm of range noise no ring fits these stems, and their noisy
    # columns read 21-59 mm, an upper bound. The beams through the axis meet each at its
    # front, a radius out (segmentation.beam_stem_diameter): 14.1, 7.0, 8.9, 14.1 and
    # 6.4 mm for 14, 7, 8, 14 and 7.
    est, truth = _scan(name, *REALISTIC)
    (stem,) = est.stems
    assert stem.diameter_from == "beams" and stem.diameter_resolved
    assert _rel(stem.diameter_m, truth["stem_diameter_m"]) <= 0.15


def test_a_noisy_maize_keeps_most_of_its_leaf_points_off_the_stem():
    # The column once reached 37 mm from the axis of a 14 mm stem (the noise band
    # added to a width that already held it): 52 % of the leaves' points were stem;
    # 28 % today (a leaf's base still shares the stem's level sets).
    points, _ = _cloud("maize", *REALISTIC)
    plant = PLANTS["maize"]()
    seg = traits.segment_for_traits(points)
    on_leaf = procedural_leaf_labels(seg.points, plant) >= 0
    assert (seg.stem_label[on_leaf] >= 0).mean() <= 0.35


def test_a_noisy_maize_stem_is_still_found():
    # One stray point used to make the base slices 74-106 mm wide: no stem.
    est, _ = _scan("maize", *REALISTIC)
    assert est.stem_count == 1
    assert 0.010 <= est.stem_diameter_m <= 0.05


def test_no_leaf_is_left_without_a_surface(monkeypatch):
    # Without the outlier removal the realistic wheat's skeleton grows three tip
    # branches whose shared nodes all go to longer leaves, leaving each 2 points:
    # no width, no area (NaN), and the plant's leaf area read NaN.
    from plantsim.evaluation import segmentation

    points, _ = _cloud("wheat", *REALISTIC)
    monkeypatch.setattr(segmentation, "outlier_mask", lambda p, **_: np.ones(len(p), dtype=bool))
    est = traits.extract_traits(points)
    assert est.leaf_count > 0
    assert np.isfinite(est.leaf_areas_m2).all() and np.isfinite(est.leaf_widths_m).all()
    assert est.leaf_area_m2 == pytest.approx(sum(est.leaf_areas_m2))


def _leaf_match(name: str, ideal: bool, step_deg: float):
    points, _ = _cloud(name, ideal, step_deg)
    return match_procedural_leaves(points, PLANTS[name]())


def test_an_ideal_maizes_found_leaves_are_mostly_its_true_leaves():
    # The count could be right with a leaf split and two merged: 8 of the 10 found leaves
    # share over half of their points' union with one true leaf (IoU 0.83 mean). The
    # 9 shifted grids read 9 to 11 leaves, 7 to 9 of them matched; the origin's grid on
    # the unrounded cloud read the 9 one to one.
    m = _leaf_match("maize", *IDEAL)
    assert m.true_positives >= 8 and m.false_positives <= 2 and m.false_negatives <= 1, m.summary()
    assert m.segmentation_quality >= 0.8, m.summary()


def test_an_ideal_wheats_leaves_mostly_match_its_true_leaves():
    # 14 of 16 match today (13 before a stem's axis followed only pieces that fit in its
    # column; 12 to 15 over the 9 shifted grids): a floor against regressions.
    m = _leaf_match("wheat", *IDEAL)
    assert m.true_positives >= 14, m.summary()


def test_an_ideal_maizes_leaves_are_read_their_full_length():
    # The outlier removal once dropped the sparse outer parts of the leaves, far from the
    # turntable's axis: the matched leaves read 4 to 39 % short (a 211 mm leaf 129 mm).
    # Each of the 8 matched is within 6.5 % of its true length today (5.4 % with the
    # spacing a percentile over the points, on another of the 9 grids).
    est, truth = _scan("maize", *IDEAL)
    m = _leaf_match("maize", *IDEAL)
    errors = [est.leaf_lengths_m[f] / truth["leaves"][t]["length_m"] - 1 for f, t, _ in m.pairs]
    assert len(errors) >= 8 and max(map(abs, errors)) <= 0.07, np.round(errors, 3)


def test_an_ideal_beans_leaves_are_read_without_their_petioles():
    # A simple leaf's truth is its lamina; the skeleton's branch runs from the stem through
    # the petiole. Measured whole, the three matched leaves read +54, +66 and +77 % long;
    # from the lamina's base, -35, -5 and +22 % today: where a lamina starts is known to
    # a level-set step (10-19 mm here, on 51-85 mm laminae), and an ovate lamina's base
    # is as narrow as a petiole.
    est, truth = _scan("bean3", *IDEAL)
    m = _leaf_match("bean3", *IDEAL)
    errors = [est.leaf_lengths_m[f] / truth["leaves"][t]["length_m"] - 1 for f, t, _ in m.pairs]
    assert len(errors) == 3 and max(map(abs, errors)) <= 0.40, np.round(errors, 3)


def test_an_ideal_rosettes_cup_of_touching_leaves_is_split_at_their_tips():
    # The inner leaves rise edge on edge, and the level sets hold them as one leaf until
    # their tips: the 30-leaf rosette read two leaves holding twelve true ones. Split where
    # the cup's reach round the axis has a lobe per tip (segmentation._split_petals), it
    # read 21 leaves for 30 (15 before; 16-25 over the grids, 11-22 before); split also
    # where the leaves' smooth surfaces meet at a crease (_split_smooth_surfaces), 25
    # (17-31), 8 of its laminae matched to a true leaf (3), and notes say so. (The 12-leaf
    # rosette: 14 for 12, 9 matched; 12 and 6 before.)
    est, _ = _scan("rosette30", *IDEAL)
    assert est.leaf_count >= 24
    assert any("a cup of touching leaves round the axis at their tips" in n for n in est.notes)
    assert any("where their smooth surfaces meet at a crease" in n for n in est.notes)
    m = _leaf_match("rosette30", *IDEAL)
    assert m.true_positives >= 7, m.summary()


def test_a_noisy_rosettes_leaves_merged_round_its_axis_are_its_true_leaves():
    # Under 10 mm of range noise the 3-leaf rosette's leaf bases are one disc round the
    # axis, and its leaves read as one. Given the beams, they are split by azimuth
    # (segmentation._split_at_axis): 3 on every shifted grid, each matched to its true
    # leaf (IoU 0.71 mean), the area +25 % (+15..+43 % over the grids).
    est, truth = _scan("rosette3", *REALISTIC)
    assert set(est.leaf_counts_over_grids) == {3}
    assert any("found by splitting leaves" in n for n in est.notes)
    points, _ = _cloud("rosette3", *REALISTIC)
    m = match_procedural_leaves(points, PLANTS["rosette3"](), range_noise_m=_RANGE_NOISE[("rosette3", *REALISTIC)])
    assert m.true_positives == 3 and m.false_positives == 0, m.summary()


def test_a_noisy_dicots_leaflets_are_found_apart_from_its_stem():
    # Its unresolved stem's column once reached 2.5 noise and a voxel past the noisy
    # width it was measured at, taking the leaflets' bases: 3 of 10 found leaves
    # matched a true leaflet. With the point spacing a percentile over the points (3.3 mm),
    # 4 of 13 (1 to 6 over the 9 shifted grids); with its median over the surface's area
    # (3.1 mm), 2 of 11 today: a floor against regressions.
    m = _leaf_match("dicot", *REALISTIC)
    assert m.true_positives >= 2, m.summary()


# A LAS file keeps coordinates on a 0.01 mm grid, and the segmentation cuts the cloud with
# voxels and level sets: rounded to that grid, an ideal maize read 10 leaves for the 9 it
# read in memory, a 12-leaf rosette 8 for 11. Traits are now measured on that grid.
@pytest.mark.parametrize("name, ideal, step_deg", [("maize", *IDEAL), ("rosette12", *IDEAL),
                                                   ("dicot", *REALISTIC)])
@pytest.mark.parametrize("suffix", [".las", ".ply"])
def test_the_traits_of_a_scan_read_back_from_its_file_are_its_own(tmp_path, name, ideal, step_deg, suffix):
    cloud, _ = _plant_cloud(name, ideal, step_deg)
    est, _ = _scan(name, ideal, step_deg)
    path = tmp_path / f"scan{suffix}"
    write_cloud(path, cloud, xyz_double=True)
    back = traits.extract_traits(read_cloud(path).points_turntable,
                                 range_noise_m=_RANGE_NOISE[(name, ideal, step_deg)],
                                 beam_gaps_m=_BEAM_GAPS[(name, ideal, step_deg)])
    assert (back.height_m, back.leaf_count, back.leaf_area_m2) == (est.height_m, est.leaf_count, est.leaf_area_m2)
    assert back.leaf_counts_over_grids == est.leaf_counts_over_grids


@pytest.mark.parametrize("name, ideal, step_deg", [
    *[(name, *IDEAL) for name in PLANTS], *[(name, *REALISTIC) for name in PLANTS]])
def test_a_micrometre_moves_the_traits_within_their_spread_over_the_grids(name, ideal, step_deg):
    # A micrometre's jitter (another build of the ray caster) changes a few grids' outcome;
    # the count stays within the range the grids read, and the area within theirs.
    points, truth = _cloud(name, ideal, step_deg)
    est, _ = _scan(name, ideal, step_deg)
    moved = traits.extract_traits(points + np.random.default_rng(1).uniform(-1e-6, 1e-6, points.shape),
                                  range_noise_m=_RANGE_NOISE[(name, ideal, step_deg)],
                                  beam_gaps_m=_BEAM_GAPS[(name, ideal, step_deg)])
    counts = est.leaf_counts_over_grids
    assert len(counts) == 9 and est.leaf_count == int(np.median(counts))
    assert min(counts) <= moved.leaf_count <= max(counts)
    assert abs(moved.leaf_count - est.leaf_count) <= 1
    areas = [a for a in est.leaf_areas_over_grids_m2 if np.isfinite(a)]
    if areas:
        assert min(areas) * 0.98 <= moved.leaf_area_m2 <= max(areas) * 1.02
