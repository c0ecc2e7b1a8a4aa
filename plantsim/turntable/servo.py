"""The servo model shared by the Dynamixel emulator and the dynamic scans.

Three pieces, usable separately:

* :class:`ServoConfig`: the motor, gearbox and controller settings in SI, with the
  one conversion to and from Dynamixel register units (:meth:`ServoConfig.to_registers`,
  :meth:`ServoConfig.from_registers`).
* :func:`plan_profile`: the firmware's velocity profile (trapezoid, triangle when the
  move is short, rectangle or step when a limit is 0 / infinite), starting from any
  position and velocity so that a new goal blends into a running move.
* :class:`PositionController` (profile + position PID + DC-motor model, returning a
  joint torque) and :class:`ShaftSim` (a one-hinge MuJoCo model driven by it).

To drive another hinge (e.g. the turntable in the full scene) with the same servo,
give the hinge ``config.joint_attributes()`` and a ``<motor>`` with
``forcerange=±config.torque_limit``, then each step::

    controller = PositionController(config)
    controller.enable(data.time, data.qpos[q])
    controller.set_goal(data.time, goal_rad)
    # every step:
    data.ctrl[actuator_id] = controller.torque(data.time, data.qpos[q], data.qvel[v], model.opt.timestep)
    mujoco.mj_step(model, data)

Motor model (ROBOTIS gives only stall torque and no-load speed at 12 V): the firmware's
PID output is a PWM duty d in [-1, 1]; a DC motor then gives the output shaft torque
``stall_torque * (d - omega / no_load_speed)`` (linear torque-speed line), clipped to
``torque_limit``. The back-EMF term is why a servo slows under load.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Mapping

from plantsim._lazy import lazy_module
import numpy as np

from plantsim.turntable import units
from plantsim.errors import SimulationError

mujoco = lazy_module("mujoco")  # loaded on first use: a kinematic scan never uses it


@dataclasses.dataclass(frozen=True)
class ServoConfig:
    """A position-controlled servo, in SI units (N m, rad, s, kg m^2).

    Defaults are the XM430-W350 at 12 V (e-Manual) with its factory gains. The
    armature (0.045) and frictionloss (0.03) are from a published MuJoCo model of the
    XM430 (source not given; ROBOTIS publishes no rotor inertia). That model's damping
    of 1.084 N m s/rad lumps in the back-EMF, which we model explicitly
    (stall_torque / no_load_speed = 0.851), so the viscous part left is 0.233;
    counting both would cap the speed near 20 rpm instead of the rated 46.

    Attributes:
        gear_ratio: gearbox reduction (informational; the armature is already
            reflected to the output shaft).
        stall_torque: output torque at zero speed and full duty, N m.
        stall_current: current at stall, A (for Present Current).
        no_load_speed: output speed at full duty and no load, rad/s.
        armature: reflected rotor inertia at the output shaft, kg m^2.
        damping: viscous friction at the output shaft, N m s/rad.
        frictionloss: dry friction at the output shaft, N m.
        torque_limit: cap on the output torque, N m (the PWM Limit register).
        position_p_gain: duty per rad of position error.
        position_i_gain: duty per (rad s) of integrated error.
        position_d_gain: duty per (rad/s) of velocity error.
        velocity_feedforward_gain: duty per (rad/s) of trajectory velocity.
        acceleration_feedforward_gain: duty per (rad/s^2) of trajectory acceleration.
        profile_velocity: cap of the profile's velocity, rad/s; ``math.inf`` = none
            (register value 0).
        profile_acceleration: profile acceleration, rad/s^2; ``math.inf`` = none.
    """

    gear_ratio: float = 353.5
    stall_torque: float = 4.1
    stall_current: float = 2.3
    no_load_speed: float = 46.0 * 2.0 * math.pi / 60.0
    armature: float = 0.045
    damping: float = 1.084 - 4.1 / (46.0 * 2.0 * math.pi / 60.0)
    frictionloss: float = 0.03
    torque_limit: float = 4.1
    position_p_gain: float = 800 / units.P_GAIN_DIVISOR * units.SI_PER_KP
    position_i_gain: float = 0.0
    position_d_gain: float = 0.0
    velocity_feedforward_gain: float = 0.0
    acceleration_feedforward_gain: float = 0.0
    profile_velocity: float = math.inf
    profile_acceleration: float = math.inf

    def __post_init__(self):
        positive = ("gear_ratio", "stall_torque", "stall_current", "no_load_speed", "torque_limit")
        non_negative = (
            "armature", "damping", "frictionloss", "position_p_gain", "position_i_gain",
            "position_d_gain", "velocity_feedforward_gain", "acceleration_feedforward_gain",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        for name in non_negative:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        for name in ("profile_velocity", "profile_acceleration"):
            value = getattr(self, name)
            if math.isnan(value) or value <= 0:
                raise ValueError(f"{name} must be > 0 (math.inf for no limit), got {value!r}")
        if self.torque_limit > self.stall_torque:
            raise ValueError(
                f"torque_limit must not exceed stall_torque ({self.stall_torque} N m), got {self.torque_limit}"
            )

    @classmethod
    def xm430_w350(cls, **overrides) -> "ServoConfig":
        """The XM430-W350 at 12 V with factory gains (P 800, I 0, D 0)."""
        return cls(**overrides)

    @classmethod
    def xl430_w250(cls, **overrides) -> "ServoConfig":
        """The XL430-W250 at 12 V with factory gains (P 640, I 0, D 4000).

        Its armature is a guess: the XM430's scaled by the squared gear ratio.
        """
        values = dict(
            gear_ratio=258.5,
            stall_torque=1.5,
            stall_current=1.4,
            no_load_speed=61.0 * 2.0 * math.pi / 60.0,
            armature=0.045 * (258.5 / 353.5) ** 2,
            torque_limit=1.5,
            position_p_gain=640 / units.P_GAIN_DIVISOR * units.SI_PER_KP,
            position_d_gain=4000 / units.D_GAIN_DIVISOR * units.SI_PER_KD,
        )
        values.update(overrides)
        return cls(**values)

    @property
    def back_emf_damping(self) -> float:
        """Torque lost per rad/s by back-EMF at any duty, N m s/rad.

        The full stall-to-no-load line; the viscous ``damping`` comes on top, so
        the model's top speed (:meth:`top_speed_rad_s`, 35.9 rpm for the
        XM430-W350) is below the rated no-load speed (46 rpm). Moving the viscous
        loss inside the line would reach 46 rpm but changes the emulator's
        settling that the hardware-in-the-loop tests were matched against, so
        the limit is stated and checked up front instead.
        """
        return self.stall_torque / self.no_load_speed

    def top_speed_rad_s(self, *, extra_damping: float = 0.0, extra_friction: float = 0.0) -> float:
        """Steady speed at full duty (the torque limit), rad/s: the fastest the servo can turn.

        Args:
            extra_damping: viscous loss of the load, N m s/rad.
            extra_friction: dry friction of the load, N m.
        """
        drive = self.torque_limit - self.frictionloss - extra_friction
        if drive <= 0:
            return 0.0
        # At full duty: torque_limit - (back_emf + damping + extra) * omega - friction = 0.
        slope = self.back_emf_damping + self.damping + extra_damping
        return drive / slope if slope > 0 else math.inf

    def joint_attributes(self) -> dict[str, str]:
        """MJCF ``<joint>`` attributes for a hinge driven by this servo."""
        return {
            "armature": repr(self.armature),
            "damping": repr(self.damping),
            "frictionloss": repr(self.frictionloss),
        }

    def to_registers(self) -> dict[str, int]:
        """The register values (raw units) that express this configuration.

        Returns:
            Register name -> raw value, for Position P/I/D Gain, Feedforward 1st/2nd
            Gain, Profile Velocity/Acceleration and PWM Limit.

        Raises:
            ValueError: if a value does not fit its register's range.
        """
        registers = {
            "Position P Gain": round(self.position_p_gain / units.SI_PER_KP * units.P_GAIN_DIVISOR),
            "Position I Gain": round(self.position_i_gain / units.SI_PER_KI * units.I_GAIN_DIVISOR),
            "Position D Gain": round(self.position_d_gain / units.SI_PER_KD * units.D_GAIN_DIVISOR),
            "Feedforward 1st Gain": round(
                self.velocity_feedforward_gain / units.SI_PER_KFF1 * units.FF_GAIN_DIVISOR
            ),
            "Feedforward 2nd Gain": round(
                self.acceleration_feedforward_gain / units.SI_PER_KFF2 * units.FF_GAIN_DIVISOR
            ),
            "Profile Velocity": 0
            if math.isinf(self.profile_velocity)
            else max(1, units.rad_s_to_velocity_units(self.profile_velocity)),
            "Profile Acceleration": 0
            if math.isinf(self.profile_acceleration)
            else max(1, units.rad_s2_to_acceleration_units(self.profile_acceleration)),
            "PWM Limit": round(self.torque_limit / self.stall_torque * units.PWM_FULL_SCALE),
        }
        limits = {"Profile Velocity": 32767, "Profile Acceleration": 32767}
        for name, value in registers.items():
            high = limits.get(name, 16383 if "Gain" in name else units.PWM_FULL_SCALE)
            if not 0 <= value <= high:
                raise ValueError(f"{name} register must be in [0, {high}], this config gives {value}")
        return registers

    def with_registers(self, registers: Mapping[str, int]) -> "ServoConfig":
        """A copy with the controller settings taken from raw register values.

        Registers not in ``registers`` keep this config's value; the mechanical
        parameters (stall torque, armature, ...) always come from ``self``.
        """
        changes = {}
        if "Position P Gain" in registers:
            changes["position_p_gain"] = registers["Position P Gain"] / units.P_GAIN_DIVISOR * units.SI_PER_KP
        if "Position I Gain" in registers:
            changes["position_i_gain"] = registers["Position I Gain"] / units.I_GAIN_DIVISOR * units.SI_PER_KI
        if "Position D Gain" in registers:
            changes["position_d_gain"] = registers["Position D Gain"] / units.D_GAIN_DIVISOR * units.SI_PER_KD
        if "Feedforward 1st Gain" in registers:
            changes["velocity_feedforward_gain"] = (
                registers["Feedforward 1st Gain"] / units.FF_GAIN_DIVISOR * units.SI_PER_KFF1
            )
        if "Feedforward 2nd Gain" in registers:
            changes["acceleration_feedforward_gain"] = (
                registers["Feedforward 2nd Gain"] / units.FF_GAIN_DIVISOR * units.SI_PER_KFF2
            )
        if "Profile Velocity" in registers:
            pv = registers["Profile Velocity"]
            changes["profile_velocity"] = math.inf if pv == 0 else units.velocity_units_to_rad_s(pv)
        if "Profile Acceleration" in registers:
            pa = registers["Profile Acceleration"]
            changes["profile_acceleration"] = math.inf if pa == 0 else units.acceleration_units_to_rad_s2(pa)
        if "PWM Limit" in registers:
            # A zero PWM limit is a valid "no torque" setting; keep the dataclass valid.
            fraction = max(registers["PWM Limit"], 1) / units.PWM_FULL_SCALE
            changes["torque_limit"] = fraction * self.stall_torque
        return dataclasses.replace(self, **changes)


# --- profile ------------------------------------------------------------------

PROFILE_STEP, PROFILE_RECTANGLE, PROFILE_TRIANGLE, PROFILE_TRAPEZOID = 0, 1, 2, 3


@dataclasses.dataclass(frozen=True)
class Profile:
    """A piecewise-constant-acceleration trajectory, starting at ``start_time``.

    Attributes:
        start_time: s.
        segment_times: (n,) float64, s from ``start_time`` at which each segment starts.
        segment_positions, segment_velocities: (n,) float64, rad and rad/s at each start.
        segment_accelerations: (n,) float64, rad/s^2 held during each segment.
        duration: s from ``start_time`` to the end (rest at ``goal``).
        goal: final position, rad.
        kind: PROFILE_STEP, PROFILE_RECTANGLE, PROFILE_TRIANGLE or PROFILE_TRAPEZOID
            (the Moving Status bits 4-5 encoding).
    """

    start_time: float
    segment_times: np.ndarray
    segment_positions: np.ndarray
    segment_velocities: np.ndarray
    segment_accelerations: np.ndarray
    duration: float
    goal: float
    kind: int

    def sample(self, t):
        """Position, velocity and acceleration at absolute time(s) ``t``.

        Args:
            t: scalar or (m,) array, s.

        Returns:
            (position, velocity, acceleration), each shaped like ``t``.
        """
        t_rel = np.asarray(t, dtype=float) - self.start_time
        if self.segment_times.size == 0:
            out = np.full(t_rel.shape, self.goal), np.zeros(t_rel.shape), np.zeros(t_rel.shape)
        else:
            index = np.clip(np.searchsorted(self.segment_times, t_rel, side="right") - 1, 0, None)
            tau = np.clip(t_rel - self.segment_times[index], 0.0, None)
            a = self.segment_accelerations[index]
            v = self.segment_velocities[index] + a * tau
            p = self.segment_positions[index] + self.segment_velocities[index] * tau + 0.5 * a * tau**2
            before = t_rel < 0
            done = t_rel >= self.duration
            p = np.where(before, self.segment_positions[0], np.where(done, self.goal, p))
            v = np.where(before, self.segment_velocities[0], np.where(done, 0.0, v))
            a = np.where(before | done, 0.0, a)
            out = p, v, a
        if np.ndim(t) == 0:
            return tuple(float(x) for x in out)
        return out

    def sample_scalar(self, t: float) -> tuple[float, float, float]:
        """:meth:`sample` for one float time, without NumPy overhead (the control loop)."""
        t_rel = t - self.start_time
        times = self.segment_times
        if times.size == 0 or t_rel >= self.duration:
            return self.goal, 0.0, 0.0
        if t_rel < 0:
            return float(self.segment_positions[0]), float(self.segment_velocities[0]), 0.0
        index = 0
        for k in range(1, times.size):
            if times[k] <= t_rel:
                index = k
        tau = t_rel - times[index]
        a = float(self.segment_accelerations[index])
        v0 = float(self.segment_velocities[index])
        return float(self.segment_positions[index]) + v0 * tau + 0.5 * a * tau * tau, v0 + a * tau, a

    def finished(self, t: float) -> bool:
        return t - self.start_time >= self.duration


def plan_profile(
    start_position: float,
    goal_position: float,
    *,
    start_velocity: float = 0.0,
    max_velocity: float = math.inf,
    max_acceleration: float = math.inf,
    start_time: float = 0.0,
) -> Profile:
    """Plans the firmware's profile from a (possibly moving) state to rest at the goal.

    Rest to rest, the move is a trapezoid with ramps of ``max_velocity /
    max_acceleration`` s, or a triangle when ``|d| <= max_velocity**2 /
    max_acceleration`` (the e-Manual's t1 = 64 PV / PA ms and triangle condition).
    From a moving start (a new goal during a move) it first brakes if it must
    (moving away, too fast to stop in time, or above the new velocity cap), so the
    velocity stays continuous: the firmware's blending of goals.

    Args:
        start_position, goal_position: rad.
        start_velocity: rad/s at ``start_time``.
        max_velocity: rad/s, ``math.inf`` for no cap (Profile Velocity 0).
        max_acceleration: rad/s^2, ``math.inf`` for no cap (Profile Acceleration 0).
        start_time: s.

    Raises:
        ValueError: if an argument is not finite (or a cap is not > 0).
    """
    for name, value in (("start_position", start_position), ("goal_position", goal_position),
                        ("start_velocity", start_velocity), ("start_time", start_time)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value!r}")
    for name, value in (("max_velocity", max_velocity), ("max_acceleration", max_acceleration)):
        if math.isnan(value) or value <= 0:
            raise ValueError(f"{name} must be > 0 (math.inf for no cap), got {value!r}")

    segments: list[tuple[float, float, float]] = []  # (duration, velocity at start, acceleration)
    p, v = float(start_position), float(start_velocity)
    d = goal_position - p
    a = max_acceleration
    if math.isinf(a):
        # Infinite acceleration: the velocity jumps; a step when velocity is uncapped too.
        if math.isinf(max_velocity) or d == 0:
            kind = PROFILE_STEP
        else:
            kind = PROFILE_RECTANGLE
            segments.append((abs(d) / max_velocity, math.copysign(max_velocity, d), 0.0))
        return _profile(start_time, p, segments, goal_position, kind)

    def brake_to(v_target: float) -> None:
        nonlocal p, v
        duration = abs(v - v_target) / a
        acc = math.copysign(a, v_target - v)
        segments.append((duration, v, acc))
        p += v * duration + 0.5 * acc * duration**2
        v = v_target

    # Above the (possibly lowered) velocity cap: slow to the cap first.
    if abs(v) > max_velocity:
        brake_to(math.copysign(max_velocity, v))
    d = goal_position - p
    stopping = v * v / (2 * a)
    if v != 0 and (d * v < 0 or stopping > abs(d)):
        brake_to(0.0)  # moving away, or would overshoot: stop, then plan afresh
    d = goal_position - p
    if d == 0 and v == 0:
        return _profile(start_time, float(start_position), segments, goal_position,
                        PROFILE_TRIANGLE if segments else PROFILE_STEP)
    s = math.copysign(1.0, d)
    speed = abs(v)
    peak = min(max_velocity, math.sqrt(a * abs(d) + speed * speed / 2))
    kind = PROFILE_TRAPEZOID if peak >= max_velocity else PROFILE_TRIANGLE
    t_acc = (peak - speed) / a
    d_acc = (peak * peak - speed * speed) / (2 * a)
    d_dec = peak * peak / (2 * a)
    d_cruise = max(abs(d) - d_acc - d_dec, 0.0)
    if t_acc > 0:
        segments.append((t_acc, s * speed, s * a))
    if d_cruise > 0:
        segments.append((d_cruise / peak, s * peak, 0.0))
    segments.append((peak / a, s * peak, -s * a))
    return _profile(start_time, float(start_position), segments, goal_position, kind)


def _profile(start_time, p0, segments, goal, kind) -> Profile:
    times, positions, velocities, accelerations = [], [], [], []
    t, p = 0.0, p0
    for duration, v, acc in segments:
        if duration <= 0:
            continue
        times.append(t)
        positions.append(p)
        velocities.append(v)
        accelerations.append(acc)
        p += v * duration + 0.5 * acc * duration**2
        t += duration
    return Profile(
        start_time=float(start_time),
        segment_times=np.array(times),
        segment_positions=np.array(positions),
        segment_velocities=np.array(velocities),
        segment_accelerations=np.array(accelerations),
        duration=t,
        goal=float(goal),
        kind=kind,
    )


# --- controller -----------------------------------------------------------------


class PositionController:
    """The firmware's position loop: profile -> PID + feed-forward -> duty -> torque.

    Stateful (the integral and the active profile), deterministic, and free of
    MuJoCo, so it can drive any hinge. Anti-windup: the integral is clamped so that
    its contribution alone never exceeds the duty limit, and it stops integrating
    while the output saturates in the direction of the error.
    """

    def __init__(self, config: ServoConfig):
        self.config = config
        self.enabled = False
        self.profile: Profile | None = None
        self.integral = 0.0  # rad s
        self.duty = 0.0
        self.motor_torque = 0.0

    @property
    def duty_limit(self) -> float:
        return self.config.torque_limit / self.config.stall_torque

    def set_config(self, config: ServoConfig) -> None:
        """Changes gains/profile limits; the running profile is kept."""
        self.config = config

    def enable(self, t: float, position: float) -> None:
        """Torque on: hold ``position`` (the firmware resets its trajectory there)."""
        self.enabled = True
        self.integral = 0.0
        self.profile = plan_profile(position, position, start_time=t)

    def disable(self) -> None:
        self.enabled = False
        self.integral = 0.0
        self.duty = 0.0
        self.motor_torque = 0.0

    def set_goal(self, t: float, goal: float, *, position: float | None = None) -> Profile:
        """Starts a profile to ``goal`` at time ``t``, blending from the current one.

        Args:
            t: s.
            goal: rad.
            position: measured position, rad; used when no profile is active.
        """
        if self.profile is not None:
            p, v, _ = self.profile.sample(t)
        elif position is not None:
            p, v = position, 0.0
        else:
            raise ValueError("position is required for the first goal (no active profile)")
        self.profile = plan_profile(
            p, goal, start_velocity=v, max_velocity=self.config.profile_velocity,
            max_acceleration=self.config.profile_acceleration, start_time=t,
        )
        return self.profile

    def reference(self, t: float) -> tuple[float, float, float]:
        """(position, velocity, acceleration) of the trajectory at ``t``."""
        if self.profile is None:
            return math.nan, 0.0, 0.0
        return self.profile.sample(t)

    def torque(self, t: float, position: float, velocity: float, dt: float) -> float:
        """Output torque (N m) to apply over the next ``dt`` seconds."""
        c = self.config
        if not self.enabled or self.profile is None:
            self.duty = 0.0
            self.motor_torque = 0.0
            return 0.0
        p_ref, v_ref, a_ref = self.profile.sample_scalar(t)
        error = p_ref - position
        unclamped = (
            c.position_p_gain * error
            + c.position_i_gain * self.integral
            + c.position_d_gain * (v_ref - velocity)
            + c.velocity_feedforward_gain * v_ref
            + c.acceleration_feedforward_gain * a_ref
        )
        limit = self.duty_limit
        duty = min(max(unclamped, -limit), limit)
        saturated_with_error = duty != unclamped and (unclamped > 0) == (error > 0)
        if c.position_i_gain > 0 and not saturated_with_error:
            self.integral += error * dt
            bound = limit / c.position_i_gain
            self.integral = min(max(self.integral, -bound), bound)
        self.duty = duty
        torque = c.stall_torque * duty - c.back_emf_damping * velocity
        self.motor_torque = min(max(torque, -c.torque_limit), c.torque_limit)
        return self.motor_torque

    @property
    def current(self) -> float:
        """Motor current, A, proportional to the motor torque."""
        return self.motor_torque / self.config.stall_torque * self.config.stall_current


_SHAFT_XML = """
<mujoco model="servo_shaft">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep}" integrator="implicitfast" gravity="0 0 0"/>
  <worldbody>
    <body name="output">
      <joint name="shaft" type="hinge" axis="0 0 1" armature="{armature}"
             damping="{damping}" frictionloss="{frictionloss}"/>
      <inertial pos="0 0 0" mass="{mass}" diaginertia="{inertia} {inertia} {inertia}"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="motor" joint="shaft" gear="1" forcerange="-{torque_limit} {torque_limit}"/>
  </actuator>
</mujoco>
"""


class ShaftSim:
    """One servo output shaft with a load, in MuJoCo, under :class:`PositionController`.

    Args:
        config: the servo.
        load_inertia: inertia of what the shaft carries about its axis, kg m^2.
        timestep: fixed MuJoCo step, s (the firmware's loop rate is about 1 kHz).
        initial_position: rad.
    """

    def __init__(self, config: ServoConfig, *, load_inertia: float = 0.0, timestep: float = 1e-3,
                 initial_position: float = 0.0):
        if not (math.isfinite(load_inertia) and load_inertia >= 0):
            raise ValueError(f"load_inertia must be finite and >= 0 kg m^2, got {load_inertia!r}")
        if not (math.isfinite(timestep) and 0 < timestep <= 0.01):
            raise ValueError(f"timestep must be in (0, 0.01] s, got {timestep!r}")
        xml = _SHAFT_XML.format(
            timestep=timestep, armature=config.armature, damping=config.damping,
            frictionloss=config.frictionloss, torque_limit=config.torque_limit,
            mass=1e-3, inertia=max(load_inertia, 1e-9),
        )
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.data.qpos[0] = initial_position
        self.controller = PositionController(config)
        self.timestep = timestep

    @property
    def config(self) -> ServoConfig:
        return self.controller.config

    def set_config(self, config: ServoConfig) -> None:
        """Applies new gains/profile/torque limit (mechanics are fixed at construction)."""
        self.controller.set_config(config)
        self.model.actuator_forcerange[0] = (-config.torque_limit, config.torque_limit)

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def position(self) -> float:
        return float(self.data.qpos[0])

    @property
    def velocity(self) -> float:
        return float(self.data.qvel[0])

    def enable(self) -> None:
        self.controller.enable(self.time, self.position)

    def disable(self) -> None:
        self.controller.disable()

    def set_goal(self, goal: float) -> Profile:
        return self.controller.set_goal(self.time, goal, position=self.position)

    def step(self, n: int = 1) -> None:
        """Advances ``n`` fixed timesteps.

        Raises:
            SimulationError: if the state becomes non-finite.
        """
        data, model, controller = self.data, self.model, self.controller
        for _ in range(n):
            data.ctrl[0] = controller.torque(data.time, data.qpos[0], data.qvel[0], self.timestep)
            mujoco.mj_step(model, data)
        if not (math.isfinite(data.qpos[0]) and math.isfinite(data.qvel[0])):
            raise SimulationError(
                f"servo shaft diverged at t={data.time:.3f} s; reduce timestep ({self.timestep}) or the gains"
            )

    def run_until(self, t: float) -> None:
        """Steps until the simulated time reaches ``t`` (s)."""
        n = int(math.floor((t - self.data.time) / self.timestep + 1e-9))
        if n > 0:
            self.step(n)
