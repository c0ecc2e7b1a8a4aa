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
    # The leaves the traits were read from, matched to the labelled ones point by point.
    matched = evaluation["leaves_matched"]
    assert matched["seen"] == 3 and matched["found"] == evaluation["n_leaves"][0]
    assert 0 <= matched["true_positives"] <= min(matched["found"], 3)
    assert (f"leaves matched {matched['true_positives']} of {matched['found']} found to 3 labelled "
            f"(PQ {matched['panoptic_quality']:.2f})") in printed


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
    assert "leaves_matched" not in evaluation


def _labelled_plant_points():
    """The two strips, a stem ring up the axis (label 1) and sparse soil (label 0) round it:
    Pheno4D's convention (0 soil, 1 stem, each leaf its own label)."""
    pts, labels = _two_leaves()
    t = np.linspace(0.0, 20 * np.pi, 400)
    stem = np.column_stack([0.004 * np.cos(t), 0.004 * np.sin(t), np.linspace(0.006, 0.07, 400)])
    soil = np.column_stack([np.random.default_rng(0).uniform(-0.1, 0.1, (200, 2)), np.full(200, 0.006)])
    return (np.vstack([pts, stem, soil]),
            np.r_[np.where(labels == 0, 5, 7), np.ones(len(stem), int), np.zeros(len(soil), int)])


def test_a_labelled_text_cloud_reads_its_leaves_alone(tmp_path, capsys):
    # A header-less x y z label file (Pheno4D's form): the fourth column is _col3.
    from plantsim.cli.app import main

    pts, labels = _labelled_plant_points()
    path = tmp_path / "plant.txt"
    np.savetxt(path, np.column_stack([pts, labels]), fmt="%.6f %.6f %.6f %d")
    out = tmp_path / "t.json"
    assert main(["traits", str(path), "--labels", "_col3", "--stem-label", "1", "--ignore-labels", "0",
                 "-o", str(out)]) == 0
    lab = json.loads(out.read_text())["labelled_leaves"]
    assert lab["field"] == "_col3" and lab["labels"] == [5, 7] and lab["leaf_count"] == 2
    assert lab["areas_m2"] == pytest.approx([0.0020, 0.0024], rel=0.02)
    assert lab["n_stem_points"] == 400 and lab["measured_from"] == "each leaf's point nearest a stem point"
    assert lab["stem_label"] == 1 and lab["ignored_labels"] == [0]
    assert "labelled leaves ('_col3'): 2 of 2 measured, area 44.27 cm^2" in capsys.readouterr().out


@pytest.mark.parametrize("suffix", [".ply", ".pcd", ".las"])
def test_a_label_field_is_read_from_each_format_that_carries_one(tmp_path, suffix):
    from plantsim.cloud.export import read_point_field, write_cloud
    from plantsim.cloud.reconstruct import PointCloud

    pts, labels = _labelled_plant_points()
    n = len(pts)
    cloud = PointCloud(points_turntable=pts, hit_class=np.ones(n, np.uint8), beam_index=np.zeros(n, np.uint16),
                       scan_index=np.zeros(n, np.uint32), turntable_angle_rad=np.zeros(n), range_m=np.ones(n),
                       time_s=np.zeros(n))
    path = tmp_path / f"plant{suffix}"
    write_cloud(path, cloud)
    data = path.read_bytes()
    if suffix == ".las":
        import laspy

        las = laspy.read(path)
        las.add_extra_dim(laspy.ExtraBytesParams(name="leaf", type=np.int16))
        las.leaf = labels.astype(np.int16)
        las.write(path)
        field = "leaf"
    elif suffix == ".ply":
        # A labels property added to the vertex element (as CloudCompare writes a scalar field).
        end = data.index(b"end_header\n")
        header = data[:end] + b"property int scalar_label\n"  # the vertex element is the file's only one
        rows = np.frombuffer(data[end + len(b"end_header\n"):], dtype=np.uint8).reshape(n, -1)
        body = np.hstack([rows, labels.astype("<i4").view(np.uint8).reshape(n, 4)])
        path.write_bytes(header + b"end_header\n" + body.tobytes())
        field = "scalar_label"
    else:
        field = "label"  # plantsim's PCD label is the class code (4, plant) for every point
        labels = np.full(n, 4)
    np.testing.assert_array_equal(read_point_field(path, field), labels)
    # The message lists the fields the file has (a PLY's without their scalar_ prefix).
    with pytest.raises(ValueError, match=f"plant{suffix} has no per-point field 'nope'; it has: .*"
                                         f"{field.removeprefix('scalar_')}"):
        read_point_field(path, "nope")


def test_labels_that_cannot_be_read_say_why(tmp_path, capsys):
    from plantsim.cli.app import main
    from plantsim.cloud.export import read_point_field

    pts, labels = _labelled_plant_points()
    path = tmp_path / "plant.txt"
    np.savetxt(path, np.column_stack([pts, labels + 0.5]), fmt="%.6f")
    assert main(["traits", str(path), "--labels", "_col3"]) == 2
    assert "the labels must be whole numbers" in capsys.readouterr().err
    assert main(["traits", str(path), "--labels", "label"]) == 2
    assert "plant.txt has no per-point field 'label'; it has: x, y, z, _col3" in capsys.readouterr().err
    with pytest.raises(ValueError, match="a .e57 cloud carries no per-point fields beyond its coordinates"):
        read_point_field(tmp_path / "plant.e57", "label")
    with pytest.raises(ValueError, match="unknown point-cloud format '.csv'"):
        read_point_field(tmp_path / "plant.csv", "label")


def test_labels_follow_the_points_the_traits_measure(tmp_path):
    # plantsim's LAS classes its points: the traits read the plant's, and so do the labels
    # (the soil here classed turntable, its labels never read).
    import laspy

    from plantsim.cli.app import main
    from plantsim.cloud.export import write_cloud
    from plantsim.cloud.reconstruct import PointCloud
    from plantsim.rig.scene import HitClass

    pts, labels = _labelled_plant_points()
    n = len(pts)
    hit = np.where(labels == 0, HitClass.TURNTABLE, HitClass.PLANT).astype(np.uint8)
    cloud = PointCloud(points_turntable=pts, hit_class=hit, beam_index=np.zeros(n, np.uint16),
                       scan_index=np.zeros(n, np.uint32), turntable_angle_rad=np.zeros(n), range_m=np.ones(n),
                       time_s=np.zeros(n))
    path = tmp_path / "plant.las"
    write_cloud(path, cloud)
    las = laspy.read(path)
    las.add_extra_dim(laspy.ExtraBytesParams(name="organ", type=np.int16))
    las.organ = np.where(labels == 0, 9, labels).astype(np.int16)  # the soil would be leaf 9 if read
    las.write(path)
    out = tmp_path / "t.json"
    assert main(["traits", str(path), "--labels", "organ", "--stem-label", "1", "-o", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["points_measured"].startswith(f"the {(labels != 0).sum()} of {n} points classed as plant")
    assert data["labelled_leaves"]["labels"] == [5, 7]
    assert data["labelled_leaves"]["areas_m2"] == pytest.approx([0.0020, 0.0024], rel=0.02)


def test_the_traits_segmentation_is_the_one_segment_for_traits_gives():
    # The evaluation scores the organs the traits were read from without segmenting twice.
    pts, labels = _labelled_plant_points()
    plant = pts[labels != 0]
    est, seg = traits.traits_and_segmentation(plant)
    again = traits.segment_for_traits(plant)
    np.testing.assert_array_equal(seg.points, again.points)
    np.testing.assert_array_equal(seg.leaf_label, again.leaf_label)
    assert est.to_dict() == traits.extract_traits(plant).to_dict()


@pytest.mark.parametrize("ideal", [True, False])
def test_points_on_a_part_the_file_labels_neither_leaf_nor_stem_are_no_leaf(tmp_path, ideal):
    # A bean's petioles are parts of their own in its OBJ, neither leaf nor stem: a beam that
    # hit one is no leaf's, though a leaf lies behind it within the noise's reach, or nearest
    # (cast against the labelled parts alone, 22 % of the petiole's points read as a leaf's).
    # The evaluation's labels from the file's parts agree with the generator's own face labels
    # (here the petioles labelled apart), read as the procedural truth reads them.
    from plantsim.evaluation.evaluate import _Proximities, _true_leaf_of, labelled_leaf_mesh, scan_range_noise
    from plantsim.evaluation.organ_match import leaf_labels_along_beams, leaf_labels_from_mesh
    from plantsim.plant.mesh import load_plant, plant_from_arrays
    from plantsim.plant.procedural import PART_LEAF, PART_PETIOLE, make_dicot, to_labelled_obj_bytes
    from plantsim.scan.config import RunConfig
    from plantsim.scan.pipeline import run_scan
    from plantsim.scan.schedule import StepScan

    plant = make_dicot(seed=1, n_leaves=3, leaflets=1)
    path = tmp_path / "bean.obj"
    path.write_bytes(to_labelled_obj_bytes(plant))
    placed = load_plant(path)
    result = run_scan(RunConfig(ideal=ideal, scan=StepScan(step_deg=3.0)), plant=placed)
    pts = result.cloud.plant_only().points_turntable
    noise = None if ideal else scan_range_noise(result)[0]
    vertices, faces, face_leaf, _ = labelled_leaf_mesh(placed)
    labels, _ = _true_leaf_of(pts, noise, placed, _Proximities(placed, vertices, faces), face_leaf)
    petiole = 1000
    parts = np.where(plant.face_part == PART_LEAF, plant.face_organ,
                     np.where(plant.face_part == PART_PETIOLE, petiole, -1))
    mesh = plant_from_arrays(plant.vertices_m, plant.faces)
    truth = (leaf_labels_from_mesh(pts, mesh.vertices_turntable, mesh.faces, parts) if ideal else
             leaf_labels_along_beams(pts, noise, mesh.vertices_turntable, mesh.faces, parts)[0])
    on_petiole, on_leaf = truth == petiole, (truth >= 0) & (truth != petiole)
    assert on_petiole.sum() >= 20 and on_leaf.any()
    assert np.mean(labels[on_petiole] < 0) >= 0.98
    # Leaves are numbered by the file's parts, the generator by its organs: the same sets.
    pairs = {(int(a), int(b)) for a, b in zip(labels[on_leaf], truth[on_leaf])}
    assert len(pairs) == 3 and len({a for a, _ in pairs}) == 3
    assert np.mean((labels < 0) == (truth < 0) | on_petiole) > 0.99


def test_label_options_without_labels_are_refused(tmp_path, capsys):
    # Nothing is silently ignored: --stem-label and --ignore-labels only say how to read --labels.
    from plantsim.cli.app import main

    pts, labels = _labelled_plant_points()
    path = tmp_path / "plant.txt"
    np.savetxt(path, np.column_stack([pts, labels]), fmt="%.6f %.6f %.6f %d")
    for extra in (["--stem-label", "1"], ["--ignore-labels", "0"]):
        assert main(["traits", str(path)] + extra) == 2
        assert "give --labels too, or drop them" in capsys.readouterr().err
