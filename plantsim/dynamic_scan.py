"""Scans with a physical turntable: dynamic step-and-shoot and continuous rotation.

Both run the servo's physics first (:class:`plantsim.dynamics.TurntableSim`,
recording the true angle at every physics step), then cast every beam at the
true turntable angle of its own instant, and give the reconstruction what a real
rig knows: encoder readings interpolated to each beam's time (de-skew), or, with
``deskew`` off, one angle per line as a naive rig would use.

Casting each beam at its own pose is exact and cheap because only the disk and
the plant turn: each ray is rotated into the turntable frame by
``Rz(-theta_true(t_beam))`` and cast against geom groups {1, 2} with the hinge at
0, and the world ray is cast once against the fixed rig (group 0); the nearer
hit wins.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os

import mujoco
import mujoco.batch
import numpy as np

from plantsim import encoder as encoder_mod
from plantsim.dynamics import DynamicScene, JitterConfig, Trajectory, TurntableDynamics, TurntableSim
from plantsim.encoder import EncoderConfig, EncoderReadings
from plantsim.scan import Progress, RawScan, StepScan, gate_ranges, ray_origins_dirs_base
from plantsim.scene import Scene
from plantsim.sensor import LidarSpec
from plantsim.transforms import rot_z_batch

log = logging.getLogger(__name__)

MODES = ("step", "continuous")
PHYSICS = ("auto", "kinematic", "dynamic")


def _groups(*groups: int) -> np.ndarray:
    return np.array([1 if g in groups else 0 for g in range(mujoco.mjNGROUP)], dtype=np.uint8)


TURNING_GEOMGROUP = _groups(1, 2)  # disk and plant: they turn with the table
FIXED_GEOMGROUP = _groups(0)  # bench, servo housing, post


@dataclasses.dataclass(frozen=True, kw_only=True)
class TurntableOptions:
    """How the turntable moves during a scan (the ``[turntable]`` TOML section).

    Attributes:
      mode: "step" (move, settle, scan one line) or "continuous" (the table
        turns at ``rpm`` while the LiDAR scans at its own rate).
      physics: "auto" (kinematic for an ideal step scan, dynamic otherwise),
        "kinematic" (the table is exactly at each commanded angle; step mode
        only) or "dynamic" (the servo in MuJoCo).
      rpm: continuous mode's turntable speed, revolutions per minute.
      deskew: reconstruct with encoder readings interpolated to each beam's
        time; False uses one angle per line (the commanded angle in step mode,
        the reading at the line's time stamp in continuous mode).
      dynamics: servo, jitter, integrator and settling.
      encoder: the encoder and how it is read.
    """

    mode: str = "step"
    physics: str = "auto"
    rpm: float = 1.0
    deskew: bool = True
    dynamics: TurntableDynamics = TurntableDynamics()
    encoder: EncoderConfig = EncoderConfig()

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"turntable mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.physics not in PHYSICS:
            raise ValueError(f"turntable physics must be one of {', '.join(PHYSICS)}, got {self.physics!r}")
        if self.mode == "continuous" and self.physics == "kinematic":
            raise ValueError("turntable physics = \"kinematic\" works only in step mode; a continuous "
                             "scan needs the servo's physics (use physics = \"auto\" or \"dynamic\")")
        if not isinstance(self.deskew, bool):
            raise ValueError(f"turntable deskew must be true or false, got {self.deskew!r}")
        if (isinstance(self.rpm, bool) or not isinstance(self.rpm, (int, float))
                or not math.isfinite(self.rpm) or self.rpm <= 0):
            raise ValueError(f"turntable rpm must be a positive number, got {self.rpm!r}")
        top_rpm = self.dynamics.servo.no_load_speed * 60 / (2 * math.pi)
        if self.rpm > top_rpm:
            raise ValueError(f"turntable rpm ({self.rpm:g}) exceeds the servo's no-load speed "
                             f"({top_rpm:.3g} rpm); choose rpm <= {top_rpm:.3g} or a faster servo")

    def uses_physics(self, ideal: bool) -> bool:
        """Whether a scan with these options runs the servo's physics."""
        if self.physics == "auto":
            # A step scan stays kinematic unless asked for: the sensor model
            # (footprint, noise) applies to kinematic scans, and its error
            # dwarfs a settled servo's.
            return self.mode == "continuous"
        return self.physics == "dynamic"

    def effective(self, ideal: bool) -> "TurntableOptions":
        """These options with every imperfection off when ``ideal``: no jitter, exact encoder."""
        if not ideal:
            return self
        return dataclasses.replace(
            self, dynamics=self.dynamics.replace(jitter=JitterConfig()),
            encoder=EncoderConfig.ideal(read_rate_hz=self.encoder.read_rate_hz))

    def replace(self, **changes) -> "TurntableOptions":
        return dataclasses.replace(self, **changes)


class PoseCaster:
    """Casts every beam at its own turntable angle (see the module docstring)."""

    def __init__(self, scene: Scene, lidar: LidarSpec, *, nthread: int | None = None, nsim: int = 64):
        self.scene = scene
        self.lidar = lidar
        self.beam_angles_rad = lidar.beam_angles_rad()
        self.origin_base, self.dirs_base = ray_origins_dirs_base(scene.T_base_lidar, self.beam_angles_rad)
        self.nsim = nsim
        nthread = nthread or max(1, os.cpu_count() or 1)
        # Every simulation keeps the hinges at 0: the turntable frame is the base frame.
        self._batch = mujoco.batch.Batch(scene.model, nsim=nsim, nthread=nthread)
        d, g = self._batch.ray(self.origin_base, self.dirs_base, geomgroup=FIXED_GEOMGROUP,
                               flg_static=True, bodyexclude=scene.lidar_body_id, ids=np.array([0]))
        self._rig_dist, self._rig_geom = d[0], g[0]

    def cast(self, table_rad: np.ndarray, *, progress: Progress | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """First hits of every beam at its own true table angle.

        Args:
          table_rad: (n_lines, n_beams) float64, true turntable angle per beam.
          progress: called with (lines done, lines total).

        Returns:
          dist_m (n_lines, n_beams) float64 (-1: miss), geom_id (n_lines, n_beams) int32.
        """
        theta = np.asarray(table_rad, dtype=np.float64)
        n_lines, n_beams = theta.shape
        dist = np.empty(theta.shape)
        geom = np.empty(theta.shape, dtype=np.int32)
        for lo in range(0, n_lines, self.nsim):
            hi = min(lo + self.nsim, n_lines)
            R_turntable_base = rot_z_batch(-theta[lo:hi].ravel()).reshape(hi - lo, n_beams, 3, 3)
            origins_turntable = R_turntable_base @ self.origin_base
            dirs_turntable = np.einsum("lbij,bj->lbi", R_turntable_base, self.dirs_base)
            d, g = self._batch.ray(origins_turntable, dirs_turntable, geomgroup=TURNING_GEOMGROUP,
                                   flg_static=False, bodyexclude=self.scene.lidar_body_id,
                                   ids=np.arange(hi - lo))
            rig_nearer = (self._rig_dist >= 0) & ((d < 0) | (self._rig_dist < d))
            dist[lo:hi] = np.where(rig_nearer, self._rig_dist, d)
            geom[lo:hi] = np.where(rig_nearer, self._rig_geom, g)
            if progress is not None:
                progress(hi, n_lines)
        return dist, geom


@dataclasses.dataclass(frozen=True, eq=False)
class DynamicScanResult:
    """A dynamic scan's raw record and what produced it.

    Attributes:
      raw: the raw record; ``turntable_angle_rad`` is what the reconstruction
        believes (encoder-based), ``true_turntable_angle_rad`` the ground truth.
      trajectory: the physics, one row per step.
      readings: the host's encoder log.
      commanded_rad: (n_lines,) float64, the commanded angle per line (step
        mode) or the line's reading (continuous mode).
    """

    raw: RawScan
    trajectory: Trajectory
    readings: EncoderReadings
    commanded_rad: np.ndarray


def _steps(duration_s: float, dt: float) -> int:
    return max(0, int(math.ceil(duration_s / dt - 1e-9)))


def _finish(scene: Scene, lidar: LidarSpec, sim: TurntableSim, options: TurntableOptions,
            line_t0: np.ndarray, line_angle_rad: np.ndarray | None, rng: np.random.Generator,
            caster: PoseCaster | None, progress: Progress | None) -> DynamicScanResult:
    time_s = line_t0[:, None] + lidar.beam_time_offsets_s()[None, :]
    # Run on past the last beam so that every beam has readings on both sides.
    t_needed = float(time_s[-1, -1]) + 1.0 / options.encoder.read_rate_hz + options.encoder.latency_s
    sim.advance(_steps(t_needed - sim.time_s, sim.dt) + 1)
    trajectory = sim.trajectory()
    true_rad = trajectory.table_at(time_s)
    readings = encoder_mod.read(trajectory.time_s, trajectory.shaft_rad, options.encoder, rng,
                                t_end_s=trajectory.time_s[-1])
    if line_angle_rad is None:
        line_angle_rad = readings.angles_at(line_t0)
    believed = readings.angles_at(time_s) if options.deskew else np.broadcast_to(
        line_angle_rad[:, None], time_s.shape)
    caster = caster or PoseCaster(scene, lidar)
    dist, geom = caster.cast(true_rad, progress=progress)
    range_m, status = gate_ranges(dist, lidar)
    raw = RawScan(turntable_angle_rad=believed, true_turntable_angle_rad=true_rad,
                  beam_angle_rad=caster.beam_angles_rad, range_m=range_m, status=status,
                  hit_class=scene.geom_class[geom], geom_id=geom, time_s=time_s,
                  T_base_lidar=scene.T_base_lidar)
    return DynamicScanResult(raw=raw, trajectory=trajectory, readings=readings,
                             commanded_rad=np.asarray(line_angle_rad))


def dynamic_step_and_shoot(dscene: DynamicScene, lidar: LidarSpec, schedule: StepScan,
                           options: TurntableOptions, rng: np.random.Generator, *,
                           caster: PoseCaster | None = None, progress: Progress | None = None
                           ) -> DynamicScanResult:
    """Step-and-shoot with the servo: command, wait until settled, scan the next line.

    The LiDAR runs freely at its scan period; the line used is the first that
    starts after the table has settled (profile done, shaft within
    ``settle_tolerance_rad`` of the goal and slower than
    ``settle_velocity_rad_s``, like the servo's Moving flag). The table may
    still creep during the line; every beam is cast at its own true angle.
    ``schedule.step_time_s`` is not used: the physics decides each step's time.

    Raises:
      SimulationError: if a step does not settle within ``settle_timeout_s``,
        or the simulation is unstable (see :class:`TurntableSim`).
    """
    dyn = options.dynamics
    sim = TurntableSim(dscene, rng)
    period = lidar.scan_period_s
    check_s = 0.01
    goals = schedule.angles_rad()
    line_t0 = np.empty(len(goals))
    for k, goal in enumerate(goals):
        profile = sim.command(float(goal))
        sim.advance(_steps(profile.start_time + profile.duration - sim.time_s, sim.dt))
        deadline = sim.time_s + dyn.settle_timeout_s
        while not (abs(sim.shaft_rad - goal) <= dyn.settle_tolerance_rad
                   and abs(sim.shaft_velocity_rad_s) <= dyn.settle_velocity_rad_s):
            if sim.time_s >= deadline:
                from plantsim.errors import SimulationError

                raise SimulationError(
                    f"line {k}: the turntable did not settle at {math.degrees(goal):.4g} deg within "
                    f"settle_timeout_s ({dyn.settle_timeout_s:g} s): error "
                    f"{sim.shaft_rad - goal:.3g} rad (tolerance {dyn.settle_tolerance_rad:.3g}), "
                    f"velocity {sim.shaft_velocity_rad_s:.3g} rad/s (threshold "
                    f"{dyn.settle_velocity_rad_s:.3g}); raise settle_tolerance_rad or "
                    f"settle_timeout_s, or the position P/I gain (friction stalls a weak P loop)")
            sim.advance(_steps(check_s, sim.dt))
        # The next line the free-running LiDAR starts after settling.
        line_t0[k] = math.ceil(sim.time_s / period - 1e-9) * period
        sim.advance(_steps(line_t0[k] + period - sim.time_s, sim.dt))
    return _finish(dscene.scene, lidar, sim, options, line_t0, goals, rng, caster, progress)


def continuous_scan(dscene: DynamicScene, lidar: LidarSpec, sweep_deg: float,
                    options: TurntableOptions, rng: np.random.Generator, *,
                    caster: PoseCaster | None = None, progress: Progress | None = None
                    ) -> DynamicScanResult:
    """The table turns at ``options.rpm`` while the LiDAR scans at its own rate.

    The servo is commanded to a far goal with its profile velocity set to the
    scan speed; lines are taken from ``spinup_margin_s`` after the ramp to full
    speed until the table has turned ``sweep_deg``.
    """
    dyn = options.dynamics
    sim = TurntableSim(dscene, rng)
    omega = options.rpm * 2 * math.pi / 60
    accel = dyn.servo.profile_acceleration
    period = lidar.scan_period_s
    t_ramp = 0.0 if math.isinf(accel) else omega / accel
    n_lines = max(1, int(math.ceil(math.radians(sweep_deg) / (omega * period) - 1e-9)))
    first = math.ceil((t_ramp + dyn.spinup_margin_s) / period - 1e-9) * period
    line_t0 = first + period * np.arange(n_lines)
    t_end = float(line_t0[-1]) + 2 * period
    braking = 0.0 if math.isinf(accel) else omega * omega / (2 * accel)
    goal = omega * (t_end - t_ramp / 2) + braking + omega * 1.0  # cruise well past the last beam
    sim.command(goal, profile_velocity_rad_s=omega)
    sim.advance(_steps(t_end, sim.dt))
    return _finish(dscene.scene, lidar, sim, options, line_t0, None, rng, caster, progress)


# --- configuration from plain data (the [turntable] TOML section) --------------------

_REGISTER_FIELDS = {
    "Position P Gain": "position_p_gain", "Position I Gain": "position_i_gain",
    "Position D Gain": "position_d_gain", "Feedforward 1st Gain": "velocity_feedforward_gain",
    "Feedforward 2nd Gain": "acceleration_feedforward_gain", "Profile Velocity": "profile_velocity",
    "Profile Acceleration": "profile_acceleration", "PWM Limit": "torque_limit",
}
_SUBTABLES = ("servo", "registers", "jitter", "encoder")


def _fields(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def _unknown(values: dict, valid: list[str], where: str) -> None:
    unknown = sorted(set(values) - set(valid))
    if unknown:
        raise ValueError(f"unknown key(s) {', '.join(unknown)} in [{where}]; valid keys: {', '.join(valid)}")


def turntable_options_from_dict(data: dict) -> TurntableOptions:
    """Builds :class:`TurntableOptions` from a parsed ``[turntable]`` section.

    Layout: top-level keys ``mode``, ``physics``, ``rpm``, ``deskew``,
    ``servo_preset`` ("xm430-w350" or "xl430-w250") and the
    :class:`TurntableDynamics` scalars (``timestep_s``, ``integrator``,
    ``settle_*``, ...); sub-tables ``[turntable.servo]`` (:class:`ServoConfig`
    fields, SI), ``[turntable.registers]`` (Dynamixel register names and raw
    values, e.g. ``"Position P Gain" = 800``, converted by
    :meth:`ServoConfig.with_registers`), ``[turntable.jitter]`` and
    ``[turntable.encoder]`` (``ticks_per_rev = 0`` means exact).

    Raises:
      ValueError: for unknown keys, a quantity given both in SI and as a
        register, or invalid values.
    """
    from plantsim.dynamics import DEFAULT_SERVO, SERVO_PRESETS
    from plantsim.servo import ServoConfig

    data = dict(data)
    dyn_scalars = [f for f in _fields(TurntableDynamics) if f not in ("servo", "jitter")]
    top = ["mode", "physics", "rpm", "deskew", "servo_preset"] + dyn_scalars
    _unknown({k: v for k, v in data.items() if k not in _SUBTABLES}, top + list(_SUBTABLES), "turntable")
    preset = data.pop("servo_preset", "xm430-w350")
    if preset not in SERVO_PRESETS:
        raise ValueError(f"turntable servo_preset must be one of {', '.join(SERVO_PRESETS)}, got {preset!r}")
    servo_si = dict(data.pop("servo", {}))
    registers = dict(data.pop("registers", {}))
    _unknown(servo_si, _fields(ServoConfig), "turntable.servo")
    _unknown(registers, list(_REGISTER_FIELDS), "turntable.registers")
    both = sorted(r for r in registers if _REGISTER_FIELDS[r] in servo_si)
    if both:
        raise ValueError(f"{', '.join(both)} set both in [turntable.registers] and as "
                         f"{', '.join(_REGISTER_FIELDS[r] for r in both)} in [turntable.servo]; give one")
    for name, value in registers.items():
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"register {name!r} must be an integer (raw units), got {value!r}")
    servo = SERVO_PRESETS[preset](profile_velocity=DEFAULT_SERVO.profile_velocity,
                                  profile_acceleration=DEFAULT_SERVO.profile_acceleration)
    servo = dataclasses.replace(servo, **servo_si).with_registers(registers)
    jitter = dict(data.pop("jitter", {}))
    _unknown(jitter, _fields(JitterConfig), "turntable.jitter")
    encoder = dict(data.pop("encoder", {}))
    _unknown(encoder, _fields(EncoderConfig), "turntable.encoder")
    if encoder.get("ticks_per_rev") == 0:
        encoder["ticks_per_rev"] = None
    dynamics = TurntableDynamics(servo=servo, jitter=JitterConfig(**jitter),
                                 **{k: data.pop(k) for k in dyn_scalars if k in data})
    return TurntableOptions(dynamics=dynamics, encoder=EncoderConfig(**encoder), **data)
