"""Tests of the servo model: config conversions, the firmware profile, the shaft."""

import math

import numpy as np
import pytest

from plantsim.turntable import servo
from plantsim.turntable import units


def analytic_rest_to_rest(t, distance, v_max, a_max):
    """Textbook trapezoid (or triangle) position for a rest-to-rest move from 0."""
    t = np.asarray(t, dtype=float)
    d = abs(distance)
    if d <= v_max**2 / a_max:
        t_ramp = math.sqrt(d / a_max)
        v_peak, t_cruise = a_max * t_ramp, 0.0
    else:
        t_ramp = v_max / a_max
        v_peak, t_cruise = v_max, (d - v_max**2 / a_max) / v_max
    t_total = 2 * t_ramp + t_cruise
    p = np.where(
        t < t_ramp,
        0.5 * a_max * t**2,
        np.where(
            t < t_ramp + t_cruise,
            0.5 * a_max * t_ramp**2 + v_peak * (t - t_ramp),
            d - 0.5 * a_max * np.clip(t_total - t, 0, None) ** 2,
        ),
    )
    return math.copysign(1, distance) * np.where(t >= t_total, d, np.where(t < 0, 0, p)), t_total


def test_config_register_round_trip():
    config = servo.ServoConfig(
        position_p_gain=6.0, position_i_gain=3.0, position_d_gain=0.05,
        velocity_feedforward_gain=0.4, profile_velocity=2.0, profile_acceleration=10.0,
        torque_limit=2.0,
    )
    registers = config.to_registers()
    back = servo.ServoConfig().with_registers(registers)
    assert back.to_registers() == registers
    assert back.profile_velocity == pytest.approx(2.0, rel=1e-2)
    assert back.position_p_gain == pytest.approx(6.0, rel=1e-3)


def test_factory_registers_give_factory_config():
    config = servo.ServoConfig.xm430_w350()
    registers = config.to_registers()
    assert registers["Position P Gain"] == 800
    assert registers["Profile Velocity"] == 0 and registers["Profile Acceleration"] == 0
    assert registers["PWM Limit"] == 885
    assert servo.ServoConfig.xl430_w250().to_registers()["Position D Gain"] == 4000


def test_config_validation_names_the_argument():
    with pytest.raises(ValueError, match="armature must be finite and >= 0"):
        servo.ServoConfig(armature=-1.0)
    with pytest.raises(ValueError, match="torque_limit must not exceed stall_torque"):
        servo.ServoConfig(torque_limit=5.0)
    with pytest.raises(ValueError, match="profile_velocity must be > 0"):
        servo.ServoConfig(profile_velocity=0.0)


@pytest.mark.parametrize("distance", [3.0, -3.0, 0.3, -0.05])
def test_profile_matches_analytic_trapezoid_and_triangle(distance):
    v_max, a_max = 2.0, 8.0
    profile = servo.plan_profile(1.0, 1.0 + distance, max_velocity=v_max, max_acceleration=a_max, start_time=5.0)
    expected_kind = servo.PROFILE_TRIANGLE if abs(distance) <= v_max**2 / a_max else servo.PROFILE_TRAPEZOID
    assert profile.kind == expected_kind
    t = np.linspace(-0.5, 3.0, 701)
    p, v, a = profile.sample(5.0 + t)
    reference, duration = analytic_rest_to_rest(t, distance, v_max, a_max)
    np.testing.assert_allclose(p - 1.0, reference, atol=1e-9)
    assert profile.duration == pytest.approx(duration)
    assert np.all(np.abs(v) <= v_max + 1e-12) and np.all(np.abs(a) <= a_max)


def test_ramp_time_is_64_pv_over_pa():
    pv, pa = 100, 20
    profile = servo.plan_profile(
        0.0, units.ticks_to_rad(4096),
        max_velocity=units.velocity_units_to_rad_s(pv),
        max_acceleration=units.acceleration_units_to_rad_s2(pa),
    )
    assert profile.segment_times[1] * 1e3 == pytest.approx(units.profile_ramp_time_ms(pv, pa))


def test_rectangle_and_step():
    rect = servo.plan_profile(0.0, 1.0, max_velocity=2.0)
    assert rect.kind == servo.PROFILE_RECTANGLE and rect.duration == pytest.approx(0.5)
    assert rect.sample(0.25)[0] == pytest.approx(0.5)
    step = servo.plan_profile(0.0, 1.0)
    assert step.kind == servo.PROFILE_STEP and step.sample(0.0)[0] == 1.0


def test_new_goal_blends_with_continuous_velocity():
    first = servo.plan_profile(0.0, 3.0, max_velocity=2.0, max_acceleration=8.0)
    t_switch = 0.6
    p, v, _ = first.sample(t_switch)
    # Reverse: must brake through zero velocity, never jump.
    second = servo.plan_profile(p, -1.0, start_velocity=v, max_velocity=2.0, max_acceleration=8.0,
                                start_time=t_switch)
    t = np.linspace(t_switch, t_switch + second.duration + 0.1, 2001)
    pos, vel, _ = second.sample(t)
    assert vel[0] == pytest.approx(v)
    assert np.max(np.abs(np.diff(vel))) <= 8.0 * (t[1] - t[0]) + 1e-9
    assert pos[-1] == -1.0 and vel[-1] == 0.0
    # Too fast to stop before a close goal: overshoot, then come back.
    third = servo.plan_profile(0.0, 0.01, start_velocity=2.0, max_velocity=2.0, max_acceleration=8.0)
    assert third.sample(third.duration)[0] == 0.01
    assert np.max(third.sample(np.linspace(0, third.duration, 500))[0]) > 0.01


def test_plan_profile_validates():
    with pytest.raises(ValueError, match="goal_position must be finite"):
        servo.plan_profile(0.0, math.nan)
    with pytest.raises(ValueError, match="max_velocity must be > 0"):
        servo.plan_profile(0.0, 1.0, max_velocity=0.0)


def tuned_config(**overrides):
    """An XM430 with stiff gains and velocity feed-forward, so it tracks within ticks."""
    base = servo.ServoConfig()
    values = dict(
        position_p_gain=3200 / units.P_GAIN_DIVISOR * units.SI_PER_KP,
        position_i_gain=2000 / units.I_GAIN_DIVISOR * units.SI_PER_KI,
        velocity_feedforward_gain=(base.damping + base.back_emf_damping) / base.stall_torque,
        profile_velocity=units.velocity_units_to_rad_s(100),
        profile_acceleration=units.acceleration_units_to_rad_s2(20),
    )
    values.update(overrides)
    return servo.ServoConfig(**values)


@pytest.mark.parametrize("goal_ticks", [1500, 300])  # trapezoid, triangle
def test_shaft_follows_profile_and_settles(goal_ticks):
    config = tuned_config()
    shaft = servo.ShaftSim(config, load_inertia=0.002)
    shaft.enable()
    goal = units.ticks_to_rad(goal_ticks)
    profile = shaft.set_goal(goal)
    t, positions = [], []
    while shaft.time < profile.duration + 1.0:
        shaft.step(5)
        t.append(shaft.time)
        positions.append(shaft.position)
    t, positions = np.array(t), np.array(positions)
    reference, duration = analytic_rest_to_rest(t, goal, config.profile_velocity, config.profile_acceleration)
    assert np.all(np.isfinite(positions))
    error_ticks = np.abs(positions - reference) / units.RAD_PER_TICK
    assert np.max(error_ticks) < 8, np.max(error_ticks)
    assert abs(shaft.position - goal) / units.RAD_PER_TICK < 2
    assert abs(shaft.velocity) < 1e-2


def test_factory_gains_settle_without_overshoot_or_nan():
    shaft = servo.ShaftSim(servo.ServoConfig(), timestep=2e-3)
    shaft.enable()
    shaft.set_goal(1.0)  # a step: factory profile is unlimited
    shaft.run_until(1.5)
    assert math.isfinite(shaft.position)
    assert not any(w.number for w in shaft.data.warning)
    assert shaft.position == pytest.approx(1.0, abs=3 * units.RAD_PER_TICK)


def test_integral_anti_windup_under_stall():
    config = tuned_config(torque_limit=0.05, profile_velocity=math.inf, profile_acceleration=math.inf)
    shaft = servo.ShaftSim(config)
    shaft.enable()
    shaft.set_goal(2.0)
    shaft.run_until(0.5)
    bound = shaft.controller.duty_limit / config.position_i_gain
    assert abs(shaft.controller.integral) <= bound + 1e-12
    assert abs(shaft.controller.motor_torque) <= 0.05 + 1e-12


def test_scalar_sampling_matches_vector_sampling():
    profile = servo.plan_profile(0.3, -2.0, start_velocity=1.0, max_velocity=2.0, max_acceleration=8.0,
                                 start_time=1.0)
    t = np.linspace(0.5, 3.5, 301)
    expected = np.array(profile.sample(t)).T
    actual = np.array([profile.sample_scalar(float(x)) for x in t])
    np.testing.assert_allclose(actual, expected, atol=1e-12)


def test_controller_drives_a_hinge_in_another_scene():
    """The reuse path for the full scene: the controller on someone else's hinge."""
    import mujoco

    config = tuned_config()
    joint = " ".join(f'{k}="{v}"' for k, v in config.joint_attributes().items())
    xml = f"""
    <mujoco>
      <compiler angle="radian" autolimits="true"/>
      <option timestep="0.002" integrator="implicitfast"/>
      <worldbody>
        <body name="turntable">
          <joint name="turntable" type="hinge" axis="0 0 1" {joint}/>
          <geom type="cylinder" size="0.15 0.01" mass="1.5"/>
        </body>
      </worldbody>
      <actuator>
        <motor joint="turntable" forcerange="-{config.torque_limit} {config.torque_limit}"/>
      </actuator>
    </mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    controller = servo.PositionController(config)
    controller.enable(data.time, data.qpos[0])
    profile = controller.set_goal(data.time, math.pi / 3)
    while data.time < profile.duration + 0.5:
        data.ctrl[0] = controller.torque(data.time, data.qpos[0], data.qvel[0], model.opt.timestep)
        mujoco.mj_step(model, data)
    assert data.qpos[0] == pytest.approx(math.pi / 3, abs=3 * units.RAD_PER_TICK)
    assert not data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
