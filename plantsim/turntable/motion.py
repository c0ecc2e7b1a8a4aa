"""Turntable motions: when each scan line is taken, where the table truly is, what the encoder says.

A motion is one part of a scan (:mod:`plantsim.scan.pipeline`); it knows nothing
of the LiDAR but its timing. Given the schedule it returns a
:class:`MotionRecord`: each line's time stamp (its first beam), the true
turntable angle at any instant, and the host's log of encoder readings, which is
all a reconstruction may use. The simulated motions are

- :func:`kinematic_step`: the table is exactly at each commanded angle for the
  whole line (a perfect motor); the encoder is read while the table rests;
- :func:`kinematic_continuous`: the table turns at exactly ``rpm`` (a perfect
  motor at constant speed);
- :func:`physics_step` and :func:`physics_continuous`: the servo in MuJoCo
  (:class:`plantsim.turntable.dynamics.TurntableSim`: PID, torque limit,
  friction, jitter, backlash), the true angle recorded at every physics step.

The real turntable (a servo that reports its angle) is driven line by line by
the scan session instead (:mod:`plantsim.scan.session`).

Times are integer nanoseconds since the scan's start where they are stored, as
in the raw record and its ROS 2 bag.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from plantsim.errors import SimulationError
from plantsim.timestamps import ns_to_s, s_to_ns
from plantsim.turntable import encoder as encoder_mod
from plantsim.turntable.dynamics import DynamicScene, Trajectory, TurntableDynamics, TurntableSim
from plantsim.turntable.encoder import EncoderConfig, EncoderReadings


@dataclasses.dataclass(frozen=True)
class LineTiming:
    """The LiDAR's timing as a motion needs it.

    Attributes:
      scan_period_s: one mirror turn (one line).
      first_beam_s: time of the first beam after the mirror's step 0, s.
      beam_offsets_s: (n_beams,) float64, each beam's time after the first beam, s.
    """

    scan_period_s: float
    first_beam_s: float
    beam_offsets_s: np.ndarray

    @property
    def last_beam_s(self) -> float:
        """The last beam's time after the first, s."""
        return float(self.beam_offsets_s[-1])


@dataclasses.dataclass(frozen=True, eq=False)
class MotionRecord:
    """What a simulated motion did.

    Attributes:
      kind: "kinematic" or "physics".
      line_stamp_ns: (n_lines,) int64, each line's first beam, ns since the scan's start.
      commanded_rad: (n_lines,) float64, commanded angle per line (NaN: not stepped).
      readings: the encoder log (time stamps are whole nanoseconds).
      trajectory: the physics, one row per step (None for a kinematic motion).
      constant_rad: (n_lines,) the table's angle during each line when it rests
        exactly there (kinematic step), else None.
      rpm: the constant speed of a kinematic continuous motion, else None.
    """

    kind: str
    line_stamp_ns: np.ndarray
    commanded_rad: np.ndarray
    readings: EncoderReadings
    trajectory: Trajectory | None = None
    constant_rad: np.ndarray | None = None
    rpm: float | None = None

    def true_angles(self, beam_time_s: np.ndarray) -> np.ndarray:
        """The true turntable angle at each beam's instant.

        Args:
          beam_time_s: (n_lines, n_beams) float64, s since the scan's start.

        Returns:
          (n_lines, n_beams) float64 radians, or (n_lines,) when the table rests
          during each line (a step scan's kinematic motion: one angle per line).
        """
        if self.constant_rad is not None:
            return self.constant_rad
        if self.rpm is not None:
            return _omega(self.rpm) * np.asarray(beam_time_s)
        return self.trajectory.table_at(beam_time_s)


def _omega(rpm: float) -> float:
    return rpm * 2 * math.pi / 60


def _quantised(readings: EncoderReadings) -> EncoderReadings:
    """Readings with whole-nanosecond time stamps (as a JointState carries them)."""
    return EncoderReadings(time_s=ns_to_s(s_to_ns(readings.time_s)), angle_rad=readings.angle_rad)


def _stamps_ns(line_t0_s: np.ndarray, timing: LineTiming) -> np.ndarray:
    return s_to_ns(np.asarray(line_t0_s) + timing.first_beam_s)


def kinematic_step(angles_rad: np.ndarray, step_time_s: float, timing: LineTiming,
                   encoder: EncoderConfig, rng: np.random.Generator) -> MotionRecord:
    """A perfect motor: line k is taken at ``k * step_time_s``, the table exactly at angle k.

    The host reads the encoder at its read rate while the line is taken (and at
    the line's last beam), so that readings never straddle a move.
    """
    angles = np.asarray(angles_rad, dtype=np.float64)
    stamps = _stamps_ns(step_time_s * np.arange(len(angles)), timing)
    span = timing.last_beam_s
    # Readings from the first beam on, and one just after the last beam (whole
    # nanoseconds), so that every beam of the line lies between two readings of it.
    per_line_ns = np.round(np.arange(0.0, span, 1.0 / encoder.read_rate_hz) * 1e9).astype(np.int64)
    per_line_ns = np.append(per_line_ns, int(np.ceil(span * 1e9)) + 1)
    t_read = ns_to_s((stamps[:, None] + per_line_ns[None, :]).ravel())
    angle_true = np.repeat(angles, len(per_line_ns))
    readings = EncoderReadings(time_s=t_read, angle_rad=encoder_mod.measure(angle_true, encoder, rng,
                                                                            time_s=t_read))
    return MotionRecord(kind="kinematic", line_stamp_ns=stamps, commanded_rad=angles,
                        readings=_quantised(readings), constant_rad=angles)


def continuous_line_count(rpm: float, sweep_deg: float, scan_period_s: float) -> int:
    """Lines a continuous scan takes to turn ``sweep_deg`` at ``rpm``."""
    return max(1, int(math.ceil(math.radians(sweep_deg) / (_omega(rpm) * scan_period_s) - 1e-9)))


def kinematic_continuous(rpm: float, sweep_deg: float, timing: LineTiming, encoder: EncoderConfig,
                         rng: np.random.Generator) -> MotionRecord:
    """A perfect motor at constant speed: the table is at ``omega * t`` from t = 0."""
    n = continuous_line_count(rpm, sweep_deg, timing.scan_period_s)
    stamps = _stamps_ns(timing.scan_period_s * np.arange(n), timing)
    t_end = float(stamps[-1]) / 1e9 + timing.last_beam_s + 2.0 / encoder.read_rate_hz + encoder.latency_s
    omega = _omega(rpm)
    readings = encoder_mod.read(np.array([0.0, t_end]), np.array([0.0, omega * t_end]), encoder, rng,
                                t_end_s=t_end)
    return MotionRecord(kind="kinematic", line_stamp_ns=stamps, commanded_rad=np.full(n, np.nan),
                        readings=_quantised(readings), rpm=float(rpm))


def _steps(duration_s: float, dt: float) -> int:
    return max(0, int(math.ceil(duration_s / dt - 1e-9)))


def _physics_record(sim: TurntableSim, line_t0: np.ndarray, commanded: np.ndarray, timing: LineTiming,
                    encoder: EncoderConfig, rng: np.random.Generator) -> MotionRecord:
    stamps = _stamps_ns(line_t0, timing)
    # Run on past the last beam so that every beam has readings on both sides.
    t_needed = float(stamps[-1]) / 1e9 + timing.last_beam_s + 1.0 / encoder.read_rate_hz + encoder.latency_s
    sim.advance(_steps(t_needed - sim.time_s, sim.dt) + 1)
    trajectory = sim.trajectory()
    readings = encoder_mod.read(trajectory.time_s, trajectory.shaft_rad, encoder, rng,
                                t_end_s=trajectory.time_s[-1])
    return MotionRecord(kind="physics", line_stamp_ns=stamps, commanded_rad=np.asarray(commanded),
                        readings=_quantised(readings), trajectory=trajectory)


def physics_step(dscene: DynamicScene, angles_rad: np.ndarray, timing: LineTiming, encoder: EncoderConfig,
                 rng: np.random.Generator) -> MotionRecord:
    """Step-and-shoot with the servo: command, wait until settled, take the next line.

    The LiDAR runs freely at its scan period; the line used is the first that
    starts after the table has settled (profile done, shaft within
    ``settle_tolerance_rad`` of the goal and slower than
    ``settle_velocity_rad_s``, like the servo's Moving flag). The table may
    still creep during the line; the record has its true angle at every instant.

    Raises:
      SimulationError: a step does not settle within ``settle_timeout_s``, or the
        simulation is unstable (see :class:`TurntableSim`).
    """
    dyn: TurntableDynamics = dscene.dynamics
    sim = TurntableSim(dscene, rng)
    period = timing.scan_period_s
    check_s = 0.01
    goals = np.asarray(angles_rad, dtype=np.float64)
    line_t0 = np.empty(len(goals))
    for k, goal in enumerate(goals):
        profile = sim.command(float(goal))
        sim.advance(_steps(profile.start_time + profile.duration - sim.time_s, sim.dt))
        deadline = sim.time_s + dyn.settle_timeout_s
        while not (abs(sim.shaft_rad - goal) <= dyn.settle_tolerance_rad
                   and abs(sim.shaft_velocity_rad_s) <= dyn.settle_velocity_rad_s):
            if sim.time_s >= deadline:
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
    return _physics_record(sim, line_t0, goals, timing, encoder, rng)


def physics_continuous(dscene: DynamicScene, rpm: float, sweep_deg: float, timing: LineTiming,
                       encoder: EncoderConfig, rng: np.random.Generator) -> MotionRecord:
    """The servo turns the table at ``rpm`` while the LiDAR scans at its own rate.

    The servo is commanded to a far goal with its profile velocity set to the
    scan speed; lines are taken from ``spinup_margin_s`` after the ramp to full
    speed until the table has turned ``sweep_deg``.
    """
    dyn = dscene.dynamics
    sim = TurntableSim(dscene, rng)
    omega = _omega(rpm)
    accel = dyn.servo.profile_acceleration
    period = timing.scan_period_s
    t_ramp = 0.0 if math.isinf(accel) else omega / accel
    n_lines = continuous_line_count(rpm, sweep_deg, period)
    first = math.ceil((t_ramp + dyn.spinup_margin_s) / period - 1e-9) * period
    line_t0 = first + period * np.arange(n_lines)
    t_end = float(line_t0[-1]) + 2 * period
    braking = 0.0 if math.isinf(accel) else omega * omega / (2 * accel)
    goal = omega * (t_end - t_ramp / 2) + braking + omega * 1.0  # cruise well past the last beam
    sim.command(goal, profile_velocity_rad_s=omega)
    sim.advance(_steps(t_end, sim.dt))
    return _physics_record(sim, line_t0, np.full(n_lines, np.nan), timing, encoder, rng)


def physics_diagnostics(record: MotionRecord, beam_time_s: np.ndarray,
                        true_rad: np.ndarray, believed_rad: np.ndarray, *,
                        settle_tolerance_rad: float | None = None) -> dict:
    """What the turntable did, for the sidecar and study rows: tracking, backlash, angle errors.

    Args:
      record: a motion record.
      beam_time_s, true_rad, believed_rad: (n_lines, n_beams) per-beam times,
        true angles and the angles the reconstruction used.
      settle_tolerance_rad: the step scans' settling tolerance (for the settle times).
    """
    out = {"motion": record.kind,
           "max_believed_minus_true_rad": float(np.max(np.abs(believed_rad - true_rad))) if np.size(true_rad) else 0.0}
    if record.trajectory is not None:
        from plantsim.turntable.dynamics import DynamicsDiagnostics

        options = {} if settle_tolerance_rad is None else {"settle_tolerance_rad": settle_tolerance_rad}
        out.update(DynamicsDiagnostics.from_trajectory(record.trajectory, true_rad=true_rad,
                                                       believed_rad=believed_rad, **options).to_dict())
    return out
