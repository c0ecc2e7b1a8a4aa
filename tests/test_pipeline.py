"""The one scan pipeline: every mode with every sensor, nothing silently ignored, the raw bag."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import trimesh

from plantsim.cli.app import main
from plantsim.cloud.bag import read_raw, write_raw
from plantsim.cloud.export import read_cloud
from plantsim.cloud.reconstruct import reconstruct
from plantsim.errors import ConfigError
from plantsim.hardware.dynamixel.emulator import DynamixelEmulator
from plantsim.hardware.dynamixel.turntable import ServoTurntable
from plantsim.plant.mesh import plant_from_arrays
from plantsim.scan.config import OutputOptions, PlantOptions, RunConfig, config_from_dict
from plantsim.scan.pipeline import run_scan, write_result
from plantsim.scan.plan import plan_scan
from plantsim.scan.raw import BeamGrid, RawScan
from plantsim.scan.schedule import StepScan
from plantsim.sensor.model import SensorModel
from plantsim.sensor.spec import PRESETS, URG_04LX_UG01, BeamStatus
from plantsim.transforms import T_from_translation_quat_xyzw, make_T, rot_z, translation_quat_xyzw
from plantsim.turntable.dynamics import JitterConfig, TurntableDynamics
from plantsim.turntable.encoder import EncoderConfig
from plantsim.turntable.options import TurntableOptions

BOX_CENTRE = np.array([0.05, 0.02, 0.05])
BOX_HALF = np.array([0.02, 0.03, 0.05])


def box_mesh():
    box = trimesh.creation.box(extents=2 * BOX_HALF)
    box.apply_translation(BOX_CENTRE)
    return box


@pytest.fixture(scope="module")
def box():
    mesh = box_mesh()
    return plant_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces), placement="none")


@pytest.fixture(scope="module")
def box_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("box") / "box.stl"
    box_mesh().export(path)
    return path


def box_distance(points: np.ndarray) -> np.ndarray:
    """Exact distance of points to the box's surface, metres."""
    d = np.abs(points - BOX_CENTRE) - BOX_HALF
    return np.linalg.norm(np.maximum(d, 0), axis=1) + np.abs(np.minimum(d.max(axis=1), 0))


MODES = {
    "step, kinematic": dict(scan=StepScan(step_deg=30), turntable=TurntableOptions(physics="kinematic")),
    "step, dynamic": dict(scan=StepScan(step_deg=30), turntable=TurntableOptions(physics="dynamic")),
    "continuous, kinematic": dict(scan=StepScan(sweep_deg=90),
                                  turntable=TurntableOptions(mode="continuous", rpm=5, physics="kinematic")),
    "continuous, dynamic": dict(scan=StepScan(sweep_deg=90),
                                turntable=TurntableOptions(mode="continuous", rpm=5, physics="dynamic")),
}


# --- every mode with every sensor ----------------------------------------------------------------

@pytest.mark.parametrize("mode", MODES)
def test_the_ideal_sensor_is_exact_in_every_mode(box, mode):
    result = run_scan(RunConfig(ideal=True, **MODES[mode]), plant=box)
    assert result.parts["lidar"]["sensor"] == "ideal" and result.raw.intensity is None
    cloud = result.cloud.plant_only()
    assert len(cloud) > 100
    # Exact geometry; the only errors left are float32 ranges and interpolating exact readings.
    assert box_distance(cloud.points_turntable).max() < 1e-6


@pytest.mark.parametrize("mode", MODES)
def test_the_sensor_model_applies_in_every_mode(box, mode):
    ideal = run_scan(RunConfig(sensor="ideal", **MODES[mode]), plant=box)
    real = run_scan(RunConfig(sensor="realistic", **MODES[mode]), plant=box)
    assert real.plan.sensor == "realistic" and real.parts["lidar"]["sensor"] == "realistic"
    assert real.parts["lidar"]["effects"]["footprint_subrays"] == 19
    assert real.raw.intensity is not None and np.isfinite(real.raw.intensity[real.raw.status == 0]).all()
    # Range noise, quantisation and mixed pixels: the realistic points leave the surface.
    real_error = np.median(box_distance(real.cloud.plant_only().points_turntable))
    ideal_error = np.median(box_distance(ideal.cloud.plant_only().points_turntable))
    # (The ideal sensor's error here is the turntable's: a 4096-tick encoder in dynamic modes.)
    assert real_error > 1e-3 and ideal_error < 1e-4 and real_error > 10 * ideal_error
    # The same motion under both sensors (same seed): the same line times.
    np.testing.assert_array_equal(real.raw.line_stamp_ns, ideal.raw.line_stamp_ns)


def test_the_rig_scan_applies_the_sensor_model_and_ideal_is_exact(tmp_path, box_file):
    # The emulator on its bus clock (simulated time moves with the exchanges), and room for
    # its thread to be kept waiting on a busy machine: the scan is the same either way.
    with DynamixelEmulator(ids=(1,), clock="bus") as emulator:
        clouds = {}
        for sensor in ("ideal", "realistic"):
            config = RunConfig(plant=PlantOptions(mesh=str(box_file), placement="none"), sensor=sensor,
                               scan=StepScan(step_deg=90), output=OutputOptions(path=str(tmp_path / f"{sensor}.ply")))
            with ServoTurntable.connect(emulator.port_path, retries=5, profile_velocity_rad_s=3.0,
                                        profile_acceleration_rad_s2=20.0, stable_interval_s=0.1,
                                        driver_options={"scheduler_allowance_s": 2.0}) as table:
                result = run_scan(config, turntable=table)
            assert result.parts["turntable"]["motion"] == "hardware"
            assert result.parts["lidar"]["sensor"] == sensor
            clouds[sensor] = result
    ideal, real = clouds["ideal"], clouds["realistic"]
    assert ideal.raw.intensity is None and real.raw.intensity is not None
    # Cast and reconstructed at the servo's reported angle: the ideal rig cloud is exact.
    assert box_distance(ideal.cloud.plant_only().points_turntable).max() < 1e-6
    assert np.median(box_distance(real.cloud.plant_only().points_turntable)) > 1e-3


def test_same_seed_same_cloud_in_continuous_realistic_scans(box):
    config = RunConfig(seed=5, **MODES["continuous, dynamic"])
    a, b = run_scan(config, plant=box), run_scan(config, plant=box)
    np.testing.assert_array_equal(a.cloud.points_turntable, b.cloud.points_turntable)
    c = run_scan(config.replace(seed=6), plant=box)
    assert not np.array_equal(a.raw.range_m, c.raw.range_m, equal_nan=True)


# --- nothing silently ignored ----------------------------------------------------------------

REFUSED = [
    ({"turntable": {"mode": "continuous"}, "scan": {"step_deg": 2.0}}, False,
     r"--step-deg applies to step scans; a continuous scan's lines are rpm x scan period apart.*set --rpm"),
    ({"turntable": {"mode": "continuous"}, "scan": {"step_time_s": 1.0}}, False, "step_time_s applies to step scans"),
    ({"turntable": {"rpm": 3}}, False, "--rpm applies to continuous scans"),
    ({"turntable": {"mode": "continuous", "settle_timeout_s": 3}}, False,
     r"\[turntable\] settle_timeout_s applies to step scans"),
    ({"turntable": {"spinup_margin_s": 1}}, False, r"spinup_margin_s applies to continuous scans"),
    ({"ideal": True, "sensor_model": {"footprint_rings": 1}}, False,
     r"\[sensor_model\] footprint_rings is set but the sensor is ideal \(--ideal\).*--sensor realistic"),
    ({"sensor": "ideal", "lidar": {"range_sigma_m": 0.01}}, False,
     r"\[lidar\] range_sigma_m is set but the sensor is ideal"),
    ({"ideal": True, "sensor": "realistic"}, False, "ideal = true makes everything perfect"),
    ({"sensor_model": {"range_noise": False}, "lidar": {"range_sigma_m": 0.005}}, False,
     r"\[lidar\] range_sigma_m is set but \[sensor_model\] range_noise is false, which turns off what uses it: "
     r"remove it, or set range_noise = true"),
    ({"sensor_model": {"systematic_error": False, "power_on_age_s": 10.0}}, False,
     r"\[sensor_model\] power_on_age_s is set but \[sensor_model\] systematic_error is false"),
    ({"sensor_model": {"quantise": False}, "lidar": {"range_resolution_m": 0.002}}, False,
     r"\[lidar\] range_resolution_m is set but \[sensor_model\] quantise is false"),
    ({"sensor_model": {"dropouts": False, "range_noise": False}, "lidar": {"detection_range_white_m": 3.0}}, False,
     r"detection_range_white_m is set but \[sensor_model\] dropouts and range_noise are false.*"
     r"set dropouts = true or range_noise = true"),
    ({"sensor_model": {"footprint_rings": 0}, "lidar": {"beam_divergence_rad": 0.002}}, False,
     r"\[lidar\] beam_divergence_rad is set but \[sensor_model\] footprint_rings = 0 \(one ray a beam\).*"
     r"set footprint_rings = 1 or more"),
    ({"sensor_model": {"adaptive_footprint": False, "flat_tolerance_m": 0.001}}, False,
     r"\[sensor_model\] flat_tolerance_m is set but \[sensor_model\] footprint_rings = 0 or adaptive_footprint "
     r"= false"),
    ({"sensor_model": {"range_noise": False, "dropouts": False, "intensity": False, "systematic_error": False,
                       "footprint_rings": 0, "reflectance_plant": 0.3}}, False,
     r"\[sensor_model\] reflectance_plant is set but \[sensor_model\] range_noise, dropouts, intensity and "
     r"systematic_error are false and footprint_rings = 0.*turn one of them on"),
    ({"sensor_model": {"intensity": False, "saturation_range_m": 0.2}}, False,
     r"\[sensor_model\] saturation_range_m is set but \[sensor_model\] intensity is false"),
    ({"turntable": {"physics": "kinematic", "jitter": {"backlash_deg": 0.5}}}, False,
     r"\[turntable.jitter\] backlash_deg needs the servo's physics, but physics = \"kinematic\""),
    ({"ideal": True, "turntable": {"jitter": {"torque_noise_nm": 0.01}}}, False,
     r"\[turntable.jitter\] torque_noise_nm is set but --ideal makes the turntable perfect"),
    ({"turntable": {"ideal": True, "encoder": {"noise_rad": 1e-4}}}, False,
     r"\[turntable.encoder\] noise_rad is set but \[turntable\] ideal = true makes the turntable perfect"),
    ({"turntable": {"physics": "dynamic"}, "scan": {"step_time_s": 1.0}}, False,
     "step_time_s is the kinematic table's line spacing"),
    ({"ideal": True}, True, "--ideal cannot make a real servo perfect: use --sensor ideal"),
    ({"turntable": {"jitter": {"backlash_deg": 1}}}, True,
     r"\[turntable.jitter\] backlash_deg describes the simulated turntable; a rig scan turns the real servo"),
    ({"turntable": {"encoder": {"ticks_per_rev": 1024}}}, True, r"\[turntable.encoder\] ticks_per_rev describes"),
    ({"turntable": {"mode": "continuous"}}, True, "continuous rig scans need a LiDAR that streams"),
    ({"scan": {"step_time_s": 1.0}}, True, r"step_time_s describes the simulated turntable"),
    ({"plant": {"areal_density_kg_m2": 0.5}, "turntable": {"physics": "kinematic"}}, False,
     r"\[plant\] areal_density_kg_m2 needs the servo's physics"),
]


@pytest.mark.parametrize("data, hardware, message", REFUSED)
def test_settings_the_parts_would_not_use_are_refused(data, hardware, message):
    with pytest.raises(ConfigError, match=message):
        plan_scan(config_from_dict(data), hardware_turntable=hardware)


def test_a_sensor_setting_is_refused_only_when_every_effect_using_it_is_off():
    # The noise law still reads detection_range_white_m with the dropouts off.
    plan_scan(config_from_dict({"sensor_model": {"dropouts": False}, "lidar": {"detection_range_white_m": 3.0}}))
    # Any one effect that reads the reflectance keeps it (here the footprint's weights).
    plan_scan(config_from_dict({"sensor_model": {"range_noise": False, "dropouts": False, "intensity": False,
                                                 "systematic_error": False, "reflectance_plant": 0.3}}))
    # A preset brings its own noise: with the noise off it is not a setting the user gave.
    plan_scan(config_from_dict({"sensor_model": {"range_noise": False}, "lidar": {"preset": "utm-30lx"}}))
    plan_scan(RunConfig(sensor_model=SensorModel(range_noise=False), lidar=PRESETS["utm-30lx"]))
    # Built in Python: a value other than its preset's counts as given.
    quiet = RunConfig(sensor_model=SensorModel(range_noise=False),
                      lidar=PRESETS["urg-04lx-ug01"].replace(range_sigma_m=0.005))
    with pytest.raises(ConfigError, match=r"\[lidar\] range_sigma_m is set but \[sensor_model\] range_noise"):
        plan_scan(quiet)


def test_a_setting_given_at_its_default_value_still_counts_as_given():
    # settle_timeout_s = 2.0 is the default: written in TOML for a continuous scan, it is still unused.
    with pytest.raises(ConfigError, match=r"\[turntable\] settle_timeout_s applies to step scans"):
        plan_scan(config_from_dict({"turntable": {"mode": "continuous", "settle_timeout_s": 2.0}}))


def test_settings_built_in_python_count_as_given():
    config = RunConfig(turntable=TurntableOptions(mode="continuous"), scan=StepScan(step_deg=2.0))
    with pytest.raises(ConfigError, match="--step-deg applies to step scans"):
        plan_scan(config)


def test_jitter_on_a_step_scan_switches_to_physics_and_says_so(box, caplog):
    config = config_from_dict({"scan": {"step_deg": 90}, "sensor": "ideal",
                               "turntable": {"jitter": {"torque_noise_nm": 0.001}}})
    with caplog.at_level(logging.WARNING, logger="plantsim.scan.pipeline"):
        result = run_scan(config, plant=box)
    assert result.plan.motion == "physics"
    assert "[turntable.jitter] torque_noise_nm is set: this step scan runs the servo's physics" in caplog.text
    assert result.parts["plan"]["notes"] and result.parts["turntable"]["jitter_active"] is True


def test_an_encoder_on_a_kinematic_table_is_honoured(box):
    """A perfect motor read through a coarse encoder: the reconstruction uses the readings."""
    config = RunConfig(sensor="ideal", scan=StepScan(step_deg=30),
                       turntable=TurntableOptions(encoder=EncoderConfig(ticks_per_rev=64)))
    result = run_scan(config, plant=box)
    assert result.plan.motion == "kinematic" and result.plan.encoder.ticks_per_rev == 64
    tick = 2 * np.pi / 64
    believed = result.raw.turntable_angle_rad
    np.testing.assert_allclose(believed, np.round(result.raw.true_turntable_angle_rad / tick) * tick)
    assert np.abs(believed - result.raw.true_turntable_angle_rad).max() > 0.01
    # --no-deskew on a step scan is honoured too: the commanded angles.
    naive = run_scan(config.replace(turntable=config.turntable.replace(deskew=False)), plant=box)
    assert naive.plan.angle_mode == "commanded"
    np.testing.assert_array_equal(naive.raw.turntable_angle_rad, naive.raw.true_turntable_angle_rad)


def test_the_sidecar_records_what_was_simulated(box_file, tmp_path):
    out = tmp_path / "c.ply"
    assert main(["scan", str(box_file), "--placement", "none", "--mode", "continuous", "--rpm", "5",
                 "--sweep-deg", "30", "--sensor", "ideal", "--turntable", "dynamic", "-o", str(out)]) == 0
    side = json.loads(out.with_name("c.ply.json").read_text())
    simulated = side["simulated"]
    assert simulated["plan"] == {"mode": "continuous", "sensor": "ideal", "motion": "physics",
                                 "angle_mode": "interpolate", "notes": [], "rig_fit_warnings": []}
    assert simulated["lidar"]["effects"].startswith("none")
    assert simulated["turntable"]["encoder"]["ticks_per_rev"] == 4096
    assert side["turntable_diagnostics"]["physics_steps"] > 0


def test_the_cli_refuses_an_ignored_option_with_one_line(box_file, tmp_path, capsys):
    out = tmp_path / "c.ply"
    assert main(["scan", str(box_file), "--mode", "continuous", "--step-deg", "2", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--step-deg applies to step scans" in err[0]
    assert not out.exists()


# --- the raw record as a ROS 2 bag -------------------------------------------------------------

def test_scan_raw_bag_reads_back_with_rosbags_and_reconstructs_bit_for_bit(box_file, tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    bag, out, again = tmp_path / "raw", tmp_path / "scan.las", tmp_path / "again.las"
    assert main(["scan", str(box_file), "--placement", "none", "--step-deg", "30", "--seed", "3",
                 "--raw", str(bag), "-o", str(out)]) == 0
    side = json.loads(out.with_name("scan.las.json").read_text())
    store = get_typestore(Stores.ROS2_HUMBLE)
    counts, scans, joints = {}, [], []
    with Reader(bag) as reader:
        for connection, _, data in reader.messages():
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
            if connection.topic == "/scan":
                scans.append(store.deserialize_cdr(data, connection.msgtype))
            elif connection.topic == "/turntable/joint_states":
                joints.append(store.deserialize_cdr(data, connection.msgtype))
        assert reader.connections[0].msgtype in ("std_msgs/msg/String",)
    assert counts["/scan"] == 12 and counts["/plantsim/ground_truth"] == 12
    assert counts["/tf_static"] == 1 and counts["/plantsim/scan_info"] == 1
    assert counts["/turntable/joint_states"] == counts["/tf"] > 12
    first = scans[0]
    assert first.header.frame_id == "lidar" and len(first.ranges) == 683 and len(first.intensities) == 683
    assert first.angle_min == pytest.approx((44 - 384) * 2 * np.pi / 1024, abs=1e-6)  # URG step 44
    assert first.angle_increment == pytest.approx(2 * np.pi / 1024, rel=1e-6)
    assert first.time_increment == pytest.approx(0.1 / 1024, rel=1e-6)
    assert first.scan_time == pytest.approx(0.1) and first.range_min == pytest.approx(0.02)
    ranges = np.concatenate([s.ranges for s in scans])
    assert np.isposinf(ranges).sum() > 0  # REP 117: no echo is +inf, never a number
    assert side["counts"]["by_status"]["no_echo"] == np.isposinf(ranges).sum()
    assert side["counts"]["by_status"]["too_near"] == np.isneginf(ranges).sum()
    assert joints[0].name == ["turntable"] and joints[0].header.frame_id == "base"

    assert main(["reconstruct", str(bag), "-o", str(again)]) == 0
    a, b = read_cloud(out), read_cloud(again)
    for field in ("points_turntable", "hit_class", "beam_index", "scan_index", "turntable_angle_rad", "range_m",
                  "time_s", "intensity"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert out.read_bytes() == again.read_bytes()


@pytest.mark.parametrize("mode", ["continuous, dynamic", "step, dynamic"])
def test_raw_round_trip_is_exact_for_dynamic_scans(box, mode, tmp_path):
    config = RunConfig(seed=1, **MODES[mode])
    result = run_scan(config, plant=box)
    write_raw(tmp_path / "bag", result.raw, metadata={"note": "test"})
    raw, info = read_raw(tmp_path / "bag")
    assert info["note"] == "test" and info["angle_mode"] == "interpolate"
    for name in ("line_stamp_ns", "range_m", "status", "intensity", "encoder_stamp_ns", "encoder_angle_rad",
                 "true_turntable_angle_rad", "hit_class", "geom_id", "T_base_lidar", "time_s"):
        np.testing.assert_array_equal(getattr(raw, name), getattr(result.raw, name), err_msg=name)
    cloud = reconstruct(raw)
    np.testing.assert_array_equal(cloud.points_turntable, result.cloud.points_turntable)


def test_write_result_writes_the_bag_beside_the_cloud(box, tmp_path):
    config = RunConfig(sensor="ideal", scan=StepScan(step_deg=90),
                       output=OutputOptions(path=str(tmp_path / "c.pcd"), raw=str(tmp_path / "bag")))
    write_result(run_scan(config, plant=box))
    assert (tmp_path / "bag" / "metadata.yaml").is_file() and (tmp_path / "bag" / "bag.mcap").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    # Written again: the old bag is replaced, not refused.
    write_result(run_scan(config, plant=box))
    with pytest.raises(FileExistsError, match="is not a ROS 2 bag folder"):
        write_raw(tmp_path, run_scan(config, plant=box).raw)


def test_a_bag_from_another_tool_reconstructs(tmp_path):
    """LaserScan + JointState + TF written by hand, as a ROS driver would record them."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    T_base_lidar = make_T(np.array([[-1.0, 0, 0], [0, 0, 1], [0, 1, 0]]).T, [0.4, 0.0, 0.1])
    translation, quat = translation_quat_xyzw(T_base_lidar)
    start = 1_700_000_000 * 10**9

    def header(ns, frame):
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                        frame_id=frame)

    with Writer(tmp_path / "rig", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        tf_c = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=store)
        scan_c = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        joint_c = writer.add_connection("/turntable/joint_states", "sensor_msgs/msg/JointState", typestore=store)
        tf = t["geometry_msgs/msg/TransformStamped"](
            header=header(start, "base"), child_frame_id="lidar", transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=translation[0], y=translation[1], z=translation[2]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=quat[0], y=quat[1], z=quat[2], w=quat[3])))
        writer.write(tf_c, start, store.serialize_cdr(t["tf2_msgs/msg/TFMessage"](transforms=[tf]),
                                                     "tf2_msgs/msg/TFMessage"))
        for k, angle in enumerate([0.0, np.pi / 2]):
            ns = start + k * 10**9
            joint = t["sensor_msgs/msg/JointState"](header=header(ns, "base"), name=["turntable"],
                                                    position=np.array([angle]), velocity=np.zeros(0),
                                                    effort=np.zeros(0))
            writer.write(joint_c, ns, store.serialize_cdr(joint, "sensor_msgs/msg/JointState"))
            scan = t["sensor_msgs/msg/LaserScan"](
                header=header(ns, "lidar"), angle_min=-0.1, angle_max=0.1, angle_increment=0.1,
                time_increment=0.0, scan_time=0.1, range_min=0.02, range_max=4.0,
                ranges=np.array([np.inf, 0.3, -np.inf], dtype=np.float32), intensities=np.zeros(0, np.float32))
            writer.write(scan_c, ns, store.serialize_cdr(scan, "sensor_msgs/msg/LaserScan"))
    raw, info = read_raw(tmp_path / "rig")
    assert info == {} and raw.angle_mode == "interpolate" and raw.true_turntable_angle_rad is None
    assert raw.status.tolist() == [[BeamStatus.NO_ECHO, BeamStatus.OK, BeamStatus.TOO_NEAR]] * 2
    cloud = reconstruct(raw)
    # Beam 1 points along the lidar's +X, at the axis: 0.3 m from (0.4, 0, 0.1) is (0.1, 0, 0.1) in base;
    # at a turntable angle of 90 degrees that point is Rz(-90) of it in the turntable frame.
    np.testing.assert_allclose(cloud.points_turntable[0], [0.1, 0.0, 0.1], atol=1e-7)
    np.testing.assert_allclose(cloud.points_turntable[1], rot_z(-np.pi / 2) @ [0.1, 0.0, 0.1], atol=1e-7)
    np.testing.assert_array_equal(cloud.time_s, [0.0, 1.0])


def test_quaternion_round_trip_is_a_rotation():
    for angles in ([0.3, -1.2, 2.0], [np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi]):
        from scipy.spatial.transform import Rotation

        R = Rotation.from_euler("xyz", angles).as_matrix()
        T = make_T(R, [1, 2, 3])
        back = T_from_translation_quat_xyzw(*translation_quat_xyzw(T))
        np.testing.assert_allclose(back, T, atol=1e-12)


def test_raw_scan_validates_its_arrays():
    grid = BeamGrid.of(URG_04LX_UG01)
    empty = np.zeros((1, grid.n_beams))
    with pytest.raises(ValueError, match="angle_mode must be one of"):
        RawScan(grid=grid, line_stamp_ns=np.zeros(1, np.int64), range_m=empty, status=empty.astype(np.uint8),
                intensity=None, encoder_stamp_ns=np.zeros(1, np.int64), encoder_angle_rad=np.zeros(1),
                commanded_rad=np.zeros(1), angle_mode="guess", lidar_pose=translation_quat_xyzw(np.eye(4)))
    with pytest.raises(ValueError, match="needs encoder readings"):
        RawScan(grid=grid, line_stamp_ns=np.zeros(1, np.int64), range_m=empty, status=empty.astype(np.uint8),
                intensity=None, encoder_stamp_ns=np.zeros(0, np.int64), encoder_angle_rad=np.zeros(0),
                commanded_rad=np.zeros(1), angle_mode="interpolate", lidar_pose=translation_quat_xyzw(np.eye(4)))


@pytest.mark.parametrize("angle_mode", ["interpolate", "line", "commanded"])
def test_reconstruct_is_the_full_grid_formula_at_the_returns_bit_for_bit(angle_mode):
    """reconstruct() works on the returns only; its values are those of the whole grid at them."""
    from plantsim.cloud.reconstruct import base_to_turntable, points_base_from_ranges
    from plantsim.scan.raw import believed_angles

    rng = np.random.default_rng(5)
    grid = BeamGrid.of(URG_04LX_UG01)
    n = 7
    status = np.where(rng.random((n, grid.n_beams)) < 0.4, BeamStatus.OK, BeamStatus.NO_ECHO).astype(np.uint8)
    raw = RawScan(grid=grid, line_stamp_ns=np.arange(n, dtype=np.int64) * 100_000_000 + 12_345,
                  range_m=rng.uniform(0.1, 2.0, (n, grid.n_beams)), status=status, intensity=None,
                  encoder_stamp_ns=np.sort(rng.integers(0, 800_000_000, 40)),
                  encoder_angle_rad=np.cumsum(rng.uniform(0, 0.05, 40)), commanded_rad=rng.uniform(0, 6, n),
                  angle_mode=angle_mode, lidar_pose=translation_quat_xyzw(make_T(rot_z(0.3), [0.4, -0.1, 0.2])),
                  encoder_offset_rad=0.25)
    lines, beams = np.nonzero(status == BeamStatus.OK)
    full = raw.turntable_angle_rad
    np.testing.assert_array_equal(believed_angles(raw, lines, beams), full[lines, beams])
    cloud = reconstruct(raw)
    expected = base_to_turntable(points_base_from_ranges(raw.range_m[lines, beams], raw.beam_angle_rad[beams],
                                                         raw.T_base_lidar), full[lines, beams])
    np.testing.assert_array_equal(cloud.points_turntable, expected)
    np.testing.assert_array_equal(cloud.turntable_angle_rad, full[lines, beams])
    np.testing.assert_array_equal(cloud.time_s, raw.time_s[lines, beams])
    with pytest.raises(ValueError, match="both lines and beams"):
        believed_angles(raw, lines)


def test_raw_counts_and_the_angle_error_metric_are_their_full_grid_definitions():
    from plantsim.evaluation.angle_error import angle_error_displacement
    from plantsim.rig.scene import HitClass
    from plantsim.scan.pipeline import angle_error_metric

    rng = np.random.default_rng(8)
    grid = BeamGrid.of(URG_04LX_UG01)
    n = 6
    shape = (n, grid.n_beams)
    status = rng.choice([int(s) for s in BeamStatus], shape).astype(np.uint8)
    hit_class = rng.choice([int(c) for c in HitClass], shape).astype(np.uint8)
    t_ns = np.arange(0, 700_000_000, 20_000_000, dtype=np.int64)
    raw = RawScan(grid=grid, line_stamp_ns=np.arange(n, dtype=np.int64) * 100_000_000, range_m=rng.uniform(0.1, 2, shape),
                  status=status, intensity=None, encoder_stamp_ns=t_ns, encoder_angle_rad=0.01 * np.arange(len(t_ns)),
                  commanded_rad=np.zeros(n), angle_mode="interpolate", hit_class=hit_class,
                  true_turntable_angle_rad=rng.uniform(0, 0.1, shape), lidar_pose=translation_quat_xyzw(np.eye(4)))
    counts = raw.counts()
    ok = status == BeamStatus.OK
    assert counts["by_status"] == {s.name.lower(): int((status == s).sum()) for s in BeamStatus}
    assert counts["returns_by_class"] == {c.name.lower(): int((ok & (hit_class == c)).sum())
                                          for c in HitClass if c != HitClass.NONE}
    assert counts["returns"] == int(ok.sum()) and counts["beams"] == status.size
    want = angle_error_displacement(raw.range_m, raw.beam_angle_rad, raw.T_base_lidar, raw.true_turntable_angle_rad,
                                    raw.turntable_angle_rad, valid=ok & (hit_class == HitClass.PLANT))
    assert want["n_points"] > 100 and want["displacement_max_m"] > 0
    assert angle_error_metric(raw) == want


def test_dynamics_settings_reach_the_physics(box):
    dyn = TurntableDynamics(jitter=JitterConfig(backlash_deg=0.2))
    result = run_scan(RunConfig(sensor="ideal", scan=StepScan(step_deg=90),
                                turntable=TurntableOptions(physics="dynamic", dynamics=dyn)), plant=box)
    assert result.parts["turntable"]["dynamics"]["jitter"]["backlash_deg"] == 0.2
    d = result.diagnostics
    assert 0 < d["max_table_minus_shaft_rad"] <= np.radians(0.1) + np.radians(0.2)  # within the play (+ margin)
    assert d["n_moves"] >= 3 and d["n_unsettled"] == 0 and d["settle_time_max_s"] > 0
    # The angle-error metric beside point-to-mesh: how far the plant's points moved.
    assert d["angle_error_plant"]["n_points"] > 0 and d["angle_error_plant"]["displacement_max_m"] > 0


# --- cheap checks before long work ----------------------------------------------------------

@pytest.mark.parametrize("data, message", [
    ({"scan": {"step_deg": 1e-300}}, r"step_deg = 1e-300 makes 3.6e\+302 lines over 360 deg, more than 360,000; "
                                     r"use step_deg >= 0.001"),
    ({"scan": {"sweep_deg": 720, "step_deg": 1}}, r"sweep_deg must be at most 360 \(one turn; more scans every angle"),
    ({"rig": {"lidar_distance_m": 1e6}}, r"the LiDAR stands 1e\+06 m from the axis.*beyond its range_max_m \(5.6 m\)"),
    ({"scan": {"step_deg": 0.002}, "lidar": {"preset": "sick-lms111"}},
     r"180,000 lines x 1081 beams = 194,580,000 beams, more than 100,000,000.*use a larger --step-deg"),
])
def test_impossible_scans_are_refused_before_any_work(data, message):
    with pytest.raises(ConfigError, match=message):
        plan_scan(config_from_dict(data))


def test_a_one_triangle_plant_scans():
    plant = plant_from_arrays(np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0.1]]), np.array([[0, 1, 2]]))
    result = run_scan(RunConfig(sensor="ideal", scan=StepScan(step_deg=30)), plant=plant)
    assert result.cloud.counts_by_class()["plant"] > 0


def test_a_plant_the_lidar_cannot_see_is_an_error_and_nothing_is_written(tmp_path, capsys):
    mesh = trimesh.creation.box(extents=[0.02, 0.02, 0.02])
    mesh.apply_translation([0.0, 0.0, 8.0])  # 8 m above the disk: beyond the URG-04LX's 5.6 m
    path = tmp_path / "high.stl"
    mesh.export(path)
    out = tmp_path / "c.las"
    assert main(["scan", str(path), "--placement", "none", "--step-deg", "90", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no beam hit the plant" in err[0] and "nothing was written" in err[0]
    assert not out.exists()


def test_wrong_types_at_the_python_entry_point_are_named():
    with pytest.raises(TypeError, match="config must be a plantsim.RunConfig, got dict"):
        run_scan({"scan": {"step_deg": 1}})
    with pytest.raises(TypeError, match="plant must be a plantsim.PlantMesh"):
        run_scan(RunConfig(), plant="plant.stl")
    with pytest.raises(TypeError, match="turntable must implement plantsim.Turntable"):
        run_scan(RunConfig(), turntable=object())
    with pytest.raises(TypeError, match="RunConfig.scan must be a plantsim.StepScan, got float"):
        RunConfig(scan=1.0)


# --- where the time went ---------------------------------------------------------------------------

@pytest.mark.parametrize("sensor", ["ideal", "realistic"])
def test_the_sidecar_counts_the_rays_cast_per_phase(box, sensor):
    from plantsim.scan.pipeline import sidecar
    from plantsim.sensor.model import SensorModel

    # every sub-ray cast (not adaptive): the count is exact; the ideal sensor takes no model
    model = {} if sensor == "ideal" else {"sensor_model": SensorModel(adaptive_footprint=False)}
    result = run_scan(RunConfig(sensor=sensor, scan=StepScan(step_deg=30), **model), plant=box)
    n_lines, n_beams = result.raw.range_m.shape
    work = result.parts["lidar"]["work"]
    perf = sidecar(result)["performance"]
    assert work["beams"] == perf["beams"] == n_lines * n_beams
    n_sub = 1 if sensor == "ideal" else result.parts["lidar"]["effects"]["footprint_subrays"]
    patterns = 1 if sensor == "ideal" else result.parts["lidar"]["effects"]["footprint_patterns"]
    assert perf["turning_cast"]["rays"] == n_lines * n_beams * n_sub
    assert perf["rig_cast_once"]["rays"] == patterns * n_beams * n_sub
    for phase in ("rig_cast_once", "turning_cast"):
        assert perf[phase]["s"] > 0
        assert perf[phase]["rays_per_s"] == pytest.approx(perf[phase]["rays"] / perf[phase]["s"], rel=1e-3)
    assert perf["scan_phase"]["s"] == pytest.approx(result.timings_s["scan"], abs=1e-6)
    # the phases the line source reports fit inside the scan phase
    inside = (perf["turning_cast"]["s"] + perf["sensor_model"]["s"] + perf["footprint_and_bookkeeping"]["s"])
    assert inside <= result.timings_s["scan"] + 1e-6
    assert (perf["sensor_model"]["s"] > 0) == (sensor == "realistic")
