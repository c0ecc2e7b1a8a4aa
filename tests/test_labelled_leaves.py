"""Leaves measured from labels given with the points (traits.measure_labelled_leaves), and
a scan's evaluation measuring its mesh's labelled leaves alone (evaluate.labelled_leaf_mesh)."""

import json

import numpy as np
import pytest

from plantsim.evaluation import evaluate, traits


def _strip(start_m, length_m, width_m, z_m, along, spacing_m=0.002):
    """A flat rectangular leaf sampled on a square grid: from ``start_m`` out along the
    horizontal unit vector ``along``, ``width_m`` across it, at height ``z_m``."""
    u = np.arange(0.0, length_m + 1e-9, spacing_m)
    w = np.arange(-width_m / 2, width_m / 2 + 1e-9, spacing_m)
    uu, ww = np.meshgrid(u, w, indexing="ij")
    a = np.array(along, dtype=float)
    across = np.array([-a[1], a[0], 0.0])
    return (start_m + uu.ravel())[:, None] * a + ww.ravel()[:, None] * across + [0.0, 0.0, z_m]


def _two_leaves():
    # 100 x 20 mm out along +x and 80 x 30 mm out along +y, 10 mm from the axis: 20 and 24 cm^2.
    a = _strip(0.01, 0.10, 0.02, 0.05, (1, 0, 0))
    b = _strip(0.01, 0.08, 0.03, 0.06, (0, 1, 0))
    return np.vstack([a, b]), np.r_[np.zeros(len(a), int), np.ones(len(b), int)]


def test_flat_labelled_leaves_read_their_area_and_length():
    # The ribbon between the margins along the midrib from each base: within 2 % of each
    # rectangle's area and length (a sampled strip's width is read as a uniform one's,
    # segmentation.uniform_width), in label order, whether the bases are given or taken as
    # each leaf's point nearest the turntable's axis.
    pts, labels = _two_leaves()
    for bases in ([[0.01, 0.0, 0.05], [0.0, 0.01, 0.06]], None):
        m = traits.measure_labelled_leaves(pts, labels, leaf_bases_m=bases)
        assert m.labels == (0, 1) and m.leaf_count == 2
        assert m.areas_m2 == pytest.approx((0.0020, 0.0024), rel=0.02)
        # A length is known to about a voxel (4 mm: twice the 2 mm spacing): where the
        # last level set's centroid sits and how far the leaf reaches past it.
        assert m.lengths_m == pytest.approx((0.10, 0.08), abs=0.004)
        assert m.leaf_area_m2 == pytest.approx(sum(m.areas_m2))
        assert m.widths_resolved == (None, None)  # no range noise given: widths not checked
    # Unlabelled points (-1) are no leaf; labels need not start at 0 or be dense.
    more = np.vstack([pts, [[0.2, 0.2, 0.1]]])
    m = traits.measure_labelled_leaves(more, np.r_[np.where(labels == 1, 4, 0), -1])
    assert m.labels == (0, 4) and m.areas_m2 == pytest.approx((0.0020, 0.0024), rel=0.02)


def test_a_leaf_with_too_few_points_or_below_the_clearance_is_not_measured():
    pts, labels = _two_leaves()
    few = np.array([[0.0, -0.05, 0.05 + 0.001 * i] for i in range(traits.LABELLED_LEAF_MIN_POINTS - 1)])
    low = _strip(0.01, 0.05, 0.01, 0.002, (0, -1, 0))  # 2 mm up, under the 5 mm ground clearance
    m = traits.measure_labelled_leaves(np.vstack([pts, few, low]),
                                       np.r_[labels, np.full(len(few), 2), np.full(len(low), 3)])
    assert m.labels == (0, 1, 2, 3) and m.leaf_count == 2
    assert m.n_points[2:] == (traits.LABELLED_LEAF_MIN_POINTS - 1, 0)
    assert all(np.isnan(m.areas_m2[2:])) and m.leaf_area_m2 == pytest.approx(sum(m.areas_m2[:2]))
    assert json.loads(json.dumps(m.to_dict()))["areas_m2"][2:] == [None, None]
    empty = traits.measure_labelled_leaves(pts, np.full(len(pts), -1))
    assert empty.leaf_count == 0 and np.isnan(empty.leaf_area_m2)


@pytest.mark.parametrize("change, message", [
    ({"leaf_label": np.zeros(3, dtype=int)}, "leaf_label must be"),
    ({"leaf_label": np.full(10, 0.5)}, "leaf_label must be"),
    ({"leaf_label": np.full(10, -2)}, "a leaf index >= 0 or -1"),
    ({"leaf_bases_m": np.zeros((1, 3))}, "a row for every label 0..1"),
    ({"leaf_bases_m": np.full((2, 3), np.nan)}, "leaf_bases_m must be finite"),
    ({"range_noise_m": np.zeros((3, 3))}, "range_noise_m must be finite and shaped like"),
])
def test_bad_labelled_leaves_say_what_is_wrong(change, message):
    args = {"points_turntable": np.random.default_rng(0).random((10, 3)), "leaf_label": np.r_[np.zeros(5, int), np.ones(5, int)]}
    args.update(change)
    with pytest.raises(ValueError, match=message):
        traits.measure_labelled_leaves(**args)


def test_a_labelled_meshs_leaves_are_placed_with_the_plant_and_based_on_its_stem(tmp_path):
    from plantsim.plant.mesh import load_plant
    from plantsim.plant.procedural import PART_LEAF, make_rosette, to_labelled_obj_bytes

    plant = make_rosette(seed=0, n_leaves=3)
    path = tmp_path / "rosette.obj"
    path.write_bytes(to_labelled_obj_bytes(plant))
    placed = load_plant(path)
    vertices, faces, face_leaf, bases = evaluate.labelled_leaf_mesh(placed)
    # The same surface as the placed plant's, in the turntable frame.
    assert len(faces) == len(plant.faces) and set(face_leaf.tolist()) == {-1, 0, 1, 2}
    lo, hi = placed.bounds_turntable()
    np.testing.assert_allclose(vertices[np.unique(faces)].min(axis=0), lo, atol=1e-9)
    np.testing.assert_allclose(vertices[np.unique(faces)].max(axis=0), hi, atol=1e-9)
    assert (face_leaf >= 0).sum() == (plant.face_part == PART_LEAF).sum()
    # Each leaf's base is where it meets the crown: on the axis's side, at the crown's top.
    assert len(bases) == 3
    assert np.all(np.hypot(bases[:, 0], bases[:, 1]) < 0.01)
    assert np.all(np.abs(bases[:, 2] - 0.02) < 0.005)
    # A mesh without labels (an STL) has none.
    import trimesh

    stl = tmp_path / "rosette.stl"
    trimesh.Trimesh(plant.vertices_m, plant.faces, process=False).export(stl)
    assert evaluate.labelled_leaf_mesh(load_plant(stl)) is None


@pytest.mark.parametrize("ideal", [True, False])
def test_a_scans_evaluation_measures_its_meshs_labelled_leaves_alone(tmp_path, capsys, ideal):
    # What the rig would read were the leaves cut out perfectly, beside what the segmentation
    # read: in the sidecar and on the evaluation line. On the realistic scan each point is
    # labelled by the leaf its beam hit.
    from plantsim.cli.app import main
    from plantsim.plant.procedural import make_rosette, to_labelled_obj_bytes, traits_to_json

    plant = make_rosette(seed=0, n_leaves=3)
    mesh = tmp_path / "rosette.obj"
    mesh.write_bytes(to_labelled_obj_bytes(plant))
    (tmp_path / "rosette.traits.json").write_text(traits_to_json(plant))
    cloud = tmp_path / "rosette.las"
    assert main(["scan", str(mesh), "-o", str(cloud), "--step-deg", "3", "--no-pictures", "--evaluate"]
                + (["--ideal"] if ideal else [])) == 0
    printed = capsys.readouterr().out
    evaluation = json.loads((tmp_path / "rosette.las.json").read_text())["evaluation"]["traits"]
    alone = evaluation["labelled_leaves_measured_alone"]
    assert alone["leaf_count"] == 3 and len(alone["areas_m2"]) == 3
    assert alone["leaf_area_relative_error"] == pytest.approx(
        abs(alone["leaf_area_m2"] - plant.traits["leaf_area_m2"]) / plant.traits["leaf_area_m2"])
    assert alone["leaf_area_relative_error"] < 0.35
    assert ("the leaf its beam hit" in alone["how"]) is not ideal
    assert f"(its 3 labelled leaves measured alone {alone['leaf_area_relative_error']:.1%})" in printed


def test_a_scan_of_an_unlabelled_mesh_says_its_leaves_were_not_measured_alone(tmp_path, capsys):
    import trimesh

    from plantsim.cli.app import main
    from plantsim.plant.procedural import make_rosette, traits_to_json

    plant = make_rosette(seed=0, n_leaves=3)
    mesh = tmp_path / "rosette.stl"
    trimesh.Trimesh(plant.vertices_m, plant.faces, process=False).export(mesh)
    (tmp_path / "rosette.traits.json").write_text(traits_to_json(plant))
    cloud = tmp_path / "rosette.las"
    assert main(["scan", str(mesh), "-o", str(cloud), "--step-deg", "6", "--no-pictures", "--evaluate", "--ideal"]) == 0
    assert "labelled leaves measured alone" not in capsys.readouterr().out
    evaluation = json.loads((tmp_path / "rosette.las.json").read_text())["evaluation"]["traits"]
    assert evaluation["labelled_leaves_measured_alone"] == {
        "how": "not measured: the mesh labels no leaf (named parts, face labels or colours)"}
