"""The calibration target and `plantsim calibrate`: exact geometry, recovered rigs, the CLI."""

from __future__ import annotations

import dataclasses
import tomllib

import mujoco
import numpy as np
import pytest

from plantsim.cli.app import main
from plantsim.cloud.calibration import PARAMETERS, calibrate
from plantsim.cloud.export import read_cloud
from plantsim.plant.mesh import load_plant
from plantsim.plant.target import CALIBRATION_TARGET, ray_distance, target_stl_bytes
from plantsim.resources import bundled_plant_path
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import build_scene
from plantsim.scan.config import PlantOptions, RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan

SAGITTA_M = CALIBRATION_TARGET.drum_radius_m * (1 - np.cos(np.pi / CALIBRATION_TARGET.sections))
TRUTH = RigGeometry(lidar_distance_m=0.357, lidar_height_m=0.142, tilt_deg=0.7, yaw_deg=-0.8, roll_deg=0.5,
                    encoder_offset_deg=3.0)


def test_the_bundled_target_is_its_description():
    assert bundled_plant_path("calibration-target").read_bytes() == target_stl_bytes(CALIBRATION_TARGET)


def test_the_distance_function_is_exact_on_the_mesh():
    vertices, faces = CALIBRATION_TARGET.mesh()
    rng = np.random.default_rng(0)
    tri = vertices[faces]
    u, v = rng.random((2, len(faces)))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    points = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    # Surface points of the faceted mesh are within a facet's sagitta of the exact surface
    # (or inside where two parts touch, where the union's surface is elsewhere).
    d = CALIBRATION_TARGET.distance(points)
    assert d.max() <= SAGITTA_M + 1e-12 and np.median(np.abs(d)) < SAGITTA_M


def test_ray_distance_agrees_with_mujoco_on_the_target_mesh():
    plant = load_plant(bundled_plant_path("calibration-target"), placement="none")
    scene = build_scene(RigGeometry(), plant)
    model, data = scene.model, mujoco.MjData(scene.model)
    mujoco.mj_kinematics(model, data)
    rng = np.random.default_rng(1)
    origins = np.column_stack([rng.uniform(0.2, 0.4, 300), rng.uniform(-0.1, 0.1, 300), rng.uniform(0.0, 0.4, 300)])
    aim = np.column_stack([np.zeros(300), np.zeros(300), rng.uniform(0.0, 0.35, 300)])
    dirs = aim - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    analytic = ray_distance(CALIBRATION_TARGET, origins, dirs)
    plant_group = np.array([0, 0, 1, 0, 0, 0], dtype=np.uint8)
    geomid = np.zeros(1, dtype=np.int32)
    hits = 0
    for o, d, a in zip(origins, dirs, analytic):
        dist = mujoco.mj_ray(model, data, o, d, plant_group, 1, -1, geomid)
        assert (dist >= 0) == np.isfinite(a)
        if dist >= 0:
            hits += 1
            assert abs(dist - a) < 3 * SAGITTA_M
    assert hits > 200


def scan_of_target(rig, sensor="ideal", step_deg=2.0):
    config = RunConfig(plant=PlantOptions(bundled="calibration-target"), rig=rig, sensor=sensor,
                       scan=StepScan(step_deg=step_deg))
    return run_scan(config)


def test_calibration_recovers_a_perturbed_rig_from_an_ideal_scan():
    raw = scan_of_target(TRUTH).raw
    fit = calibrate(raw, nominal=RigGeometry())
    tolerance = {"lidar_distance_m": 1e-5, "lidar_height_m": 1e-5, "tilt_deg": 0.005, "yaw_deg": 0.005,
                 "roll_deg": 0.005, "encoder_offset_deg": 0.005}
    for name in PARAMETERS:
        assert getattr(fit.rig, name) == pytest.approx(getattr(TRUTH, name), abs=tolerance[name]), name
    assert fit.n_kept == fit.n_points and fit.rms_m < 1e-5


def test_the_encoder_offset_changes_no_simulated_cloud():
    plain = scan_of_target(dataclasses.replace(TRUTH, encoder_offset_deg=0.0))
    offset = scan_of_target(TRUTH)
    np.testing.assert_allclose(offset.cloud.points_turntable, plain.cloud.points_turntable, atol=1e-9)
    assert not np.allclose(offset.raw.encoder_angle_rad[-1], plain.raw.encoder_angle_rad[-1])


def test_calibrate_cli_writes_a_rig_that_reconstruct_uses(tmp_path, capsys):
    truth = tmp_path / "truth.toml"
    truth.write_text('[plant]\nbundled = "calibration-target"\n[rig]\nlidar_distance_m = 0.357\n'
                     "lidar_height_m = 0.142\ntilt_deg = 0.7\nyaw_deg = -0.8\nroll_deg = 0.5\n"
                     "encoder_offset_deg = 3.0\n")
    nominal = tmp_path / "nominal.toml"
    nominal.write_text("[rig]\nlidar_distance_m = 0.35\nlidar_height_m = 0.15\n")
    bag, fitted = tmp_path / "bag", tmp_path / "fitted.toml"
    assert main(["scan", "--config", str(truth), "--sensor", "ideal", "--step-deg", "3", "--raw", str(bag),
                 "-o", str(tmp_path / "t.las")]) == 0
    assert main(["calibrate", str(bag), "-o", str(fitted), "--start", str(nominal)]) == 0
    rig = tomllib.loads(fitted.read_text())["rig"]
    assert rig["lidar_distance_m"] == pytest.approx(0.357, abs=1e-4)
    assert rig["encoder_offset_deg"] == pytest.approx(3.0, abs=0.01)
    for name, path in (("right", fitted), ("wrong", nominal)):
        assert main(["reconstruct", str(bag), "--rig", str(path), "-o", str(tmp_path / f"{name}.las")]) == 0
    right = read_cloud(tmp_path / "right.las").plant_only().points_turntable
    wrong = read_cloud(tmp_path / "wrong.las").plant_only().points_turntable
    assert np.median(np.abs(CALIBRATION_TARGET.distance(right))) < 2e-5
    assert np.median(np.abs(CALIBRATION_TARGET.distance(wrong))) > 2e-3


def test_a_scan_of_something_else_is_refused():
    from plantsim.plant.mesh import plant_from_arrays

    far = plant_from_arrays(np.array([[0, 0, 1.0], [0.01, 0, 1.0], [0, 0.01, 1.0], [0, 0, 1.01]]),
                            np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]), placement="none")
    raw = run_scan(RunConfig(sensor="ideal", scan=StepScan(step_deg=10)), plant=far).raw  # an empty disk
    with pytest.raises(ValueError, match="returns lie near the calibration target under the starting rig"):
        calibrate(raw)
