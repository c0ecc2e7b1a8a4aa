"""The raw record of a scan: every beam of every line, misses included.

Reconstruction into a point cloud is :mod:`plantsim.cloud.reconstruct`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from plantsim.rig.scene import HitClass
from plantsim.sensor.spec import BeamStatus


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
