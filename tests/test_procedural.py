"""Tests of the procedural plant generator: traits checked against the mesh itself."""

import io
import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import load_script

from plantsim.plant.procedural import PART_EAR, PART_LEAF, PART_STEM, MaizeParams, WheatParams, make_maize, make_wheat, to_stl_bytes, traits_to_json

REPO_ROOT = Path(__file__).resolve().parents[1]
GENERATORS = {"maize": make_maize, "wheat": make_wheat}
TRAIT_KEYS = {
    "name", "generator", "seed", "params", "units", "up", "height_m", "stem_diameter_m",
    "stems", "stem_distances_m", "mean_stem_distance_m", "mean_nearest_stem_distance_m",
    "leaves", "leaf_width_m",
    "leaf_length_m", "leaf_area_m2", "n_vertices", "n_faces",
}


@pytest.fixture(scope="module", params=sorted(GENERATORS))
def plant(request):
    return GENERATORS[request.param](seed=0)


def _triangle_areas(vertices, faces):
    """Reference triangle areas by Heron's formula (independent of the generator's cross product)."""
    tri = vertices[faces]
    a = np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1)
    b = np.linalg.norm(tri[:, 2] - tri[:, 1], axis=1)
    c = np.linalg.norm(tri[:, 0] - tri[:, 2], axis=1)
    s = 0.5 * (a + b + c)
    return np.sqrt(np.maximum(s * (s - a) * (s - b) * (s - c), 0.0))


def _organ_vertex_ids(plant, part, organ):
    mask = (plant.face_part == part) & (plant.face_organ == organ)
    return np.unique(plant.faces[mask])


def _bottom_ring(plant, stem):
    """The stem's base ring: its vertices at z = 0 other than the cap centre."""
    ids = _organ_vertex_ids(plant, PART_STEM, stem)
    at_ground = plant.vertices_m[ids][plant.vertices_m[ids, 2] == 0.0]
    centre = at_ground.mean(axis=0)
    ring = at_ground[np.linalg.norm(at_ground - centre, axis=1) > 1e-9]
    return ring, ring.mean(axis=0)


def _leaf_grid(plant, leaf):
    """A leaf's vertices as (rows, columns, 3) and its tip, from its own vertex block."""
    ids = _organ_vertex_ids(plant, PART_LEAF, leaf)
    assert np.array_equal(ids, np.arange(ids[0], ids[-1] + 1)), "leaf vertices are one block"
    rows, cols = plant.params.leaf_segments, plant.params.leaf_width_segments + 1
    vertices = plant.vertices_m[ids]
    assert len(vertices) == rows * cols + 1
    return vertices[:-1].reshape(rows, cols, 3), vertices[-1]


# ------------------------------------------------------------------------ determinism


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_same_seed_is_bit_identical_and_another_seed_differs(name):
    make = GENERATORS[name]
    a, b, c = make(seed=3), make(seed=3), make(seed=4)
    assert np.array_equal(a.vertices_m, b.vertices_m)
    assert np.array_equal(a.faces, b.faces)
    assert to_stl_bytes(a) == to_stl_bytes(b)
    assert traits_to_json(a) == traits_to_json(b)
    assert a.vertices_m.shape == c.vertices_m.shape
    assert not np.array_equal(a.vertices_m, c.vertices_m)
    assert traits_to_json(a) != traits_to_json(c)


def test_generator_leaves_global_random_state_alone():
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    make_maize(seed=0)
    make_wheat(seed=0)
    assert np.array_equal(np.random.get_state()[1], before)


# ---------------------------------------------------------------- traits vs the mesh


def test_traits_follow_the_schema(plant):
    traits = plant.traits
    assert set(traits) == TRAIT_KEYS
    assert traits["name"] == plant.name
    assert traits["generator"] == f"plantsim.plant.procedural.make_{plant.name}"
    assert traits["units"] == "m" and traits["up"] == "z" and traits["seed"] == 0
    assert traits["n_vertices"] == len(plant.vertices_m)
    assert traits["n_faces"] == len(plant.faces)
    assert set(traits["params"]) == {f for f in plant.params.__dataclass_fields__}
    assert [s["index"] for s in traits["stems"]] == list(range(len(traits["stems"])))
    assert [leaf["index"] for leaf in traits["leaves"]] == list(range(len(traits["leaves"])))
    json.loads(traits_to_json(plant))  # serialisable, no NaN


def test_plant_frame_base_at_origin_lowest_point_at_zero(plant):
    vertices = plant.vertices_m
    assert vertices.dtype == np.float64 and vertices.shape[1] == 3
    assert np.isfinite(vertices).all()
    assert vertices[:, 2].min() == 0.0
    _, centre = _bottom_ring(plant, 0)
    np.testing.assert_allclose(centre, [0.0, 0.0, 0.0], atol=1e-12)


def test_height_is_max_z(plant):
    assert plant.traits["height_m"] == plant.vertices_m[:, 2].max()


def test_stem_diameters_and_bases_from_bottom_rings(plant):
    traits = plant.traits
    diameters, bases = [], []
    for stem in traits["stems"]:
        ring, centre = _bottom_ring(plant, stem["index"])
        assert len(ring) == plant.params.stem_sides
        radii = np.linalg.norm(ring - centre, axis=1)
        np.testing.assert_allclose(radii, radii[0], rtol=1e-9)  # a regular polygon
        diameters.append(2.0 * radii.max())  # circumscribed
        bases.append(centre[:2])
        np.testing.assert_allclose(stem["diameter_m"], diameters[-1], rtol=1e-9)
        np.testing.assert_allclose(stem["base_xy_m"], centre[:2], atol=1e-12)
        assert stem["height_m"] == stem["top_xyz_m"][2]
    np.testing.assert_allclose(traits["stem_diameter_m"], np.mean(diameters), rtol=1e-9)

    bases = np.array(bases)
    pairs = {tuple(p["stems"]): p["distance_m"] for p in traits["stem_distances_m"]}
    assert set(pairs) == set(itertools.combinations(range(len(bases)), 2))
    for (i, j), distance in pairs.items():
        np.testing.assert_allclose(distance, np.linalg.norm(bases[i] - bases[j]), rtol=1e-9)
    if len(bases) == 1:
        assert traits["mean_stem_distance_m"] is None
        assert traits["mean_nearest_stem_distance_m"] is None
    else:
        dist = np.linalg.norm(bases[:, None] - bases[None], axis=-1)
        iu = np.triu_indices(len(bases), k=1)
        np.testing.assert_allclose(traits["mean_stem_distance_m"], dist[iu].mean(), rtol=1e-9)
        np.fill_diagonal(dist, np.inf)
        np.testing.assert_allclose(traits["mean_nearest_stem_distance_m"], dist.min(axis=1).mean(),
                                   rtol=1e-9)


def test_leaf_traits_from_midrib_cross_sections_and_triangles(plant):
    traits = plant.traits
    total_area = 0.0
    for leaf in traits["leaves"]:
        grid, tip = _leaf_grid(plant, leaf["index"])
        midrib = np.concatenate([grid[:, grid.shape[1] // 2], tip[None]])
        polyline = np.linalg.norm(np.diff(midrib, axis=0), axis=1).sum()
        assert leaf["length_m"] == pytest.approx(polyline, rel=0.01)
        widest = np.linalg.norm(grid[:, 0] - grid[:, -1], axis=1).max()
        assert leaf["width_m"] == pytest.approx(widest, rel=0.01)
        assert leaf["insertion_height_m"] == pytest.approx(midrib[0, 2], abs=1e-12)
        mask = (plant.face_part == PART_LEAF) & (plant.face_organ == leaf["index"])
        area = _triangle_areas(plant.vertices_m, plant.faces[mask]).sum()
        assert leaf["area_m2"] == pytest.approx(area, rel=1e-9)
        total_area += area
    assert traits["leaf_area_m2"] == pytest.approx(total_area, rel=1e-9)
    assert traits["leaf_width_m"] == max(leaf["width_m"] for leaf in traits["leaves"])
    assert traits["leaf_length_m"] == max(leaf["length_m"] for leaf in traits["leaves"])


def test_leaf_length_matches_nominal_arc_length():
    plant = make_maize(seed=0, n_leaves=1, size_jitter=0.0, leaf_length=0.3, leaf_width=0.04)
    assert plant.traits["leaves"][0]["length_m"] == pytest.approx(0.3 * 0.45 + 0.3 * 0.55
                                                                  * np.exp(-((0.5 - 0.6) / 0.35) ** 2),
                                                                  rel=1e-12)


# ------------------------------------------------------------------------ mesh quality


def test_no_degenerate_faces_and_every_vertex_used(plant):
    faces = plant.faces
    assert faces.dtype == np.int64 and faces.shape[1] == 3
    assert faces.min() >= 0 and faces.max() < len(plant.vertices_m)
    assert (faces[:, 0] != faces[:, 1]).all()
    assert (faces[:, 1] != faces[:, 2]).all()
    assert (faces[:, 0] != faces[:, 2]).all()
    assert _triangle_areas(plant.vertices_m, faces).min() > 1e-10  # m^2
    assert np.array_equal(np.unique(faces), np.arange(len(plant.vertices_m)))
    # Still no zero-area triangle once rounded to the STL's float32.
    tri32 = plant.vertices_m.astype(np.float32)[faces].astype(np.float64)
    area32 = 0.5 * np.linalg.norm(np.cross(tri32[:, 1] - tri32[:, 0], tri32[:, 2] - tri32[:, 0]), axis=1)
    assert area32.min() > 0.0


def test_face_labels(plant):
    m = len(plant.faces)
    assert plant.face_part.shape == (m,) and plant.face_organ.shape == (m,)
    n_stems, n_leaves = len(plant.traits["stems"]), len(plant.traits["leaves"])
    assert set(np.unique(plant.face_organ[plant.face_part == PART_STEM])) == set(range(n_stems))
    assert set(np.unique(plant.face_organ[plant.face_part == PART_LEAF])) == set(range(n_leaves))
    ears = set(np.unique(plant.face_organ[plant.face_part == PART_EAR]))
    assert ears == (set(range(n_stems)) if plant.name == "wheat" else set())


def test_stems_and_ears_are_closed_and_outward(plant):
    for part in (PART_STEM, PART_EAR):
        for organ in np.unique(plant.face_organ[plant.face_part == part]):
            faces = plant.faces[(plant.face_part == part) & (plant.face_organ == organ)]
            mesh = trimesh.Trimesh(plant.vertices_m, faces, process=False)
            mesh.remove_unreferenced_vertices()
            assert mesh.is_watertight
            assert mesh.volume > 0.0  # outward winding


def test_stl_round_trip_and_size(plant):
    data = to_stl_bytes(plant)
    assert len(plant.faces) <= 39_998
    assert len(data) == 84 + 50 * len(plant.faces) < 2_000_000
    assert not data.startswith(b"solid")
    mesh = trimesh.load(io.BytesIO(data), file_type="stl", process=False)
    np.testing.assert_allclose(mesh.triangles, plant.vertices_m[plant.faces], atol=1e-7)


# --------------------------------------------------------------------------- realism


@pytest.mark.parametrize("seed", range(5))
def test_maize_is_sized_like_a_young_maize(seed):
    traits = make_maize(seed=seed).traits
    assert 0.45 <= traits["height_m"] <= 0.65
    assert 0.012 <= traits["stem_diameter_m"] <= 0.016
    assert 8 <= len(traits["leaves"]) <= 10
    for leaf in traits["leaves"]:
        assert 0.02 <= leaf["width_m"] <= 0.06
        assert 0.15 <= leaf["length_m"] <= 0.45


@pytest.mark.parametrize("seed", range(5))
def test_wheat_is_sized_like_wheat(seed):
    traits = make_wheat(seed=seed).traits
    assert 0.5 <= traits["height_m"] <= 0.6
    assert 3 <= len(traits["stems"]) <= 5
    assert traits["stem_diameter_m"] == pytest.approx(0.004, rel=0.05)
    assert 0.02 <= traits["mean_nearest_stem_distance_m"] <= 0.05
    for leaf in traits["leaves"]:
        assert 0.006 <= leaf["width_m"] <= 0.012


# ------------------------------------------------------------------------ validation


@pytest.mark.parametrize(
    ("make", "params", "message"),
    [
        (make_maize, {"n_leaves": 0}, r"n_leaves must be an integer in \[1, 30\], got 0"),
        (make_maize, {"n_leaves": 2.5}, r"n_leaves must be an integer"),
        (make_maize, {"stem_sides": 12}, r"stem_sides must be an integer in \[24, 256\], got 12"),
        (make_maize, {"stem_diameter": -0.01}, r"stem_diameter must be a number in \(0.0, 0.1\] m"),
        (make_maize, {"stem_length": float("nan")}, r"stem_length must be a number"),
        (make_maize, {"stem_top_diameter": 0.02}, r"stem_top_diameter must not exceed stem_diameter"),
        (make_maize, {"leaf_width": 0.5, "leaf_length": 0.2}, r"leaf_width must be"),
        (make_maize, {"leaf_width_segments": 5}, r"leaf_width_segments must be even"),
        (make_maize, {"leaf_tip_angle_deg": 10.0}, r"leaf_tip_angle_deg must be at least"),
        (make_maize, {"leaf_lenght": 0.3}, r"unknown MaizeParams field\(s\) \['leaf_lenght'\]; valid names: n_leaves"),
        (make_maize, {"seed": -1}, r"seed must be a non-negative integer, got -1"),
        (make_wheat, {"n_tillers": 9}, r"n_tillers must be an integer in \[1, 8\], got 9"),
        (make_wheat, {"tiller_spacing": 0.005}, r"tiller_spacing must be at least"),
        (make_wheat, {"ear_length": 0.0}, r"ear_length must be a number in \(0.0, 0.5\] m"),
        (make_wheat, {"stem_sides": True}, r"stem_sides must be an integer"),
    ],
)
def test_invalid_parameters_are_rejected(make, params, message):
    with pytest.raises(ValueError, match=message):
        make(**params)


def test_params_are_frozen_keyword_only_and_converted():
    params = MaizeParams(n_leaves=np.int64(8), stem_length=1)
    assert type(params.n_leaves) is int and type(params.stem_length) is float
    with pytest.raises(AttributeError):
        params.n_leaves = 3
    with pytest.raises(TypeError):
        WheatParams(4)


def test_arrays_are_read_only():
    plant = make_maize(seed=0)
    with pytest.raises(ValueError):
        plant.vertices_m[0, 0] = 1.0


# ------------------------------------------------------------------- bundled assets


def test_committed_assets_equal_a_fresh_regeneration(tmp_path):
    written = load_script("make_plants").write_plants(tmp_path)
    names = sorted(path.name for path, _ in written)
    assert names == ["maize.stl", "maize.traits.json", "wheat.stl", "wheat.traits.json"]
    for name in names:
        fresh = (tmp_path / name).read_bytes()
        committed = (REPO_ROOT / "assets" / name).read_bytes()
        assert fresh == committed, f"assets/{name} is stale: run scripts/make_plants.py"
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_committed_traits_describe_the_committed_stl():
    for name in GENERATORS:
        traits = json.loads((REPO_ROOT / "assets" / f"{name}.traits.json").read_text())
        mesh = trimesh.load(REPO_ROOT / "assets" / f"{name}.stl", process=False)
        assert len(mesh.faces) == traits["n_faces"]
        assert mesh.bounds[1, 2] == pytest.approx(traits["height_m"], abs=1e-6)
        assert mesh.bounds[0, 2] == 0.0


# ------------------------------------------------------------------------ rosette


@pytest.mark.parametrize("n_leaves", [3, 12, 30])
def test_rosette_traits_are_those_of_its_labelled_faces(n_leaves):
    from plantsim.plant.procedural import PART_LEAF, PART_STEM, make_rosette

    plant = make_rosette(seed=3, n_leaves=n_leaves)
    t = plant.traits
    v, f = plant.vertices_m, plant.faces
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    leaf = plant.face_part == PART_LEAF
    assert len(t["leaves"]) == n_leaves == len(np.unique(plant.face_organ[leaf]))
    for lf in t["leaves"]:
        mine = leaf & (plant.face_organ == lf["index"])
        assert lf["area_m2"] == pytest.approx(area[mine].sum(), rel=1e-12)
        # A leaf is longer than the straight line from its collar to its tip, wider than 0.
        pts = v[np.unique(f[mine])]
        assert lf["length_m"] >= np.ptp(pts, axis=0).max() * 0.5 and lf["width_m"] > 0
    assert t["leaf_area_m2"] == pytest.approx(area[leaf].sum(), rel=1e-12)
    assert t["height_m"] == pytest.approx(v[:, 2].max()) and v[:, 2].min() == 0.0
    (stem,) = t["stems"]
    assert stem["diameter_m"] == pytest.approx(0.008) and stem["height_m"] == pytest.approx(0.02)
    assert set(np.unique(plant.face_part)) == {PART_STEM, PART_LEAF}


def test_rosette_leaves_overlap_when_crowded_and_params_are_checked():
    from plantsim.plant.procedural import make_rosette

    crowded = make_rosette(seed=0, n_leaves=30).traits
    # Thirty leaves of ~0.1 m x 0.05 m around one crown: their summed area is far more
    # than the disc they cover, so they overlap (as a rosette's do).
    radius = max(lf["length_m"] for lf in crowded["leaves"])
    assert crowded["leaf_area_m2"] > 0.5 * np.pi * radius ** 2
    with pytest.raises(ValueError, match=r"leaf_width_segments must be even"):
        make_rosette(leaf_width_segments=5)
    with pytest.raises(ValueError, match=r"unknown RosetteParams field\(s\) \['n_tillers'\]"):
        make_rosette(n_tillers=2)
    again = make_rosette(seed=0, n_leaves=30)
    assert np.array_equal(again.vertices_m, make_rosette(seed=0, n_leaves=30).vertices_m)


# -------------------------------------------------------------------------- dicot


def _heron_leaf_areas(plant):
    """Per-leaf area by a brute-force loop over the leaf faces (Heron's formula)."""
    areas = {}
    tri_area = _triangle_areas(plant.vertices_m, plant.faces)
    for face, (part, organ) in enumerate(zip(plant.face_part.tolist(), plant.face_organ.tolist())):
        if part == PART_LEAF:
            areas[organ] = areas.get(organ, 0.0) + float(tri_area[face])
    return areas


@pytest.mark.parametrize("kw", [{}, {"leaflets": 1, "n_leaves": 3}, {"n_branches": 2, "leaves_per_branch": 2},
                                {"n_leaves": 30, "leaflets": 1}])
def test_dicot_exact_traits_against_brute_force(kw):
    from plantsim.plant.procedural import PART_BRANCH, PART_PETIOLE, make_dicot

    plant = make_dicot(seed=5, **kw)
    t = plant.traits
    n_laminae = plant.params.n_leaves * plant.params.leaflets
    assert len(t["leaves"]) == n_laminae == len(np.unique(plant.face_organ[plant.face_part == PART_LEAF]))
    heron = _heron_leaf_areas(plant)
    for leaf in t["leaves"]:
        assert leaf["area_m2"] == pytest.approx(heron[leaf["index"]], rel=1e-9)
        grid, tip = _leaf_grid(plant, leaf["index"])
        midrib = np.concatenate([grid[:, grid.shape[1] // 2], tip[None]])
        assert leaf["length_m"] == pytest.approx(np.linalg.norm(np.diff(midrib, axis=0), axis=1).sum(), rel=1e-12)
        assert leaf["width_m"] == pytest.approx(np.linalg.norm(grid[:, 0] - grid[:, -1], axis=1).max(), rel=1e-12)
        chord = tip - midrib[0]
        assert leaf["inclination_deg"] == pytest.approx(np.degrees(np.arctan2(chord[2], np.hypot(*chord[:2]))))
        assert 0.0 < leaf["width_m"] < leaf["length_m"] < 0.2
    assert t["leaf_area_m2"] == pytest.approx(sum(heron.values()), rel=1e-9)
    # Petioles: one per petiolate leaf, each naming its laminae; branches as asked.
    assert len(t["petioles"]) == plant.params.n_leaves
    assert sorted(i for pt in t["petioles"] for i in pt["leaves"]) == list(range(n_laminae))
    assert len(np.unique(plant.face_organ[plant.face_part == PART_PETIOLE])) == plant.params.n_leaves
    assert len(t["branches"]) == plant.params.n_branches
    assert len(np.unique(plant.face_organ[plant.face_part == PART_BRANCH])) == plant.params.n_branches
    (stem,) = t["stems"]
    ring, centre = _bottom_ring(plant, 0)
    assert 2 * np.linalg.norm(ring - centre, axis=1).max() == pytest.approx(stem["diameter_m"], rel=1e-9)
    assert t["height_m"] == plant.vertices_m[:, 2].max() and plant.vertices_m[:, 2].min() == 0.0


@pytest.mark.parametrize("n_leaves", [3, 7, 12, 20, 30])
@pytest.mark.parametrize("generator", ["maize", "rosette", "dicot"])
def test_leaf_count_parameter_is_honoured_from_3_to_30(generator, n_leaves):
    from plantsim.plant import procedural

    plant = getattr(procedural, f"make_{generator}")(seed=n_leaves, n_leaves=n_leaves, **(
        {"leaflets": 1} if generator == "dicot" else {}))
    assert len(plant.traits["leaves"]) == n_leaves
    leaf = plant.face_part == PART_LEAF
    assert sorted(np.unique(plant.face_organ[leaf])) == list(range(n_leaves))
    # Labels are consistent: every face labelled, every leaf index once in the traits.
    assert [lf["index"] for lf in plant.traits["leaves"]] == list(range(n_leaves))
    assert len(plant.face_part) == len(plant.face_organ) == len(plant.faces)


def test_dicot_is_deterministic_and_fits_the_default_rig():
    from plantsim.plant.mesh import plant_from_arrays
    from plantsim.plant.procedural import make_dicot
    from plantsim.rig.fit import rig_fit_warnings
    from plantsim.rig.geometry import RigGeometry
    from plantsim.sensor.spec import URG_04LX_UG01

    a, b, c = make_dicot(seed=4), make_dicot(seed=4), make_dicot(seed=5)
    assert np.array_equal(a.vertices_m, b.vertices_m) and traits_to_json(a) == traits_to_json(b)
    assert not np.array_equal(a.vertices_m, c.vertices_m)
    for kw in ({}, {"n_leaves": 30}, {"n_branches": 3, "n_leaves": 12}, {"leaflets": 1, "n_leaves": 3}):
        plant = make_dicot(seed=1, **kw)
        placed = plant_from_arrays(plant.vertices_m, plant.faces)
        assert rig_fit_warnings(placed, RigGeometry(), URG_04LX_UG01) == [], kw
        assert 0.25 <= plant.traits["height_m"] <= 0.45


def _touching_pairs(plant, gap=0.003, away=0.03):
    """Pairs of leaves whose vertices come within ``gap`` m of each other away from the
    stem (farther than ``away`` m from the axis, where every collar meets)."""
    from scipy.spatial import cKDTree

    v, leaf = plant.vertices_m, plant.face_part == PART_LEAF
    pts = {}
    for k in np.unique(plant.face_organ[leaf]).tolist():
        ids = np.unique(plant.faces[leaf & (plant.face_organ == k)])
        pts[k] = v[ids][np.hypot(v[ids, 0], v[ids, 1]) > away]
    trees = {k: cKDTree(p) for k, p in pts.items() if len(p)}
    return sum(1 for a in trees for b in trees
               if a < b and trees[a].query(pts[b], distance_upper_bound=gap)[0].min() < gap)


def test_touching_leaves_are_a_parameter_setting():
    from plantsim.plant.procedural import make_dicot, make_rosette

    assert _touching_pairs(make_maize(seed=0, n_leaves=6)) == 0
    # Small phyllotaxy spread and short internodes stack the maize leaves onto each other.
    assert _touching_pairs(make_maize(seed=0, n_leaves=6, phyllotaxy_deg=10.0, phyllotaxy_jitter_deg=0.0,
                                      lowest_leaf_fraction=0.3, highest_leaf_fraction=0.4)) >= 2
    assert _touching_pairs(make_dicot(seed=0, n_leaves=10, leaflets=1)) == 0
    assert _touching_pairs(make_dicot(seed=0, n_leaves=10, leaflets=1, stem_length=0.12, leaflet_length=0.11,
                                      leaflet_width=0.08, phyllotaxy_deg=30.0, lowest_node_fraction=0.5)) >= 3
    assert _touching_pairs(make_rosette(seed=0, n_leaves=6)) == 0
    assert _touching_pairs(make_rosette(seed=0, n_leaves=30)) >= 10


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"n_leaves": 31}, r"n_leaves must be an integer in \[1, 30\], got 31"),
        ({"leaflets": 2}, r"leaflets must be 1 \(simple leaves\) or 3 \(trifoliate\), got 2"),
        ({"leaflet_width": 0.1, "leaflet_length": 0.08}, r"leaflet_width must be less than leaflet_length"),
        ({"petiole_length": 0.005}, r"petiole_diameter must be at most petiole_length / 4"),
        ({"n_branches": 3, "leaves_per_branch": 3, "n_leaves": 8}, r"n_leaves must be at least n_branches \* "
                                                                   r"\(leaves_per_branch \+ 1\) = 12"),
        ({"leaf_angle_deg": 5.0}, r"leaf_angle_deg must be a number in \[10.0, 110.0\] deg, got 5.0"),
        ({"phyllotaxy_deg": -1}, r"phyllotaxy_deg must be a number in \[0.0, 360.0\] deg"),
        ({"leaf_width_segments": 7}, r"leaf_width_segments must be even"),
        ({"highest_node_fraction": 0.2}, r"highest_node_fraction must be at least lowest_node_fraction"),
        ({"leaf_lenght": 0.1}, r"unknown DicotParams field\(s\) \['leaf_lenght'\]; valid names: n_leaves"),
        ({"seed": -2}, r"seed must be a non-negative integer, got -2"),
    ],
)
def test_dicot_invalid_parameters_are_rejected(params, message):
    from plantsim.plant.procedural import make_dicot

    with pytest.raises(ValueError, match=message):
        make_dicot(**params)


def test_extra_plants_are_written_with_labels_and_truth(tmp_path):
    from plantsim.evaluation.evaluate import truth_from_labelled_mesh

    written = load_script("make_plants").write_extra_plants(tmp_path)
    assert len(written) == 2 * len(load_script("make_plants").EXTRA_PLANTS)
    truth = json.loads((tmp_path / "dicot.obj.traits.json").read_text())
    labelled = truth_from_labelled_mesh(tmp_path / "dicot.obj", n_samples_per_m2=0)
    assert labelled["leaf_count"] == len(truth["leaves"]) == 24
    assert labelled["leaf_area_m2"] == pytest.approx(truth["leaf_area_m2"], rel=1e-8)


def test_cli_plant_make_writes_mesh_and_truth(tmp_path, capsys):
    from plantsim.cli.app import main
    from plantsim.evaluation.evaluate import truth_from_labelled_mesh, truth_traits_path

    out = tmp_path / "bean.obj"
    assert main(["plant", "make", "dicot", "--seed", "3", "--set", "n_leaves=4", "--set", "leaflets=1",
                 "-o", str(out)]) == 0
    assert "4 leaves" in capsys.readouterr().out
    truth = json.loads(truth_traits_path(out).read_text())
    assert truth["params"]["n_leaves"] == 4 and truth["seed"] == 3
    assert truth_from_labelled_mesh(out, n_samples_per_m2=0)["leaf_count"] == 4
    assert main(["plant", "make", "maize", "-o", str(tmp_path / "m.stl")]) == 0
    assert (tmp_path / "m.traits.json").is_file()
    # Trifoliate leaves count once, as the traits count them; their laminae said beside.
    assert main(["plant", "make", "dicot", "--set", "n_leaves=4", "-o", str(tmp_path / "t.obj")]) == 0
    assert "4 leaves (12 laminae)" in capsys.readouterr().out
    assert main(["plant", "make", "dicot", "--set", "leaflets=2", "-o", str(out)]) == 2
    assert "leaflets must be 1 (simple leaves) or 3 (trifoliate), got 2" in capsys.readouterr().err
    assert main(["plant", "make", "dicot", "-o", str(tmp_path / "x.ply")]) == 2
    assert "give -o MESH ending in .obj or .stl" in capsys.readouterr().err
