"""Plant import: formats, units, up axis, placement, bad meshes, big meshes."""

import logging

import numpy as np
import pytest
import trimesh

from plantsim.errors import MeshError
from plantsim.plant.mesh import load_plant, plant_from_arrays, shell_inertia
from plantsim.cloud.reconstruct import reconstruct
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.schedule import StepScan
from plantsim.scan.pipeline import step_and_shoot
from plantsim.rig.scene import build_scene
from plantsim.sensor.spec import URG_04LX_UG01


def leaf_like_mesh():
    """An L-shaped open surface (no volume) 0.2 m tall, base off the origin, in cm, Y up."""
    v = np.array([[0, 0, 0], [2, 0, 0], [2, 20, 0], [0, 20, 0], [2, 20, 8], [0, 20, 8]], float)
    v += [5.0, 3.0, -4.0]
    f = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4], [3, 4, 5]])
    return v, f


def write(tmp_path, name, vertices, faces, file_type):
    path = tmp_path / name
    data = trimesh.Trimesh(vertices, faces, process=False).export(file_type=file_type)
    path.write_bytes(data.encode("ascii") if isinstance(data, str) else data)
    return path


@pytest.mark.parametrize("name, file_type", [("p.stl", "stl"), ("p_ascii.stl", "stl_ascii"),
                                             ("p.obj", "obj"), ("p.ply", "ply")])
def test_formats_units_up_and_placement(tmp_path, name, file_type):
    v, f = leaf_like_mesh()
    path = write(tmp_path, name, v, f, file_type)
    plant = load_plant(path, units="cm", up="y")
    lo, hi = plant.bounds_turntable()
    assert hi[2] - lo[2] == pytest.approx(0.20, abs=1e-6)  # Y (20 cm) became Z
    assert lo[2] == pytest.approx(0.0, abs=1e-12)  # resting on the disk top
    # Base (the file's lowest edge, y = 3 cm, x = 5..7 cm, z = -4 cm) centred on the axis.
    base = plant.vertices_turntable[plant.vertices_turntable[:, 2] < 1e-9]
    np.testing.assert_allclose((base.min(0) + base.max(0))[:2] / 2, [0, 0], atol=1e-9)
    assert plant.n_faces == 4 and plant.n_degenerate_dropped == 0
    # T_turntable_mesh maps the file's coordinates (in metres) to the turntable frame.
    T = plant.T_turntable_mesh
    np.testing.assert_allclose(T[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(T[:3, :3] @ (v[0] * 0.01) + T[:3, 3],
                               [-0.01, 0.0, 0.0], atol=1e-12)  # file (5, 3, -4) cm


def test_binary_stl_whose_header_starts_with_solid(tmp_path):
    v, f = leaf_like_mesh()
    data = trimesh.Trimesh(v, f, process=False).export(file_type="stl")
    path = tmp_path / "solid_header.stl"
    path.write_bytes(b"solid trigo" + data[11:])
    assert path.read_bytes()[:5] == b"solid"
    plant = load_plant(path, units="cm", up="y")
    assert plant.n_faces == 4


@pytest.mark.parametrize("up, axis", [("x", 0), ("y", 1), ("z", 2)])
def test_up_axis_becomes_z_without_mirroring(up, axis):
    v = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], float)
    v[:, axis] *= 30  # the up axis is the long one
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    plant = plant_from_arrays(v, f, up=up)
    assert np.ptp(plant.vertices_turntable[:, 2]) == pytest.approx(0.3)
    assert np.linalg.det(plant.T_turntable_mesh[:3, :3]) == pytest.approx(1.0)


def test_degenerate_faces_are_dropped_and_counted(caplog):
    v, f = leaf_like_mesh()
    v = np.vstack([v, [[1, 1, 1], [2, 2, 2], [3, 3, 3]]])  # collinear: zero area
    f = np.vstack([f, [[0, 0, 1]], [[6, 7, 8]]])
    with caplog.at_level(logging.WARNING):
        plant = plant_from_arrays(v, f, units="cm")
    assert plant.n_degenerate_dropped == 2 and plant.n_faces == 4 and plant.n_faces_in_file == 6
    assert "dropped 2 degenerate faces of 6" in caplog.text


@pytest.mark.parametrize("vertices, faces, message", [
    (np.zeros((0, 3)), np.zeros((0, 3), int), "has no triangles"),
    (np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]]), np.array([[0, 1, 2]]), "1 of 3 vertices are NaN or infinite"),
    (np.array([[0, 0, 0], [1, 0, 0], [np.inf, 1, 0]]), np.array([[0, 1, 2]]), "NaN or infinite"),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 5]]), "face indices out of range"),
    (np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]]), np.array([[0, 1, 2]]), "all 1 faces are degenerate"),
])
def test_bad_meshes_raise_clear_errors(vertices, faces, message):
    with pytest.raises(MeshError, match=message):
        plant_from_arrays(vertices, faces)


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="mesh file not found"):
        load_plant(tmp_path / "missing.stl")
    (tmp_path / "empty.stl").write_bytes(b"")
    with pytest.raises(MeshError, match="is empty"):
        load_plant(tmp_path / "empty.stl")
    (tmp_path / "garbage.stl").write_bytes(b"this is not a mesh at all" * 10)
    with pytest.raises(MeshError, match="is not a readable STL: not ASCII"):
        load_plant(tmp_path / "garbage.stl")
    (tmp_path / "garbage.ply").write_bytes(b"\x00\x01\x02 junk")
    with pytest.raises(MeshError, match="cannot parse"):
        load_plant(tmp_path / "garbage.ply")
    (tmp_path / "plant.dae").write_bytes(b"<xml/>")
    with pytest.raises(ValueError, match="use one of .stl, .obj, .ply"):
        load_plant(tmp_path / "plant.dae")
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="NaN or infinite"):
        load_plant(tmp_path / "nan.obj")


def test_size_warning_suggests_the_unit(caplog):
    v, f = leaf_like_mesh()
    with caplog.at_level(logging.WARNING):
        plant_from_arrays(v, f, units="cm", up="y")  # 0.2 m: plausible
    assert "looks off" not in caplog.text
    with caplog.at_level(logging.WARNING):
        plant_from_arrays(v * 10, f, units="m", up="y")  # "200 m" tall: really cm
    assert "200 m tall with units='m', which looks off for a plant; did you mean units='cm'" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        plant_from_arrays(v, f, units="mm", up="y")  # 2 cm: a seedling, plausible
        plant_from_arrays(v / 100, f, units="mm", up="y")  # 0.2 mm: really m
    assert "did you mean units='m'" in caplog.text


def test_explicit_transform_must_be_rigid():
    v, f = leaf_like_mesh()
    with pytest.raises(ValueError, match="must be rigid"):
        plant_from_arrays(v, f, units="cm", T_turntable_mesh=np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ValueError, match="units must be one of m, cm, mm"):
        plant_from_arrays(v, f, units="inch")


def test_shell_inertia_of_a_square_plate_matches_the_textbook():
    # A 1 m x 1 m plate of 1 kg in the XY plane: Ixx = Iyy = m/12, Izz = m/6.
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    mass, com, inertia = shell_inertia(v, f, areal_density_kg_m2=1.0)
    assert mass == pytest.approx(1.0)
    np.testing.assert_allclose(com, 0, atol=1e-15)
    np.testing.assert_allclose(np.diag(inertia), [1 / 12, 1 / 12, 1 / 6], rtol=1e-12)


def test_mesh_over_200k_faces_compiles_and_scans():
    sphere = trimesh.creation.icosphere(subdivisions=7, radius=0.05)  # 327,680 faces
    assert len(sphere.faces) > 200_000
    plant = plant_from_arrays(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    scene = build_scene(RigGeometry(), plant)
    assert scene.model.mesh_facenum[0] == len(sphere.faces)
    raw = step_and_shoot(scene, URG_04LX_UG01, StepScan(step_deg=90))
    points = reconstruct(raw).plant_only().points_turntable
    centre = np.array([0, 0, 0.05])
    r = np.linalg.norm(points - centre, axis=1)
    assert len(points) > 100 and np.abs(r - 0.05).max() < 2e-6  # chord error of the facets


def test_vertex_deduplication_is_numpys_unique():
    from plantsim.plant.mesh import unique_rows
    from plantsim.resources import bundled_plant_path
    from plantsim.plant.mesh import binary_stl_arrays

    rng = np.random.default_rng(0)
    grid = rng.integers(0, 5, size=(5000, 3)).astype(np.float64) * 0.25  # many exact duplicates
    for vertices in (grid, binary_stl_arrays(bundled_plant_path("maize").read_bytes())[0]):
        expected, expected_inverse = np.unique(vertices, axis=0, return_inverse=True)
        unique, inverse = unique_rows(vertices)
        np.testing.assert_array_equal(unique, expected)
        np.testing.assert_array_equal(inverse, expected_inverse.reshape(-1))


def _clean_arrays_reference(vertices, faces):
    """clean_arrays as it was written with np.unique (the reference for the faster one)."""
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    faces = inverse.reshape(-1)[faces].astype(np.int64)
    tri = unique[faces]
    doubled_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    extent = float(np.ptp(unique, axis=0).max()) or 1.0
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    faces = faces[~(repeated | (doubled_area <= 1e-14 * extent * extent))]
    used = np.unique(faces)
    remap = np.full(len(unique), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return unique[used], remap[faces].astype(np.int32)


def test_cleaning_gives_the_np_unique_result_exactly():
    from plantsim.plant.mesh import clean_arrays
    from plantsim.plant.mesh import binary_stl_arrays
    from plantsim.resources import bundled_plant_path

    rng = np.random.default_rng(1)
    grid = rng.integers(0, 6, size=(3000, 3)).astype(np.float64) * 0.1
    grid[::7] *= -1.0  # signed zeros among the duplicates
    faces = rng.integers(0, len(grid), size=(2000, 3))
    faces[:50, 1] = faces[:50, 0]  # repeated indices: dropped, and their lone vertices with them
    cases = [(grid, faces), binary_stl_arrays(bundled_plant_path("maize").read_bytes())]
    for vertices, faces in cases:
        expected_vertices, expected_faces = _clean_arrays_reference(vertices, faces)
        got_vertices, got_faces, n_dropped = clean_arrays(vertices, faces)
        assert len(got_vertices) < len(np.unique(vertices, axis=0)) or vertices is not grid
        np.testing.assert_array_equal(got_vertices, expected_vertices)
        np.testing.assert_array_equal(got_faces, expected_faces)
        assert got_faces.dtype == np.int32 and n_dropped == len(faces) - len(expected_faces)
