"""Turntable dynamics (issue 4): scene content, servo gains, encoder, dynamic scans, stability."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest
import trimesh

from plantsim.scan.config import RunConfig, config_from_dict
from plantsim.rig.scene import LIDAR_GEOMGROUP
from plantsim.scan.plan import plan_scan
from plantsim.scan.pipeline import run_scan
from plantsim.scan.raw import BeamGrid
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.sensor.spec import BeamStatus
from plantsim.turntable.options import TurntableOptions, turntable_options_from_dict
from plantsim.turntable.dynamics import DEFAULT_SERVO, JitterConfig, TurntableDynamics, TurntableSim, build_dynamic_scene, torque_gains
from plantsim.turntable import units
from plantsim.turntable.encoder import EncoderConfig, measure, read
from plantsim.errors import ConfigError, SimulationError
from plantsim.plant.mesh import plant_from_arrays
from plantsim.cloud.reconstruct import reconstruct
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.schedule import StepScan
from plantsim.rig.scene import build_scene
from plantsim.sensor.spec import PRESETS

LIDAR = PRESETS["urg-04lx-ug01"]
BOX_CENTRE = np.array([0.05, 0.02, 0.05])
BOX_HALF = np.array([0.02, 0.03, 0.05])


@pytest.fixture(scope="module")
def box_plant():
    """An off-axis box: every point of it moves when the table turns."""
    box = trimesh.creation.box(extents=2 * BOX_HALF)
    box.apply_translation(BOX_CENTRE)
    return plant_from_arrays(np.asarray(box.vertices), np.asarray(box.faces), placement="none")


def box_distance(points: np.ndarray) -> np.ndarray:
    """Exact distance of points to the box's surface, metres."""
    d = np.abs(points - BOX_CENTRE) - BOX_HALF
    return np.linalg.norm(np.maximum(d, 0), axis=1) + np.abs(np.minimum(d.max(axis=1), 0))


def step_and_check(model: mujoco.MjModel, n: int = 200) -> None:
    data = mujoco.MjData(model)
    for _ in range(n):
        mujoco.mj_step(model, data)
    assert not [w for w in data.warning if w.number], "MuJoCo warned"
    assert np.all(np.isfinite(data.qpos))


# --- scene content ------------------------------------------------------------------

def test_static_scene_has_no_actuator():
    model = build_scene(RigGeometry()).model
    assert (model.nu, model.nactuator, model.na, model.ntendon, model.nplugin) == (0, 0, 0, 0, 0)
    step_and_check(model)


def test_dynamic_scene_adds_only_the_servo():
    ds = build_dynamic_scene(RigGeometry(), None, TurntableDynamics())
    m = ds.scene.model
    assert (m.nactuator, m.nu, m.ntendon, m.nplugin, m.njnt) == (1, 3, 0, 0, 1)
    assert m.actuator_gaintype[0] == mujoco.mjtGain.mjGAIN_PID
    assert m.actuator_forcerange[0].tolist() == [-DEFAULT_SERVO.torque_limit, DEFAULT_SERVO.torque_limit]
    g = torque_gains(DEFAULT_SERVO)
    assert m.actuator_biasprm[0][1] == pytest.approx(-g["kp"])
    joint = m.joint("turntable")
    assert m.dof_armature[joint.dofadr[0]] == pytest.approx(DEFAULT_SERVO.armature)
    # Back-EMF is folded into the hinge's damping.
    assert np.ravel(m.dof_damping)[joint.dofadr[0]] == pytest.approx(DEFAULT_SERVO.damping
                                                             + DEFAULT_SERVO.back_emf_damping)
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    step_and_check(m)


@pytest.mark.parametrize("jitter, nactuator, nu, ntendon, njnt", [
    (JitterConfig(ripple_torque_nm=0.01), 2, 3, 0, 1),
    (JitterConfig(torque_noise_nm=0.01), 2, 4, 0, 1),
    (JitterConfig(backlash_deg=0.25), 1, 3, 1, 2),
    (JitterConfig(ripple_torque_nm=0.01, torque_noise_nm=0.01, backlash_deg=0.25), 3, 4, 1, 2),
])
def test_each_jitter_source_adds_its_own_element(jitter, nactuator, nu, ntendon, njnt):
    m = build_dynamic_scene(RigGeometry(), None, TurntableDynamics(jitter=jitter)).scene.model
    assert (m.nactuator, m.nu, m.ntendon, m.njnt, m.nplugin) == (nactuator, nu, ntendon, njnt, 0)
    if jitter.ripple_torque_nm:
        ripple = m.actuator("ripple").id
        # Periodic in motor angle: gear ratio x periods per motor turn.
        assert m.actuator_biasprm[ripple][1] == round(DEFAULT_SERVO.gear_ratio * 6)
    if jitter.backlash_deg:
        assert m.tendon_range[0] == pytest.approx([-math.radians(0.125), math.radians(0.125)])
    step_and_check(m)


# --- gains: SI and registers, one conversion --------------------------------------

def test_torque_gains_follow_the_firmware_scaling():
    g = torque_gains(DEFAULT_SERVO)
    # KP = P/128 in PWM per tick; 885 PWM = full duty = stall torque.
    expected = 800 / 128 * (4096 / (2 * math.pi)) / 885 * DEFAULT_SERVO.stall_torque
    assert g["kp"] == pytest.approx(expected)
    assert g["ki"] == 0 and g["imax"] == 0


def test_registers_and_si_configure_the_same_servo():
    by_register = turntable_options_from_dict(
        {"registers": {"Position P Gain": 1600, "Position I Gain": 100, "Profile Velocity": 50}})
    servo = by_register.dynamics.servo
    assert servo.to_registers()["Position P Gain"] == 1600
    assert torque_gains(servo)["kp"] == pytest.approx(2 * torque_gains(DEFAULT_SERVO)["kp"])
    by_si = turntable_options_from_dict({"servo": {"position_p_gain": servo.position_p_gain,
                                                   "position_i_gain": servo.position_i_gain}})
    assert torque_gains(by_si.dynamics.servo) == pytest.approx(torque_gains(servo))
    m = build_dynamic_scene(RigGeometry(), None, by_register.dynamics).scene.model
    assert m.na == 1  # the integral state
    g = torque_gains(servo)
    assert m.actuator_dynprm[0][0] == pytest.approx(g["imax"])


def test_turntable_config_errors_are_pinned():
    with pytest.raises(ValueError, match="Position P Gain set both"):
        turntable_options_from_dict({"registers": {"Position P Gain": 800},
                                     "servo": {"position_p_gain": 1.0}})
    with pytest.raises(ValueError, match=r"unknown key\(s\) bogus in \[turntable.jitter\]"):
        turntable_options_from_dict({"jitter": {"bogus": 1}})
    with pytest.raises(ValueError, match="exceeds the servo's no-load speed"):
        TurntableOptions(mode="continuous", rpm=600)
    with pytest.raises(ValueError, match="integrator must be one of"):
        TurntableDynamics(integrator="rk45")
    with pytest.raises(ConfigError, match=r"\[turntable\] turntable mode must be one of"):
        config_from_dict({"turntable": {"mode": "spin"}})
    config = config_from_dict({"turntable": {"mode": "continuous", "rpm": 2,
                                             "encoder": {"ticks_per_rev": 0}}})
    assert config.turntable.rpm == 2 and config.turntable.encoder.ticks_per_rev is None


# --- encoder -------------------------------------------------------------------------

def test_quantisation_error_has_the_expected_magnitude():
    rng = np.random.default_rng(1)
    theta = rng.uniform(0, 2 * math.pi, 50_000)
    error = measure(theta, EncoderConfig(), rng) - theta
    tick = 2 * math.pi / 4096
    assert np.abs(error).max() <= tick / 2 + 1e-12
    # Uniform over one tick: RMS = tick / sqrt(12).
    assert np.sqrt(np.mean(error**2)) == pytest.approx(tick / math.sqrt(12), rel=0.03)
    assert np.all(measure(theta, EncoderConfig.ideal(), rng) == theta)


def test_encoder_offset_eccentricity_latency():
    rng = np.random.default_rng(2)
    t = np.linspace(0, 10, 10_001)
    omega = 0.5
    config = EncoderConfig(ticks_per_rev=None, offset_rad=0.01, eccentricity_rad=0.002,
                           latency_s=0.02, read_rate_hz=50, drift_rad_per_s=1e-4)
    readings = read(t, omega * t, config, rng)
    assert readings.time_s[1] == pytest.approx(0.02)
    late = readings.time_s > 1
    true_then = omega * (readings.time_s[late] - 0.02)
    expected = (true_then + 0.01 + 0.002 * np.sin(true_then)
                + 1e-4 * (readings.time_s[late] - 0.02))
    assert readings.angle_rad[late] == pytest.approx(expected, abs=1e-9)


# --- scans ---------------------------------------------------------------------------

def test_continuous_ideal_scan_deskews_to_within_a_millimetre(box_plant):
    errors = {}
    for deskew in (True, False):
        config = RunConfig(ideal=True, turntable=TurntableOptions(mode="continuous", rpm=5, physics="dynamic",
                                                                  deskew=deskew))
        raw = run_scan(config, plant=box_plant).raw
        assert raw.n_lines == 120
        # Every beam of a line has its own pose: the table turns during a line.
        assert np.all(np.diff(raw.true_turntable_angle_rad[60]) > 0)
        cloud = reconstruct(raw).plant_only()
        assert len(cloud) > 1000
        errors[deskew] = box_distance(cloud.points_turntable).max()
    assert errors[True] < 1e-3
    assert errors[False] > 5 * errors[True]
    assert errors[False] > 2e-4


def test_casting_in_the_turntable_frame_equals_casting_the_turned_scene(box_plant):
    """Rays turned by -theta against the scene at 0 are MuJoCo's own rays at theta (mj_ray)."""
    scene = build_scene(RigGeometry(), box_plant)
    lidar = SimulatedLidar(scene, LIDAR, BeamGrid.of(LIDAR).beam_angles_rad())
    angles = np.radians([0.0, 33.0, 200.0])
    per_line = lidar.cast_lines(angles, np.random.default_rng(0))
    per_beam = lidar.cast_lines(np.repeat(angles[:, None], LIDAR.n_beams, axis=1), np.random.default_rng(0))
    for field in ("range_m", "status", "geom_id"):
        np.testing.assert_array_equal(getattr(per_line, field), getattr(per_beam, field))
    model, data = scene.model, mujoco.MjData(scene.model)
    geomid = np.zeros(1, dtype=np.int32)
    origins, dirs = lidar.caster.origins_base, lidar.caster.dirs_base
    hits = 0
    for k, angle in enumerate(angles):
        data.qpos[scene.turntable_qpos_adr] = angle
        mujoco.mj_kinematics(model, data)
        for b in range(0, LIDAR.n_beams, 7):
            dist = mujoco.mj_ray(model, data, origins[b], dirs[b], LIDAR_GEOMGROUP, 1, scene.lidar_body_id, geomid)
            assert per_line.geom_id[k, b] == geomid[0]
            if dist >= 0 and per_line.status[k, b] == BeamStatus.OK:
                assert per_line.range_m[k, b] == pytest.approx(dist, rel=1e-7, abs=1e-12)
                hits += 1
    assert hits > 50


def test_dynamic_step_scan_settles_and_knows_its_angles(box_plant):
    options = TurntableOptions(physics="dynamic")  # non-ideal default: 4096-tick encoder
    schedule = StepScan(step_deg=30.0)
    result = run_scan(RunConfig(sensor="ideal", scan=schedule, turntable=options), plant=box_plant)
    raw = result.raw
    assert result.plan.motion == "physics"
    true = raw.true_turntable_angle_rad
    assert np.abs(true - schedule.angles_rad()[:, None]).max() < 3 * options.dynamics.settle_tolerance_rad
    # What the reconstruction believes is the encoder: within a tick or so of the truth.
    assert np.abs(raw.turntable_angle_rad - true).max() < 1.5 * units.RAD_PER_TICK
    assert np.all(np.diff(raw.time_s[:, 0]) > 0)
    # Lines start on the free-running LiDAR's own clock.
    line_t0 = raw.time_s[:, 0] - LIDAR.beam_time_offsets_s()[0]
    assert np.allclose(line_t0 / LIDAR.scan_period_s, np.round(line_t0 / LIDAR.scan_period_s), atol=1e-6)
    assert result.diagnostics["max_believed_minus_true_rad"] < 1.5 * units.RAD_PER_TICK


def test_settle_timeout_is_an_error(box_plant):
    weak = dataclasses.replace(DEFAULT_SERVO, position_p_gain=DEFAULT_SERVO.position_p_gain / 20)
    options = TurntableOptions(physics="dynamic", dynamics=TurntableDynamics(
        servo=weak, settle_timeout_s=0.2, max_tracking_error_rad=1.0))
    with pytest.raises(SimulationError, match="did not settle .* raise settle_tolerance_rad"):
        run_scan(RunConfig(sensor="ideal", scan=StepScan(step_deg=90.0), turntable=options), plant=box_plant)


def test_the_plan_picks_the_turntable_motion():
    assert plan_scan(RunConfig(ideal=True, scan=StepScan(step_deg=45.0))).motion == "kinematic"
    assert plan_scan(RunConfig()).motion == "kinematic"
    assert plan_scan(RunConfig(turntable=TurntableOptions(physics="dynamic"))).motion == "physics"
    assert plan_scan(RunConfig(ideal=True, turntable=TurntableOptions(physics="dynamic"))).motion == "physics"
    assert plan_scan(RunConfig(ideal=True, turntable=TurntableOptions(mode="continuous"))).motion == "kinematic"
    assert plan_scan(RunConfig(turntable=TurntableOptions(mode="continuous"))).motion == "physics"


def test_same_seed_same_scan_with_jitter(box_plant):
    dyn = TurntableDynamics(jitter=JitterConfig(torque_noise_nm=0.02, ripple_torque_nm=0.01))
    options = TurntableOptions(mode="continuous", rpm=10, dynamics=dyn, encoder=EncoderConfig(noise_rad=1e-4))
    runs = [run_scan(RunConfig(seed=seed, sensor="ideal", scan=StepScan(sweep_deg=30), turntable=options),
                     plant=box_plant).raw for seed in (3, 3, 4)]
    assert np.array_equal(runs[0].turntable_angle_rad, runs[1].turntable_angle_rad)
    assert np.array_equal(runs[0].range_m, runs[1].range_m, equal_nan=True)
    assert not np.array_equal(runs[0].turntable_angle_rad, runs[2].turntable_angle_rad)


# --- stability ------------------------------------------------------------------------

def scaled(factor: float) -> TurntableDynamics:
    s = DEFAULT_SERVO
    return TurntableDynamics(servo=dataclasses.replace(s, position_p_gain=s.position_p_gain * factor))


@pytest.mark.parametrize("gain, timestep, integrator", [
    (1e4, 1e-2, "implicitfast"), (1e4, 1e-3, "euler"), (1e3, 1e-2, "rk4"),
])
def test_too_stiff_for_the_timestep_is_refused_with_the_fix(gain, timestep, integrator):
    dyn = scaled(gain).replace(timestep_s=timestep, integrator=integrator)
    ds = build_dynamic_scene(RigGeometry(), None, dyn)
    with pytest.raises(SimulationError, match=r"too stiff for the timestep.*use timestep_s <= "):
        TurntableSim(ds, np.random.default_rng(0))


def test_explicit_damping_under_rk4_names_implicitfast():
    s = DEFAULT_SERVO
    dyn = TurntableDynamics(servo=dataclasses.replace(s, damping=200.0), timestep_s=1e-3,
                            integrator="rk4")
    ds = build_dynamic_scene(RigGeometry(), None, dyn)
    with pytest.raises(SimulationError, match='damping is too stiff .* integrator = "implicitfast"'):
        TurntableSim(ds, np.random.default_rng(0))


def test_weak_servo_that_cannot_follow_stops_the_scan(box_plant):
    options = TurntableOptions(mode="continuous", rpm=20, dynamics=scaled(1e-3))
    with pytest.raises(SimulationError, match="could not follow its profile"):
        run_scan(RunConfig(sensor="ideal", scan=StepScan(sweep_deg=90), turntable=options), plant=box_plant)


@pytest.mark.parametrize("gain, timestep, integrator, inertia", [
    (1.0, 1e-3, "implicitfast", None), (1.0, 1e-2, "euler", None), (1.0, 1e-5, "rk4", None),
    (1e2, 1e-4, "implicitfast", None), (1.0, 1e-3, "implicitfast", 1.0),
    (1.0, 1e-3, "euler", 1e-8),
])
def test_stable_cases_track_the_profile(gain, timestep, integrator, inertia):
    dyn = scaled(gain).replace(timestep_s=timestep, integrator=integrator)
    ds = build_dynamic_scene(RigGeometry(), None, dyn)
    if inertia is not None:
        ds.scene.model.body_inertia[ds.scene.model.body("turntable").id] = [inertia, inertia, inertia]
    sim = TurntableSim(ds, np.random.default_rng(0))
    sim.command(math.radians(10))
    sim.advance(int(round(0.6 / timestep)) if timestep >= 1e-4 else 6000)
    tr = sim.trajectory()
    assert np.all(np.isfinite(tr.table_rad))
    assert np.abs(tr.shaft_rad - tr.setpoint_rad).max() < dyn.max_tracking_error_rad


# --- end to end ----------------------------------------------------------------------

@pytest.fixture()
def box_file(tmp_path):
    box = trimesh.creation.box(extents=2 * BOX_HALF)
    box.apply_translation(BOX_CENTRE)
    path = tmp_path / "box.stl"
    path.write_bytes(box.export(file_type="stl"))
    return path


def test_cli_continuous_scan_writes_a_cloud(box_file, tmp_path):
    from plantsim.cli.app import main

    out = tmp_path / "scan.ply"
    # A whole turn: the off-axis box crosses the scan plane only between -18 and +59 degrees.
    assert main(["scan", str(box_file), "--placement", "none", "--mode", "continuous", "--rpm", "10",
                 "--no-deskew", "-o", str(out)]) == 0
    assert out.exists()


def test_a_diverging_setup_writes_nothing(box_file, tmp_path, capsys):
    from plantsim.cli.app import main

    config = tmp_path / "stiff.toml"
    config.write_text('[turntable]\nmode = "continuous"\ntimestep_s = 0.03\nintegrator = "euler"\n'
                      '[turntable.registers]\n"Position P Gain" = 16000\n')
    out = tmp_path / "scan.ply"
    assert main(["scan", str(box_file), "--config", str(config), "-o", str(out)]) == 2
    assert "too stiff for the timestep" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("case, outcome, match", [
    (dict(gain_factor=1e4, timestep_s=1e-2, integrator="euler"), "refused", "use timestep_s <="),
    (dict(gain_factor=1e-3, timestep_s=1e-3), "stopped", "raise the position P gain"),
    (dict(rev_per_s=10.0), "error", "exceeds the servo's no-load speed"),
    (dict(gain_factor=1e2, timestep_s=1e-4, integrator="rk4"), "ok", ""),
    (dict(load_inertia_kg_m2=1e-8, timestep_s=1e-2, integrator="euler"), "ok", ""),
])
def test_stability_matrix_subset(case, outcome, match):
    from plantsim.turntable.stability import run_case

    out = run_case(duration_s=0.3, **case)
    assert out.outcome == outcome, out.message
    assert match in out.message
    if outcome == "ok":
        assert out.max_tracking_error_rad < 0.2
