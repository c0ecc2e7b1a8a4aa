"""The turntable as a physical system: the servo, its jitter, and the physics loop.

The servo itself (settings in SI and Dynamixel registers, the firmware's motion
profile) is :mod:`plantsim.turntable.servo`; this module puts it into the scan scene:

- The turntable hinge gets the servo's reflected armature, viscous damping plus
  back-EMF (``stall_torque / no_load_speed``: a PWM-driven DC motor at fixed duty
  loses that much torque per rad/s), and dry friction.
- A MuJoCo ``pid`` actuator with inputs ``[pos, vel, ff]`` closes the firmware's
  position loop: ``tau = kp (p_ref - q) + kd (v_ref - qdot) + ki x_I + ff``, the
  integral ``x_I`` clamped at ``imax`` (anti-windup) and the output at the torque
  limit. The gains are the servo's duty gains times its stall torque (duty 1 =
  stall torque), so the register conversion stays in :class:`ServoConfig`.
- Jitter, each only when its magnitude is non-zero: torque ripple periodic in
  motor angle (a passive ``dcmotor`` actuator with cogging at
  ``gear_ratio x periods_per_motor_rev`` periods per table turn); random torque
  noise (a ``motor`` actuator fed a held white sequence); gear backlash (the
  servo output becomes its own body, coupled to the table by a fixed tendon
  whose range is the play).

The encoder and the PID sit on the servo output shaft; backlash lies between it
and the table, so the encoder does not see it (as with a table driven through a
gear or coupling). Without backlash the servo output is the table hinge.

:class:`TurntableSim` steps the physics with fixed timesteps in chunks inside
MuJoCo (``mujoco.rollout`` with the profile as the control sequence), records
the true angles at every step, and stops with
:class:`~plantsim.errors.SimulationError` (cause, step time and fix named) when
the settings cannot be simulated (checked before stepping) or any step of the
run goes wrong: the shaft or the table cannot follow, the table leaves the
gear's play, the table oscillates, the ripple is not resolved.
:class:`DynamicsDiagnostics` summarises a trajectory for sidecars and studies.
See docs/turntable-dynamics.md.
"""

from __future__ import annotations

import dataclasses
import logging
import math

from plantsim._lazy import lazy_module
import numpy as np

from plantsim.turntable import units
from plantsim.errors import SimulationError
from plantsim.plant.mesh import PlantMesh
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import Scene, build_spec, compile_scene
from plantsim.turntable.servo import Profile, ServoConfig, plan_profile

mujoco = lazy_module("mujoco")  # loaded on first use: a kinematic scan never uses it

log = logging.getLogger(__name__)

INTEGRATORS = {  # name -> mujoco.mjtIntegrator member name (looked up when a scene is built)
    "euler": "mjINT_EULER",
    "implicitfast": "mjINT_IMPLICITFAST",
    "rk4": "mjINT_RK4",
}

# Largest omega_n * dt for which a stiff position loop is integrated stably and
# accurately: explicit position feedback under (semi-implicit) Euler diverges at 2;
# RK4's stability limit for an oscillator is 2.83. Half of each, for accuracy.
_MAX_OMEGA_DT = {"euler": 1.0, "implicitfast": 1.0, "rk4": 1.4}
# Largest (explicit) damping rate c / I * dt: explicit damping diverges at 2.
_MAX_DAMPING_DT = 1.0

# The scan default: an XM430-W350 with a gentle profile (Profile Velocity 50 =
# 11.4 rpm, Profile Acceleration 20 = 7.5 rad/s^2); the factory 0/0 (no profile)
# would kick the table with a step setpoint.
DEFAULT_SERVO = ServoConfig.xm430_w350(
    profile_velocity=units.velocity_units_to_rad_s(50),
    profile_acceleration=units.acceleration_units_to_rad_s2(20))

# Shortest timestep accepted, s: below it even a short scan needs ~1e8 steps.
MIN_TIMESTEP_S = 1e-6
DEFAULT_TIMESTEP_S = 1e-3
# Physics steps the cogging ripple needs per period: below 2 (Nyquist) the
# sampled ripple folds towards DC and pushes the table like a slow torque (at
# 1.13 steps a period, 5 rpm with timestep 5e-3 s, the table jitter was 88,230
# urad instead of 34); 2.5 leaves a margin.
MIN_STEPS_PER_PERIOD = 2.5
# Alternations of the velocity error beyond +-max_velocity_error_rad_s within
# oscillation_window_s that count as a sustained oscillation (3 full swings).
OSCILLATION_SWINGS = 6
# Floor of the servo output body's own inertia with backlash, as a fraction of
# the table's: with armature = 0 the output body was weightless and the backlash
# stop could not hold it (the table ended 48 degrees behind the servo).
OUTPUT_INERTIA_FLOOR_FRACTION = 0.1

# Dry friction of the turntable's own bearing, N m (only with backlash, where the
# table has its own hinge).
TABLE_BEARING_FRICTION_NM = 0.002

SERVO_PRESETS = {"xm430-w350": ServoConfig.xm430_w350, "xl430-w250": ServoConfig.xl430_w250}


def _check_number(owner: str, name: str, value, *, minimum: float = 0.0, strict: bool = False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{owner}{name} must be a finite number, got {value!r}")
    if value < minimum or (strict and value == minimum):
        raise ValueError(f"{owner}{name} must be {'>' if strict else '>='} {minimum}, got {value}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class JitterConfig:
    """The motor's imperfections; each is off at 0 (and then not in the scene).

    Attributes:
      ripple_torque_nm: amplitude of the torque ripple at the output shaft, N m.
      ripple_periods_per_motor_rev: ripple periods per motor revolution (cogging
        of a motor with that many slots); through the gear this is
        ``round(gear_ratio * periods)`` periods per table turn.
      torque_noise_nm: standard deviation of a random torque at the output, N m,
        white and held for ``torque_noise_period_s``.
      torque_noise_period_s: hold time of one torque-noise sample, s (its
        bandwidth; independent of the physics timestep).
      backlash_deg: total play of the gear between the servo output and the
        table, degrees.
    """

    ripple_torque_nm: float = 0.0
    ripple_periods_per_motor_rev: int = 6
    torque_noise_nm: float = 0.0
    torque_noise_period_s: float = 1e-3
    backlash_deg: float = 0.0

    def __post_init__(self):
        for name in ("ripple_torque_nm", "torque_noise_nm", "backlash_deg"):
            _check_number("jitter ", name, getattr(self, name))
        _check_number("jitter ", "torque_noise_period_s", self.torque_noise_period_s, strict=True)
        p = self.ripple_periods_per_motor_rev
        if isinstance(p, bool) or not isinstance(p, int) or p < 1:
            raise ValueError(f"jitter ripple_periods_per_motor_rev must be a positive integer, got {p!r}")
        if self.backlash_deg >= 90:
            raise ValueError(f"jitter backlash_deg must be < 90, got {self.backlash_deg}")

    @property
    def any(self) -> bool:
        return bool(self.ripple_torque_nm or self.torque_noise_nm or self.backlash_deg)


@dataclasses.dataclass(frozen=True, kw_only=True)
class TurntableDynamics:
    """How the turntable's physics is simulated and when a step counts as settled.

    Attributes:
      servo: the servo (SI; see :meth:`ServoConfig.with_registers` for registers).
      jitter: the motor's imperfections.
      timestep_s: fixed physics timestep, s.
      integrator: "implicitfast" (default), "euler" or "rk4".
      settle_tolerance_rad: a step has arrived when the encoder is this close to
        the goal (default 2 ticks) ...
      settle_velocity_rad_s: ... and the shaft is slower than this (default the
        Moving Threshold's factory value, 10 x 0.229 rpm) ...
      settle_timeout_s: ... within this time after the profile ends, else the
        scan stops with an error.
      max_tracking_error_rad: the scan stops if the shaft is ever further than
        this from the profile's setpoint (the servo cannot follow, or the
        simulation diverged).
      spinup_margin_s: continuous mode: time after the ramp to full speed before
        the first line, for the loop's transient to decay.
      max_play_excess_rad: the scan stops if the table is ever further than
        this beyond the gear's play from the servo shaft (the backlash stop
        gave way), radians.
      max_velocity_error_rad_s: sustained oscillation: the scan stops when the
        table's velocity swings beyond +- this around the profile's velocity
        ``OSCILLATION_SWINGS`` times within ``oscillation_window_s``.
      oscillation_window_s: see ``max_velocity_error_rad_s``, s.
      max_physics_steps: a run stops before taking more physics steps than
        this (a timestep far too small for the scan would otherwise run for
        hours and fill the memory with its record).
      controller_ticks_per_rev: the position loop acts on whole encoder ticks
        of this resolution, as the firmware does (4096 for the XM430; sub-tick
        moves then do not settle exactly); None = on the exact angle. Steps
        one ``mj_step`` at a time (the control depends on every step's angle),
        so a long run is ~1.5x slower.
    """

    servo: ServoConfig = DEFAULT_SERVO
    jitter: JitterConfig = JitterConfig()
    timestep_s: float = 1e-3
    integrator: str = "implicitfast"
    settle_tolerance_rad: float = 2 * units.RAD_PER_TICK
    settle_velocity_rad_s: float = units.velocity_units_to_rad_s(10)
    settle_timeout_s: float = 2.0
    max_tracking_error_rad: float = 0.2
    spinup_margin_s: float = 0.3
    max_play_excess_rad: float = math.radians(0.1)
    max_velocity_error_rad_s: float = 0.5
    oscillation_window_s: float = 1.0
    max_physics_steps: int = 4_000_000
    controller_ticks_per_rev: int | None = None

    def __post_init__(self):
        if not isinstance(self.servo, ServoConfig):
            raise ValueError(f"servo must be a ServoConfig, got {type(self.servo).__name__}")
        if not isinstance(self.jitter, JitterConfig):
            raise ValueError(f"jitter must be a JitterConfig, got {type(self.jitter).__name__}")
        for name in ("timestep_s", "settle_tolerance_rad", "settle_velocity_rad_s",
                     "settle_timeout_s", "max_tracking_error_rad", "max_play_excess_rad",
                     "max_velocity_error_rad_s", "oscillation_window_s"):
            _check_number("", name, getattr(self, name), strict=True)
        _check_number("", "spinup_margin_s", self.spinup_margin_s)
        if self.timestep_s > 0.05:
            raise ValueError(f"timestep_s must be at most 0.05 s, got {self.timestep_s}")
        if self.timestep_s < MIN_TIMESTEP_S:
            raise ValueError(
                f"timestep_s must be at least {MIN_TIMESTEP_S:g} s, got {self.timestep_s:g}: a 1-rpm "
                f"turn would take {60 / self.timestep_s:.3g} physics steps; the default "
                f"{DEFAULT_TIMESTEP_S:g} s resolves the servo (see docs/turntable-dynamics.md)")
        t = self.controller_ticks_per_rev
        if t is not None and (isinstance(t, bool) or not isinstance(t, int) or t < 2):
            raise ValueError(f"controller_ticks_per_rev must be an integer >= 2 or None (exact), got {t!r}")
        p = self.max_physics_steps
        if isinstance(p, bool) or not isinstance(p, int) or p < 1:
            raise ValueError(f"max_physics_steps must be a positive integer, got {p!r}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {', '.join(INTEGRATORS)}, got {self.integrator!r}")

    def replace(self, **changes) -> "TurntableDynamics":
        return dataclasses.replace(self, **changes)


def torque_gains(servo: ServoConfig) -> dict:
    """The servo's firmware gains as torque-space PID gains (duty 1 = stall torque).

    Returns:
      dict with kp (N m/rad), ki (N m/(rad s)), kd (N m s/rad), kff_vel (N m s/rad),
      kff_acc (N m s^2/rad) and imax (rad s: the integral at which ki alone
      reaches the torque limit, the firmware's anti-windup bound).
    """
    s = servo.stall_torque
    ki = s * servo.position_i_gain
    return {"kp": s * servo.position_p_gain, "ki": ki, "kd": s * servo.position_d_gain,
            "kff_vel": s * servo.velocity_feedforward_gain,
            "kff_acc": s * servo.acceleration_feedforward_gain,
            "imax": servo.torque_limit / ki if ki > 0 else 0.0}


@dataclasses.dataclass(frozen=True, eq=False)
class DynamicScene:
    """A scan scene with the servo in it.

    Attributes:
      scene: the compiled scene (``scene.model`` holds the actuators).
      dynamics: the settings it was built with.
      servo_qpos_adr, servo_dof_adr: the servo output shaft's hinge (the
        turntable hinge itself when there is no backlash).
      table_dof_adr: the turntable hinge's dof.
      servo_ctrl_adr: first of the pid actuator's three controls (pos, vel, ff).
      noise_ctrl_adr: the torque-noise motor's control, or -1.
    """

    scene: Scene
    dynamics: TurntableDynamics
    servo_qpos_adr: int
    servo_dof_adr: int
    table_dof_adr: int
    servo_ctrl_adr: int
    noise_ctrl_adr: int


def add_servo(spec: mujoco.MjSpec, dynamics: TurntableDynamics) -> None:
    """Adds the servo, and the jitter sources in use, to a scene's spec (in place)."""
    servo, jitter = dynamics.servo, dynamics.jitter
    spec.option.timestep = dynamics.timestep_s
    spec.option.integrator = getattr(mujoco.mjtIntegrator, INTEGRATORS[dynamics.integrator])
    table_joint = spec.joint("turntable")
    if jitter.backlash_deg > 0:
        # The servo output is its own body; the table floats within the play.
        rotor = spec.worldbody.add_body(name="servo_output", pos=[0, 0, 0])
        rotor.add_joint(name="servo", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1])
        # Its mass is in the armature; a token inertia keeps the body valid.
        rotor.explicitinertial = True
        rotor.mass, rotor.inertia = 1e-3, [1e-7, 1e-7, 1e-7]
        servo_joint = spec.joint("servo")
        half = math.radians(jitter.backlash_deg) / 2
        tendon = spec.add_tendon(name="backlash", limited=1, range=[-half, half])
        # A stiff stop: the fastest the integrator resolves (time constant of two
        # timesteps, critically damped) and full impedance from the first
        # micro-radian of penetration, so the play holds down to small plays
        # (the default soft limit let the table get 0.72 deg from the shaft in a 1-degree play).
        tendon.solref_limit = [2 * dynamics.timestep_s, 1.0]
        tendon.solimp_limit = [0.99, 0.999, 1e-6, 0.5, 2.0]
        tendon.wrap_joint("turntable", 1.0)
        tendon.wrap_joint("servo", -1.0)
        # The table's own bearing: a little dry friction, so it rests where the
        # gear leaves it inside the play rather than drifting without end.
        table_joint.frictionloss = TABLE_BEARING_FRICTION_NM
    else:
        servo_joint = table_joint
    servo_joint.armature = servo.armature
    # Stiction: the dry friction's constraint as stiff as the integrator allows,
    # so a torque below the friction holds the shaft (MuJoCo's default soft
    # friction let it creep through the P loop's dead band: 29 -> 19 ticks in 8 s
    # where the dead band ends at 20.7).
    for joint in {servo_joint.name: servo_joint, table_joint.name: table_joint}.values():
        joint.solref_friction = [2 * dynamics.timestep_s, 1.0]
        joint.solimp_friction = [0.99, 0.999, 1e-6, 0.5, 2.0]
    servo_joint.damping = [servo.damping + servo.back_emf_damping, 0.0, 0.0]  # linear term only
    servo_joint.frictionloss = servo.frictionloss

    g = torque_gains(servo)
    act = spec.add_actuator(name="servo", target=servo_joint.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    inputs = mujoco.mjtCtrlInput
    act.set_to_pid(kp=g["kp"], kv=g["kd"], ki=g["ki"] if g["ki"] > 0 else -1,
                   imax=g["imax"] if g["ki"] > 0 else -1,
                   ctrlspec=int(inputs.mjINPUT_POS) | int(inputs.mjINPUT_VEL) | int(inputs.mjINPUT_FF))
    act.forcelimited = 1
    act.forcerange = [-servo.torque_limit, servo.torque_limit]
    if jitter.ripple_torque_nm > 0:
        poles = int(round(servo.gear_ratio * jitter.ripple_periods_per_motor_rev))
        ripple = spec.add_actuator(name="ripple", target=servo_joint.name,
                                   trntype=mujoco.mjtTrn.mjTRN_JOINT)
        # Passive dcmotor: no inputs, no electrical branch; only the cogging term.
        ripple.set_to_dcmotor(motorconst=[0, 0], resistance=1.0,
                              cogging=[jitter.ripple_torque_nm, poles, 0.0],
                              ctrlspec=int(inputs.mjINPUT_NONE))
    if jitter.torque_noise_nm > 0:
        noise = spec.add_actuator(name="torque_noise", target=servo_joint.name,
                                  trntype=mujoco.mjtTrn.mjTRN_JOINT)
        noise.set_to_motor()


def build_dynamic_scene(rig: RigGeometry, plant: PlantMesh | None, dynamics: TurntableDynamics, *,
                        plant_areal_density_kg_m2: float = 0.3) -> DynamicScene:
    """Builds and compiles the scan scene with the servo driving the turntable."""
    spec = build_spec(rig, plant, plant_areal_density_kg_m2=plant_areal_density_kg_m2)
    add_servo(spec, dynamics)
    scene = compile_scene(spec, rig, plant)
    m = scene.model
    servo_name = "servo" if dynamics.jitter.backlash_deg > 0 else "turntable"
    servo_joint = m.joint(servo_name).id
    if dynamics.jitter.backlash_deg > 0:
        # Floor inertia on the servo side of the gear (see OUTPUT_INERTIA_FLOOR_FRACTION).
        data = mujoco.MjData(m)
        mujoco.mj_forward(m, data)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, data, M)
        table_dof = int(m.jnt_dofadr[m.joint("turntable").id])
        servo_dof = int(m.jnt_dofadr[servo_joint])
        floor = OUTPUT_INERTIA_FLOOR_FRACTION * float(M[table_dof, table_dof])
        if m.dof_armature[servo_dof] < floor:
            log.info("servo armature %.3g kg m^2 raised to the backlash floor %.3g kg m^2",
                     m.dof_armature[servo_dof], floor)
            m.dof_armature[servo_dof] = floor
            mujoco.mj_setConst(m, data)  # the constraints' inverse weights depend on it
    noise_adr = (int(m.actuator_ctrladr[m.actuator("torque_noise").id])
                 if dynamics.jitter.torque_noise_nm > 0 else -1)
    return DynamicScene(
        scene=scene, dynamics=dynamics,
        servo_qpos_adr=int(m.jnt_qposadr[servo_joint]), servo_dof_adr=int(m.jnt_dofadr[servo_joint]),
        table_dof_adr=int(m.jnt_dofadr[m.joint("turntable").id]),
        servo_ctrl_adr=int(m.actuator_ctrladr[m.actuator("servo").id]), noise_ctrl_adr=noise_adr)


def driven_inertia(dscene: DynamicScene) -> float:
    """Inertia the servo drives about the axis (armature + table + plant), kg m^2."""
    m = dscene.scene.model
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, data, M)
    dofs = {dscene.servo_dof_adr, dscene.table_dof_adr}
    return float(sum(M[i, i] for i in dofs))


def check_stability(dscene: DynamicScene) -> None:
    """Refuses settings that the chosen integrator cannot integrate stably.

    Raises:
      SimulationError: naming the stiff term, the limit, and a timestep or
        integrator that would work.
    """
    d = dscene.dynamics
    g = torque_gains(d.servo)
    inertia = driven_inertia(dscene)
    dt = d.timestep_s
    jitter = d.jitter
    if jitter.torque_noise_nm > 0 and jitter.torque_noise_period_s < dt:
        raise SimulationError(
            f"the torque noise is not resolved by the timestep: torque_noise_period_s "
            f"({jitter.torque_noise_period_s:g} s) is shorter than timestep_s ({dt:g} s), so each "
            f"step would see a fresh sample and the noise's bandwidth would be the timestep's; use "
            f"torque_noise_period_s >= {dt:g} or a smaller timestep_s")
    omega = math.sqrt(g["kp"] / inertia)
    limit = _MAX_OMEGA_DT[d.integrator]
    if omega * dt > limit:
        raise SimulationError(
            f"the position loop is too stiff for the timestep: kp = {g['kp']:.4g} N m/rad on "
            f"{inertia:.4g} kg m^2 rings at {omega:.4g} rad/s, and omega * timestep = "
            f"{omega * dt:.3g} exceeds {limit} for the {d.integrator} integrator; use "
            f"timestep_s <= {limit / omega:.3g} or lower the position P gain")
    # PI(D) loop on inertia I and damping c: I s^3 + (c + kd) s^2 + kp s + ki is
    # stable only while ki < (c + kd) kp / I (Routh-Hurwitz). "Position I Gain" =
    # 16383 broke this and swung the table by 6.3 rad/s while the position error
    # stayed under the tracking guard.
    c_total = d.servo.damping + d.servo.back_emf_damping + g["kd"]
    ki_max = c_total * g["kp"] / inertia
    if g["ki"] > 0 and g["ki"] >= ki_max:
        safe_si = 0.5 * ki_max / d.servo.stall_torque
        register = int(safe_si / units.SI_PER_KI * units.I_GAIN_DIVISOR)
        raise SimulationError(
            f"the position loop is unstable: ki = {g['ki']:.4g} N m/(rad s) is above the Routh-Hurwitz "
            f"limit (c + kd) kp / I = {ki_max:.4g} for kp = {g['kp']:.4g} N m/rad, c + kd = {c_total:.4g} "
            f"N m s/rad on {inertia:.4g} kg m^2, so the table would oscillate with growing amplitude; "
            f"use position_i_gain <= {safe_si:.4g} (\"Position I Gain\" <= {register}), or raise the D gain")
    # Explicitly integrated damping: the pid's kd under Euler, everything under RK4.
    explicit_c = {"euler": g["kd"], "implicitfast": 0.0,
                  "rk4": g["kd"] + d.servo.damping + d.servo.back_emf_damping}[d.integrator]
    if explicit_c / inertia * dt > _MAX_DAMPING_DT:
        raise SimulationError(
            f"the damping is too stiff for the {d.integrator} integrator: c = {explicit_c:.4g} "
            f"N m s/rad on {inertia:.4g} kg m^2 gives c / I * timestep = "
            f"{explicit_c / inertia * dt:.3g} > {_MAX_DAMPING_DT}; use integrator = "
            f"\"implicitfast\" (it integrates damping implicitly) or timestep_s <= "
            f"{_MAX_DAMPING_DT * inertia / explicit_c:.3g}")


@dataclasses.dataclass(frozen=True, eq=False)
class Trajectory:
    """What the physics did, one row per physics step (after the step).

    Attributes:
      time_s: (n,) float64 s, strictly increasing, starting at 0 (the state
        before the first step).
      table_rad: (n,) float64, the turntable's true angle.
      shaft_rad: (n,) float64, the servo output shaft's angle (what the encoder
        measures; equal to ``table_rad`` without backlash).
      shaft_velocity_rad_s: (n,) float64.
      setpoint_rad: (n,) float64, the profile's position setpoint.
      table_velocity_rad_s: (n,) float64, the turntable's true velocity (None
        for trajectories made elsewhere).
      setpoint_velocity_rad_s: (n,) float64, the profile's velocity (or None).
    """

    time_s: np.ndarray
    table_rad: np.ndarray
    shaft_rad: np.ndarray
    shaft_velocity_rad_s: np.ndarray
    setpoint_rad: np.ndarray
    table_velocity_rad_s: np.ndarray | None = None
    setpoint_velocity_rad_s: np.ndarray | None = None

    def table_at(self, t_s: np.ndarray) -> np.ndarray:
        """True table angle at any times (linear between physics steps), radians."""
        return np.interp(t_s, self.time_s, self.table_rad)


# Chunks shorter than this step one mj_step at a time (rollout's call costs ~1 ms).
_ROLLOUT_MIN_STEPS = 100

_REC_T, _REC_TABLE, _REC_SHAFT, _REC_SHAFT_V, _REC_SET, _REC_TABLE_V, _REC_SET_V = range(7)


class TurntableSim:
    """Steps the dynamic scene under the servo's motion profile and records it.

    The physics runs in chunks of ``chunk_steps`` steps inside MuJoCo
    (:func:`mujoco.rollout.rollout` with the chunk's control sequence: the
    profile's setpoint, velocity and feed-forward, and the held torque noise,
    one row per step), so a 1-rpm turn is ~60 calls instead of 60,000. After
    each chunk every step is checked (:meth:`_check`); a stop names the step's
    time, the cause and a fix.

    Args:
      dscene: from :func:`build_dynamic_scene`.
      rng: the run's random generator (torque noise).
      chunk_steps: physics steps per MuJoCo call (and between checks).

    Raises:
      SimulationError: from :func:`check_stability`, before any step.
    """

    def __init__(self, dscene: DynamicScene, rng: np.random.Generator, *, chunk_steps: int = 1000):
        check_stability(dscene)
        if isinstance(chunk_steps, bool) or not isinstance(chunk_steps, int) or chunk_steps < 1:
            raise ValueError(f"chunk_steps must be a positive integer, got {chunk_steps!r}")
        self.dscene = dscene
        self.model = dscene.scene.model
        self.data = mujoco.MjData(self.model)
        self.rng = rng
        self.chunk_steps = chunk_steps
        self.dt = dscene.dynamics.timestep_s
        self.steps = 0
        self.profile: Profile = plan_profile(0.0, 0.0)
        self._gains = torque_gains(dscene.dynamics.servo)
        self._records: list[np.ndarray] = [np.zeros((1, 7))]
        self._noise_values = np.zeros(0)
        m = self.model
        self._table_qa = int(m.jnt_qposadr[m.joint("turntable").id])
        self._spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self._qpos0 = mujoco.mj_stateSize(m, int(mujoco.mjtState.mjSTATE_TIME))
        self._qvel0 = mujoco.mj_stateSize(m, int(mujoco.mjtState.mjSTATE_TIME | mujoco.mjtState.mjSTATE_QPOS))
        self._state = np.empty(mujoco.mj_stateSize(m, self._spec))
        self._swing_times: list[float] = []
        self._last_sign = 0
        dyn = dscene.dynamics
        self._half_play = math.radians(dyn.jitter.backlash_deg) / 2
        c_total = dyn.servo.damping + dyn.servo.back_emf_damping + self._gains["kd"]
        ki_max = c_total * self._gains["kp"] / driven_inertia(dscene)
        self._i_register_safe = int(0.5 * ki_max / dyn.servo.stall_torque / units.SI_PER_KI * units.I_GAIN_DIVISOR)
        self._ripple_periods = (int(round(dyn.servo.gear_ratio * dyn.jitter.ripple_periods_per_motor_rev))
                                if dyn.jitter.ripple_torque_nm > 0 else 0)

    @property
    def time_s(self) -> float:
        return self.steps * self.dt

    @property
    def shaft_rad(self) -> float:
        return float(self.data.qpos[self.dscene.servo_qpos_adr])

    @property
    def shaft_velocity_rad_s(self) -> float:
        return float(self.data.qvel[self.dscene.servo_dof_adr])

    @property
    def table_rad(self) -> float:
        return float(self.data.qpos[self._table_qa])

    def _top_speed(self) -> float:
        dyn = self.dscene.dynamics
        return dyn.servo.top_speed_rad_s(
            extra_friction=TABLE_BEARING_FRICTION_NM if dyn.jitter.backlash_deg > 0 else 0.0)

    def reachable_speed_rad_s(self, *, lag: bool = True) -> float:
        """Fastest profile speed this sim accepts, rad/s.

        The lesser of 90 % of the servo's top speed and, for a loop without I
        gain, the speed at which the P loop's steady lag (the torque to overcome
        the losses, less the velocity feed-forward, over kp) reaches 80 % of
        ``max_tracking_error_rad`` (only with ``lag``: a profile that cruises).
        """
        dyn = self.dscene.dynamics
        servo, g = dyn.servo, self._gains
        top = self._top_speed()
        safe = 0.9 * top
        slope = servo.back_emf_damping + servo.damping - g["kff_vel"]
        if lag and g["ki"] == 0 and g["kp"] > 0 and slope > 0:
            friction = servo.frictionloss + (TABLE_BEARING_FRICTION_NM if dyn.jitter.backlash_deg > 0 else 0.0)
            safe = min(safe, max(0.8 * dyn.max_tracking_error_rad * g["kp"] - friction, 0.0) / slope)
        return safe

    def _resolution_fix(self, speed_rad_s: float, minimum: float = MIN_STEPS_PER_PERIOD) -> str | None:
        """Why the cogging ripple is not resolved at this speed, or None.

        ``minimum`` steps a period are asked of the planned speed; the speed
        actually reached (which overshoots the plan a little) is held to 2.
        """
        if not self._ripple_periods or speed_rad_s <= 0:
            return None
        period = 2 * math.pi / (self._ripple_periods * speed_rad_s)
        if period >= minimum * self.dt:
            return None
        return (f"the cogging ripple is not resolved by the timestep: {self._ripple_periods} periods a "
                f"turn at {speed_rad_s:.3g} rad/s last {period:.3g} s, {period / self.dt:.3g} timesteps "
                f"(at least {minimum:g} needed); use timestep_s <= "
                f"{period / MIN_STEPS_PER_PERIOD:.3g}")

    def command(self, goal_rad: float, *, profile_velocity_rad_s: float | None = None) -> Profile:
        """Sets a new goal now; the profile blends from the current setpoint.

        Raises:
          SimulationError: the profile's speed is above what the servo can reach
            (its top speed at full duty against its own losses), or the cogging
            ripple at that speed is not resolved by the timestep.
        """
        dyn = self.dscene.dynamics
        servo = dyn.servo
        cap = servo.profile_velocity if profile_velocity_rad_s is None else profile_velocity_rad_s
        p, v, _ = self.profile.sample(self.time_s)
        profile = plan_profile(
            p, goal_rad, start_velocity=v, start_time=self.time_s,
            max_velocity=cap, max_acceleration=servo.profile_acceleration)
        peak = float(np.max(np.abs(profile.segment_velocities))) if profile.segment_velocities.size else 0.0
        if profile.segment_velocities.size:
            peak = max(peak, float(np.max(np.abs(profile.segment_velocities + profile.segment_accelerations
                                                  * np.diff(np.append(profile.segment_times,
                                                                      profile.duration))))))
        if math.isfinite(cap) and peak > 0:
            # The loop's steady lag matters only where the profile cruises long
            # enough to reach it (3 of the P loop's slow time constants, c / kp).
            cruise = np.diff(np.append(profile.segment_times, profile.duration))[
                profile.segment_accelerations == 0]
            g = self._gains
            settle = 3 * (servo.back_emf_damping + servo.damping) / g["kp"] if g["kp"] > 0 else math.inf
            safe = self.reachable_speed_rad_s(lag=bool(cruise.size) and float(cruise.max()) > settle)
            rpm = 60 / (2 * math.pi)
            if peak > safe:
                top = self._top_speed()
                limit_rpm = math.floor(safe * rpm * 10) / 10
                if safe < 0.9 * top:
                    fix = ("raise the position P gain or the velocity feed-forward"
                           + (f", or choose rpm <= {limit_rpm:g}" if limit_rpm > 0 else ""))
                    cause = (f"the position loop's steady lag at that speed would exceed 80 % of "
                             f"max_tracking_error_rad ({dyn.max_tracking_error_rad:g} rad)")
                else:
                    fix = f"choose rpm <= {limit_rpm:g}, or use a faster servo"
                    cause = "the position loop needs a 10 % margin of duty"
                raise SimulationError(
                    f"the servo cannot follow {peak:.4g} rad/s ({peak * rpm:.4g} rpm): its top speed at full "
                    f"duty against its own losses (back-EMF line plus viscous damping) is {top:.4g} rad/s "
                    f"({top * rpm:.4g} rpm; the rated no-load speed is {servo.no_load_speed * rpm:.3g} rpm) "
                    f"and {cause}; {fix}")
            why = self._resolution_fix(peak)
            if why:
                raise SimulationError(why)
        self.profile = profile
        return profile

    def _noise(self, t: np.ndarray) -> np.ndarray:
        period = self.dscene.dynamics.jitter.torque_noise_period_s
        k = np.floor(t / period + 1e-9).astype(np.int64)
        need = int(k.max()) + 1
        if need > len(self._noise_values):
            more = self.rng.normal(0.0, self.dscene.dynamics.jitter.torque_noise_nm,
                                   max(need - len(self._noise_values), 1024))
            self._noise_values = np.concatenate([self._noise_values, more])
        return self._noise_values[k]

    def advance(self, n_steps: int) -> None:
        """Runs ``n_steps`` physics steps in chunks, checking every step of each chunk.

        Raises:
          SimulationError: the run would exceed ``max_physics_steps`` (before any
            step), or a check failed (see :meth:`_check`); the message names the
            time of the first bad step, the cause and a fix.
        """
        from mujoco import rollout

        dyn = self.dscene.dynamics
        if self.steps + n_steps > dyn.max_physics_steps:
            raise SimulationError(
                f"the turntable simulation would take {self.steps + n_steps:,} physics steps "
                f"({(self.steps + n_steps) * self.dt:.4g} s of rig time at timestep_s = {self.dt:g}), more "
                f"than max_physics_steps ({dyn.max_physics_steps:,}; about "
                f"{dyn.max_physics_steps * 5e-6 / 60:.0f} min and {dyn.max_physics_steps * 56 / 1e9:.2g} GB); "
                f"use a larger timestep_s (the default {DEFAULT_TIMESTEP_S:g} s resolves the servo), a "
                f"shorter scan, or raise max_physics_steps")
        m, d, ds = self.model, self.data, self.dscene
        g = self._gains
        qa, va = ds.servo_qpos_adr, ds.servo_dof_adr
        tq = self._table_qa
        tv = ds.table_dof_adr
        ca, na = ds.servo_ctrl_adr, ds.noise_ctrl_adr
        q0, v0 = self._qpos0, self._qvel0
        tick = 2 * math.pi / dyn.controller_ticks_per_rev if dyn.controller_ticks_per_rev else 0.0
        done = 0
        while done < n_steps:
            n = min(self.chunk_steps, n_steps - done)
            t = (self.steps + np.arange(n)) * self.dt
            p_ref, v_ref, a_ref = self.profile.sample(t)
            ctrl = np.zeros((n, m.nu))
            ctrl[:, ca] = p_ref
            ctrl[:, ca + 1] = v_ref
            ctrl[:, ca + 2] = g["kff_vel"] * v_ref + g["kff_acc"] * a_ref
            if na >= 0:
                ctrl[:, na] = self._noise(t)
            rec = np.empty((n, 7))
            if tick:
                # The pid sees kp (ctrl_pos - q): feeding p_ref + (q - q_tick) makes it
                # act on the whole-tick angle q_tick (the integral likewise).
                for i in range(n):
                    d.ctrl[:] = ctrl[i]
                    q = d.qpos[qa]
                    d.ctrl[ca] += q - math.floor(q / tick + 0.5) * tick
                    mujoco.mj_step(m, d)
                    rec[i, _REC_TABLE] = d.qpos[tq]
                    rec[i, _REC_SHAFT] = d.qpos[qa]
                    rec[i, _REC_SHAFT_V] = d.qvel[va]
                    rec[i, _REC_TABLE_V] = d.qvel[tv]
            elif n < _ROLLOUT_MIN_STEPS:
                # A few steps (a step scan's settling checks): the rollout call's
                # fixed cost (~1 ms) would dominate; the same steps one by one.
                for i in range(n):
                    d.ctrl[:] = ctrl[i]
                    mujoco.mj_step(m, d)
                    rec[i, _REC_TABLE] = d.qpos[tq]
                    rec[i, _REC_SHAFT] = d.qpos[qa]
                    rec[i, _REC_SHAFT_V] = d.qvel[va]
                    rec[i, _REC_TABLE_V] = d.qvel[tv]
            else:
                mujoco.mj_getState(m, d, self._state, self._spec)
                # The solver's warm start carries over, so chunking changes nothing.
                states, _ = rollout.rollout(m, d, self._state[None], ctrl[None],
                                            control_spec=int(mujoco.mjtState.mjSTATE_CTRL),
                                            initial_warmstart=d.qacc_warmstart.copy()[None])
                states = states[0]
                mujoco.mj_setState(m, d, states[-1], self._spec)
                d.ctrl[:] = ctrl[-1]
                rec[:, _REC_TABLE] = states[:, q0 + tq]
                rec[:, _REC_SHAFT] = states[:, q0 + qa]
                rec[:, _REC_SHAFT_V] = states[:, v0 + va]
                rec[:, _REC_TABLE_V] = states[:, v0 + tv]
            self.steps += n
            rec[:, _REC_T] = (self.steps - n + 1 + np.arange(n)) * self.dt
            p_after, v_after, _ = self.profile.sample(rec[:, _REC_T])
            rec[:, _REC_SET] = p_after
            rec[:, _REC_SET_V] = v_after
            self._records.append(rec)
            done += n
            self._check(rec)

    def _stop(self, rec: np.ndarray, i: int, what: str) -> SimulationError:
        return SimulationError(f"{what} at t = {rec[i, _REC_T]:.6g} s (physics step "
                               f"{self.steps - len(rec) + 1 + i:,})")

    def _check(self, rec: np.ndarray) -> None:
        """Checks every step of a chunk; raises at the first bad one.

        Checks: a finite state; shaft and table within ``max_tracking_error_rad``
        of the setpoint (the table also within the play); the table within
        ``max_play_excess_rad`` beyond the play from the shaft; no sustained
        oscillation of the table's velocity about the profile's; the cogging
        ripple resolved at the speed actually reached.
        """
        dyn = self.dscene.dynamics
        fix_dt = (f"use a smaller timestep_s (now {dyn.timestep_s:g} s)"
                  + ("" if dyn.integrator == "implicitfast" else " or integrator = \"implicitfast\""))
        finite = np.all(np.isfinite(rec), axis=1)
        if not finite.all():
            i = int(np.argmin(finite))
            raise SimulationError(
                f"the turntable simulation diverged (non-finite state) at t = {rec[i, _REC_T]:.6g} s "
                f"(physics step {self.steps - len(rec) + 1 + i:,}); {fix_dt}")
        bad = []  # (index, message)
        error = np.abs(rec[:, _REC_SHAFT] - rec[:, _REC_SET])
        over = np.flatnonzero(error > dyn.max_tracking_error_rad)
        if over.size:
            i = int(over[0])
            bad.append((i, f"the servo could not follow its profile: the shaft's tracking error "
                           f"{error[i]:.4g} rad exceeds max_tracking_error_rad ({dyn.max_tracking_error_rad:g}) "
                           f"at t = {rec[i, _REC_T]:.6g} s; the gains may be too low for the friction and load, "
                           f"the torque limit too low for the profile acceleration, or the simulation unstable: "
                           f"raise the position P gain, lower the profile's velocity/acceleration, or {fix_dt}"))
        gap = np.abs(rec[:, _REC_TABLE] - rec[:, _REC_SHAFT]) - self._half_play
        over = np.flatnonzero(gap > dyn.max_play_excess_rad)
        if over.size:
            i = int(over[0])
            bad.append((i, f"the table left the gear's play: it is {math.degrees(gap[i] + self._half_play):.4g} "
                           f"deg from the servo shaft, {math.degrees(gap[i]):.3g} deg beyond the half play "
                           f"({math.degrees(self._half_play):.3g} deg; max_play_excess_rad = "
                           f"{dyn.max_play_excess_rad:.3g}) at t = {rec[i, _REC_T]:.6g} s: the backlash stop "
                           f"gave way; raise the servo armature, or {fix_dt}"))
        table_error = np.abs(rec[:, _REC_TABLE] - rec[:, _REC_SET]) - self._half_play
        over = np.flatnonzero(table_error > dyn.max_tracking_error_rad)
        if over.size:
            i = int(over[0])
            bad.append((i, f"the table could not follow the profile: {table_error[i] + self._half_play:.4g} rad "
                           f"from the setpoint (max_tracking_error_rad {dyn.max_tracking_error_rad:g} plus the "
                           f"half play) at t = {rec[i, _REC_T]:.6g} s; raise the position P gain, lower the "
                           f"profile's velocity/acceleration, or {fix_dt}"))
        i = self._oscillation(rec)
        if i is not None:
            bad.append((i, f"the turntable oscillates: its velocity swung beyond +-{dyn.max_velocity_error_rad_s:g} "
                           f"rad/s about the profile's {OSCILLATION_SWINGS} times within "
                           f"oscillation_window_s ({dyn.oscillation_window_s:g} s), by t = {rec[i, _REC_T]:.6g} s: "
                           f"the position loop is unstable; use \"Position I Gain\" <= {self._i_register_safe} "
                           f"(half the Routh-Hurwitz limit for this load), add D gain, or {fix_dt}"))
        speed = float(np.max(np.abs(rec[:, _REC_SHAFT_V])))
        why = self._resolution_fix(speed, 2.0)
        if why:
            i = int(np.argmax(np.abs(rec[:, _REC_SHAFT_V])))
            bad.append((i, f"{why} (the shaft reached this speed at t = {rec[i, _REC_T]:.6g} s)"))
        # MuJoCo's own warnings (e.g. a huge velocity it reset) are known per chunk only:
        # a step-level cause above, when there is one, is reported first.
        warned = [mujoco.mjtWarning(i).name for i, w in enumerate(self.data.warning) if w.number]
        if bad:
            i, message = min(bad, key=lambda b: b[0])
            raise SimulationError(f"{message} [physics step {self.steps - len(rec) + 1 + i:,}]"
                                  + (f" (MuJoCo also warned: {', '.join(warned)})" if warned else ""))
        if warned:
            raise SimulationError(
                f"MuJoCo warned during the turntable simulation in the chunk ending at t = "
                f"{rec[-1, _REC_T]:.6g} s ({', '.join(warned)}); {fix_dt}")

    def _oscillation(self, rec: np.ndarray) -> int | None:
        """Index of the step that completes a sustained oscillation, or None."""
        dyn = self.dscene.dynamics
        e = rec[:, _REC_TABLE_V] - rec[:, _REC_SET_V]
        thr = dyn.max_velocity_error_rad_s
        sign = np.where(e > thr, 1, np.where(e < -thr, -1, 0))
        idx = np.flatnonzero(sign)
        if not idx.size:
            return None
        s = sign[idx]
        prev = np.concatenate([[self._last_sign], s[:-1]])
        flips = idx[(s != prev) & (prev != 0)]
        self._last_sign = int(s[-1])
        for i in flips:
            t = float(rec[i, _REC_T])
            self._swing_times.append(t)
            recent = [x for x in self._swing_times if x > t - dyn.oscillation_window_s]
            self._swing_times = recent
            if len(recent) >= OSCILLATION_SWINGS:
                return int(i)
        return None

    def trajectory(self) -> Trajectory:
        rec = np.concatenate(self._records)
        return Trajectory(time_s=rec[:, _REC_T].copy(), table_rad=rec[:, _REC_TABLE].copy(),
                          shaft_rad=rec[:, _REC_SHAFT].copy(), shaft_velocity_rad_s=rec[:, _REC_SHAFT_V].copy(),
                          setpoint_rad=rec[:, _REC_SET].copy(), table_velocity_rad_s=rec[:, _REC_TABLE_V].copy(),
                          setpoint_velocity_rad_s=rec[:, _REC_SET_V].copy())


@dataclasses.dataclass(frozen=True, kw_only=True)
class DynamicsDiagnostics:
    """What the servo and the table did in a dynamic scan, for sidecars and study rows.

    Attributes:
      physics_steps: steps taken.
      simulated_time_s: rig time simulated, s.
      max_tracking_error_rad: largest |shaft - setpoint|.
      max_table_tracking_error_rad: largest |table - setpoint| (includes the play).
      max_table_minus_shaft_rad: largest |table - shaft| (0 without backlash).
      max_table_velocity_error_rad_s: largest |table velocity - profile velocity|
        (NaN when the trajectory has no table velocity).
      cruise_table_speed_p2p_rad_s: peak-to-peak table speed while the profile
        cruises, including the transient after the ramp (continuous scans; NaN
        when it never cruises).
      n_moves: rests of the profile (step moves that ended).
      n_unsettled: rests in which the shaft never came within the tolerance to
        stay.
      settle_time_max_s, settle_time_median_s: time from the end of each move's
        profile until the shaft (what the servo's Moving flag judges; the table
        may lie anywhere in the play) is within ``settle_tolerance_rad`` of the
        goal for the rest of the rest (NaN when there are no settled moves).
      max_believed_minus_true_rad: largest |believed - true| per-beam angle, when
        given (else NaN).
    """

    physics_steps: int
    simulated_time_s: float
    max_tracking_error_rad: float
    max_table_tracking_error_rad: float
    max_table_minus_shaft_rad: float
    max_table_velocity_error_rad_s: float
    cruise_table_speed_p2p_rad_s: float
    n_moves: int
    n_unsettled: int
    settle_time_max_s: float
    settle_time_median_s: float
    max_believed_minus_true_rad: float = math.nan

    @classmethod
    def from_trajectory(cls, trajectory: Trajectory, *, settle_tolerance_rad: float = 2 * units.RAD_PER_TICK,
                        true_rad: np.ndarray | None = None,
                        believed_rad: np.ndarray | None = None) -> "DynamicsDiagnostics":
        """Computes the diagnostics of a recorded trajectory (pure; no MuJoCo).

        Args:
          trajectory: from :meth:`TurntableSim.trajectory`.
          settle_tolerance_rad: how close to the goal counts as settled, radians.
          true_rad, believed_rad: optional same-shaped per-beam angles (true, and
            as reconstructed), radians.
        """
        tr = trajectory
        t = np.asarray(tr.time_s)
        table, shaft, setp = np.asarray(tr.table_rad), np.asarray(tr.shaft_rad), np.asarray(tr.setpoint_rad)
        if tr.table_velocity_rad_s is not None and tr.setpoint_velocity_rad_s is not None:
            vel_err = np.abs(np.asarray(tr.table_velocity_rad_s) - np.asarray(tr.setpoint_velocity_rad_s))
            max_vel_err = float(vel_err.max())
            sv = np.asarray(tr.setpoint_velocity_rad_s)
            cruise = (sv != 0) & (np.abs(np.diff(sv, prepend=sv[0])) < 1e-12)
            p2p = (float(np.ptp(np.asarray(tr.table_velocity_rad_s)[cruise])) if cruise.sum() > 1 else math.nan)
        else:
            max_vel_err, p2p = math.nan, math.nan
        # Rests: runs of a constant setpoint (profile finished).
        rest = np.concatenate([[False], np.diff(setp) == 0])
        settle, unsettled = [], 0
        if rest.any():
            edges = np.diff(rest.astype(np.int8), prepend=0, append=0)
            starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
            for a, b in zip(starts, ends):
                a0 = a - 1  # the step where the profile reached its goal
                if b - a0 < 2 or a0 <= 0:
                    continue
                outside = np.abs(shaft[a0:b] - setp[a0:b]) > settle_tolerance_rad
                if outside[-1]:
                    unsettled += 1
                    continue
                last_out = np.flatnonzero(outside)
                k = a0 + (int(last_out[-1]) + 1 if last_out.size else 0)
                settle.append(float(t[k] - t[a0]))
        if true_rad is not None and believed_rad is not None:
            from plantsim.evaluation.angle_error import max_believed_minus_true_rad
            believed = max_believed_minus_true_rad(true_rad, believed_rad)
        else:
            believed = math.nan
        return cls(physics_steps=int(len(t) - 1), simulated_time_s=float(t[-1]),
                   max_tracking_error_rad=float(np.max(np.abs(shaft - setp))),
                   max_table_tracking_error_rad=float(np.max(np.abs(table - setp))),
                   max_table_minus_shaft_rad=float(np.max(np.abs(table - shaft))),
                   max_table_velocity_error_rad_s=max_vel_err, cruise_table_speed_p2p_rad_s=p2p,
                   n_moves=len(settle) + unsettled, n_unsettled=unsettled,
                   settle_time_max_s=max(settle) if settle else math.nan,
                   settle_time_median_s=float(np.median(settle)) if settle else math.nan,
                   max_believed_minus_true_rad=believed)

    def to_dict(self) -> dict:
        """JSON-able dict (NaN becomes None)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in dataclasses.asdict(self).items()}
