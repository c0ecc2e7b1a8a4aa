"""Step-and-shoot scans: turn the table to each angle, cast one LiDAR line.

The raw record (:class:`RawScan`) keeps, per beam, the turntable angle, beam
angle, range, status, what it hit and its time. Reconstruction into a point
cloud is :mod:`plantsim.reconstruct`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from typing import Callable

import mujoco
import mujoco.batch
import numpy as np

from plantsim.rig import beam_dirs_lidar
from plantsim.scene import LIDAR_GEOMGROUP, HitClass, Scene
from plantsim.sensor import BeamStatus, LidarSpec

log = logging.getLogger(__name__)

# MuJoCo's mesh BVH can cull a ray that lies exactly in a plane holding mesh
# vertices (../shared/notes/mujoco-raycasting.md): a scan plane through the
# turntable axis is that case at every angle where the plant has a vertex row.
# Moving every origin this far off the scan plane, along its normal, removes
# it; the reconstruction error it adds is at most this distance.
AXIS_TRAP_OFFSET_M = 1e-9

Progress = Callable[[int, int], None]


@dataclasses.dataclass(frozen=True, kw_only=True)
class StepScan:
    """A step-and-shoot schedule (the original tool's mode).

    Attributes:
      step_deg: turntable step between scan lines, degrees (> 0, divides sweep_deg).
      sweep_deg: total turn; lines are taken at 0, step, ..., sweep - step
        (the half-open range: a full 360 does not repeat angle 0).
      step_time_s: time from one line's start to the next (move, settle and
        one scan); must be at least the sensor's scan period.
    """

    step_deg: float = 1.0
    sweep_deg: float = 360.0
    step_time_s: float = 0.5

    def __post_init__(self):
        for field in ("step_deg", "sweep_deg", "step_time_s"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{field} must be a finite number, got {value!r}")
            if value <= 0:
                raise ValueError(f"{field} must be > 0, got {value}")
        if self.sweep_deg > 3600:
            raise ValueError(f"sweep_deg must be at most 3600 (10 turns), got {self.sweep_deg}")
        n = self.sweep_deg / self.step_deg
        if abs(n - round(n)) > 1e-9 * max(1.0, n) or round(n) < 1:
            raise ValueError(
                f"step_deg must divide sweep_deg evenly, got step_deg={self.step_deg} and "
                f"sweep_deg={self.sweep_deg} ({n:.4g} steps); try step_deg="
                f"{self.sweep_deg / max(1, round(n)):.6g}")

    @property
    def n_lines(self) -> int:
        return int(round(self.sweep_deg / self.step_deg))

    def angles_rad(self) -> np.ndarray:
        """Commanded turntable angles. Returns (n_lines,) float64, radians."""
        return np.deg2rad(self.step_deg * np.arange(self.n_lines))


@dataclasses.dataclass(frozen=True, eq=False)
class RawScan:
    """Everything the sensor and turntable produced, one row per scan line.

    Attributes:
      turntable_angle_rad: (n_lines, n_beams) float64: the turntable angle at
        each beam's instant, as the reconstruction knows it (commanded angle
        in a kinematic scan; encoder readings in dynamic scans).
      true_turntable_angle_rad: (n_lines, n_beams) float64: the angle the rays
        were really cast at (ground truth).
      beam_angle_rad: (n_beams,) float64, lidar frame.
      range_m: (n_lines, n_beams) float64, metres; NaN where there is no return.
      status: (n_lines, n_beams) uint8, :class:`BeamStatus`.
      hit_class: (n_lines, n_beams) uint8, :class:`HitClass` of the first
        surface along the beam (also for beams without a return, e.g. too near).
      geom_id: (n_lines, n_beams) int32, MuJoCo geom id or -1.
      time_s: (n_lines, n_beams) float64, seconds since the scan's start.
      T_base_lidar: (4, 4) float64.
      intensity: (n_lines, n_beams) float32 received power in [0, 1] (NaN
        without echo), or None when not modelled (ideal scans).
    """

    turntable_angle_rad: np.ndarray
    true_turntable_angle_rad: np.ndarray
    beam_angle_rad: np.ndarray
    range_m: np.ndarray
    status: np.ndarray
    hit_class: np.ndarray
    geom_id: np.ndarray
    time_s: np.ndarray
    T_base_lidar: np.ndarray
    intensity: np.ndarray | None = None

    @property
    def n_lines(self) -> int:
        return int(self.range_m.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.range_m.shape[1])

    def counts(self) -> dict:
        """Beams by status and returns by hit class, for the sidecar."""
        ok = self.status == BeamStatus.OK
        return {
            "beams": int(self.status.size),
            "returns": int(ok.sum()),
            "by_status": {s.name.lower(): int((self.status == s).sum()) for s in BeamStatus},
            "returns_by_class": {c.name.lower(): int((ok & (self.hit_class == c)).sum())
                                 for c in HitClass if c != HitClass.NONE},
        }


def ray_origins_dirs_base(T_base_lidar: np.ndarray, beam_angles_rad: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """World-frame rays of one scan line, with the axis-trap guard applied.

    Returns:
      origin_base (3,) float64 metres, dirs_base (n_beams, 3) float64 unit vectors.
    """
    R = T_base_lidar[:3, :3]
    dirs_base = beam_dirs_lidar(beam_angles_rad) @ R.T
    origin_base = T_base_lidar[:3, 3] + AXIS_TRAP_OFFSET_M * R[:, 2]
    return origin_base, dirs_base


def gate_ranges(dist_m: np.ndarray, lidar: LidarSpec) -> tuple[np.ndarray, np.ndarray]:
    """Applies the sensor's range limits to first-hit distances.

    Args:
      dist_m: (...) float64 metres, MuJoCo's first-hit distance, -1 for a miss.
      lidar: the sensor.

    Returns:
      range_m (...) float64 with NaN where there is no return, status (...) uint8.
    """
    status = np.full(dist_m.shape, BeamStatus.OK, dtype=np.uint8)
    status[(dist_m < 0) | (dist_m > lidar.range_max_m)] = BeamStatus.NO_ECHO
    status[(dist_m >= 0) & (dist_m < lidar.range_min_m)] = BeamStatus.TOO_NEAR
    range_m = np.where(status == BeamStatus.OK, dist_m, np.nan)
    return range_m, status


class RayCaster:
    """Casts LiDAR lines at given turntable angles with ``mujoco.batch``.

    One simulation per scan line: its hinge angle is that line's, and all lines
    share the same world-frame rays. The batch releases the GIL and runs on
    ``nthread`` threads.
    """

    def __init__(self, scene: Scene, lidar: LidarSpec, *, nthread: int | None = None,
                 max_lines: int = 4096):
        self.scene = scene
        self.lidar = lidar
        self.beam_angles_rad = lidar.beam_angles_rad()
        self.origin_base, self.dirs_base = ray_origins_dirs_base(scene.T_base_lidar,
                                                                  self.beam_angles_rad)
        self.nthread = nthread or max(1, os.cpu_count() or 1)
        self._max_lines = max_lines
        self._batch = None
        self._nsim = 0

    def _ensure_batch(self, n: int):
        if self._batch is None or self._nsim < n:
            self._nsim = max(n, 1)
            self._batch = mujoco.batch.Batch(self.scene.model, nsim=self._nsim, nthread=self.nthread)
        return self._batch

    def cast(self, qpos_turntable_rad: np.ndarray, *, progress: Progress | None = None,
             chunk_lines: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """First-hit distance and geom per beam, one line per turntable angle.

        Args:
          qpos_turntable_rad: (n_lines,) float64, the true hinge angle per line.
          progress: called with (lines done, lines total) after each chunk.
          chunk_lines: lines per batch call (progress granularity).

        Returns:
          dist_m (n_lines, n_beams) float64 (-1: miss), geom_id (n_lines, n_beams) int32.
        """
        q = np.asarray(qpos_turntable_rad, dtype=np.float64).reshape(-1)
        n = len(q)
        dist = np.empty((n, len(self.dirs_base)))
        geom = np.empty((n, len(self.dirs_base)), dtype=np.int32)
        adr = self.scene.turntable_qpos_adr
        for start in range(0, n, self._max_lines):
            block = q[start:start + self._max_lines]
            batch = self._ensure_batch(len(block))
            qpos = batch.bind("qpos")
            qpos[: len(block), adr] = block
            for lo in range(0, len(block), chunk_lines):
                ids = np.arange(lo, min(lo + chunk_lines, len(block)))
                d, g = batch.ray(self.origin_base, self.dirs_base, geomgroup=LIDAR_GEOMGROUP,
                                 flg_static=True, bodyexclude=self.scene.lidar_body_id, ids=ids)
                dist[start + ids] = d
                geom[start + ids] = g
                if progress is not None:
                    progress(start + ids[-1] + 1, n)
        return dist, geom


def step_and_shoot(scene: Scene, lidar: LidarSpec, schedule: StepScan, *,
                   caster: RayCaster | None = None, progress: Progress | None = None) -> RawScan:
    """An ideal, kinematic step-and-shoot scan (no actuator, no physics).

    The table is exactly at each commanded angle for the whole line.

    Args:
      scene: a compiled scene from :func:`plantsim.scene.build_scene`.
      lidar: the sensor.
      schedule: angles and timing.
      caster: a :class:`RayCaster` to reuse (it must be for this scene and sensor).
      progress: called with (lines done, lines total).

    Returns:
      The :class:`RawScan`.
    """
    if schedule.step_time_s < lidar.scan_period_s:
        raise ValueError(
            f"step_time_s ({schedule.step_time_s} s) must be at least the sensor's scan period "
            f"({lidar.scan_period_s} s): one line must fit in one step")
    caster = caster or RayCaster(scene, lidar)
    dist, geom = caster.cast(schedule.angles_rad(), progress=progress)
    range_m, status = gate_ranges(dist, lidar)
    return kinematic_raw_scan(scene, lidar, schedule, range_m=range_m, status=status, geom_id=geom)


def kinematic_raw_scan(scene: Scene, lidar: LidarSpec, schedule: StepScan, *, range_m: np.ndarray,
                       status: np.ndarray, geom_id: np.ndarray,
                       intensity: np.ndarray | None = None) -> RawScan:
    """The raw record of a kinematic step-and-shoot scan from its per-beam results.

    The table is exactly at each commanded angle for the whole line; line j
    starts at ``j * step_time_s`` and its beams follow the sensor's timing.

    Args:
      range_m, status, geom_id: (n_lines, n_beams) per-beam results.
      intensity: optional (n_lines, n_beams) float.
    """
    angles = schedule.angles_rad()
    line_t0 = schedule.step_time_s * np.arange(schedule.n_lines)
    time_s = line_t0[:, None] + lidar.beam_time_offsets_s()[None, :]
    angle_per_beam = np.broadcast_to(angles[:, None], range_m.shape)
    return RawScan(
        turntable_angle_rad=angle_per_beam,
        true_turntable_angle_rad=angle_per_beam,
        beam_angle_rad=lidar.beam_angles_rad(),
        range_m=range_m,
        status=status,
        hit_class=scene.geom_class[geom_id],
        geom_id=geom_id,
        time_s=time_s,
        T_base_lidar=scene.T_base_lidar,
        intensity=intensity,
    )
