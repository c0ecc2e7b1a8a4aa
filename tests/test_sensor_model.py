"""The sensor model against analytic cases: plates, thin cylinders, range limits."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from plantsim.sensor.footprint import combine_footprint, subray_pattern, subrays_lidar
from plantsim.scan.config import config_from_dict
from plantsim.errors import ConfigError
from plantsim.cloud.reconstruct import reconstruct
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.schedule import StepScan
from plantsim.scan.pipeline import step_and_shoot
from plantsim.rig.scene import build_spec, compile_scene
from plantsim.sensor.spec import PRESETS, URG_04LX_UG01, BeamStatus, LidarSpec, lidar_preset
from plantsim.sensor.model import COS_INCIDENCE_FLOOR, SensorModel, apply_sensor, range_sigma
from plantsim.scan.raw import BeamGrid
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.scan.pipeline import step_and_shoot as _sas

RIG = RigGeometry()  # LiDAR at x = 0.35 m, z = 0.15 m; beam 0 points along base -X.
X_LIDAR = RIG.lidar_distance_m
Z_LIDAR = RIG.lidar_height_m
FRONT_BEAM = 384 - 44  # URG-04LX beam at angle 0


def scene_with(*geoms: dict):
    """The rig with extra world geoms (plant class: geom group 2)."""
    spec = build_spec(RIG, None)
    for geom in geoms:
        spec.worldbody.add_geom(group=2, contype=0, conaffinity=0, **geom)
    return compile_scene(spec, RIG, None)


def wall(distance_m: float, *, tilt_rad: float = 0.0, half_m: float = 2.0) -> dict:
    """A plate facing the LiDAR, ``distance_m`` from it along beam 0, turned about base Y."""
    quat = [math.cos(tilt_rad / 2), 0.0, math.sin(tilt_rad / 2), 0.0]
    return dict(name=f"wall{distance_m}", type=mujoco.mjtGeom.mjGEOM_BOX,
                size=[0.001, half_m, half_m],
                pos=[X_LIDAR - distance_m - 0.001 / math.cos(tilt_rad), 0.0, Z_LIDAR], quat=quat)


def scan(scene, model, *, lidar=URG_04LX_UG01, lines=1, seed=0):
    schedule = StepScan(step_deg=1.0, sweep_deg=float(lines))
    return _sas(scene, lidar, schedule, model=model, rng=np.random.default_rng(seed))


NO_NOISE = SensorModel(range_noise=False, quantise=False)


# --- pure parts --------------------------------------------------------------

def test_subray_pattern_rings_and_weights():
    for rings, n in ((0, 1), (1, 7), (2, 19), (3, 37)):
        pattern = subray_pattern(rings)
        assert pattern.n_subrays == n
        assert pattern.weights.sum() == pytest.approx(1.0)
        assert np.all(pattern.offsets[0] == 0)
        assert pattern.probe[0] == 0 and len(set(pattern.probe)) == len(pattern.probe)
    pattern = subray_pattern(2)
    # Gaussian profile exp(-2 rho^2): the outer ring (rho = 1) weighs e^-2 of the axis.
    assert pattern.weights[-1] / pattern.weights[0] == pytest.approx(math.exp(-2))
    np.testing.assert_allclose(np.linalg.norm(pattern.offsets[pattern.probe[1:]], axis=1), 1.0)
    with pytest.raises(ValueError, match="n_rings must be a non-negative integer, got -1"):
        subray_pattern(-1)


def test_subray_footprint_radius_grows_with_divergence():
    pattern = subray_pattern(1)
    origins, dirs = subrays_lidar(np.array([0.3]), pattern, divergence_rad=0.01,
                                  exit_diameter_m=0.004)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0)
    # At 2 m along the beam, the outer ring is D0/2 + r div/2 = 2 mm + 10 mm off axis.
    axis = dirs[0, 0]
    for j in range(1, 7):
        t = 2.0 / (dirs[0, j] @ axis)
        point = origins[0, j] + t * dirs[0, j]
        off = point - (point @ axis) * axis
        assert np.linalg.norm(off) == pytest.approx(0.012, rel=1e-4)


def test_combine_two_surfaces_gives_a_range_between_them():
    dist = np.array([[0.3, 0.4, -1.0, 9.0]])
    cos = np.ones_like(dist)
    refl = np.full_like(dist, 0.5)
    weights = np.array([0.25, 0.25, 0.25, 0.25])
    ret = combine_footprint(dist, cos, refl, weights, range_max_m=5.0)
    p = 0.25 * 0.5 * np.array([1 / 0.09, 1 / 0.16])  # the miss and the 9 m hit return nothing
    assert ret.range_m[0] == pytest.approx((p @ [0.3, 0.4]) / p.sum())
    assert 0.3 < ret.range_m[0] < 0.4
    assert ret.power[0] == pytest.approx(p.sum())
    assert ret.dominant[0] == 0
    nothing = combine_footprint(np.array([[-1.0, 7.0]]), np.ones((1, 2)), np.ones((1, 2)),
                                np.array([0.5, 0.5]), range_max_m=5.0)
    assert np.isnan(nothing.range_m[0]) and nothing.dominant[0] == -1


def test_worst_case_range_sigma_has_the_datasheet_bands_and_grows_with_incidence():
    lidar = PRESETS["urg-04lx-ug01-worst-case"]
    np.testing.assert_allclose(range_sigma(np.array([0.1, 0.5, 1.0, 2.0, 4.0]), np.ones(5), lidar),
                               [0.030, 0.030, 0.030, 0.060, 0.120])
    cos60 = math.cos(math.radians(60))
    assert range_sigma(0.5, cos60, lidar) == pytest.approx(0.060)  # 1/cos law at gain 1
    assert range_sigma(0.5, 0.0, lidar) == pytest.approx(0.030 / COS_INCIDENCE_FLOOR)
    flat = lidar.replace(range_sigma_incidence_gain=0.0)
    assert range_sigma(0.5, cos60, flat) == pytest.approx(0.030)


def test_apply_sensor_gates_measured_ranges_and_never_clamps():
    lidar = URG_04LX_UG01.replace(range_min_m=0.5, range_max_m=1.0)
    true = np.full((200, 50), 0.99)
    true[:, :25] = 0.51
    range_m, status, intensity = apply_sensor(true, np.full(true.shape, 200.0), np.ones(true.shape),
                                              np.zeros(true.shape), lidar, SensorModel(),
                                              np.random.default_rng(1))
    ok = status == BeamStatus.OK
    assert 0 < ok.sum() < ok.size
    assert np.all(range_m[ok] >= 0.5) and np.all(range_m[ok] <= 1.0)
    assert np.all(np.isnan(range_m[~ok]))
    assert (status == BeamStatus.TOO_NEAR).sum() > 0 and (status == BeamStatus.NO_ECHO).sum() > 0
    assert np.all(intensity == np.float32(1.0))  # 200 m^-2 x (0.1 m)^2 saturates


# --- analytic scenes ---------------------------------------------------------

@pytest.mark.parametrize("distance_m", [0.3, 0.8, 2.0])
def test_flat_plate_is_unbiased_with_the_model_sigma(distance_m):
    scene = scene_with(wall(distance_m))
    wall_id = scene.model.geom(f"wall{distance_m}").id
    raw = scan(scene, SensorModel(), lines=120)
    angle = raw.beam_angle_rad[None, :].repeat(raw.n_lines, 0)
    # Beams whose footprint is wholly on the wall: two neighbours each side on it too.
    on = raw.geom_id == wall_id
    on_wall = on.copy()
    for shift in (1, 2):
        on_wall[:, shift:-shift] &= on[:, :-2 * shift] & on[:, 2 * shift:]
    on_wall &= np.abs(angle) < math.radians(30)
    assert np.all(raw.status[on_wall] == BeamStatus.OK)
    true = distance_m / np.cos(angle[on_wall])
    sigma = range_sigma(true, np.cos(angle[on_wall]), URG_04LX_UG01, reflectance=0.5)
    z = (raw.range_m[on_wall] - true) / sigma
    n = z.size
    assert n > 2000
    assert abs(z.mean()) < 4 / math.sqrt(n)
    assert z.std() == pytest.approx(1.0, abs=0.1)
    # The quantisation to 1 mm is there.
    np.testing.assert_allclose(raw.range_m[on_wall] * 1000, np.round(raw.range_m[on_wall] * 1000),
                               atol=1e-6)


def test_thin_cylinders_before_a_wall_give_mixed_pixels_that_one_ray_does_not():
    # Ten 3 mm rods across the scan plane 0.3 m away (axis along base Y), a wall at 0.4 m.
    rods = [dict(name=f"rod{k}", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.0015, 0.05],
                 pos=[X_LIDAR - 0.3, 0.0, Z_LIDAR + 0.3 * math.tan(math.radians(-8 + 1.7 * k))],
                 quat=[math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])
            for k in range(10)]
    scene = scene_with(*rods, wall(0.4))

    def mixed(model):
        raw = scan(scene, model)
        ok = raw.status[0] == BeamStatus.OK
        x_dist = raw.range_m[0] * np.cos(raw.beam_angle_rad)
        band = np.abs(raw.beam_angle_rad) < math.radians(10)
        between = ok & band & (x_dist > 0.3 + 0.003) & (x_dist < 0.4 - 0.003)
        return int(between.sum()), int((ok & band).sum())

    n_mixed, n_ok = mixed(NO_NOISE)
    assert n_mixed >= 5, (n_mixed, n_ok)
    assert mixed(SensorModel(range_noise=False, quantise=False, footprint_rings=0))[0] == 0
    # The adaptive footprint finds the same mixed pixels as casting every sub-ray.
    full = SensorModel(range_noise=False, quantise=False, adaptive_footprint=False)
    assert mixed(full)[0] == n_mixed


def test_footprints_split_far_apart_give_edge_errors_not_points():
    # 3 mm rods 0.3 m away, a bright wall 0.5 m behind them: where a footprint
    # straddles both, the returns spread over more than 0.1 m (URG preset).
    rods = [dict(name=f"rod{k}", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.0015, 0.05],
                 pos=[X_LIDAR - 0.3, 0.0, Z_LIDAR + 0.3 * math.tan(math.radians(-8 + 1.7 * k))],
                 quat=[math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])
            for k in range(10)]
    scene = scene_with(*rods, wall(0.8))
    raw = scan(scene, NO_NOISE)
    band = np.abs(raw.beam_angle_rad) < math.radians(10)
    edge = band & (raw.status[0] == BeamStatus.EDGE)
    assert edge.sum() >= 5
    assert np.all(np.isnan(raw.range_m[0, edge]))
    assert raw.counts()["by_status"]["edge"] == int((raw.status == BeamStatus.EDGE).sum())
    # With dropouts off those beams are mixed pixels between rod and wall instead.
    mixed = scan(scene, SensorModel(range_noise=False, quantise=False, dropouts=False))
    x_dist = mixed.range_m[0, edge] * np.cos(mixed.beam_angle_rad[edge])
    assert np.all((x_dist > 0.3) & (x_dist < 0.8))


def test_intensity_falls_as_cos_of_incidence():
    for model in (SensorModel(range_noise=False), SensorModel(range_noise=False, footprint_rings=0),
                  SensorModel(range_noise=False, adaptive_footprint=False)):
        values = []
        for deg in (0, 30, 60, 75):
            raw = scan(scene_with(wall(0.5, tilt_rad=math.radians(deg))), model)
            assert raw.status[0, FRONT_BEAM] == BeamStatus.OK
            values.append(float(raw.intensity[0, FRONT_BEAM]))
        # P = rho cos / r^2 = 0.5 cos / 0.25 m^2, times (0.1 m)^2 saturation range.
        assert values[0] == pytest.approx(0.02, rel=1e-3)
        rel = 1e-5 if model.footprint_rings == 0 or model.adaptive_footprint else 0.01
        np.testing.assert_allclose(np.array(values) / values[0],
                                   np.cos(np.radians([0, 30, 60, 75])), rtol=rel)


def test_dark_grazing_surface_drops_out_as_low_intensity_and_stays_a_miss():
    scene = scene_with(wall(0.5, tilt_rad=math.radians(85)))
    dark = SensorModel(reflectance_plant=0.02)
    raw = scan(scene, dark)
    assert raw.status[0, FRONT_BEAM] == BeamStatus.LOW_INTENSITY
    assert np.isnan(raw.range_m[0, FRONT_BEAM])
    assert raw.counts()["by_status"]["low_intensity"] > 0
    cloud = reconstruct(raw)
    assert not np.any((cloud.scan_index == 0) & (cloud.beam_index == FRONT_BEAM))
    assert len(cloud) == raw.counts()["returns"]
    # Without dropouts the same beam has a range.
    assert scan(scene, SensorModel(reflectance_plant=0.02, dropouts=False)).status[0, FRONT_BEAM] \
        == BeamStatus.OK


def test_nothing_below_min_range_or_beyond_max_range(caplog):
    lidar = URG_04LX_UG01.replace(range_min_m=0.5, range_max_m=1.0)
    near = scan(scene_with(wall(0.3)), SensorModel(), lidar=lidar, lines=5)
    assert near.status[0, FRONT_BEAM] == BeamStatus.TOO_NEAR
    assert "more than gave a range: move the sensor back" in caplog.text
    far = scan(scene_with(wall(1.5)), SensorModel(), lidar=lidar, lines=5)
    assert far.status[0, FRONT_BEAM] == BeamStatus.NO_ECHO
    edge = scan(scene_with(wall(0.99)), SensorModel(), lidar=lidar, lines=30)
    for raw in (near, far, edge):
        ok = raw.status == BeamStatus.OK
        assert np.all(raw.range_m[ok] >= 0.5) and np.all(raw.range_m[ok] <= 1.0)
        assert np.all(np.isnan(raw.range_m[~ok]))
    # Noise pushes some of the 0.99 m returns past 1 m: they are misses, not clamped points.
    front = edge.status[:, FRONT_BEAM]
    assert np.any(front == BeamStatus.NO_ECHO) and np.any(front == BeamStatus.OK)


def test_same_seed_same_scan_bit_for_bit_other_seed_differs():
    scene = scene_with(wall(0.5), wall(0.8, half_m=0.05))
    a, b = scan(scene, SensorModel(), lines=4, seed=7), scan(scene, SensorModel(), lines=4, seed=7)
    for field in ("range_m", "status", "intensity", "geom_id"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    c = scan(scene, SensorModel(), lines=4, seed=8)
    assert not np.array_equal(a.range_m, c.range_m, equal_nan=True)


def test_everything_off_is_the_ideal_scan_bit_for_bit():
    scene = scene_with(wall(0.5, tilt_rad=0.3), wall(0.35, half_m=0.02))
    schedule = StepScan(step_deg=10.0)
    ideal = step_and_shoot(scene, URG_04LX_UG01, schedule)
    off = _sas(scene, URG_04LX_UG01, schedule, model=SensorModel.off(), rng=np.random.default_rng(0))
    for field in ("range_m", "status", "geom_id", "hit_class", "time_s"):
        np.testing.assert_array_equal(getattr(off, field), getattr(ideal, field))
    assert off.intensity is None and ideal.intensity is None


def test_beam_times_follow_the_mirror_steps():
    scene = scene_with(wall(0.5))
    raw = _sas(scene, URG_04LX_UG01, StepScan(step_deg=90.0, step_time_s=0.5), model=SensorModel(),
               rng=np.random.default_rng(0))
    # SCIP 2.0: step k at t0 + k / 1024 x 100 ms; beam 0 is step 44.
    k = 44 + np.arange(683)
    np.testing.assert_allclose(raw.time_s[0], k / 1024 * 0.1)
    np.testing.assert_allclose(raw.time_s[3], 1.5 + k / 1024 * 0.1)
    offsets = URG_04LX_UG01.beam_time_offsets_s()
    assert offsets[-1] - offsets[0] == pytest.approx(682 / 1024 * 0.1)
    assert offsets[-1] < URG_04LX_UG01.scan_period_s


def test_adaptive_footprint_refines_only_edges():
    scene = scene_with(wall(0.5))
    caster = SimulatedLidar(scene, URG_04LX_UG01, BeamGrid.of(URG_04LX_UG01).beam_angles_rad(),
                            model=SensorModel())
    caster.cast_lines(np.zeros(1), np.random.default_rng(0))
    # Only beams whose footprint crosses a boundary (wall edges, the bench, the
    # turntable, the post) are refined, not the flat wall.
    assert 0 < caster.n_refined < 60


# --- presets and configuration ------------------------------------------------

def test_presets_are_valid_and_sourced():
    assert set(PRESETS) == {"urg-04lx-ug01", "utm-30lx", "sick-lms111", "urg-04lx-ug01-worst-case"}
    assert lidar_preset("UTM-30LX").fov_deg == pytest.approx(270.0)
    assert lidar_preset("sick-lms111").n_beams == 1081
    urg = lidar_preset("urg-04lx-ug01")
    assert urg.range_resolution_m == 0.001 and urg.range_sigma_m == 0.010
    assert lidar_preset("urg-04lx-ug01-worst-case").range_sigma_m == 0.030
    for spec in PRESETS.values():
        assert spec.beam_divergence_rad > 0 and spec.detection_range_white_m is not None
    with pytest.raises(ValueError, match="unknown LiDAR preset 'x'; valid presets: "
                                         "urg-04lx-ug01, utm-30lx, sick-lms111, "
                                         "urg-04lx-ug01-worst-case"):
        lidar_preset("x")


def test_lidar_noise_parameters_are_validated():
    with pytest.raises(ValueError, match="range_sigma_m must be a finite number >= 0, got -0.01"):
        URG_04LX_UG01.replace(range_sigma_m=-0.01)
    with pytest.raises(ValueError, match="detection_range_white_m must be a finite number > 0 or "
                                         "None, got 0"):
        URG_04LX_UG01.replace(detection_range_white_m=0)


def test_sensor_model_is_validated():
    with pytest.raises(ValueError, match="footprint_rings must be an integer from 0 to 10, got -1"):
        SensorModel(footprint_rings=-1)
    with pytest.raises(ValueError, match=r"reflectance_plant must be a number in \[0, 1\], got 1.5"):
        SensorModel(reflectance_plant=1.5)
    with pytest.raises(ValueError, match="range_noise must be true or false, got 1"):
        SensorModel(range_noise=1)


def test_toml_sections_for_the_sensor_model_and_a_user_lidar():
    config = config_from_dict({
        "sensor_model": {"footprint_rings": 3, "reflectance_plant": 0.4, "reflectance_rig": 0.05},
        "lidar": {"preset": "sick-lms111", "range_sigma_m": 0.02, "name": "my-lms"},
    })
    assert config.sensor_model.footprint_rings == 3
    assert config.sensor_model.reflectance_plant == 0.4
    assert config.lidar.name == "my-lms" and config.lidar.range_sigma_m == 0.02
    assert config.lidar.beam_divergence_rad == 0.015
    assert config.to_dict()["sensor_model"]["reflectance_rig"] == 0.05
    custom = config_from_dict({"lidar": {
        "name": "bench-unit", "n_beams": 181, "angle_min_deg": -90.0, "angle_increment_deg": 1.0,
        "range_min_m": 0.05, "range_max_m": 8.0, "scan_period_s": 0.1, "steps_per_rev": None,
        "first_step": 0, "beam_divergence_rad": 0.003, "range_sigma_m": 0.01}})
    assert isinstance(custom.lidar, LidarSpec) and custom.lidar.n_beams == 181
    with pytest.raises(ConfigError, match=r"unknown key\(s\) rings in \[sensor_model\]"):
        config_from_dict({"sensor_model": {"rings": 2}})
    with pytest.raises(ConfigError, match=r"\[sensor_model\] footprint_rings must be an integer"):
        config_from_dict({"sensor_model": {"footprint_rings": 11}})


def test_mixed_pixels_in_a_scan_form_a_continuum():
    """A thin horizontal rod 0.2 m before a wall, across the scan plane: footprints straddling its
    edges give ranges all the way between the two surfaces (jittered footprints), not a few levels;
    one ray per beam gives none."""
    post = dict(name="post", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.004, 0.3, 0],
                pos=[X_LIDAR - 0.3, 0.0, Z_LIDAR], quat=[math.cos(math.pi / 4), math.sin(math.pi / 4), 0, 0])
    scene = scene_with(wall(0.5), post)
    lidar = URG_04LX_UG01.replace(n_beams=200, angle_min_deg=-1.0, angle_increment_deg=0.01, steps_per_rev=None,
                                  first_step=0)
    model = SensorModel(range_noise=False, quantise=False, dropouts=False)
    raw = scan(scene, model, lidar=lidar, lines=60)
    r = raw.range_m[raw.status == 0]
    between = r[(r > 0.305) & (r < 0.495)]
    assert len(np.unique(np.round(between, 4))) > 200  # 0.1 mm bins: a continuum (a fixed pattern: ~40)
    single = scan(scene, SensorModel(range_noise=False, quantise=False, dropouts=False, footprint_rings=0),
                  lidar=lidar, lines=60)
    r1 = single.range_m[single.status == 0]
    assert not ((r1 > 0.305) & (r1 < 0.495)).any()


def test_range_sigma_at_least_reads_the_noise_back_from_the_intensity_and_never_above_it():
    # The received-power law: the intensity the model writes, min(1, P sat^2), gives P back
    # below saturation, and so the very sigma the noise was drawn with. Without the
    # intensity (a real URG gives none) a white target head-on, the most power at that
    # range, bounds it from below for any reflectance and incidence.
    from plantsim.sensor.model import intensity_from_power, range_sigma_at_least, received_power

    rng = np.random.default_rng(0)
    lidar, model = URG_04LX_UG01, SensorModel()
    r = np.r_[rng.uniform(0.02, 0.1, 100), rng.uniform(0.1, 4.0, 1900)]  # saturated within 0.1 m
    cos = rng.uniform(0.05, 1.0, 2000)
    rho = rng.uniform(0.05, 1.0, 2000)
    true = range_sigma(r, cos, lidar, reflectance=rho)
    intensity = intensity_from_power(received_power(r, cos, rho), model)
    below = intensity < 1.0
    assert below.sum() > 1000 and (~below).sum() > 10
    got = range_sigma_at_least(r, lidar, intensity=intensity, model=model)
    np.testing.assert_allclose(got[below], true[below], rtol=1e-12)
    assert np.all(got <= true * (1 + 1e-12))
    blind = range_sigma_at_least(r, lidar)
    assert np.all(blind <= true * (1 + 1e-12)) and np.all(blind >= lidar.range_sigma_m)
    np.testing.assert_allclose(range_sigma_at_least(r, lidar), range_sigma(r, np.ones_like(r), lidar))
    # The datasheet band grows with incidence, which a cloud does not record: head-on.
    worst = PRESETS["urg-04lx-ug01-worst-case"]
    np.testing.assert_allclose(range_sigma_at_least(np.array([0.5, 2.0]), worst), [0.030, 0.060])
    assert np.all(range_sigma_at_least(r, worst) <= range_sigma(r, cos, worst) * (1 + 1e-12))
    with pytest.raises(ValueError, match="an intensity needs the model that wrote it"):
        range_sigma_at_least(r, lidar, intensity=intensity)
