"""Truth traits from a mesh that labels its own parts (issue 13, item 4)."""

import math

import numpy as np
import pytest
import trimesh

from plantsim.evaluation import evaluate
from plantsim.plant.mesh import load_plant

R_STEM = 0.006
H_STEM = 0.4


def _sheet(length, width, origin, direction, n=30):
    """A flat horizontal rectangle as a triangle grid: vertices, faces."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    across = np.cross([0.0, 0.0, 1.0], d)
    u, v = np.meshgrid(np.linspace(0, length, n + 1), np.linspace(-width / 2, width / 2, 5), indexing="ij")
    verts = np.asarray(origin) + u.reshape(-1, 1) * d + v.reshape(-1, 1) * across
    faces = []
    for i in range(n):
        for j in range(4):
            a, b, c, e = i * 5 + j, i * 5 + j + 1, (i + 1) * 5 + j, (i + 1) * 5 + j + 1
            faces += [[a, c, b], [b, c, e]]
    return verts, np.array(faces)


def _parts():
    cyl = trimesh.creation.cylinder(radius=R_STEM, height=H_STEM, sections=96)
    cyl.apply_translation([0.02, -0.01, H_STEM / 2])
    leaf_a = _sheet(0.25, 0.02, (0.02 + R_STEM, -0.01, 0.15), (1.0, 0.0, 0.0))
    leaf_b = _sheet(0.18, 0.03, (0.02 - R_STEM, -0.01, 0.30), (-1.0, 0.0, 0.0))
    return [("stem", (np.asarray(cyl.vertices), np.asarray(cyl.faces))), ("leaf_1", leaf_a), ("leaf_2", leaf_b)]


def _write_obj(path, parts, scale=1.0):
    lines, offset = [], 1
    for name, (v, f) in parts:
        lines.append(f"o {name}")
        lines += [f"v {x * scale:.9g} {y * scale:.9g} {z * scale:.9g}" for x, y, z in v]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in f]
        offset += len(v)
    path.write_text("\n".join(lines) + "\n")


def _write_ply(path, parts):
    verts, faces, labels = [], [], []
    offset = 0
    for k, (_name, (v, f)) in enumerate(parts):
        verts.append(v)
        faces.append(f + offset)
        labels += [k] * len(f)
        offset += len(v)
    v, f = np.vstack(verts), np.vstack(faces)
    head = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y",
            "property float z", f"element face {len(f)}", "property list uchar int vertex_indices",
            "property int label", "end_header"]
    body = [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in v] + [f"3 {a} {b} {c} {k}" for (a, b, c), k in zip(f, labels)]
    path.write_text("\n".join(head + body) + "\n")


def _check(truth):
    assert truth["height_m"] == pytest.approx(H_STEM, abs=1e-6)
    (stem,) = truth["stems"]
    assert stem["diameter_m"] == pytest.approx(2 * R_STEM, rel=1e-3)
    assert stem["base_xy_m"] == pytest.approx([0.02, -0.01], abs=1e-6)
    assert stem["height_m"] == pytest.approx(H_STEM, abs=1e-6)
    a, b = sorted(truth["leaves"], key=lambda lf: lf["width_m"])
    # Areas are exact (sums of triangles); length and width by the midrib method on dense samples.
    assert a["area_m2"] == pytest.approx(0.25 * 0.02, rel=1e-6)
    assert b["area_m2"] == pytest.approx(0.18 * 0.03, rel=1e-6)
    assert truth["leaf_area_m2"] == pytest.approx(0.25 * 0.02 + 0.18 * 0.03, rel=1e-6)
    assert a["length_m"] == pytest.approx(0.25, rel=0.03) and a["width_m"] == pytest.approx(0.02, rel=0.08)
    assert b["length_m"] == pytest.approx(0.18, rel=0.03) and b["width_m"] == pytest.approx(0.03, rel=0.08)


def test_truth_from_obj_objects(tmp_path):
    path = tmp_path / "plant.obj"
    _write_obj(path, _parts())
    _check(evaluate.truth_from_labelled_mesh(path, n_samples_per_m2=1.0e6))


def test_truth_from_obj_in_millimetres(tmp_path):
    path = tmp_path / "plant_mm.obj"
    _write_obj(path, _parts(), scale=1000.0)
    _check(evaluate.truth_from_labelled_mesh(path, units_scale=0.001, n_samples_per_m2=1.0e6))


def test_truth_from_ply_face_labels(tmp_path):
    path = tmp_path / "plant.ply"
    _write_ply(path, _parts())
    _check(evaluate.truth_from_labelled_mesh(path, n_samples_per_m2=1.0e6))


def test_an_unlabelled_mesh_gives_no_truth(tmp_path):
    path = tmp_path / "box.stl"
    path.write_bytes(trimesh.creation.box(extents=[0.1, 0.1, 0.3]).export(file_type="stl"))
    assert evaluate.truth_from_labelled_mesh(path) is None


def test_evaluate_compares_with_the_labelled_mesh(tmp_path):
    path = tmp_path / "plant.obj"
    _write_obj(path, _parts())
    plant = load_plant(path)
    # A "scan": the placed mesh's own surface, densely sampled.
    mesh = trimesh.Trimesh(plant.vertices_turntable, plant.faces, process=False)
    pts, _ = trimesh.sample.sample_surface(mesh, 40_000, seed=1)
    ev = evaluate.evaluate_cloud(pts, plant, threads=1)
    assert ev.truth_path.endswith("(face labels)")
    assert ev.traits is not None
    assert ev.traits["height_m"].reference == pytest.approx(H_STEM, abs=1e-3)
    assert ev.traits["leaf_area_m2"].reference == pytest.approx(0.0104, rel=1e-6)
    assert ev.traits.n_leaves[1] == 2 and ev.traits.n_stems[1] == 1
    assert math.isfinite(ev.traits["stem_diameter_m"].estimate)


# ------------------------------------------- labelled procedural plants, every label form
from plantsim.plant import labels  # noqa: E402
from plantsim.plant.procedural import (  # noqa: E402
    PART_LEAF, PART_STEM, make_dicot, make_maize, make_rosette, to_labelled_obj_bytes)


@pytest.fixture(scope="module")
def small_dicot():
    # No lean: the stem's top ring lies level with its axis top, so the stem heights agree exactly.
    return make_dicot(seed=2, n_leaves=4, leaflets=3, n_branches=1, leaves_per_branch=1, stem_lean_deg=0.0)


def _organ_colours(plant, *, instance):
    """Per-face sRGB: plantsim's palette (semantic) or one green shade per leaf (instance)."""
    rgb = np.tile(np.array(labels.PART_COLOURS_RGB["petiole"]), (len(plant.faces), 1))
    rgb[plant.face_part == PART_STEM] = labels.PART_COLOURS_RGB["stem"]
    leaf = plant.face_part == PART_LEAF
    if instance:
        k = plant.face_organ[leaf]
        rgb[leaf] = np.column_stack([10 + 7 * (k % 20), 120 + 4 * (k % 30), 20 + 3 * (k // 20)])
    else:
        rgb[leaf] = labels.PART_COLOURS_RGB["leaf"]
    return rgb


def _ply_bytes(v, f, *, vertex_rgb=None, face_rgb=None):
    """ASCII PLY with double coordinates (trimesh's exporter writes float32) and colours."""
    head = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property double x", "property double y",
            "property double z"]
    if vertex_rgb is not None:
        head += ["property uchar red", "property uchar green", "property uchar blue"]
    head += [f"element face {len(f)}", "property list uchar int vertex_indices"]
    if face_rgb is not None:
        head += ["property uchar red", "property uchar green", "property uchar blue"]
    head.append("end_header")
    body = [" ".join([repr(x) for x in row] + ([] if vertex_rgb is None else [str(c) for c in vertex_rgb[i]]))
            for i, row in enumerate(v.tolist())]
    body += [" ".join(["3"] + [str(k) for k in row] + ([] if face_rgb is None else [str(c) for c in face_rgb[i]]))
             for i, row in enumerate(f.tolist())]
    return ("\n".join(head + body) + "\n").encode()


def _check_exact(truth, plant, *, area_rel=1e-9):
    """Leaf count, each leaf's area, the total leaf area and the stem height are the generator's."""
    t = plant.traits
    assert truth["leaf_count"] == len(t["leaves"])
    got = sorted(lf["area_m2"] for lf in truth["leaves"])
    want = sorted(lf["area_m2"] for lf in t["leaves"])
    np.testing.assert_allclose(got, want, rtol=area_rel)
    assert truth["leaf_area_m2"] == pytest.approx(t["leaf_area_m2"], rel=area_rel)
    assert truth["stem_count"] == len(t["stems"])
    assert max(s["height_m"] for s in truth["stems"]) == pytest.approx(
        max(s["height_m"] for s in t["stems"]), rel=max(area_rel, 1e-12))
    # Height: the top of the stem and leaf faces (petioles and branches are neither).
    organs = np.isin(plant.face_part, [PART_STEM, PART_LEAF])
    assert truth["height_m"] == pytest.approx(plant.vertices_m[plant.faces[organs]][..., 2].max(),
                                              rel=max(area_rel, 1e-12))


def test_truth_from_obj_objects_of_a_procedural_dicot(small_dicot):
    data = to_labelled_obj_bytes(small_dicot)
    assert b"\no petiole_0\n" in data and b"\no branch_0\n" in data
    _check_exact(evaluate.truth_from_labelled_mesh(data, file_type="obj", n_samples_per_m2=0), small_dicot)


@pytest.mark.parametrize("instance", [False, True], ids=["semantic", "instance"])
def test_truth_from_ply_vertex_colours(small_dicot, instance):
    plant = small_dicot
    # Organs never share vertices, so each vertex takes its face's colour unambiguously.
    face_rgb = _organ_colours(plant, instance=instance)
    vertex_rgb = np.zeros((len(plant.vertices_m), 3), dtype=np.uint8)
    vertex_rgb[plant.faces.reshape(-1)] = np.repeat(face_rgb, 3, axis=0)
    data = _ply_bytes(plant.vertices_m, plant.faces, vertex_rgb=vertex_rgb)
    _check_exact(evaluate.truth_from_labelled_mesh(data, file_type="ply", n_samples_per_m2=0), plant)


def test_truth_from_ply_face_colours_of_a_maize():
    plant = make_maize(seed=1, n_leaves=5, stem_lean_deg=0.0)
    data = _ply_bytes(plant.vertices_m, plant.faces, face_rgb=_organ_colours(plant, instance=True))
    truth = evaluate.truth_from_labelled_mesh(data, file_type="ply", n_samples_per_m2=0)
    _check_exact(truth, plant)


def test_truth_from_a_glb_scene_of_named_nodes(small_dicot):
    plant = small_dicot
    scene = trimesh.Scene()
    for (part, organ) in sorted(set(zip(plant.face_part.tolist(), plant.face_organ.tolist()))):
        mine = (plant.face_part == part) & (plant.face_organ == organ)
        ids, faces = np.unique(plant.faces[mine], return_inverse=True)
        name = {PART_STEM: "stem", PART_LEAF: "leaf"}.get(part, "petiole")
        scene.add_geometry(trimesh.Trimesh(plant.vertices_m[ids], faces.reshape(-1, 3), process=False),
                           node_name=f"{name}_{organ}_{part}", geom_name=f"g{part}_{organ}")
    truth = evaluate.truth_from_labelled_mesh(scene.export(file_type="glb"), file_type="glb",
                                              n_samples_per_m2=0)
    # glTF stores float32 positions: areas agree to float32 rounding, not to 1e-9.
    _check_exact(truth, plant, area_rel=2e-6)


def test_truth_from_face_label_arrays_in_memory():
    plant = make_rosette(seed=1, n_leaves=5)
    face_labels = np.where(plant.face_part == PART_LEAF, plant.face_organ + 1, 0)
    parts = labels.parts_from_face_labels(plant.vertices_m, plant.faces, face_labels)
    assert [p.kind for p in parts].count("leaf") == 5 and [p.kind for p in parts].count("stem") == 1
    areas = sorted(float(trimesh.Trimesh(p.vertices, p.faces, process=False).area)
                   for p in parts if p.kind == "leaf")
    np.testing.assert_allclose(areas, sorted(lf["area_m2"] for lf in plant.traits["leaves"]), rtol=1e-12)
    # A Pheno4D-like convention: 0 soil, 1 stem, 2.. leaves.
    shifted = np.where(plant.face_part == PART_LEAF, plant.face_organ + 2, 1)
    parts = labels.parts_from_face_labels(plant.vertices_m, plant.faces, shifted, stem_label=1,
                                          ignore_labels=(0,))
    assert len(parts) == 6
    with pytest.raises(ValueError, match=r"face_labels must have one label per face \(\d+\), got 3"):
        labels.parts_from_face_labels(plant.vertices_m, plant.faces, [0, 1, 2])


def test_ply_vertex_label_property_and_unwelded_stl_like_vertices():
    plant = make_rosette(seed=0, n_leaves=3)
    # Every face on its own three vertices (as STL stores them): leaves are told apart
    # by their labels; the stem's patch is welded back by exact position.
    v = plant.vertices_m[plant.faces.reshape(-1)]
    f = np.arange(len(v)).reshape(-1, 3)
    vertex_label = np.repeat(np.where(plant.face_part == PART_LEAF, plant.face_organ + 1, 0), 3)
    head = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property double x", "property double y",
            "property double z", "property int label", f"element face {len(f)}",
            "property list uchar int vertex_indices", "end_header"]
    body = [f"{x!r} {y!r} {z!r} {k}" for (x, y, z), k in zip(v.tolist(), vertex_label)]
    body += [f"3 {a} {b} {c}" for a, b, c in f]
    data = ("\n".join(head + body) + "\n").encode()
    truth = evaluate.truth_from_labelled_mesh(data, file_type="ply", n_samples_per_m2=0)
    assert truth["leaf_count"] == 3 and truth["stem_count"] == 1
    assert truth["leaf_area_m2"] == pytest.approx(plant.traits["leaf_area_m2"], rel=1e-9)


def test_colour_rules_and_legend():
    assert labels.colour_kind((34, 139, 34)) == "leaf"
    assert labels.colour_kind((139, 69, 19)) == "stem"
    assert labels.colour_kind((128, 128, 0)) is None          # plantsim's petiole colour
    assert labels.colour_kind((250, 250, 250)) is None        # unpainted
    assert labels.colour_kind((60, 200, 90)) == "leaf"
    assert labels.colour_kind((160, 100, 60)) == "stem"
    assert labels.colour_kind((160, 100, 60), {(160, 100, 60): "ignore"}) is None
    with pytest.raises(ValueError, match=r"legend values must be 'stem', 'leaf' or 'ignore', got 'root'"):
        labels.read_labelled_parts(b"", file_type="obj", legend={(1, 2, 3): "root"})
    with pytest.raises(ValueError, match=r"file_type is needed"):
        labels.read_labelled_parts(b"ply")
    # One colour everywhere is a painted mesh, not a labelled one.
    box = trimesh.creation.box()
    assert labels.parts_from_colours(box.vertices, box.faces, np.tile([30, 160, 40], (12, 1))) == []


def test_truth_notes_name_missing_and_unknown_keys():
    full = {"height_m": 0.3, "stems": [{"base_xy_m": [0, 0]}], "stem_distances_m": [], "leaves": [{}],
            "leaf_area_m2": 0.01, "convex_hull_volume_m3": 1e-3, "projected_area_xy_m2": 0.02}
    # One stem: no distance between stems is expected.
    assert evaluate.truth_notes(full) == []
    two = dict(full, stems=[{"base_xy_m": [0, 0]}, {"base_xy_m": [0.04, 0]}])
    assert evaluate.truth_notes(two) == ["truth has no stem_distances_m: not compared"]
    notes = evaluate.truth_notes({"height_m": 0.3, "plant_height_mm": 300})
    assert notes[0] == "truth lacks stems, leaves, leaf_area_m2: those traits are not compared"
    assert notes[1] == "truth has no convex_hull_volume_m3, projected_area_xy_m2: not compared"
    assert notes[2] == "truth keys not in the schema, ignored: plant_height_mm"


def test_evaluate_notes_a_truth_without_leaves_and_still_compares_height(tmp_path, caplog):
    path = tmp_path / "plant.obj"
    _write_obj(path, _parts())
    (tmp_path / "plant.traits.json").write_text('{"height_m": 0.4}')
    plant = load_plant(path)
    mesh = trimesh.Trimesh(plant.vertices_turntable, plant.faces, process=False)
    pts, _ = trimesh.sample.sample_surface(mesh, 20_000, seed=1)
    with caplog.at_level("INFO", logger="plantsim.evaluation.evaluate"):
        ev = evaluate.evaluate_cloud(pts, plant, threads=1)
    assert "truth lacks stems, leaves, leaf_area_m2: those traits are not compared" in caplog.text
    assert ev.traits["height_m"].reference == pytest.approx(0.4)
    with pytest.raises(KeyError):
        ev.traits["leaf_area_m2"]


def test_truth_from_obj_vertex_colours_and_a_glb_with_vertex_colours():
    plant = make_rosette(seed=4, n_leaves=4)
    face_rgb = _organ_colours(plant, instance=True)
    vertex_rgb = np.zeros((len(plant.vertices_m), 3), dtype=np.int64)
    vertex_rgb[plant.faces.reshape(-1)] = np.repeat(face_rgb, 3, axis=0)
    lines = [f"v {x!r} {y!r} {z!r} {r / 255:.6f} {g / 255:.6f} {b / 255:.6f}"
             for (x, y, z), (r, g, b) in zip(plant.vertices_m.tolist(), vertex_rgb.tolist())]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in plant.faces.tolist()]
    truth = evaluate.truth_from_labelled_mesh("\n".join(lines).encode(), file_type="obj", n_samples_per_m2=0)
    _check_exact(truth, plant)
    # One GLB mesh (no organ names) whose COLOR_0 says the organs.
    mesh = trimesh.Trimesh(plant.vertices_m, plant.faces, vertex_colors=vertex_rgb.astype(np.uint8),
                           process=False)
    glb = trimesh.Scene({"plant": mesh}).export(file_type="glb")
    _check_exact(evaluate.truth_from_labelled_mesh(glb, file_type="glb", n_samples_per_m2=0), plant,
                 area_rel=2e-6)
