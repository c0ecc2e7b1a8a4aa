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
