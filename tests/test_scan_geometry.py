"""Reconstruction against analytic shapes: ideal points lie on the true surface.

The shapes are MuJoCo primitives (exact spheres, cylinders, boxes) and a box
mesh (exact planar faces), all placed off the turntable axis, so a wrong sign
of the turntable rotation (the original tool's mirror) cannot pass.
"""

import math

import mujoco
import numpy as np
import pytest

from plantsim.sensor import casting as scan_module
from plantsim.plant.mesh import plant_from_arrays
from plantsim.cloud.reconstruct import reconstruct
from plantsim.rig.geometry import RigGeometry, beam_dirs_lidar
from plantsim.scan.raw import BeamGrid
from plantsim.scan.schedule import StepScan
from plantsim.scan.pipeline import step_and_shoot
from plantsim.rig.scene import HitClass, build_spec, build_scene, compile_scene
from plantsim.sensor.spec import URG_04LX_UG01
from plantsim.transforms import make_T, rot_z

from conftest import brute_force_first_hit

TOL_M = 1e-6


def scene_with_primitive(rig, geom_type, size, pos_turntable, quat=(1, 0, 0, 0)):
    spec = build_spec(rig)
    body = spec.body("turntable").add_body(name="shape", pos=pos_turntable, quat=quat)
    body.add_geom(spec.find_default("plant"), type=geom_type, size=size)
    return compile_scene(spec, rig, None)


def plant_points(scene, step_deg=3.0, rig=None):
    raw = step_and_shoot(scene, URG_04LX_UG01, StepScan(step_deg=step_deg))
    return reconstruct(raw).plant_only().points_turntable, raw


@pytest.mark.parametrize("rig", [RigGeometry(), RigGeometry(lidar_distance_m=0.42, lidar_height_m=0.3,
                                                            tilt_deg=-20, yaw_deg=4, roll_deg=3)])
def test_sphere_off_axis(rig):
    centre = np.array([0.04, -0.03, 0.12])
    scene = scene_with_primitive(rig, mujoco.mjtGeom.mjGEOM_SPHERE, [0.035, 0, 0], centre)
    points, _ = plant_points(scene)
    assert len(points) > 500
    residual = np.linalg.norm(points - centre, axis=1) - 0.035
    assert np.abs(residual).max() < TOL_M
    # The mirror image (the original tool's sign error) is far off the sphere.
    mirrored = points * [1, -1, 1]
    assert np.abs(np.linalg.norm(mirrored - centre, axis=1) - 0.035).max() > 0.03


def test_cylinder_off_axis():
    centre = np.array([-0.05, 0.02, 0.1])
    scene = scene_with_primitive(RigGeometry(), mujoco.mjtGeom.mjGEOM_CYLINDER, [0.012, 0.08, 0], centre)
    points, _ = plant_points(scene, step_deg=2.0)
    radial = np.linalg.norm(points[:, :2] - centre[:2], axis=1)
    # A finite cylinder is the intersection of an infinite one and a slab, so a
    # point is on its surface exactly when the larger of the two excesses is 0.
    excess = np.maximum(radial - 0.012, np.abs(points[:, 2] - centre[2]) - 0.08)
    assert len(points) > 300 and (np.abs(points[:, 2] - centre[2]) < 0.079).sum() > 200
    assert np.abs(excess).max() < TOL_M


def test_rotated_box_primitive_off_axis():
    centre = np.array([0.03, 0.05, 0.09])
    half = np.array([0.02, 0.03, 0.05])
    angle = 0.4
    quat = [math.cos(angle / 2), 0, 0, math.sin(angle / 2)]
    scene = scene_with_primitive(RigGeometry(), mujoco.mjtGeom.mjGEOM_BOX, half, centre, quat)
    points, _ = plant_points(scene)
    local = (points - centre) @ rot_z(angle)  # turntable -> box frame
    excess = np.abs(local) - half
    # Every point lies on a face: its largest excess is 0 and none is outside.
    assert np.abs(excess.max(axis=1)).max() < TOL_M


def test_box_mesh_placed_by_explicit_transform(box_mesh):
    vertices, faces = box_mesh
    T = make_T(rot_z(0.7), [0.05, -0.04, 0.06])
    plant = plant_from_arrays(vertices, faces, T_turntable_mesh=T)
    scene = build_scene(RigGeometry(), plant)
    points, raw = plant_points(scene, step_deg=4.0)
    local = (points - T[:3, 3]) @ T[:3, :3]
    excess = np.abs(local) - np.array([0.02, 0.03, 0.06])
    assert len(points) > 300
    assert np.abs(excess.max(axis=1)).max() < TOL_M


def test_hand_computed_beam_on_a_box_face(box_mesh):
    """Beam 340 (angle 0) at table angle 0 and 90 deg: ranges worked out by hand."""
    vertices, faces = box_mesh  # 40 x 60 x 120 mm
    plant = plant_from_arrays(vertices, faces, T_turntable_mesh=make_T(t=[0.0, 0.0, 0.06]))
    rig = RigGeometry(lidar_distance_m=0.35, lidar_height_m=0.05)
    raw = step_and_shoot(build_scene(rig, plant), URG_04LX_UG01, StepScan(step_deg=90))
    # At 0 deg the +X face (x = 0.02) faces the sensor: range 0.35 - 0.02. Ranges are
    # float32 values, as a LaserScan carries them: exact to half a float32 step.
    assert raw.range_m[0, 340] == np.float32(0.33)
    # At +90 deg (counter-clockwise) the box's -Y face (y = -0.03) turns to face +X.
    assert raw.range_m[1, 340] == np.float32(0.32)
    cloud = reconstruct(raw)
    first = (cloud.scan_index == 1) & (cloud.beam_index == 340)
    np.testing.assert_allclose(cloud.points_turntable[first][0], [0.0, -0.03, 0.05], atol=1e-7)


def test_axis_trap_is_guarded(monkeypatch):
    """A scan plane through the axis of a mesh sphere centred on it: brute force agrees."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    vertices = np.asarray(sphere.vertices) + [0, 0, 0.1]
    plant = plant_from_arrays(vertices, np.asarray(sphere.faces), placement="none")
    rig = RigGeometry(lidar_distance_m=0.35, lidar_height_m=0.1)
    lidar = URG_04LX_UG01.replace(n_beams=401, angle_min_deg=-20, angle_increment_deg=0.1)
    scene = build_scene(rig, plant)
    origin = rig.T_base_lidar()[:3, 3]
    dirs = beam_dirs_lidar(BeamGrid.of(lidar).beam_angles_rad()) @ rig.T_base_lidar()[:3, :3].T
    reference = brute_force_first_hit(origin, dirs, plant.vertices_turntable, plant.faces)
    assert np.isfinite(reference).sum() > 100

    def first_line_ranges():
        # MuJoCo's BVH is the one with the trap (Embree, float32 traversal, is not).
        raw = step_and_shoot(scene, lidar, StepScan(step_deg=90), caster="mujoco")
        plant_hit = raw.hit_class[0] == HitClass.PLANT
        return np.where(plant_hit, raw.range_m[0], np.inf)

    guarded = first_line_ranges()
    np.testing.assert_allclose(guarded, reference, atol=1e-7)
    # Without the guard MuJoCo gets beams wrong: the test can fail.
    monkeypatch.setattr(scan_module, "AXIS_TRAP_OFFSET_M", 0.0)
    unguarded = first_line_ranges()
    wrong = np.isfinite(unguarded) != np.isfinite(reference)
    both = np.isfinite(unguarded) & np.isfinite(reference)
    wrong[both] = np.abs(unguarded[both] - reference[both]) > 1e-7
    assert wrong.sum() > 10


def test_misses_are_never_points_and_limits_are_honoured(box_mesh):
    vertices, faces = box_mesh
    plant = plant_from_arrays(vertices, faces)
    lidar = URG_04LX_UG01.replace(range_min_m=0.30, range_max_m=0.40)
    raw = step_and_shoot(build_scene(RigGeometry(), plant), lidar, StepScan(step_deg=30))
    cloud = reconstruct(raw)
    assert np.isfinite(cloud.points_turntable).all()
    assert (cloud.range_m >= 0.30).all() and (cloud.range_m <= 0.40).all()
    counts = raw.counts()
    assert counts["by_status"]["no_echo"] > 0 and counts["by_status"]["too_near"] > 0
    assert counts["returns"] == len(cloud)
    assert not np.any(np.all(cloud.points_turntable == 0, axis=1))


def test_scan_schedule_validation():
    with pytest.raises(ValueError, match="step_deg must be > 0"):
        StepScan(step_deg=0)
    with pytest.raises(ValueError, match="step_deg must be > 0"):
        StepScan(step_deg=-1)
    with pytest.raises(ValueError, match="step_deg must be a finite number"):
        StepScan(step_deg=float("nan"))
    with pytest.raises(ValueError, match="step_deg must divide sweep_deg evenly"):
        StepScan(step_deg=0.7)
    assert StepScan(step_deg=0.25).n_lines == 1440
    np.testing.assert_allclose(np.rad2deg(StepScan(step_deg=90, sweep_deg=270).angles_rad()), [0, 90, 180])


def test_beam_times_follow_the_mirror(box_mesh):
    vertices, faces = box_mesh
    raw = step_and_shoot(build_scene(RigGeometry(), plant_from_arrays(vertices, faces)),
                         URG_04LX_UG01, StepScan(step_deg=120, step_time_s=0.5))
    expected = 0.5 * np.arange(3)[:, None] + (44 + np.arange(683))[None, :] / 1024 * 0.1
    np.testing.assert_allclose(raw.time_s, expected, atol=1e-15)
