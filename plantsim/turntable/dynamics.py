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

:class:`TurntableSim` steps the physics with fixed timesteps, feeds the profile
as the setpoint, records the true angles at every step, and stops with
:class:`~plantsim.errors.SimulationError` (cause and fix named) when the
simulation is unstable or the servo cannot follow.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import mujoco
import numpy as np

from plantsim.turntable import units
from plantsim.errors import SimulationError
from plantsim.plant.mesh import PlantMesh
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import Scene, build_spec, compile_scene
from plantsim.turntable.servo import Profile, ServoConfig, plan_profile

log = logging.getLogger(__name__)

INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
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

    def __post_init__(self):
        if not isinstance(self.servo, ServoConfig):
            raise ValueError(f"servo must be a ServoConfig, got {type(self.servo).__name__}")
        if not isinstance(self.jitter, JitterConfig):
            raise ValueError(f"jitter must be a JitterConfig, got {type(self.jitter).__name__}")
        for name in ("timestep_s", "settle_tolerance_rad", "settle_velocity_rad_s",
                     "settle_timeout_s", "max_tracking_error_rad"):
            _check_number("", name, getattr(self, name), strict=True)
        _check_number("", "spinup_margin_s", self.spinup_margin_s)
        if self.timestep_s > 0.05:
            raise ValueError(f"timestep_s must be at most 0.05 s, got {self.timestep_s}")
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
    spec.option.integrator = INTEGRATORS[dynamics.integrator]
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
        tendon.wrap_joint("turntable", 1.0)
        tendon.wrap_joint("servo", -1.0)
        # The table's own bearing: a little dry friction, so it rests where the
        # gear leaves it inside the play rather than drifting without end.
        table_joint.frictionloss = TABLE_BEARING_FRICTION_NM
    else:
        servo_joint = table_joint
    servo_joint.armature = servo.armature
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
    omega = math.sqrt(g["kp"] / inertia)
    limit = _MAX_OMEGA_DT[d.integrator]
    if omega * dt > limit:
        raise SimulationError(
            f"the position loop is too stiff for the timestep: kp = {g['kp']:.4g} N m/rad on "
            f"{inertia:.4g} kg m^2 rings at {omega:.4g} rad/s, and omega * timestep = "
            f"{omega * dt:.3g} exceeds {limit} for the {d.integrator} integrator; use "
            f"timestep_s <= {limit / omega:.3g} or lower the position P gain")
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
    """

    time_s: np.ndarray
    table_rad: np.ndarray
    shaft_rad: np.ndarray
    shaft_velocity_rad_s: np.ndarray
    setpoint_rad: np.ndarray

    def table_at(self, t_s: np.ndarray) -> np.ndarray:
        """True table angle at any times (linear between physics steps), radians."""
        return np.interp(t_s, self.time_s, self.table_rad)


class TurntableSim:
    """Steps the dynamic scene under the servo's motion profile and records it.

    Args:
      dscene: from :func:`build_dynamic_scene`.
      rng: the run's random generator (torque noise).
      chunk_steps: physics steps between stability checks.

    Raises:
      SimulationError: from :func:`check_stability`, before any step.
    """

    def __init__(self, dscene: DynamicScene, rng: np.random.Generator, *, chunk_steps: int = 200):
        check_stability(dscene)
        self.dscene = dscene
        self.model = dscene.scene.model
        self.data = mujoco.MjData(self.model)
        self.rng = rng
        self.chunk_steps = chunk_steps
        self.dt = dscene.dynamics.timestep_s
        self.steps = 0
        self.profile: Profile = plan_profile(0.0, 0.0)
        self._gains = torque_gains(dscene.dynamics.servo)
        self._records: list[np.ndarray] = [np.zeros((1, 5))]
        self._noise_t_end = 0.0
        self._noise_values = np.zeros(0)

    @property
    def time_s(self) -> float:
        return self.steps * self.dt

    @property
    def shaft_rad(self) -> float:
        return float(self.data.qpos[self.dscene.servo_qpos_adr])

    @property
    def shaft_velocity_rad_s(self) -> float:
        return float(self.data.qvel[self.dscene.servo_dof_adr])

    def command(self, goal_rad: float, *, profile_velocity_rad_s: float | None = None) -> Profile:
        """Sets a new goal now; the profile blends from the current setpoint."""
        servo = self.dscene.dynamics.servo
        p, v, _ = self.profile.sample(self.time_s)
        self.profile = plan_profile(
            p, goal_rad, start_velocity=v, start_time=self.time_s,
            max_velocity=servo.profile_velocity if profile_velocity_rad_s is None else profile_velocity_rad_s,
            max_acceleration=servo.profile_acceleration)
        return self.profile

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
        """Runs ``n_steps`` physics steps, checking stability every chunk.

        Raises:
          SimulationError: on a non-finite state, a MuJoCo warning, or a tracking
            error beyond ``max_tracking_error_rad``; the message names the fix.
        """
        m, d, ds = self.model, self.data, self.dscene
        g = self._gains
        qa, va = ds.servo_qpos_adr, ds.servo_dof_adr
        table_qa = int(m.jnt_qposadr[m.joint("turntable").id])
        ca, na = ds.servo_ctrl_adr, ds.noise_ctrl_adr
        done = 0
        while done < n_steps:
            n = min(self.chunk_steps, n_steps - done)
            t = (self.steps + np.arange(n)) * self.dt
            p_ref, v_ref, a_ref = self.profile.sample(t)
            ff = g["kff_vel"] * v_ref + g["kff_acc"] * a_ref
            ctrl = np.stack([p_ref, v_ref, ff], axis=1)
            noise = self._noise(t) if na >= 0 else None
            rec = np.empty((n, 5))
            for i in range(n):
                d.ctrl[ca:ca + 3] = ctrl[i]
                if noise is not None:
                    d.ctrl[na] = noise[i]
                mujoco.mj_step(m, d)
                rec[i, 1] = d.qpos[table_qa]
                rec[i, 2] = d.qpos[qa]
                rec[i, 3] = d.qvel[va]
            self.steps += n
            rec[:, 0] = (self.steps - n + 1 + np.arange(n)) * self.dt
            rec[:, 4] = self.profile.sample(rec[:, 0])[0]
            self._records.append(rec)
            done += n
            self._check(rec)

    def _check(self, rec: np.ndarray) -> None:
        d, dyn = self.data, self.dscene.dynamics
        fix = (f"use a smaller timestep_s (now {dyn.timestep_s:g} s)"
               + ("" if dyn.integrator == "implicitfast" else " or integrator = \"implicitfast\""))
        if not np.all(np.isfinite(rec)):
            raise SimulationError(f"the turntable simulation diverged (non-finite state) near "
                                  f"t = {rec[0, 0]:.4g} s; {fix}")
        warned = [mujoco.mjtWarning(i).name for i, w in enumerate(d.warning) if w.number]
        if warned:
            raise SimulationError(f"MuJoCo warned during the turntable simulation near "
                                  f"t = {rec[-1, 0]:.4g} s ({', '.join(warned)}); {fix}")
        error = np.abs(rec[:, 2] - rec[:, 4])
        worst = int(np.argmax(error))
        if error[worst] > dyn.max_tracking_error_rad:
            raise SimulationError(
                f"the servo could not follow its profile: tracking error {error[worst]:.4g} rad "
                f"at t = {rec[worst, 0]:.4g} s exceeds max_tracking_error_rad "
                f"({dyn.max_tracking_error_rad:g}); the gains may be too low for the friction and "
                f"load, the torque limit too low for the profile acceleration, or the simulation "
                f"unstable: raise the position P gain, lower the profile's velocity/acceleration, "
                f"or {fix}")

    def trajectory(self) -> Trajectory:
        rec = np.concatenate(self._records)
        return Trajectory(time_s=rec[:, 0].copy(), table_rad=rec[:, 1].copy(), shaft_rad=rec[:, 2].copy(),
                          shaft_velocity_rad_s=rec[:, 3].copy(), setpoint_rad=rec[:, 4].copy())
