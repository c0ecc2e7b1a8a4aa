"""Issue 10: range error split into power-driven noise, bias and drift; mixed pixels; the fit."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import HitClass, build_spec, compile_scene
from plantsim.scan.config import config_from_dict
from plantsim.scan.pipeline import step_and_shoot
from plantsim.scan.schedule import StepScan
from plantsim.sensor.fit import FlatTargetRecording, fit_sensor
from plantsim.sensor.flat_target import FlatTarget, simulate_flat_target
from plantsim.sensor.footprint import (combine_footprint, jitter_subrays, subray_pattern,
                                       subrays_lidar)
from plantsim.sensor.model import (SensorModel, apply_sensor, range_bias, range_sigma,
                                   received_power, warmup_drift)
from plantsim.sensor.spec import PRESETS, URG_04LX_UG01, BeamStatus

RIG = RigGeometry()
X_LIDAR = RIG.lidar_distance_m
Z_LIDAR = RIG.lidar_height_m
FRONT_BEAM = 384 - 44


# --- the noise law -------------------------------------------------------------

def test_noise_is_a_function_of_received_power_with_a_floor():
    lidar = URG_04LX_UG01  # 10 mm floor, 1 % of the white-equivalent range
    # A white plate head-on at r: sigma = hypot(10 mm, 0.01 r).
    r = np.array([0.1, 0.5, 1.0, 2.0, 4.0])
    np.testing.assert_allclose(range_sigma(r, np.ones(5), lidar), np.hypot(0.010, 0.01 * r))
    # Range, reflectance and incidence act through P alone: equal power, equal sigma.
    a = range_sigma(0.5, 1.0, lidar, reflectance=0.25)
    b = range_sigma(1.0, 1.0, lidar, reflectance=1.0)
    c = range_sigma(0.5, 0.5, lidar, reflectance=0.5)
    assert a == pytest.approx(b) and a == pytest.approx(c)
    # The matte-target figure the sources give: about 10 mm at 0.1-1 m.
    assert np.all(range_sigma(np.array([0.1, 0.3, 1.0]), 1.0, lidar, reflectance=0.9) < 0.0151)
    # Grazing incidence: bounded by the detection threshold, never unbounded.
    graze = range_sigma(0.3, np.array([1e-3, 1e-9, 0.0]), lidar, reflectance=0.5)
    np.testing.assert_allclose(graze, math.hypot(0.010, 0.01 * 5.6))
    # The noise no longer explodes as 1/cos: at 80 degrees it is far below the worst case.
    cos80 = math.cos(math.radians(80))
    worst = PRESETS["urg-04lx-ug01-worst-case"]
    assert range_sigma(0.3, cos80, worst) == pytest.approx(0.030 / cos80)
    assert range_sigma(0.3, cos80, lidar, reflectance=0.5) < 0.3 * range_sigma(0.3, cos80, worst)


def test_systematic_error_offset_scale_reflectance_and_warmup():
    lidar = URG_04LX_UG01.replace(range_bias_m=0.004, range_bias_rel=0.01, range_bias_dark_m=0.02,
                                  warmup_drift_m=0.012, warmup_time_constant_s=300.0)
    bias = range_bias(np.array([0.5, 2.0]), np.array([1.0, 0.0]), lidar)
    np.testing.assert_allclose(bias, [0.004 + 0.005, 0.004 + 0.02 + 0.02])
    assert warmup_drift(0.0, lidar) == pytest.approx(0.012)
    assert warmup_drift(300.0, lidar) == pytest.approx(0.012 / math.e)
    with_drift = range_bias(0.5, 1.0, lidar, time_since_power_on_s=0.0, material_bias_m=-0.003)
    assert with_drift == pytest.approx(0.009 + 0.012 - 0.003)


def test_apply_sensor_bias_drift_and_material_offsets_without_noise():
    lidar = URG_04LX_UG01.replace(range_bias_m=0.005, warmup_drift_m=0.010,
                                  warmup_time_constant_s=100.0, range_resolution_m=0.0)
    model = SensorModel(range_noise=False, power_on_age_s=0.0, range_bias_plant_m=0.002)
    true = np.full((3, 2), 0.5)
    power = received_power(true, 1.0, 0.5)
    line_time = np.array([0.0, 100.0, 1e6])
    hit_class = np.full(true.shape, HitClass.PLANT, dtype=np.uint8)
    hit_class[:, 1] = HitClass.RIG
    out, status, _ = apply_sensor(true, power, np.ones(true.shape), np.zeros(true.shape), lidar, model,
                                  np.random.default_rng(0), hit_class=hit_class, line_time_s=line_time)
    assert np.all(status == BeamStatus.OK)
    expected = 0.5 + 0.005 + 0.010 * np.exp(-line_time / 100.0)
    np.testing.assert_allclose(out[:, 0], expected + 0.002)  # plant: its material offset
    np.testing.assert_allclose(out[:, 1], expected)  # rig: none
    # The apparent reflectance from the power is the true one: the dark walk applies.
    dark = lidar.replace(range_bias_dark_m=0.02)
    out, _, _ = apply_sensor(true, power, np.ones(true.shape), np.zeros(true.shape), dark,
                             SensorModel(range_noise=False), np.random.default_rng(0))
    np.testing.assert_allclose(out, 0.5 + 0.005 + 0.02 * 0.5, atol=1e-6)


# --- flat plates through the whole scan pipeline ---------------------------------

def _scene_with_wall(distance_m: float, tilt_rad: float):
    spec = build_spec(RIG, None)
    quat = [math.cos(tilt_rad / 2), 0.0, math.sin(tilt_rad / 2), 0.0]
    spec.worldbody.add_geom(name="wall", group=2, contype=0, conaffinity=0,
                            type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.001, 2.0, 2.0],
                            pos=[X_LIDAR - distance_m - 0.001 / math.cos(tilt_rad), 0.0, Z_LIDAR],
                            quat=quat)
    return compile_scene(spec, RIG, None)


@pytest.mark.parametrize("distance_m,tilt_deg", [(0.3, 0.0), (0.3, 60.0), (1.0, 0.0), (1.0, 45.0),
                                                 (2.5, 0.0)])
def test_flat_plate_sd_and_bias_match_the_model(distance_m, tilt_deg):
    lidar = URG_04LX_UG01.replace(range_bias_m=0.006, range_bias_dark_m=0.010)
    scene = _scene_with_wall(distance_m, math.radians(tilt_deg))
    wall_id = scene.model.geom("wall").id
    raw = step_and_shoot(scene, lidar, StepScan(step_deg=1.0, sweep_deg=360.0), model=SensorModel(),
                         rng=np.random.default_rng(5))
    # The front beam meets the tilted plate at incidence tilt_deg; nearby beams at
    # nearly the same incidence: use +-3 beams around it.
    beams = FRONT_BEAM + np.arange(-3, 4)
    on = raw.geom_id[:, beams] == wall_id
    assert np.all(on) and np.all(raw.status[:, beams] == BeamStatus.OK)
    a = raw.beam_angle_rad[beams]
    tilt = math.radians(tilt_deg)
    # The plate passes through the point distance_m ahead, its normal turned by
    # the tilt towards positive beam angles: r(a) = d cos t / cos(a - t).
    true = distance_m * math.cos(tilt) / np.cos(a - tilt)
    cos_inc = np.cos(a - tilt)
    err = raw.range_m[:, beams] - true[None, :]
    sigma = range_sigma(true, cos_inc, lidar, reflectance=0.5)
    bias = range_bias(true, 0.5, lidar, time_since_power_on_s=3600.0)
    n = err.size
    assert err.mean() == pytest.approx(bias.mean(), abs=4 * sigma.mean() / math.sqrt(n))
    assert (err - bias).std() == pytest.approx(math.sqrt(np.mean(sigma ** 2)), rel=0.1)


# --- mixed pixels ----------------------------------------------------------------

def _cylinder_then_wall(origins, dirs, *, x_cyl, radius, x_wall):
    """First-hit distance along rays (+X-ish) against a cylinder (axis along Z at
    (x_cyl, y_c=0)) in front of a wall x = x_wall; returns distance and |cos|."""
    o, d = origins.reshape(-1, 3), dirs.reshape(-1, 3)
    # Cylinder: (ox + t dx - xc)^2 + (oy + t dy)^2 = R^2.
    px, py = o[:, 0] - x_cyl, o[:, 1]
    A = d[:, 0] ** 2 + d[:, 1] ** 2
    B = 2 * (px * d[:, 0] + py * d[:, 1])
    C = px ** 2 + py ** 2 - radius ** 2
    disc = B ** 2 - 4 * A * C
    t_cyl = np.where(disc >= 0, (-B - np.sqrt(np.maximum(disc, 0))) / (2 * A), np.inf)
    t_wall = (x_wall - o[:, 0]) / d[:, 0]
    hit_cyl = t_cyl < t_wall
    t = np.where(hit_cyl, t_cyl, t_wall)
    p = o + t[:, None] * d
    n_cyl = np.stack([p[:, 0] - x_cyl, p[:, 1], 0 * p[:, 0]], axis=1) / radius
    normal = np.where(hit_cyl[:, None], n_cyl, np.array([1.0, 0.0, 0.0]))
    cos = np.abs(np.sum(normal * d, axis=1))
    return t.reshape(origins.shape[:-1]), cos.reshape(origins.shape[:-1])


def _mixed_ranges(n_rings, *, jitter, n_draws=400):
    """A 2 mm stem (axis out of the scan plane) 0.3 m ahead of a wall at 0.4 m; the
    beam's footprint (URG: 10 mrad) sweeps across the stem's edge as the stem moves."""
    pattern = subray_pattern(n_rings)
    rng = np.random.default_rng(11)
    # Beams around 0 deg in a lidar frame where +Z is the stem axis: the beam
    # sweeps in the scan plane (the in-plane offset crosses the stem's edge).
    angles = np.linspace(-0.012, 0.012, 241)
    offsets, weights = (jitter_subrays(pattern, rng, (n_draws, len(angles))) if jitter
                        else (None, pattern.weights))
    origins, dirs = subrays_lidar(angles, pattern, divergence_rad=0.010, exit_diameter_m=0.0,
                                  offsets=offsets)
    dist, cos = _cylinder_then_wall(origins, dirs, x_cyl=0.301, radius=0.001, x_wall=0.4)
    ret = combine_footprint(dist, cos, np.full(dist.shape, 0.5), weights, range_max_m=5.0)
    r = ret.range_m.ravel()
    return r[(r > 0.3 + 0.001) & (r < 0.4 - 0.001)]


def test_mixed_pixels_behind_a_thin_stem_form_a_continuum():
    between = _mixed_ranges(2, jitter=True)
    levels = np.unique(np.round(between, 4))  # 0.1 mm bins
    assert len(between) > 1000
    assert len(levels) > 300, len(levels)
    # They fill the gap between stem and wall: no stretch of 0.5 mm of its inner
    # 90 mm is empty (the last few mm next to each surface need a sub-ray far
    # out in the beam's tail: finite sampling).
    def widest_gap(r):
        inner = r[(r > 0.305) & (r < 0.395)]
        return np.max(np.diff(np.sort(np.concatenate([[0.305], inner, [0.395]]))))

    assert widest_gap(between) < 0.0005
    # A fixed pattern leaves steps (empty stretches of several mm) however
    # finely the edge is swept, and one ray per beam gives no mixed pixel at all.
    fixed = _mixed_ranges(2, jitter=False, n_draws=1)
    assert widest_gap(fixed) > 0.003
    assert len(_mixed_ranges(0, jitter=True)) == 0


def test_jittered_footprint_integrates_the_gaussian_profile():
    # The power share of a half-plane edge at offset s (in 1/e^2 radii) is, for
    # the profile exp(-2 rho^2), Phi(2 s) (a Gaussian of sigma 1/2 per axis).
    from statistics import NormalDist

    pattern = subray_pattern(2)
    offsets, weights = jitter_subrays(pattern, np.random.default_rng(4), (20000,))
    assert offsets.shape == (20000, 19, 2) and np.allclose(weights.sum(axis=-1), 1.0)
    assert np.all(np.hypot(*offsets[:, 0].T) <= 0.25)  # the axis ray stays in its disk
    for s in (-0.5, 0.0, 0.3, 0.8):
        share = (weights * (offsets[..., 0] < s)).sum(axis=-1).mean()
        assert share == pytest.approx(NormalDist(0, 0.5).cdf(s), abs=0.02), s


def test_twisted_rings_have_distinct_offsets_and_rotation_keeps_the_footprint():
    pattern = subray_pattern(3)
    for axis in (0, 1):
        assert len(np.unique(np.round(pattern.offsets[:, axis], 9))) == pattern.n_subrays
    angles = np.array([0.0, 0.5])
    _, d0 = subrays_lidar(angles, pattern, divergence_rad=0.01, exit_diameter_m=0.002)
    rot = np.array([[0.0, 0.0], [1.0, 2.0]])
    _, d1 = subrays_lidar(angles, pattern, divergence_rad=0.01, exit_diameter_m=0.002,
                           rotation_rad=rot)
    assert d1.shape == (2,) + d0.shape
    np.testing.assert_allclose(d1[0], d0)
    np.testing.assert_allclose(d1[1, :, 0], d0[:, 0])  # the axis ray never moves
    # A turn keeps each sub-ray's angle from the axis.
    np.testing.assert_allclose(np.einsum("bsk,bk->bs", d1[1], d0[:, 0]),
                               np.einsum("bsk,bk->bs", d0, d0[:, 0]))
    with pytest.raises(ValueError, match=r"rotation_rad must have shape \(\.\.\., n_beams\) with "
                                         r"n_beams = 2, got shape \(3,\)"):
        subrays_lidar(angles, pattern, divergence_rad=0.01, exit_diameter_m=0.0,
                      rotation_rad=np.zeros(3))


# --- the fit ---------------------------------------------------------------------

TRUE = dict(range_sigma_m=0.008, range_sigma_rel=0.012, range_bias_m=0.015, range_bias_rel=0.005,
            range_bias_dark_m=0.02, warmup_drift_m=-0.015, warmup_time_constant_s=600.0)


def _recording(lidar, *, n_lines=2400, start_s=0.0, distances=(0.2, 0.4, 0.8, 1.5, 3.0),
               reflectances=(0.9, 0.2), seed=0):
    k = np.arange(n_lines)
    d = np.asarray(distances)[k % len(distances)]
    rho = np.asarray(reflectances)[(k // len(distances)) % len(reflectances)]
    t = start_s + 1.5 * k
    angles = URG_04LX_UG01.beam_angles_rad()[::3]
    target = FlatTarget.make(n_lines, distance_m=d, half_width_m=0.3 * d, reflectance=rho)
    model = SensorModel(power_on_age_s=start_s)
    r, _ = simulate_flat_target(target, angles, t - start_s, lidar, model, np.random.default_rng(seed))
    return FlatTargetRecording(range_m=r, beam_angles_rad=angles, time_since_power_on_s=t,
                               target=target)


@pytest.mark.parametrize("seed", [0, 1])
def test_fit_recovers_known_parameters_within_10_percent(seed):
    lidar = URG_04LX_UG01.replace(**TRUE)
    fitted = fit_sensor(_recording(lidar, seed=seed))
    for key, value in TRUE.items():
        assert getattr(fitted, key) == pytest.approx(value, rel=0.10), key
    assert fitted.n_returns > 10_000 and fitted.n_outliers < 0.01 * fitted.n_returns


def test_fit_leaves_out_what_the_recording_cannot_separate():
    lidar = URG_04LX_UG01.replace(range_sigma_m=0.010, range_bias_m=-0.01, warmup_drift_m=0.01)
    # One distance, one reflectance, warmed up: offset and noise only.
    fitted = fit_sensor(_recording(lidar, n_lines=600, start_s=7200.0, distances=(0.5,),
                                   reflectances=(0.9,)))
    assert fitted.range_bias_rel is None and fitted.range_bias_dark_m is None
    assert fitted.warmup_drift_m is None and fitted.warmup_time_constant_s is None
    assert fitted.range_bias_m == pytest.approx(-0.01, abs=0.001)
    assert fitted.range_sigma_m == pytest.approx(math.hypot(0.010, 0.01 * 0.5 / math.sqrt(0.9)),
                                                 rel=0.1)
    toml = fitted.to_toml("urg-04lx-ug01", source="bag")
    assert "range_bias_rel, range_bias_dark_m, warmup_drift_m" in toml


def test_fitted_toml_is_a_config_a_scan_reads():
    import tomllib

    fitted = fit_sensor(_recording(URG_04LX_UG01.replace(**TRUE), n_lines=1200))
    config = config_from_dict(tomllib.loads(fitted.to_toml("urg-04lx-ug01")))
    assert config.lidar.range_sigma_m == pytest.approx(fitted.range_sigma_m, rel=1e-5)
    assert config.lidar.warmup_time_constant_s == pytest.approx(fitted.warmup_time_constant_s, rel=1e-5)
    assert config.lidar.n_beams == 683


def test_fit_refuses_a_recording_without_the_plate_in_view():
    lidar = URG_04LX_UG01
    rec = _recording(lidar, n_lines=20)
    blank = FlatTargetRecording(range_m=np.full(rec.range_m.shape, np.nan),
                                beam_angles_rad=rec.beam_angles_rad,
                                time_since_power_on_s=rec.time_since_power_on_s, target=rec.target)
    with pytest.raises(ValueError, match=r"only 0 returns lie on the plate \(need at least 100\)"):
        fit_sensor(blank)
    with pytest.raises(ValueError, match=r"time_since_power_on_s must have shape \(20,\) \(one time "
                                         r"per line\), got shape \(3,\)"):
        FlatTargetRecording(range_m=rec.range_m, beam_angles_rad=rec.beam_angles_rad,
                            time_since_power_on_s=np.zeros(3), target=rec.target)


def test_new_lidar_and_model_fields_are_validated():
    with pytest.raises(ValueError, match="noise_law must be one of received-power, datasheet-band, "
                                         "got 'gauss'"):
        URG_04LX_UG01.replace(noise_law="gauss")
    with pytest.raises(ValueError, match="warmup_time_constant_s must be a finite number of seconds "
                                         "> 0, got 0"):
        URG_04LX_UG01.replace(warmup_time_constant_s=0)
    with pytest.raises(ValueError, match="range_bias_rel must be a fraction of the range within "
                                         r"\+-0.5, got 0.7"):
        URG_04LX_UG01.replace(range_bias_rel=0.7)
    with pytest.raises(ValueError, match="power_on_age_s must be a finite number of seconds >= 0, "
                                         "got -1"):
        SensorModel(power_on_age_s=-1)


def test_sensor_fit_cli_reads_a_bag(tmp_path):
    from plantsim.cli.app import main
    from plantsim.cloud.bag import write_raw
    from plantsim.scan.raw import BeamGrid, RawScan

    lidar = URG_04LX_UG01.replace(range_bias_m=0.012)
    n = 300
    t = 0.1 * np.arange(n)
    d = np.where(t < 15.0, 0.5, 1.2)
    target = FlatTarget.make(n, distance_m=d, half_width_m=0.3)
    grid = BeamGrid.of(lidar)
    r, status = simulate_flat_target(target, grid.beam_angles_rad(), t, lidar, SensorModel(),
                                     np.random.default_rng(2))
    raw = RawScan(grid=grid, line_stamp_ns=np.round(t * 1e9).astype(np.int64),
                  range_m=r.astype(np.float32).astype(np.float64), status=status, intensity=None,
                  encoder_stamp_ns=np.array([0], dtype=np.int64), encoder_angle_rad=np.zeros(1),
                  commanded_rad=np.full(n, np.nan), angle_mode="line",
                  lidar_pose=(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])))
    write_raw(tmp_path / "bag", raw)
    out = tmp_path / "sensor.toml"
    code = main(["sensor", "fit", str(tmp_path / "bag"), "--target", "0:15:0.5",
                 "--target", "15:30:1.2", "--reflectance", "0.9", "--half-width-m", "0.3",
                 "--power-on-s", "3600", "-o", str(out)])
    assert code == 0
    text = out.read_text()
    assert 'preset = "urg-04lx-ug01"' in text
    import tomllib

    fitted = tomllib.loads(text)["lidar"]
    assert fitted["range_bias_m"] == pytest.approx(0.012, abs=0.002)
    assert fitted["range_sigma_m"] == pytest.approx(0.010, rel=0.15)
