"""From the raw record to a point cloud in the turntable frame.

The kinematic model: a return of range r on beam angle a is the point
``r (cos a, sin a, 0)`` in the lidar frame; ``T_base_lidar`` puts it in the
base frame; undoing the turntable's turn theta (counter-clockwise from above,
``T_base_turntable = Rz(theta)``) puts it in the turntable frame:

    points_turntable = Rz(-theta) @ (R_base_lidar @ points_lidar + t_base_lidar)

The original ROS/Gazebo tool applied Rz(+theta) and so mirrored every plant.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from plantsim.rig.geometry import beam_dirs_lidar
from plantsim.scan.raw import RawScan, believed_angles
from plantsim.rig.scene import HitClass
from plantsim.sensor.spec import BeamStatus


@dataclasses.dataclass(frozen=True, eq=False)
class PointCloud:
    """Returns of a scan as points, one row per return (misses are never points).

    Attributes:
      points_turntable: (n, 3) float64, metres, turntable frame.
      hit_class: (n,) uint8 :class:`HitClass`.
      beam_index: (n,) uint16, beam within its line.
      scan_index: (n,) uint32, line (turntable step) index.
      turntable_angle_rad: (n,) float64, the angle used to reconstruct the point.
      range_m: (n,) float64.
      time_s: (n,) float64, the beam's time since the scan's start.
      intensity: (n,) float32 received power in [0, 1], or None when not modelled.
    """

    points_turntable: np.ndarray
    hit_class: np.ndarray
    beam_index: np.ndarray
    scan_index: np.ndarray
    turntable_angle_rad: np.ndarray
    range_m: np.ndarray
    time_s: np.ndarray
    intensity: np.ndarray | None = None

    def __len__(self) -> int:
        return int(len(self.points_turntable))

    def select(self, mask: np.ndarray) -> "PointCloud":
        """The points where ``mask`` ((n,) bool) is True."""
        return PointCloud(**{f.name: (None if getattr(self, f.name) is None
                                      else getattr(self, f.name)[mask])
                             for f in dataclasses.fields(self)})

    def plant_only(self) -> "PointCloud":
        return self.select(self.hit_class == HitClass.PLANT)

    def counts_by_class(self) -> dict:
        return {c.name.lower(): int((self.hit_class == c).sum()) for c in HitClass if c != HitClass.NONE}


def points_base_from_ranges(range_m: np.ndarray, beam_angle_rad: np.ndarray,
                            T_base_lidar: np.ndarray) -> np.ndarray:
    """Base-frame points of returns.

    Args:
      range_m: (n,) float64 metres.
      beam_angle_rad: (n,) float64 radians, lidar frame.
      T_base_lidar: (4, 4) float64.

    Returns:
      points_base: (n, 3) float64 metres.
    """
    return points_base_from_dirs(range_m, beam_dirs_lidar(beam_angle_rad), T_base_lidar)


def points_base_from_dirs(range_m: np.ndarray, dirs_lidar: np.ndarray, T_base_lidar: np.ndarray) -> np.ndarray:
    """:func:`points_base_from_ranges` given the beams' unit directions (n, 3), lidar frame."""
    return (range_m[:, None] * dirs_lidar) @ T_base_lidar[:3, :3].T + T_base_lidar[:3, 3]


def base_to_turntable(points_base: np.ndarray, turntable_angle_rad: np.ndarray) -> np.ndarray:
    """Undoes the turntable's turn: ``Rz(-theta)`` per point.

    Args:
      points_base: (n, 3) float64 metres, base frame.
      turntable_angle_rad: (n,) float64 radians, counter-clockwise from above.

    Returns:
      points_turntable: (n, 3) float64 metres.
    """
    # Rz(-theta) applied row by row, without forming the (n, 3, 3) matrices of
    # rot_z_batch (the same products, a third of the time and no 72 bytes a point).
    theta = np.asarray(turntable_angle_rad, dtype=np.float64)
    points_base = np.asarray(points_base, dtype=np.float64)
    c, s = np.cos(theta), np.sin(theta)
    points_turntable = np.empty(np.broadcast_shapes(points_base.shape, theta.shape + (3,)))
    points_turntable[..., 0] = c * points_base[..., 0] + s * points_base[..., 1]
    points_turntable[..., 1] = c * points_base[..., 1] - s * points_base[..., 0]
    points_turntable[..., 2] = points_base[..., 2]
    return points_turntable


def beam_dirs_turntable(points_turntable: np.ndarray, turntable_angle_rad: np.ndarray,
                        T_base_lidar: np.ndarray) -> np.ndarray:
    """Unit direction of each point's beam, from the LiDAR to the point, in the turntable frame.

    At the turntable angle a point was reconstructed with, the LiDAR's origin
    (``T_base_lidar``'s translation) sits at ``Rz(-theta) t_base_lidar`` in the turntable
    frame; the beam runs from there to the point. The direction along which the
    sensor's range noise moves the point.

    Args:
      points_turntable: (n, 3) float64 metres.
      turntable_angle_rad: (n,) float64 radians, the angle each point was reconstructed with.
      T_base_lidar: (4, 4) float64.

    Returns:
      (n, 3) float64 unit vectors (a point at the LiDAR's origin gets a zero vector).
    """
    points_turntable = np.asarray(points_turntable, dtype=np.float64).reshape(-1, 3)
    theta = np.asarray(turntable_angle_rad, dtype=np.float64).reshape(-1)
    if len(theta) != len(points_turntable):
        raise ValueError(f"turntable_angle_rad has {len(theta)} angles for {len(points_turntable)} points")
    t_base_lidar = np.asarray(T_base_lidar, dtype=np.float64)[:3, 3]
    d = points_turntable - base_to_turntable(np.broadcast_to(t_base_lidar, points_turntable.shape), theta)
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    return np.divide(d, norm, out=np.zeros_like(d), where=norm > 0)


def reconstruct(raw: RawScan, *, intensity: np.ndarray | None = None) -> PointCloud:
    """The point cloud of a raw scan's returns, in the turntable frame.

    Args:
      raw: the raw record.
      intensity: optional (n_lines, n_beams) per-beam intensity; default:
        the raw record's own (None for ideal scans).

    Returns:
      :class:`PointCloud` with one point per beam whose status is OK.
    """
    if intensity is None:
        intensity = raw.intensity
    ok = raw.status == BeamStatus.OK
    lines, beams = np.nonzero(ok)
    range_m = raw.range_m[lines, beams]
    # Per return only, not per beam of the grid (most beams miss): the same values as
    # raw.turntable_angle_rad[lines, beams], raw.time_s[lines, beams] and
    # beam_dirs_lidar(raw.beam_angle_rad[beams]), bit for bit.
    angle = believed_angles(raw, lines, beams)
    dirs_lidar = beam_dirs_lidar(raw.beam_angle_rad)[beams]
    points_base = points_base_from_dirs(range_m, dirs_lidar, raw.T_base_lidar)
    return PointCloud(
        points_turntable=base_to_turntable(points_base, angle),
        hit_class=raw.hit_class[lines, beams],
        beam_index=beams.astype(np.uint16),
        scan_index=lines.astype(np.uint32),
        turntable_angle_rad=angle,
        range_m=range_m,
        time_s=raw.time_s_at(lines, beams),
        intensity=None if intensity is None else intensity[lines, beams].astype(np.float32),
    )
