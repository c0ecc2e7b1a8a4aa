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

import numpy as np

from plantsim.turntable import encoder as encoder_mod
from plantsim.turntable.dynamics import DynamicScene, Trajectory, TurntableSim
from plantsim.turntable.encoder import EncoderReadings
from plantsim.turntable.options import TurntableOptions
from plantsim.scan.schedule import Progress, StepScan
from plantsim.scan.raw import RawScan
from plantsim.sensor.casting import PoseCaster, gate_ranges
from plantsim.rig.scene import Scene
from plantsim.sensor.spec import LidarSpec

log = logging.getLogger(__name__)


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


