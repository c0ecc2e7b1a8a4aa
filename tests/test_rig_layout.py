"""The rig read without MuJoCo (plantsim.rig.layout) and cast analytically (plantsim.sensor.primitives)
against MuJoCo's compiled model and mj_ray, the reference."""

import mujoco
import numpy as np
import pytest

from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.layout import N_GROUPS, LayoutError, rig_layout
from plantsim.rig.scene import _compile_checked, build_scene, build_spec
from plantsim.sensor.casting import CAST_GEOMGROUP, turning_bounds, turning_geoms
from plantsim.sensor.primitives import cast_geoms

RIGS = [
    RigGeometry(),
    RigGeometry(lidar_distance_m=0.6, lidar_height_m=0.4, tilt_deg=12.0, yaw_deg=-7.0, roll_deg=3.0),
    RigGeometry(lidar_distance_m=0.25, lidar_height_m=-0.05, disk_radius_m=0.15, disk_thickness_m=0.02,
                pedestal_height_m=0.12, yaw_deg=30.0),
]


def _tetra():
    vertices = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.02], [0.0, 0.05, 0.04], [0.01, 0.01, 0.2]])
    faces = np.array([[0, 1, 2], [0, 1, 3], [1, 2, 3], [0, 2, 3]])
    return plant_from_arrays(vertices, faces, placement="none")


def _compiled(rig, plant):
    return _compile_checked(build_spec(rig, plant, plant_areal_density_kg_m2=None))


def test_group_count_is_mujocos():
    assert N_GROUPS == mujoco.mjNGROUP


@pytest.mark.parametrize("rig", RIGS)
@pytest.mark.parametrize("with_plant", [False, True])
def test_layout_equals_the_compiled_model(rig, with_plant):
    plant = _tetra() if with_plant else None
    model = _compiled(rig, plant)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    layout = rig_layout(rig, with_plant=with_plant)
    assert [model.body(b).name for b in range(model.nbody)] == list(layout.bodies)
    assert model.ngeom == len(layout.geoms)
    for g, geom in enumerate(layout.geoms):
        assert model.geom(g).name == geom.name
        assert mujoco.mjtGeom(model.geom_type[g]).name == f"mjGEOM_{geom.type.upper()}"
        assert int(model.geom_group[g]) == geom.group
        assert model.body(model.geom_bodyid[g]).name == geom.body
        if geom.type == "mesh":  # MuJoCo re-centres a mesh in its geom frame: its pose is its own
            continue
        np.testing.assert_allclose(model.geom_size[g], geom.size, rtol=0, atol=1e-15)
        np.testing.assert_allclose(data.geom_xpos[g], geom.pos_base, rtol=0, atol=1e-15)
        np.testing.assert_allclose(data.geom_xmat[g].reshape(3, 3), geom.R_base_geom, rtol=0, atol=1e-15)


@pytest.mark.parametrize("rig", RIGS)
def test_a_lazy_scene_agrees_with_its_compiled_model(rig):
    scene = build_scene(rig, _tetra())
    assert scene.layout is not None and not scene.model_compiled
    turning, bounds = turning_geoms(scene), turning_bounds(scene)
    model = scene.model  # compiles, and checks the classes and the LiDAR's body against the layout
    assert scene.model_compiled
    eager = build_scene(rig, _tetra(), plant_areal_density_kg_m2=0.3)  # compiled at once (physics wants it)
    assert eager.layout is None
    np.testing.assert_array_equal(turning, turning_geoms(eager))
    np.testing.assert_array_equal(scene.geom_class, eager.geom_class)
    assert scene.lidar_body_id == eager.lidar_body_id == model.body("lidar").id
    # The same cylinder to the float32 rounding of MuJoCo's mesh vertices (both pad for it).
    np.testing.assert_allclose(bounds, turning_bounds(eager), rtol=0, atol=2e-6)


def _rays(rig, rng, n):
    """Rays from the LiDAR, from around and inside the rig, and rays aimed at edges and rims."""
    layout = rig_layout(rig, with_plant=False)
    origins, dirs = [], []
    lidar = rig.T_base_lidar()[:3, 3]
    d = rng.normal(size=(n, 3))
    origins.append(np.broadcast_to(lidar, (n, 3)))
    dirs.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    o = rng.uniform([-0.5, -0.5, -0.2], [0.9, 0.5, 0.6], size=(n, 3))  # some start inside a geom
    d = rng.normal(size=(n, 3))
    origins.append(o)
    dirs.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    for geom in layout.geoms:
        if geom.type not in ("box", "cylinder"):
            continue
        s = geom.size
        # Corners/edges of a box, the rims of a cylinder: grazing and exact-edge hits.
        if geom.type == "box":
            local = np.array([[sx * s[0], sy * s[1], sz * s[2]] for sx in (-1, 1) for sy in (-1, 1)
                              for sz in (-1, 1)])
        else:
            a = rng.uniform(0, 2 * np.pi, 16)
            local = np.stack([s[0] * np.cos(a), s[0] * np.sin(a), np.repeat([-s[1], s[1]], 8)], axis=1)
        targets = local @ geom.R_base_geom.T + geom.pos_base
        for target in targets:
            src = target + rng.normal(size=(8, 3)) * 0.3
            dd = target - src
            origins.append(src)
            dirs.append(dd / np.linalg.norm(dd, axis=1, keepdims=True))
            # Along the axes: rays that run exactly in a face's plane.
            axis = geom.R_base_geom
            origins.append(target - 0.3 * axis.T)
            dirs.append(axis.T.copy())
    return np.concatenate(origins), np.concatenate(dirs)


@pytest.mark.parametrize("rig", RIGS)
def test_primitive_casts_equal_mj_ray(rig):
    scene = build_scene(rig)  # lazy
    layout = scene.layout
    prims = [(i, g) for i, g in enumerate(layout.geoms)
             if CAST_GEOMGROUP[g.group] and g.body != "lidar" and g.type != "mesh"]
    origins, dirs = _rays(rig, np.random.default_rng(7), 3000)
    dist, geom_id, normal = cast_geoms(prims, origins, dirs, normals=True)
    model = scene.model
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    want_d = np.empty(len(origins))
    want_g = np.empty(len(origins), dtype=np.int32)
    want_n = np.zeros((len(origins), 3))
    gid, nrm = np.array([-1], np.int32), np.zeros(3)
    for k, (o, d) in enumerate(zip(origins, dirs)):
        want_d[k] = mujoco.mj_ray(model, data, o, d, CAST_GEOMGROUP, 1, scene.lidar_body_id, gid, nrm)
        want_g[k] = gid[0]
        want_n[k] = nrm
    assert (want_d >= 0).sum() > len(origins) // 8  # the test casts plenty of hits
    np.testing.assert_array_equal(geom_id, want_g)
    hit = want_d >= 0
    np.testing.assert_array_equal(dist < 0, ~hit)
    np.testing.assert_allclose(dist[hit], want_d[hit], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(normal[hit], want_n[hit], rtol=0, atol=1e-12)


def test_an_unreadable_rig_file_falls_back_to_mujoco(monkeypatch, caplog):
    import plantsim.rig.scene as scene_module

    def refuse(rig, *, with_plant):
        raise LayoutError("geom 'x': type 'capsule' is not cast without MuJoCo")

    monkeypatch.setattr(scene_module, "rig_layout", refuse)
    with caplog.at_level("INFO"):
        scene = build_scene(RigGeometry())
    assert scene.layout is None and scene.model_compiled
    assert "MuJoCo compiles the scene now: geom 'x'" in caplog.text
