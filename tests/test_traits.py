"""plantsim.traits on clouds whose traits are known by construction."""

import json
import math

import numpy as np
import pytest
import trimesh

from plantsim.evaluation import metrics, traits


def _cylinder_cloud(rng, center_xy, radius, height, n, noise_m=0.0, z0=0.0):
    theta = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(z0, z0 + height, n)
    p = np.column_stack(
        [center_xy[0] + radius * np.cos(theta), center_xy[1] + radius * np.sin(theta), z]
    )
    return p + rng.normal(size=p.shape) * noise_m


def _strip(rng, length, width, n, origin=(0.0, 0.0, 0.0), direction=(1.0, 0.0, 0.0)):
    """Flat rectangle: ``length`` along ``direction`` (horizontal), ``width`` across, in z-plane."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    across = np.cross([0.0, 0.0, 1.0], d)
    u = rng.uniform(0, length, n)
    v = rng.uniform(-width / 2, width / 2, n)
    return np.asarray(origin) + u[:, None] * d + v[:, None] * across


# --------------------------------------------------------------------------
# height
# --------------------------------------------------------------------------
def test_height_is_the_top_above_the_base_or_a_percentile():
    z = np.linspace(0.1, 0.6, 1001)
    pts = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    assert traits.plant_height(pts, base_z=0.1) == pytest.approx(0.5)
    assert traits.plant_height(pts) == pytest.approx(0.6)
    assert traits.plant_height(pts, percentile=50) == pytest.approx(0.35)
    with pytest.raises(ValueError, match=r"percentile must be in \(0, 100\], got 0"):
        traits.plant_height(pts, percentile=0)


# --------------------------------------------------------------------------
# circles and stems
# --------------------------------------------------------------------------
def test_circle_fit_is_exact_on_a_circle_and_survives_a_half_arc():
    theta = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    xy = np.column_stack([0.3 + 0.006 * np.cos(theta), -0.2 + 0.006 * np.sin(theta)])
    fit = traits.fit_circle(xy)
    assert fit.center_xy == pytest.approx((0.3, -0.2), abs=1e-12)
    assert fit.radius == pytest.approx(0.006, rel=1e-9)
    rng = np.random.default_rng(0)
    half = np.linspace(0, np.pi, 200)
    arc = np.column_stack([0.006 * np.cos(half), 0.006 * np.sin(half)])
    arc += rng.normal(size=arc.shape) * 0.0001
    assert traits.fit_circle(arc).radius == pytest.approx(0.006, rel=0.03)
    with pytest.raises(ValueError, match=r"a circle needs at least 3 points, got 2"):
        traits.fit_circle(xy[:2])


def test_stem_diameter_of_a_sampled_cylinder_exact_without_noise():
    rng = np.random.default_rng(1)
    pts = _cylinder_cloud(rng, (0.01, -0.02), 0.002, 0.5, 20_000)
    (stem,) = traits.estimate_stems(pts)
    assert stem.diameter_m == pytest.approx(0.004, rel=1e-9)
    assert stem.center_xy_m == pytest.approx((0.01, -0.02), abs=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_stem_diameter_of_a_noisy_cylinder_within_five_percent(seed):
    # 0.2 mm Gaussian noise on a 4 mm wheat stem, about 400 points in the slice:
    # the geometric fit stays within 5 % (0.2 mm) of the diameter.
    rng = np.random.default_rng(seed)
    pts = _cylinder_cloud(rng, (0.0, 0.0), 0.002, 0.5, 20_000, noise_m=0.0002)
    (stem,) = traits.estimate_stems(pts)
    assert stem.diameter_m == pytest.approx(0.004, rel=0.05)
    assert stem.rms_residual_m == pytest.approx(0.0002, rel=0.3)


def test_two_and_three_stems_give_their_centre_distances():
    rng = np.random.default_rng(2)
    centres = [(0.0, 0.0), (0.042, 0.0), (0.02, 0.03)]
    pts = np.vstack([_cylinder_cloud(rng, c, 0.002, 0.4, 10_000) for c in centres])
    two = traits.extract_traits(pts[:20_000])
    assert len(two.stems) == 2
    # Traits are measured on the LAS file's 0.01 mm grid (traits.on_file_grid).
    assert two.mean_stem_distance_m == pytest.approx(0.042, abs=2e-5)
    assert two.stem_diameter_m == pytest.approx(0.004, abs=2e-5)
    three = traits.extract_traits(pts)
    c = np.array(centres)
    d = {(i, j): np.linalg.norm(c[i] - c[j]) for i in range(3) for j in range(i + 1, 3)}
    assert len(three.stems) == 3 and len(three.stem_distances) == 3
    assert three.mean_stem_distance_m == pytest.approx(np.mean(list(d.values())), abs=2e-5)
    nearest = [min(v for k, v in d.items() if i in k) for i in range(3)]
    assert three.mean_nearest_stem_distance_m == pytest.approx(np.mean(nearest), abs=2e-5)
    got = sorted(p.distance_m for p in three.stem_distances)
    assert got == pytest.approx(sorted(d.values()), abs=2e-5)


def test_each_stem_has_its_own_height(tmp_path, capsys):
    # A main culm and a tiller differ in height; the plant's stem height is the
    # tallest's, and each stem says its own (read where the walk up it stopped: no range
    # noise is given). The surface of a procedural wheat, sampled densely (no occlusion).
    from plantsim.cli.app import build_parser
    from plantsim.plant.procedural import make_wheat

    plant = make_wheat(seed=1, n_tillers=2, leaves_per_tiller=3)
    pts, _ = metrics.sample_surface(plant.vertices_m, plant.faces, 150_000, rng=0)
    t = traits.extract_traits(pts)
    truth = traits.traits_from_truth(plant.traits)
    assert len(t.stems) == len(truth.stems) == 2
    assert [st.height_m for st in truth.stems] == [st["height_m"] for st in plant.traits["stems"]]
    assert truth.stems[0].height_m != truth.stems[1].height_m
    for st in t.stems:
        (true,) = [tr for tr in truth.stems if np.hypot(*np.subtract(tr.center_xy_m, st.center_xy_m)) < 0.005]
        assert st.height_m == pytest.approx(true.height_m, rel=0.05) and st.height_from == "walk"
    assert t.stem_height_m == max(st.height_m for st in t.stems)
    # The comparison with the truth matches stems by centre and gives each one's height.
    c = traits.compare_traits(t, truth)
    for k, true in enumerate(plant.traits["stems"]):
        e = c[f"stem[{k}].height_m"]
        assert e.reference == true["height_m"] and e.relative_error <= 0.05
    # The CLI prints every stem of a plant with several.
    path = tmp_path / "tillers.ply"
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\n"
              "property float y\nproperty float z\nend_header\n" % len(pts))
    path.write_bytes(header.encode("ascii") + pts.astype("<f4").tobytes())
    out = tmp_path / "t.json"
    args = build_parser().parse_args(["traits", str(path), "-o", str(out)])
    assert args.func(args) == 0
    (line,) = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("stems: ")]
    for st in json.loads(out.read_text())["stems"]:
        assert f"{1e3 * st['height_m']:.0f} mm tall" in line


# --------------------------------------------------------------------------
# leaves
# --------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(3))
def test_a_flat_strip_leaf_gives_its_length_and_width(seed):
    rng = np.random.default_rng(seed)
    pts = _strip(rng, 0.3, 0.02, 5_000, origin=(0.0, 0.0, 0.2), direction=(1.0, 1.0, 0.0))
    length, width = traits.leaf_length_width(pts, link_distance=0.006, bin_length=0.01)
    assert length == pytest.approx(0.3, rel=0.02)
    assert width == pytest.approx(0.02, rel=0.02)


def test_a_curled_leaf_is_measured_along_its_surface():
    rng = np.random.default_rng(4)
    u = rng.uniform(0, 0.3, 5_000)
    v = rng.uniform(-0.01, 0.01, 5_000)
    radius = 0.1  # bent through 172 degrees: the chord is far shorter than the leaf
    pts = np.column_stack([radius * np.sin(u / radius), v, 0.1 + radius * (1 - np.cos(u / radius))])
    length, width = traits.leaf_length_width(pts, link_distance=0.006, bin_length=0.01)
    assert length == pytest.approx(0.3, rel=0.02)
    assert width == pytest.approx(0.02, rel=0.02)


def test_a_stem_with_two_leaves_is_taken_apart():
    rng = np.random.default_rng(5)
    r = 0.006
    stem = _cylinder_cloud(rng, (0.0, 0.0), r, 0.4, 30_000)
    leaf_a = _strip(rng, 0.25, 0.018, 6_000, origin=(r, 0.0, 0.15), direction=(1.0, 0.0, 0.0))
    leaf_b = _strip(rng, 0.20, 0.030, 6_000, origin=(-r, 0.0, 0.30), direction=(-1.0, 0.2, 0.0))
    pts = np.vstack([stem, leaf_a, leaf_b])
    t = traits.extract_traits(pts)
    assert len(t.stems) == 1
    assert t.stems[0].diameter_m == pytest.approx(2 * r, abs=2e-5)  # on the 0.01 mm grid
    assert len(t.leaves) == 2
    by_width = sorted(t.leaves, key=lambda lf: lf.width_m)
    # The level-set skeleton measures each leaf from where it leaves the stem's skeleton
    # (a few mm inside the stem surface) and its width from the cross-section spread:
    # lengths within 10 %, widths within 6 % on this sampling (0.25 m and 0.20 m strips
    # read 0.254 m and 0.217 m; 18 mm and 30 mm read 17.3 mm and 28.7 mm).
    assert by_width[0].length_m == pytest.approx(0.25, rel=0.10)
    assert by_width[0].width_m == pytest.approx(0.018, rel=0.06)
    assert by_width[1].length_m == pytest.approx(0.20, rel=0.10)
    assert by_width[1].width_m == pytest.approx(0.030, rel=0.06)
    assert t.leaf_width_m == by_width[1].width_m
    assert t.height_m == pytest.approx(0.4, abs=1e-3)


def _stem_with(rng, *leaves, height=0.4):
    return np.vstack([_cylinder_cloud(rng, (0.0, 0.0), 0.006, height, 30_000), *leaves])


def test_a_leaf_whose_middle_band_is_hidden_stays_one_leaf():
    # A band along the middle of a leaf that no view sees (a leaf below shades it)
    # cuts it into two parallel halves, each with its own tip: 45 mm wide, 16 mm
    # hidden. They lie side by side in one plane, so they are one leaf, and the
    # leaf's width and area span the hidden band.
    rng = np.random.default_rng(7)
    leaf = _strip(rng, 0.25, 0.045, 12_000, origin=(0.006, 0.0, 0.2))
    leaf = leaf[np.abs(leaf[:, 1]) > 0.008]
    t = traits.extract_traits(_stem_with(rng, leaf))
    assert t.leaf_count == 1
    assert t.leaf_widths_m[0] == pytest.approx(0.045, rel=0.06)
    assert t.leaf_area_m2 == pytest.approx(0.25 * 0.045, rel=0.10)


def test_stacked_leaves_and_leaflets_side_by_side_stay_apart():
    rng = np.random.default_rng(8)
    # Two leaves one above the other, 12 mm apart: parallel and level, but the
    # offset is along their normal.
    lower = _strip(rng, 0.22, 0.03, 6_000, origin=(0.006, 0.0, 0.20))
    upper = _strip(rng, 0.22, 0.03, 6_000, origin=(0.006, 0.0, 0.212))
    assert traits.extract_traits(_stem_with(rng, lower, upper)).leaf_count == 2
    # Two parallel leaflets in one plane, on stalks to either side: 70 mm apart and
    # 180 mm long, side by side but not three times as long as they are apart: not the
    # halves of one leaf.
    organs = []
    for side in (-1.0, 1.0):
        organs.append(_strip(rng, 0.03, 0.004, 1_000, origin=(0.0, 0.005 * side, 0.2),
                             direction=(0.0, side, 0.0)))
        organs.append(_strip(rng, 0.18, 0.03, 7_000, origin=(-0.002, 0.035 * side, 0.2)))
    assert traits.extract_traits(_stem_with(rng, *organs, height=0.3)).leaf_count == 2

def test_a_stem_split_lengthwise_by_a_hidden_band_is_one_stem_to_its_top():
    # A leaf wrapped round a stem hides two bands of it from every view over a
    # stretch: there the stem's level sets are two half-rings side by side. The
    # stem goes on up through both; its top is its own (0.4 m), and no "leaf" is
    # made of the stem's upper part (a maize read 10 leaves for 9, its longest
    # leaf 0.48 m for 0.39 m and its stem 0.24 m for 0.42 m).
    rng = np.random.default_rng(9)
    r = 0.006
    stem = _cylinder_cloud(rng, (0.0, 0.0), r, 0.4, 30_000)
    azimuth = np.arctan2(stem[:, 1], stem[:, 0])
    hidden = ((stem[:, 2] > 0.15) & (stem[:, 2] < 0.25)
              & (np.abs(np.sin(azimuth)) < np.sin(np.radians(40.0))))
    stem = stem[~hidden]
    leaf_a = _strip(rng, 0.20, 0.03, 6_000, origin=(0.0, r, 0.12), direction=(0.0, 1.0, 0.0))
    leaf_b = _strip(rng, 0.20, 0.03, 6_000, origin=(0.0, -r, 0.30), direction=(0.0, -1.0, 0.0))
    t = traits.extract_traits(np.vstack([stem, leaf_a, leaf_b]))
    assert t.stem_count == 1
    assert t.stem_height_m == pytest.approx(0.4, abs=0.01)
    assert t.leaf_count == 2
    assert max(t.leaf_lengths_m) == pytest.approx(0.20, rel=0.10)


@pytest.mark.parametrize("gap", [0.008, 0.012, "slanted"])
@pytest.mark.parametrize("seed", [0, 1])
def test_a_lone_scan_line_beside_a_leaf_is_not_a_leaf(seed, gap):
    # A leaf seen at a grazing angle (a rosette's outer leaves from the side) is
    # sampled in scan lines a centimetre apart; a stretch of one line falls apart from
    # its leaf and is bridged to the graph as a branch of its own. It made a third
    # "leaf" here, of no area; a leaf is a surface, and the line joins what it hangs from.
    rng = np.random.default_rng(seed)
    r = 0.004
    stem = _cylinder_cloud(rng, (0.0, 0.0), r, 0.25, 20_000)
    leaf_a = _strip(rng, 0.12, 0.03, 8_000, origin=(r, 0.0, 0.10), direction=(1.0, 0.0, 0.0))
    leaf_b = _strip(rng, 0.12, 0.03, 8_000, origin=(-r, 0.0, 0.18), direction=(-1.0, 0.0, 0.0))
    x = np.arange(0.05, 0.11, 0.0004)  # 6 cm of one line, beside leaf a's edge
    # Slanted: 12 mm off at the stem end, 7 mm at the far end, where its shortest link
    # to the leaf is. Hung by that end alone, its near end lay 0.18 m from the stem
    # along the graph, past the leaf's tip, and the line was taken for the leaf.
    y = 0.015 + (np.interp(x, [0.05, 0.11], [0.012, 0.007]) if gap == "slanted" else np.full_like(x, gap))
    line = np.column_stack([x, y, np.full_like(x, 0.10)])
    t = traits.extract_traits(np.vstack([stem, leaf_a, leaf_b, line]))
    assert t.leaf_count == 2
    # Where the line joins leaf a it can lengthen it too: the two leaves read 0.123 to
    # 0.145 m over the 9 shifted grids (0.124 m with the junction inside the stem).
    for length in t.leaf_lengths_m:
        assert length == pytest.approx(0.125, rel=0.15)
    # The line joins leaf a's cross-sections and widens them (its width reads 35-43 mm
    # for 30): that leaf's area reads up to 16 % large; the other leaf's is its own.
    clean, joined = sorted(t.leaf_areas_m2)
    assert clean == pytest.approx(0.12 * 0.03, rel=0.06)
    assert joined == pytest.approx(0.12 * 0.03, rel=0.20)


def _flared_stem(rng, r, r_base, flare_height, height, n):
    """A stem of radius ``r`` widening to ``r_base`` at the soil over its lowest ``flare_height``."""
    z = rng.uniform(0.0, height, n)
    radius = np.where(z < flare_height, r + (r_base - r) * (1.0 - z / flare_height) ** 2, r)
    theta = rng.uniform(0.0, 2.0 * np.pi, n)
    return np.column_stack([radius * np.cos(theta), radius * np.sin(theta), z])


@pytest.mark.parametrize("seed", range(3))
def test_a_stem_diameter_is_read_above_its_basal_flare(seed):
    # A maize stem widens into its root collar: 25 mm at the soil, 14 mm from 3 cm up
    # (the seed rig's maize measured so). Read over the base slices it was 18 mm here,
    # and 20.7 mm on the seed rig's maize against the paper's hand-measured 12.5 mm.
    rng = np.random.default_rng(seed)
    r = 0.007
    stem = _flared_stem(rng, r, 0.0125, 0.03, 0.4, 60_000)
    leaves = [_strip(rng, 0.2, 0.03, 5_000, origin=(r * np.cos(a), r * np.sin(a), z),
                     direction=(np.cos(a), np.sin(a), 0.0))
              for z, a in ((0.15, 0.0), (0.25, 2.5), (0.33, 4.4))]
    t = traits.extract_traits(np.vstack([stem, *leaves]))
    (found,) = t.stems
    assert found.diameter_resolved
    assert found.diameter_m == pytest.approx(2 * r, rel=0.05)
    assert t.leaf_count == 3


def _rising_leaf(rng, azimuth, elevation_deg, z, length, width, n, r):
    """A strip leaving a stem of radius ``r`` at height ``z``, rising at ``elevation_deg``,
    narrow at its base (a third of ``width``) and full width from 30 % of its length."""
    e = np.radians(elevation_deg)
    along = np.array([np.cos(azimuth) * np.cos(e), np.sin(azimuth) * np.cos(e), np.sin(e)])
    across = np.array([-np.sin(azimuth), np.cos(azimuth), 0.0])
    u, v = rng.uniform(0.0, length, n), rng.uniform(-0.5, 0.5, n)
    w = width * np.minimum(1.0, 0.3 + u / (0.3 * length))
    base = np.array([r * np.cos(azimuth), r * np.sin(azimuth), z])
    return base + u[:, None] * along + (v * w)[:, None] * across


@pytest.mark.parametrize("seed", range(4))
def test_a_leaf_cut_off_from_its_stem_is_bridged_to_the_stem_not_to_a_leaf_tip_below_it(seed):
    # Leaves hide a stem's sides above 0.15 m and its -y half above 0.24 m: the top
    # leaf (at 0.33 m, toward -y) lies 12 mm from the stem's last visible half, a
    # component of its own. A steep narrow leaf below ends 29 mm under it. The graph
    # bridged the top leaf both ways, and the steep tip's path to its outer part was
    # the shorter: the leaf fell in two, one "leaf" 0.45 m long (seed 1).
    rng = np.random.default_rng(seed)
    r = 0.007
    stem = _cylinder_cloud(rng, (0.0, 0.0), r, 0.42, 40_000)
    azimuth, z = np.arctan2(stem[:, 1], stem[:, 0]), stem[:, 2]
    hidden = (z > 0.15) & (np.abs(np.cos(azimuth)) > np.cos(np.radians(50.0)))
    hidden |= (z > 0.24) & (stem[:, 1] < 0)
    leaves = [_rising_leaf(rng, np.pi / 2, 20.0, 0.15, 0.25, 0.05, 6000, r),
              _rising_leaf(rng, -np.pi / 2, 30.0, 0.33, 0.25, 0.05, 6000, r),
              _rising_leaf(rng, -np.pi / 2 - 0.5, 60.0, 0.19, 0.20, 0.006, 1500, r)]
    t = traits.extract_traits(np.vstack([stem[~hidden], *leaves]))
    assert t.stem_count == 1 and t.leaf_count == 3
    # Lengths from the stem's axis: each leaf's own plus the stem radius, and the
    # first centimetre of the junction's level set.
    assert sorted(t.leaf_lengths_m) == pytest.approx([0.20, 0.25, 0.25], abs=0.04)
    assert sorted(t.leaf_areas_m2)[1:] == pytest.approx([0.25 * 0.05 * 0.9] * 2, rel=0.15)


@pytest.mark.parametrize("seed", range(4))
def test_a_rosette_crown_is_one_stem_on_the_axis_not_its_steep_leaves(seed):
    # A rosette's stem is a crown 2 cm tall; its inner leaves rise from the crown's top
    # at 60-65 degrees, and each is a compact column in the slices above it. Those
    # columns made 2-4 "stems" 15-20 mm wide here (and 4 on the procedural rosettes);
    # a stem rises from the base, slice after slice, with a ring that changes slowly.
    rng = np.random.default_rng(seed)
    r = 0.004
    crown = _cylinder_cloud(rng, (0.0, 0.0), r, 0.02, 300)
    leaves = [_rising_leaf(rng, a, elevation, 0.018, length, 0.02, 700, r)
              for a, elevation, length in ((0.0, 65.0, 0.06), (2.4, 65.0, 0.06), (4.4, 60.0, 0.07),
                                           (1.2, 25.0, 0.09), (3.5, 20.0, 0.10), (5.4, 25.0, 0.09))]
    t = traits.extract_traits(np.vstack([crown, *leaves]))
    (stem,) = t.stems
    assert np.hypot(*stem.center_xy_m) < 0.001
    assert stem.diameter_m == pytest.approx(2 * r, rel=0.20) and stem.diameter_resolved
    assert 5 <= t.leaf_count <= 6


def _beam_noise(rng, pts, sigma, lidar_distance=0.35, lidar_height=0.15):
    """Range noise as a turntable LiDAR makes it: every beam lies in a vertical plane
    through the axis (the fan), so a point moves along its own azimuth, rising or
    falling as the beam from a LiDAR at (``lidar_distance``, ``lidar_height``) does."""
    phi = np.arctan2(pts[:, 1], pts[:, 0])
    elev = np.arctan2(pts[:, 2] - lidar_height, lidar_distance - np.hypot(pts[:, 0], pts[:, 1]))
    e = rng.normal(0.0, sigma, len(pts))
    return pts + e[:, None] * np.column_stack([np.cos(elev) * np.cos(phi), np.cos(elev) * np.sin(phi), np.sin(elev)])


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("length, sigma", [(0.06, 0.008), (0.07, 0.010)])
def test_short_sparse_leaves_on_a_noisy_stem_column_are_leaves(seed, length, sigma):
    # A 7 mm stem seen by a noisy LiDAR fills a column several centimetres wide and
    # holds most of the points; short leaves (as a bean's leaflets) leave it with a few
    # hundred points each. The level sets put most of each leaf in the column's pieces,
    # so its branch past them is shorter than a leaf's minimum; its tip lies well out
    # of the column, so it is a leaf all the same (three, not 0-2).
    rng = np.random.default_rng(seed)
    r = 0.0035
    stem = _cylinder_cloud(rng, (0.0, 0.0), r, 0.35, 40_000)
    leaves = [_strip(rng, length, 0.025, 400, origin=(r * np.cos(a), r * np.sin(a), z),
                     direction=(np.cos(a), np.sin(a), 0.0))
              for z, a in ((0.14, 0.0), (0.21, 2.1), (0.28, 4.2))]
    t = traits.extract_traits(_beam_noise(rng, np.vstack([stem, *leaves]), sigma))
    assert t.stem_count == 1
    assert t.leaf_count == 3
    # The beams run along these leaves (each lies in the fan's plane at its azimuth), so
    # the range noise moves their tips' points out along them: read up to about 2 sigma
    # long (0.067-0.091 m today for 0.06 and 0.07), never short.
    for got in t.leaf_lengths_m:
        assert 0.9 * length <= got <= length + 2.5 * sigma


@pytest.mark.parametrize("seed", range(4))
def test_a_thin_noisy_stem_with_leaves_rising_from_its_base_is_one_stem_on_its_axis(seed):
    # A 4 mm stem (a wheat culm) seen through 8 mm of range noise is a disc centimetres
    # wide in the base slices, and three leaves leaving it low at 20 degrees join that
    # disc there as bands: the slice cluster is too wide for a stem, and a band's own
    # mean moves 4-5 cm from one slice to the next. The stem is the dense core that
    # stays put (the old rule found none in three seeds of four, or a leaf band).
    rng = np.random.default_rng(seed)
    r = 0.002
    stem = _cylinder_cloud(rng, (0.0, 0.0), r, 0.45, 30_000)
    leaves = []
    for z, a in ((0.015, 0.3), (0.03, 2.4), (0.045, 4.4)):
        along = np.array([np.cos(a), np.sin(a), np.tan(np.radians(20.0))])
        across = np.array([-np.sin(a), np.cos(a), 0.0])
        u, v = rng.uniform(0.0, 0.15, 1500), rng.uniform(-0.005, 0.005, 1500)
        leaves.append(np.array([r * np.cos(a), r * np.sin(a), z]) + u[:, None] * along + v[:, None] * across)
    plant = np.vstack([stem, *leaves])
    t = traits.extract_traits(_beam_noise(rng, plant, 0.008))
    (found,) = t.stems
    assert np.hypot(*found.center_xy_m) < 0.003
    # The noise hides the 4 mm: the diameter is said to be an upper bound, not a measure.
    assert found.diameter_m > 0.004
    assert not found.diameter_resolved
    assert any("diameter not resolved" in note for note in t.notes)
    # Without the noise the same stem is a ring: measured, and nothing is said of it.
    # (A leaf band may still pass for a second, wider stem there: not asserted.)
    clean = traits.extract_traits(plant)
    (axis,) = [s for s in clean.stems if np.hypot(*s.center_xy_m) < 0.001]
    assert axis.diameter_m == pytest.approx(0.004, rel=0.05) and axis.diameter_resolved


# --------------------------------------------------------------------------
# volume and area
# --------------------------------------------------------------------------
def test_convex_hull_volume_of_a_sampled_box():
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    v = np.asarray(box.vertices) + [0.0, 0.0, 0.15]
    samples, _ = metrics.sample_surface(v, box.faces, 5_000, rng=0)
    pts = np.vstack([samples, v])  # the corners make the hull exact
    assert traits.convex_hull_volume(pts) == pytest.approx(0.006, rel=1e-9)
    assert traits.convex_hull_volume(samples) == pytest.approx(0.006, rel=0.05)
    assert math.isnan(traits.convex_hull_volume(np.zeros((3, 3))))
    flat = np.column_stack([np.random.default_rng(0).random((10, 2)), np.zeros(10)])
    assert math.isnan(traits.convex_hull_volume(flat))


def test_projected_area_of_a_filled_square():
    g = np.arange(0.0005, 0.1, 0.001)
    xx, yy = np.meshgrid(g, g)
    pts = np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, 0.2)])
    assert traits.projected_area_xy(pts, cell=0.005) == pytest.approx(0.01, rel=1e-9)
    with pytest.raises(ValueError, match=r"cell must be > 0 metres, got 0"):
        traits.projected_area_xy(pts, cell=0)


# --------------------------------------------------------------------------
# truth and errors
# --------------------------------------------------------------------------
def _truth():
    return {
        "height_m": 0.555,
        "stem_diameter_m": 0.004,
        "stems": [
            {"index": 0, "base_xy_m": [0.0, 0.0], "diameter_m": 0.004, "height_m": 0.55,
             "top_xyz_m": [0.0, 0.0, 0.55]},
            {"index": 1, "base_xy_m": [0.042, 0.0], "diameter_m": 0.004, "height_m": 0.5,
             "top_xyz_m": [0.04, 0.0, 0.5]},
        ],
        "stem_distances_m": [{"stems": [0, 1], "distance_m": 0.042}],
        "mean_stem_distance_m": 0.042,
        "leaves": [
            {"index": 0, "stem": 0, "insertion_height_m": 0.1, "length_m": 0.2, "width_m": 0.008,
             "area_m2": 0.0012},
            {"index": 1, "stem": 1, "insertion_height_m": 0.15, "length_m": 0.25, "width_m": 0.01,
             "area_m2": 0.0018},
        ],
        "leaf_width_m": 0.01,
        "leaf_length_m": 0.25,
        "leaf_area_m2": 0.003,
    }


def test_traits_from_truth_reads_the_schema():
    t = traits.traits_from_truth(_truth())
    assert t.height_m == 0.555
    assert [s.center_xy_m for s in t.stems] == [(0.0, 0.0), (0.042, 0.0)]
    assert t.stem_diameter_m == pytest.approx(0.004)
    assert t.mean_stem_distance_m == pytest.approx(0.042)
    assert t.leaf_width_m == 0.01 and t.leaf_length_m == 0.25
    assert len(t.leaves) == 2
    assert math.isnan(t.convex_hull_volume_m3)
    assert json.loads(json.dumps(t.to_dict()))["height_m"] == 0.555


def test_traits_from_truth_validation():
    bad = _truth()
    del bad["height_m"]
    # A missing key is skipped (issue 13): height is NaN and not compared.
    assert math.isnan(traits.traits_from_truth(bad).height_m)
    bad = _truth()
    bad["leaves"][1]["width_m"] = "wide"
    with pytest.raises(ValueError, match=r"truth\['leaves'\]\[1\]\['width_m'\] must be a number, got 'wide'"):
        traits.traits_from_truth(bad)
    with pytest.raises(ValueError, match=r"truth must be a dict parsed from the traits JSON, got list"):
        traits.traits_from_truth([])


def test_errors_are_absolute_and_relative_as_in_the_paper():
    # The paper's Table I, wheat at 1 degree: stem diameter S = 5.00 mm against R = 4.00 mm.
    e = traits.trait_error("stem_diameter_m", 0.005, 0.004)
    assert e.absolute_error == pytest.approx(0.001)
    assert e.relative_error == pytest.approx(0.25)
    assert traits.trait_error("height_m", 0.442, 0.555).relative_error == pytest.approx(0.2036, abs=1e-4)
    assert math.isnan(traits.trait_error("offset", 0.001, 0.0).relative_error)


def test_compare_a_scan_against_the_truth():
    rng = np.random.default_rng(6)
    pts = np.vstack([
        _cylinder_cloud(rng, (0.0005, 0.0), 0.0025, 0.5, 10_000),
        _cylinder_cloud(rng, (0.047, 0.0), 0.0025, 0.45, 10_000),
    ])
    estimate = traits.extract_traits(pts)
    c = traits.compare_traits(estimate, traits.traits_from_truth(_truth()))
    # Within a voxel (2 mm): sampled evenly, the column on the axis holds fewer points a
    # voxel than a turntable scan puts there, and is asked for as many
    # (traits.axis_crowding): its partly filled top voxel does not count, and the
    # height, from the voxel below, reads 1.0 mm low.
    assert c["height_m"].estimate == pytest.approx(0.5, abs=2e-3)
    assert c["height_m"].relative_error == pytest.approx(abs(c["height_m"].estimate - 0.555) / 0.555, abs=1e-12)
    # The cloud is measured on the LAS file's 0.01 mm grid (traits.on_file_grid).
    assert c["stem_diameter_m"].relative_error == pytest.approx(0.25, abs=5e-3)
    assert c["mean_stem_distance_m"].absolute_error == pytest.approx(0.0045, abs=2e-5)
    assert c["stem[1].center_offset_m"].absolute_error == pytest.approx(0.005, abs=2e-5)
    assert c["stem[0].diameter_m"].relative_error == pytest.approx(0.25, abs=5e-3)
    # The counts are (estimate, truth). (The skeleton reads the two bare stems' upper
    # parts as two stem-wide "leaves": a known defect, issue 13, not pinned here.)
    assert c.n_stems == (2, 2) and c.n_leaves == (len(estimate.leaves), 2)
    # A trait the truth does not give is skipped, not compared.
    with pytest.raises(KeyError, match="no error for 'convex_hull_volume_m3'"):
        c["convex_hull_volume_m3"]
    d = c.to_dict()
    assert json.loads(json.dumps(d)) == d


def test_traits_from_mesh_of_a_cylinder():
    cyl = trimesh.creation.cylinder(radius=0.006, height=0.4, sections=64)
    v = np.asarray(cyl.vertices) + [0.0, 0.0, 0.2]
    t = traits.traits_from_mesh(v, cyl.faces, n_samples=50_000, rng=0)
    assert t.height_m == pytest.approx(0.4, abs=1e-12)
    # A 64-gon reads a hair smaller than its circumscribed circle.
    assert t.stem_diameter_m == pytest.approx(0.012, rel=0.005)
    assert t.convex_hull_volume_m3 == pytest.approx(cyl.volume * (0.4 - 0.005) / 0.4, rel=0.02)


# --------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------
def test_settings_and_cloud_validation():
    with pytest.raises(ValueError, match=r"stem_slice_thickness must be a finite number > 0 metres, got 0"):
        traits.TraitSettings(stem_slice_thickness=0)
    with pytest.raises(ValueError, match=r"height_percentile must be in \(0, 100\], got 101"):
        traits.TraitSettings(height_percentile=101)
    with pytest.raises(ValueError, match=r"leaf_min_points must be an int >= 3, got 2"):
        traits.TraitSettings(leaf_min_points=2)
    with pytest.raises(TypeError):
        traits.TraitSettings(0.0)  # keyword-only
    with pytest.raises(ValueError, match=r"points_turntable is empty \(shape \(0, 3\)\)"):
        traits.extract_traits(np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"points_turntable holds 1 non-finite rows"):
        traits.extract_traits(np.array([[0.0, 0.0, np.nan], [0.0, 0.0, 0.1]]))


def test_a_cloud_with_no_stem_in_the_slice_gives_nan_not_zero():
    rng = np.random.default_rng(7)
    pts = _strip(rng, 0.2, 0.02, 2_000, origin=(0.0, 0.0, 0.3))
    t = traits.extract_traits(pts)
    assert t.stems == () and math.isnan(t.stem_diameter_m) and math.isnan(t.mean_stem_distance_m)
    # "No stem" is said honestly, with the scale it was judged at.
    assert any(note.startswith("no stem: no compact column persists") for note in t.notes)
    assert t.height_m == pytest.approx(0.3)
    # A flat strip spans no volume and, seen from its own lowest points, has no branch:
    # both NaNs carry a note.
    assert math.isnan(t.convex_hull_volume_m3) and math.isnan(t.leaf_area_m2) and t.leaf_count == 0
    assert any(note.startswith("convex hull volume NaN: the points above the ground clearance are flat")
               for note in t.notes)
    assert any(note.startswith("no leaf:") and "lowest points" in note for note in t.notes)


def test_a_bare_stem_has_no_leaf_and_says_so():
    # A 0.4 m stem with nothing on it: one stem, no leaf. Leaf area is NaN (not
    # measured), never 0 (measured bare), and a note says why, with the length a
    # branch needed (10 % of the height).
    rng = np.random.default_rng(1)
    t = traits.extract_traits(_cylinder_cloud(rng, (0.0, 0.0), 0.004, 0.4, 20_000))
    assert t.stem_count == 1 and t.leaf_count == 0
    assert math.isnan(t.leaf_area_m2) and math.isnan(t.leaf_length_m) and math.isnan(t.leaf_width_m)
    (note,) = [n for n in t.notes if n.startswith("no leaf:")]
    assert "reaches 40 mm (the shortest leaf counted) beyond the stem" in note
    # A stem with one leaf says nothing of the kind.
    leaf = _strip(rng, 0.12, 0.02, 3_000, origin=(0.004, 0.0, 0.25))
    t = traits.extract_traits(np.vstack([_cylinder_cloud(rng, (0.0, 0.0), 0.004, 0.4, 20_000), leaf]))
    assert t.leaf_count == 1 and not any(n.startswith("no leaf") for n in t.notes)


def test_a_flat_clouds_hull_failure_is_logged_in_one_line(caplog):
    pts = np.column_stack([np.random.default_rng(2).uniform(0, 0.1, (300, 2)), np.full(300, 0.2)])
    with caplog.at_level("WARNING", logger="plantsim.evaluation.traits"):
        assert math.isnan(traits.convex_hull_volume(pts))
    (record,) = caplog.records
    assert record.getMessage().startswith("convex hull failed (flat or degenerate cloud), volume is NaN: QH")
    assert "\n" not in record.getMessage()


def test_a_straight_slice_component_is_not_taken_for_a_stem(caplog):
    # A leaf blade crossing the slice edge-on: a straight segment of points fits only
    # an enormous circle; it must not become a stem.
    x = np.linspace(0.0, 0.03, 60)
    blade = np.column_stack([x, 0.0005 * np.sin(40 * x), np.full_like(x, 0.02)])
    rng = np.random.default_rng(8)
    stem = _cylinder_cloud(rng, (0.1, 0.1), 0.003, 0.1, 3_000)
    with caplog.at_level("INFO", logger="plantsim.evaluation.traits"):
        stems = traits.estimate_stems(np.vstack([blade, stem]))
    assert len(stems) == 1 and stems[0].diameter_m == pytest.approx(0.006, rel=1e-6)
    assert "is no stem" in caplog.text


def test_truth_aggregates_follow_one_definition_and_disagreement_is_logged(caplog):
    truth = _truth()
    truth["leaf_width_m"] = 0.009  # say, a mean over leaves rather than the largest
    with caplog.at_level("WARNING", logger="plantsim.evaluation.traits"):
        t = traits.traits_from_truth(truth)
    assert t.leaf_width_m == 0.01
    assert "truth['leaf_width_m'] = 0.009 differs from 0.01" in caplog.text


def test_traits_from_mesh_of_a_stem_with_a_flat_leaf():
    cyl = trimesh.creation.cylinder(radius=0.006, height=0.4, sections=48)
    cyl.apply_translation([0.0, 0.0, 0.2])
    leaf = trimesh.creation.box(extents=(0.25, 0.02, 0.001))
    leaf.apply_translation([0.006 + 0.125, 0.0, 0.2])
    mesh = trimesh.util.concatenate([cyl, leaf])
    t = traits.traits_from_mesh(mesh.vertices, mesh.faces, n_samples=100_000, rng=0)
    assert len(t.stems) == 1 and len(t.leaves) == 1
    # Measured from the stem's skeleton: the blade's 0.25 m plus part of the stem radius.
    assert t.leaf_length_m == pytest.approx(0.25, rel=0.03)
    # The box's 1 mm sides put 5 % of the samples on its margins, where a uniformly
    # sampled strip (the width's model: segmentation.uniform_width) has none: 4 % wide.
    assert t.leaf_width_m == pytest.approx(0.02, rel=0.05)


@pytest.mark.parametrize("seed", range(6))
def test_a_noisy_stem_reads_no_taller_than_the_plant(seed):
    # A 0.35 m stem under 10 mm of beam noise: its top is read by the plant height's own
    # robust rule, so it is within 2 % of the truth and never above the plant's height
    # (the top skeleton piece's centroid read up to 3.6 mm above it in two seeds of six).
    rng = np.random.default_rng(seed)
    r = 0.0035
    stem = _cylinder_cloud(rng, (0.0, 0.0), r, 0.35, 40_000)
    leaves = [_strip(rng, 0.07, 0.025, 400, origin=(r * np.cos(a), r * np.sin(a), z),
                     direction=(np.cos(a), np.sin(a), 0.0))
              for z, a in ((0.14, 0.0), (0.21, 2.1), (0.28, 4.2))]
    t = traits.extract_traits(_beam_noise(rng, np.vstack([stem, *leaves]), 0.010))
    assert t.stem_height_m <= t.height_m
    assert t.stem_height_m == pytest.approx(0.35, rel=0.02)


def _rod(rng, start, direction, length, radius, n):
    """Points on a round rod (a petiole) from ``start`` along ``direction``."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    a = np.cross(d, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(d, a)
    t, phi = rng.uniform(0.0, length, n), rng.uniform(0.0, 2 * np.pi, n)
    return (np.asarray(start) + t[:, None] * d
            + radius * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b))


def test_a_midrib_ending_past_its_points_is_measured_not_refused():
    # A 100 x 20 mm strip whose midrib runs on to 0.3 m: no point is nearest its last
    # node. Its length is the midrib's, with no reach past the last node (this raised
    # numpy's "zero-size array" error before).
    rng = np.random.default_rng(0)
    pts = _strip(rng, 0.1, 0.02, 500)
    midrib = np.array([[0.0, 0.0, 0.0], [0.03, 0.0, 0.0], [0.06, 0.0, 0.0], [0.09, 0.0, 0.0], [0.30, 0.0, 0.0]])
    length, width, area, incl = traits._leaf_measures(pts, midrib)[:4]
    assert length == pytest.approx(0.30)
    assert width == pytest.approx(0.02, rel=0.1)
    assert incl == pytest.approx(0.0)


def test_a_leaf_on_a_petiole_is_measured_from_its_lamina():
    # Three 80 x 40 mm laminae, each at the end of a 60 mm petiole 3 mm thick: the leaf a
    # plant scientist measures (and the procedural dicots' truth) is the lamina. The
    # skeleton's branch runs from the stem through the petiole; measured whole, each leaf
    # read 0.14 m long. The petiole's nodes read under a fifth of the lamina's width; the
    # lamina then reads 0.085-0.103 m (where it starts is known to half a node, and the
    # midrib's level sets wander a little across the strip).
    rng = np.random.default_rng(3)
    r = 0.0035
    parts = [_cylinder_cloud(rng, (0.0, 0.0), r, 0.35, 30_000)]
    for z, a in ((0.14, 0.0), (0.21, 2.1), (0.28, 4.2)):
        d = (np.cos(a), np.sin(a), 0.0)
        start = np.array([r * d[0], r * d[1], z])
        parts.append(_rod(rng, start, d, 0.06, 0.0015, 900))
        parts.append(_strip(rng, 0.08, 0.04, 4000, origin=start + 0.06 * np.asarray(d), direction=d))
    t = traits.extract_traits(np.vstack(parts))
    assert t.leaf_count == 3
    for leaf in t.leaves:
        assert 0.95 * 0.08 <= leaf.length_m <= 0.08 + 0.5 * 0.06
        assert leaf.width_m == pytest.approx(0.04, rel=0.10)
        assert leaf.area_m2 == pytest.approx(0.08 * 0.04, rel=0.15)
        assert abs(leaf.inclination_deg) < 5.0


# --------------------------------------------------------------------------
# leaf widths against the range noise
# --------------------------------------------------------------------------
def _leaf_under_beam_noise(rng, sigma_m, beam_dir, width_m=0.040):
    """A stem with one flat 40 mm leaf (horizontal, along +x, 0.2 m up) whose points the
    range noise moved along ``beam_dir`` (every beam parallel): the cloud and each
    point's noise vector, the stem's noise-free."""
    stem = _cylinder_cloud(rng, (0.0, 0.0), 0.006, 0.4, 30_000)
    leaf = _strip(rng, 0.25, width_m, 12_000, origin=(0.006, 0.0, 0.2))
    d = np.asarray(beam_dir, float) / np.linalg.norm(beam_dir)
    leaf = leaf + rng.normal(0.0, sigma_m, len(leaf))[:, None] * d
    noise = np.vstack([np.zeros_like(stem), np.tile(sigma_m * d, (len(leaf), 1))])
    return np.vstack([stem, leaf]), noise


@pytest.mark.parametrize("seed", range(2))
def test_a_leaf_widened_by_noise_in_its_plane_is_flagged_not_one_with_noise_along_its_normal(seed):
    # 8 mm of range noise on a 40 mm leaf. Beams crossing the leaf in its plane
    # (across the midrib) move its points across: it reads about 1.36 times as wide, and
    # the noise alone reads 33 mm across it, over half that: not resolved. Beams along
    # its normal move the points out of its plane: the width stays, the noise reads
    # nothing across it: resolved. Without the noise vectors nothing is claimed.
    rng = np.random.default_rng(seed)
    pts, noise = _leaf_under_beam_noise(rng, 0.008, (0.0, 1.0, 0.0))
    t = traits.extract_traits(pts, range_noise_m=noise)
    (leaf,) = t.leaves
    assert leaf.width_m == pytest.approx(1.36 * 0.040, rel=0.10)
    # 4.11 sigma, read across the midrib as the skeleton's nodes see it (their tangents
    # wobble a few degrees in the noise: 3 % less).
    assert leaf.noise_width_m == pytest.approx(4.11 * 0.008, rel=0.06)
    assert leaf.width_resolved is False
    (note,) = [n for n in t.notes if n.startswith("leaf widths not resolved")]
    assert f"reads {round(1e3 * leaf.noise_width_m)} mm across 1 of 1 leaves" in note
    assert "100 % of the leaf area" in note
    assert traits.extract_traits(pts).leaves[0].width_resolved is None
    # Every beam runs along the width: no plane across them explains the points' spread
    # along them as noise, and nothing is read across them.
    assert leaf.width_across_beams_share == 0.0
    assert not [n for n in t.notes if n.startswith("leaf widths read across the beams")]

    pts, noise = _leaf_under_beam_noise(rng, 0.008, (0.0, 0.0, 1.0))
    t = traits.extract_traits(pts, range_noise_m=noise)
    # (The clean stem above a leaf noisy out of its plane can come out as a second,
    # 12 mm "leaf": the segmentation's, not what is tested here.)
    leaf = max(t.leaves, key=lambda lf: lf.width_m)
    assert all(lf.width_resolved is True for lf in t.leaves)
    assert leaf.width_m == pytest.approx(0.040, rel=0.06)
    assert leaf.noise_width_m < 0.05 * leaf.width_m
    assert leaf.width_resolved is True
    assert not [n for n in t.notes if n.startswith("leaf widths not resolved")]


def test_a_noiseless_sensor_resolves_every_width_and_bad_noise_vectors_are_refused():
    rng = np.random.default_rng(9)
    pts, _ = _leaf_under_beam_noise(rng, 0.0, (0.0, 1.0, 0.0))
    (leaf,) = traits.extract_traits(pts, range_noise_m=np.zeros_like(pts)).leaves
    assert leaf.noise_width_m == 0.0 and leaf.width_resolved is True
    with pytest.raises(ValueError, match=r"range_noise_m must be finite and shaped like points_turntable"):
        traits.extract_traits(pts, range_noise_m=np.zeros((len(pts) - 1, 3)))
    bad = np.zeros_like(pts)
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match=r"range_noise_m must be finite"):
        traits.extract_traits(pts, range_noise_m=bad)


@pytest.mark.parametrize("n", [3, 5, 20, 300])
def test_uniform_width_reads_a_uniformly_sampled_strip_unbiased(n):
    # The 2nd-98th percentile extent of n uniform samples averages 0.96 w (n - 1) / (n + 1)
    # (0.48 w for 3 points, 0.95 w for 300); uniform_width divides that out.
    from plantsim.evaluation.segmentation import uniform_width

    rng = np.random.default_rng(n)
    width_m = 0.03
    u = rng.uniform(-0.5 * width_m, 0.5 * width_m, size=(4000, n))
    reads = np.array([uniform_width(row) for row in u])
    extents = np.percentile(u, 98, axis=1) - np.percentile(u, 2, axis=1)
    assert extents.mean() == pytest.approx(0.96 * width_m * (n - 1) / (n + 1), rel=0.01)
    assert reads.mean() == pytest.approx(width_m, rel=0.01)
    with pytest.raises(ValueError, match="at least 2 points"):
        uniform_width(u[0, :1])
