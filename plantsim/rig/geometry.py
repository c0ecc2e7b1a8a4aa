"""Rig geometry: where the LiDAR sits relative to the turntable.

Frames (all right-handed, metres):

- ``base``: fixed to the bench. Origin on the turntable axis at the disk top,
  +Z up along the axis, +X horizontal towards the LiDAR. It is MuJoCo's world
  frame in plantsim's scenes.
- ``turntable``: fixed to the disk and the plant. It coincides with ``base`` at
  turntable angle 0 and turns with the disk: ``T_base_turntable = Rz(theta)``,
  positive theta counter-clockwise seen from above (right hand about +Z).
  Undoing the turntable is therefore ``Rz(-theta)``; the original ROS/Gazebo
  tool used ``Rz(+theta)`` and mirrored every plant.
- ``lidar``: see :mod:`plantsim.sensor.spec`. With tilt, yaw and roll at zero the
  sensor's +X (beam angle 0) points horizontally at the axis (base -X), its +Y
  (positive beam angles) points up (base +Z), and the scan plane is the
  vertical plane through the axis.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from plantsim.transforms import make_T, rot_x, rot_z

# Lidar axes expressed in the base frame at zero tilt/yaw/roll (columns): +X to
# the axis, +Y up, +Z = X cross Y.
_R_BASE_LIDAR0 = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]).T


@dataclasses.dataclass(frozen=True, kw_only=True)
class RigGeometry:
    """Where the LiDAR is mounted, and the size of the turntable.

    Attributes:
      lidar_distance_m: horizontal distance from the turntable axis to the
        LiDAR's optical centre.
      lidar_height_m: height of the optical centre above the disk top.
      tilt_deg: boresight elevation: the fan turned within its own plane,
        positive up (rotation about the lidar's +Z).
      yaw_deg: the sensor turned about the vertical through its optical centre,
        positive counter-clockwise from above; non-zero moves the scan plane
        off the axis by ``lidar_distance_m * sin(yaw)``.
      roll_deg: the scan plane leaned about the boresight (rotation about the
        lidar's +X), positive by the right hand rule.
      disk_radius_m: turntable disk radius.
      disk_thickness_m: turntable disk thickness (its top is at z = 0).
      pedestal_height_m: height of the servo housing under the disk; the bench
        top is this far below the disk's underside.
      encoder_offset_deg: what the turntable's encoder reads with the table at
        angle 0 (its zero is not the plant's): the reconstruction subtracts it
        from every reading and commanded angle. A simulated encoder reads it too,
        so it changes no simulated cloud; on a real rig it is what calibration
        (:func:`plantsim.cloud.calibration.calibrate`) measures.
    """

    lidar_distance_m: float = 0.35
    lidar_height_m: float = 0.15
    tilt_deg: float = 0.0
    yaw_deg: float = 0.0
    roll_deg: float = 0.0
    disk_radius_m: float = 0.10
    disk_thickness_m: float = 0.01
    pedestal_height_m: float = 0.07
    encoder_offset_deg: float = 0.0

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"rig {field.name} must be a finite number, got {value!r}")
        for field in ("disk_radius_m", "disk_thickness_m", "pedestal_height_m"):
            if getattr(self, field) <= 0:
                raise ValueError(f"rig {field} must be > 0, got {getattr(self, field)}")
        if self.lidar_distance_m <= self.disk_radius_m:
            raise ValueError(
                f"lidar_distance_m ({self.lidar_distance_m} m) must exceed disk_radius_m "
                f"({self.disk_radius_m} m): the sensor would sit on the turntable")
        if self.lidar_height_m <= -self.pedestal_height_m - self.disk_thickness_m:
            raise ValueError(
                f"lidar_height_m ({self.lidar_height_m} m) puts the sensor below the bench top")

    def T_base_lidar(self) -> np.ndarray:
        """The LiDAR's pose in the base frame. Returns (4, 4) float64."""
        R = (rot_z(math.radians(self.yaw_deg)) @ _R_BASE_LIDAR0
             @ rot_z(math.radians(self.tilt_deg)) @ rot_x(math.radians(self.roll_deg)))
        return make_T(R, [self.lidar_distance_m, 0.0, self.lidar_height_m])

    def replace(self, **changes) -> "RigGeometry":
        return dataclasses.replace(self, **changes)


def beam_dirs_lidar(beam_angles_rad: np.ndarray) -> np.ndarray:
    """Unit beam directions in the lidar frame.

    Args:
      beam_angles_rad: (n,) float64, radians.

    Returns:
      (n, 3) float64, unit vectors in the lidar X-Y plane.
    """
    a = np.asarray(beam_angles_rad, dtype=np.float64)
    return np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
