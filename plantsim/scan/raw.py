"""The raw record of a scan: what a real rig knows, plus the ground truth when simulated.

One :class:`RawScan` holds exactly what the ROS 2 bag of a scan holds
(:mod:`plantsim.cloud.bag`), at the bag's precision, so that a cloud rebuilt from
the bag is bit for bit the scan's own cloud:

- per line (a ``sensor_msgs/LaserScan``): the stamp of its first beam (integer
  nanoseconds since the scan's start), ranges (float32 values; NaN without a
  return, the reason in ``status``), intensities (float32 or none);
- the sensor's beam grid as LaserScan carries it: ``angle_min`` and
  ``angle_increment`` (float32), ``time_increment`` (float32, beam to beam);
- the turntable encoder's readings (``sensor_msgs/JointState``: stamp in
  nanoseconds, angle float64) and, per line, the commanded angle (step scans);
- the sensor's pose (a TF transform: translation and quaternion, from which
  ``T_base_lidar`` is derived);
- how the reconstruction turns readings into a turntable angle per beam
  (``angle_mode``);
- when simulated, the ground truth: the true turntable angle of every beam, and
  what each beam hit (:class:`~plantsim.rig.scene.HitClass`, MuJoCo geom id).

Reconstruction into a point cloud is :mod:`plantsim.cloud.reconstruct`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from plantsim.rig.scene import HitClass
from plantsim.sensor.spec import BeamStatus, LidarSpec
from plantsim.timestamps import ns_to_s, s_to_ns  # noqa: F401 (part of this module's surface)
from plantsim.transforms import T_from_translation_quat_xyzw, translation_quat_xyzw

# How the reconstruction knows the turntable angle of a beam.
ANGLE_MODES = {
    "interpolate": "encoder readings interpolated linearly to each beam's time (de-skew)",
    "line": "the encoder reading interpolated to the line's first beam, held for the whole line",
    "commanded": "the angle the table was commanded to for the line (a rig that trusts its motor)",
}


@dataclasses.dataclass(frozen=True)
class BeamGrid:
    """A 2D LiDAR's beams as a ``sensor_msgs/LaserScan`` describes them.

    Attributes:
      angle_min_rad: beam 0's angle, lidar frame (a float32 value).
      angle_increment_rad: angle between beams (a float32 value).
      time_increment_s: time between beams (a float32 value).
      n_beams: beams per line.
      scan_period_s: time between lines of a free-running sensor (LaserScan ``scan_time``).
      range_min_m, range_max_m: the sensor's range limits.
    """

    angle_min_rad: float
    angle_increment_rad: float
    time_increment_s: float
    n_beams: int
    scan_period_s: float
    range_min_m: float
    range_max_m: float

    @classmethod
    def of(cls, lidar: LidarSpec) -> "BeamGrid":
        """The grid of a sensor, rounded to what a LaserScan message can carry."""
        offsets = lidar.beam_time_offsets_s()
        step_s = (offsets[1] - offsets[0]) if lidar.n_beams > 1 else lidar.scan_period_s
        f32 = lambda x: float(np.float32(x))  # noqa: E731 (LaserScan's fields are float32)
        return cls(angle_min_rad=f32(math.radians(lidar.angle_min_deg)),
                   angle_increment_rad=f32(math.radians(lidar.angle_increment_deg)),
                   time_increment_s=f32(step_s), n_beams=int(lidar.n_beams),
                   scan_period_s=f32(lidar.scan_period_s), range_min_m=f32(lidar.range_min_m),
                   range_max_m=f32(lidar.range_max_m))

    def beam_angles_rad(self) -> np.ndarray:
        """(n_beams,) float64, radians, lidar frame."""
        return self.angle_min_rad + self.angle_increment_rad * np.arange(self.n_beams)

    def beam_offsets_s(self) -> np.ndarray:
        """(n_beams,) float64: each beam's time after the line's first beam, s."""
        return self.time_increment_s * np.arange(self.n_beams)


def lidar_pose_of(T_base_lidar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sensor's pose as a TF transform carries it: translation (3,) and quaternion (x, y, z, w)."""
    return translation_quat_xyzw(T_base_lidar)


@dataclasses.dataclass(frozen=True, eq=False)
class RawScan:
    """Everything the sensor and turntable produced, one row per scan line.

    Attributes:
      grid: the beam grid.
      line_stamp_ns: (n_lines,) int64, each line's first beam, ns since the scan's start.
      range_m: (n_lines, n_beams) float64 (float32 values), metres; NaN unless OK.
      status: (n_lines, n_beams) uint8 :class:`BeamStatus`.
      intensity: (n_lines, n_beams) float32 in [0, 1] (NaN without echo), or None.
      encoder_stamp_ns: (n_readings,) int64, increasing, ns since the scan's start.
      encoder_angle_rad: (n_readings,) float64, the readings (unwrapped).
      commanded_rad: (n_lines,) float64, the commanded angle per line (NaN when
        the table was not stepped, as in continuous scans).
      angle_mode: one of :data:`ANGLE_MODES`.
      lidar_pose: (translation (3,) metres, quaternion (x, y, z, w)) of the
        sensor in the base frame, as TF carries it (:func:`lidar_pose_of`).
      true_turntable_angle_rad: (n_lines, n_beams) float64, the angle each beam
        was really cast at, or None (a real scan has no ground truth).
      hit_class: (n_lines, n_beams) uint8 :class:`HitClass` of the first surface
        along the beam (NONE for a real sensor).
      geom_id: (n_lines, n_beams) int32, MuJoCo geom id or -1.
      start_unix_ns: absolute time of the scan's start (0 for a simulated scan).
      encoder_offset_rad: the encoder's reading at turntable angle 0; subtracted
        from readings and commanded angles to give turntable angles.
    """

    grid: BeamGrid
    line_stamp_ns: np.ndarray
    range_m: np.ndarray
    status: np.ndarray
    intensity: np.ndarray | None
    encoder_stamp_ns: np.ndarray
    encoder_angle_rad: np.ndarray
    commanded_rad: np.ndarray
    angle_mode: str
    lidar_pose: tuple
    true_turntable_angle_rad: np.ndarray | None = None
    hit_class: np.ndarray | None = None
    geom_id: np.ndarray | None = None
    start_unix_ns: int = 0
    encoder_offset_rad: float = 0.0

    def __post_init__(self):
        if self.angle_mode not in ANGLE_MODES:
            raise ValueError(f"angle_mode must be one of {', '.join(ANGLE_MODES)}, got {self.angle_mode!r}")
        shape = self.range_m.shape
        if len(shape) != 2 or shape[1] != self.grid.n_beams:
            raise ValueError(f"range_m must be (n_lines, {self.grid.n_beams}), got {shape}")
        if self.hit_class is None:
            object.__setattr__(self, "hit_class", np.full(shape, HitClass.NONE, dtype=np.uint8))
        if self.geom_id is None:
            object.__setattr__(self, "geom_id", np.full(shape, -1, dtype=np.int32))
        for name in ("status", "hit_class", "geom_id"):
            if getattr(self, name).shape != shape:
                raise ValueError(f"{name} must have the shape of range_m {shape}, "
                                 f"got {getattr(self, name).shape}")
        if len(self.line_stamp_ns) != shape[0] or len(self.commanded_rad) != shape[0]:
            raise ValueError("line_stamp_ns and commanded_rad need one entry per line")
        if len(self.encoder_stamp_ns) != len(self.encoder_angle_rad):
            raise ValueError("encoder_stamp_ns and encoder_angle_rad must have the same length")
        if self.angle_mode != "commanded" and shape[0] and len(self.encoder_stamp_ns) == 0:
            raise ValueError(f"angle_mode {self.angle_mode!r} needs encoder readings, and there are none")

    @property
    def T_base_lidar(self) -> np.ndarray:
        """(4, 4) float64, the sensor's pose in the base frame."""
        return T_from_translation_quat_xyzw(*self.lidar_pose)

    @property
    def n_lines(self) -> int:
        return int(self.range_m.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.range_m.shape[1])

    @property
    def beam_angle_rad(self) -> np.ndarray:
        """(n_beams,) float64, radians, lidar frame."""
        return self.grid.beam_angles_rad()

    @property
    def line_time_s(self) -> np.ndarray:
        """(n_lines,) float64: each line's first beam, s since the scan's start."""
        return ns_to_s(self.line_stamp_ns)

    @property
    def time_s(self) -> np.ndarray:
        """(n_lines, n_beams) float64: each beam's time, s since the scan's start."""
        return self.line_time_s[:, None] + self.grid.beam_offsets_s()[None, :]

    def time_s_at(self, lines: np.ndarray, beams: np.ndarray) -> np.ndarray:
        """(k,) float64: ``time_s[lines, beams]``, bit for bit, computed for those beams only."""
        return self.line_time_s[lines] + self.grid.beam_offsets_s()[beams]

    @property
    def encoder_time_s(self) -> np.ndarray:
        return ns_to_s(self.encoder_stamp_ns)

    @property
    def turntable_angle_rad(self) -> np.ndarray:
        """(n_lines, n_beams) float64: the angle the reconstruction uses for each beam."""
        return believed_angles(self)

    def counts(self) -> dict:
        """Beams by status and returns by hit class, for the sidecar."""
        ok = self.status == BeamStatus.OK
        # One pass each (codes are small non-negative ints); codes outside the enums are not counted.
        by_status = np.bincount(self.status.ravel(), minlength=max(BeamStatus) + 1)
        by_class = np.bincount(self.hit_class[ok], minlength=max(HitClass) + 1)
        return {
            "beams": int(self.status.size),
            "returns": int(ok.sum()),
            "by_status": {s.name.lower(): int(by_status[s]) for s in BeamStatus},
            "returns_by_class": {c.name.lower(): int(by_class[c]) for c in HitClass if c != HitClass.NONE},
        }

    def replace(self, **changes) -> "RawScan":
        return dataclasses.replace(self, **changes)


def believed_angles(raw: RawScan, lines: np.ndarray | None = None, beams: np.ndarray | None = None
                    ) -> np.ndarray:
    """What the rig believes the turntable angle of every beam was (see :data:`ANGLE_MODES`).

    Args:
      raw: the raw record.
      lines, beams: (k,) int indices of the beams wanted (e.g. ``np.nonzero`` of the
        returns); None for every beam. The values are those of the full grid at
        those beams, bit for bit, at the cost of the beams asked for.

    Returns:
      (n_lines, n_beams) float64, radians; or (k,) for ``lines, beams``.
    """
    if (lines is None) != (beams is None):
        raise ValueError("give both lines and beams, or neither")
    offset = raw.encoder_offset_rad
    if raw.angle_mode == "commanded":
        per_line = raw.commanded_rad - offset
    else:
        t_read, angle = raw.encoder_time_s, raw.encoder_angle_rad - offset
        if raw.angle_mode == "line":
            per_line = np.interp(raw.line_time_s, t_read, angle)
        elif lines is None:
            return np.interp(raw.time_s, t_read, angle)
        else:
            return np.interp(raw.time_s_at(lines, beams), t_read, angle)
    if lines is None:
        return np.broadcast_to(per_line[:, None], raw.range_m.shape).copy()
    return per_line[lines]
