"""Frames, by hand: transforms, the LiDAR mount, beam angles and times."""

import math

import numpy as np
import pytest

from plantsim.rig.geometry import RigGeometry
from plantsim.sensor.spec import URG_04LX_UG01, LidarSpec, lidar_preset
from plantsim.transforms import apply_T, invert_T, make_T, rot_x, rot_y, rot_z


def test_rotations_match_hand_computed_values():
    np.testing.assert_allclose(rot_z(math.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rot_x(math.pi / 2) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(rot_y(math.pi / 2) @ [0, 0, 1], [1, 0, 0], atol=1e-15)


def test_invert_and_apply_compose():
    T_a_b = make_T(rot_z(0.3) @ rot_x(-1.1), [0.1, -0.2, 0.3])
    T_b_a = invert_T(T_a_b)
    np.testing.assert_allclose(T_a_b @ T_b_a, np.eye(4), atol=1e-15)
    p_b = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(apply_T(T_b_a, apply_T(T_a_b, p_b)), p_b, atol=1e-14)


def test_default_lidar_looks_at_the_axis_with_positive_beams_up():
    rig = RigGeometry(lidar_distance_m=0.35, lidar_height_m=0.15)
    T = rig.T_base_lidar()
    np.testing.assert_allclose(T[:3, 3], [0.35, 0, 0.15])
    np.testing.assert_allclose(T[:3, 0], [-1, 0, 0], atol=1e-15)  # beam 0 points at the axis
    np.testing.assert_allclose(T[:3, 1], [0, 0, 1], atol=1e-15)   # +90 deg beam points up
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


def test_yaw_moves_the_scan_plane_off_the_axis_by_d_sin_yaw():
    rig = RigGeometry(lidar_distance_m=0.4, yaw_deg=10.0)
    T = rig.T_base_lidar()
    normal = T[:3, 2]
    # Distance from the axis (origin) to the scan plane through the sensor.
    assert abs(normal @ T[:3, 3]) == pytest.approx(0.4 * math.sin(math.radians(10)), rel=1e-12)


def test_tilt_turns_the_boresight_up():
    T = RigGeometry(tilt_deg=30.0).T_base_lidar()
    np.testing.assert_allclose(T[:3, 0], [-math.cos(math.radians(30)), 0, 0.5], atol=1e-15)


def test_urg04lx_preset_grid_and_beam_times():
    lidar = URG_04LX_UG01
    angles = np.rad2deg(lidar.beam_angles_rad())
    assert len(angles) == 683
    assert angles[0] == pytest.approx(-119.53125)
    assert angles[-1] == pytest.approx(120.234375)
    assert angles[-1] - angles[0] == pytest.approx(239.765625)  # 682 intervals: 239.77 deg
    assert angles[340] == pytest.approx(0.0, abs=1e-12)  # step 384 is the front
    t = lidar.beam_time_offsets_s()
    assert t[0] == pytest.approx(44 / 1024 * 0.1)
    assert t[-1] == pytest.approx(726 / 1024 * 0.1)
    assert lidar_preset("URG-04LX-UG01") is lidar


@pytest.mark.parametrize("changes, message", [
    ({"range_min_m": 5.0, "range_max_m": 4.0}, "range_min_m must be less than range_max_m"),
    ({"range_min_m": 4.0, "range_max_m": 4.0}, "range_min_m must be less than range_max_m"),
    ({"angle_increment_deg": 0.0}, "angle_increment_deg must be > 0"),
    ({"n_beams": 0}, "n_beams must be a positive integer"),
    ({"scan_period_s": float("nan")}, "scan_period_s must be a finite number"),
])
def test_lidar_spec_rejects_impossible_settings(changes, message):
    with pytest.raises(ValueError, match=message):
        URG_04LX_UG01.replace(**changes)


def test_unknown_preset_lists_the_valid_ones():
    with pytest.raises(ValueError, match="valid presets: urg-04lx-ug01"):
        lidar_preset("velodyne")


def test_rig_rejects_a_sensor_on_the_disk():
    with pytest.raises(ValueError, match="must exceed disk_radius_m"):
        RigGeometry(lidar_distance_m=0.05)
    with pytest.raises(ValueError, match="must be a finite number"):
        RigGeometry(lidar_height_m=float("inf"))


def test_custom_lidar_without_encoder_spreads_beams_over_the_fov():
    lidar = LidarSpec(n_beams=5, angle_min_deg=-90, angle_increment_deg=45, range_min_m=0.1,
                      range_max_m=10, scan_period_s=0.04)
    np.testing.assert_allclose(lidar.beam_time_offsets_s(), np.arange(5) * 0.125 * 0.04)


def test_base_to_turntable_undoes_the_turn_point_by_point():
    from plantsim.cloud.reconstruct import base_to_turntable
    from plantsim.transforms import rot_z_batch

    # A point on +x seen with the table turned 90 degrees counter-clockwise sits on -y of the table.
    got = base_to_turntable(np.array([[1.0, 0.0, 0.5], [0.0, 2.0, -1.0]]), np.array([math.pi / 2, math.pi]))
    np.testing.assert_allclose(got, [[0.0, -1.0, 0.5], [0.0, -2.0, -1.0]], atol=1e-15)
    rng = np.random.default_rng(0)
    pts, theta = rng.normal(size=(50, 3)), rng.uniform(-7, 7, 50)
    np.testing.assert_array_equal(base_to_turntable(pts, theta),
                                  np.einsum("nij,nj->ni", rot_z_batch(-theta), pts))
    np.testing.assert_allclose(base_to_turntable(pts, 0.3), pts @ rot_z(-0.3).T, atol=1e-15)
