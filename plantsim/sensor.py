"""2D LiDAR sensor specifications and the per-beam status codes.

A :class:`LidarSpec` says what the sensor is (its angular grid, range limits,
timing); where it sits on the rig is :class:`plantsim.rig.RigGeometry`.

Lidar frame: origin at the optical centre; +X is the beam at angle 0 (the
"front" step); beams lie in the X-Y plane and a positive beam angle turns from
+X towards +Y (counter-clockwise about +Z). On the rig the sensor is mounted on
its side so that +Y points up: positive beam angles point up.
"""

from __future__ import annotations

import dataclasses
import enum
import math

import numpy as np


class BeamStatus(enum.IntEnum):
    """Why a beam has, or has not, a range (kept per beam in the raw record).

    The codes with a Hokuyo counterpart name it; a miss is always recorded as a
    status, never as a point.
    """

    OK = 0
    NO_ECHO = 1  # nothing within range_max_m (the sensor reports "no object").
    TOO_NEAR = 2  # first surface closer than range_min_m (URG error code 0-ish region).
    LOW_INTENSITY = 3  # too little received energy (URG error codes 1-2).
    EDGE = 4  # preceding/succeeding step error at edges (URG error code 7).


@dataclasses.dataclass(frozen=True, kw_only=True)
class LidarSpec:
    """What a 2D scanning LiDAR is: angular grid, range limits, timing.

    Attributes:
      name: preset or user name.
      n_beams: beams per scan line.
      angle_min_deg: beam angle of beam 0, degrees, lidar frame.
      angle_increment_deg: angle between neighbouring beams, degrees (> 0).
      range_min_m: shortest range the sensor reports; a nearer first surface is
        no return (TOO_NEAR), never a clamped point.
      range_max_m: longest range it reports; beyond is NO_ECHO.
      scan_period_s: time of one mirror turn (one scan line).
      steps_per_rev: angular steps of the encoder in one mirror turn; beam i is
        taken at ``t0 + (first_step + i) / steps_per_rev * scan_period_s``,
        t0 being the line's time stamp (step 0).
      first_step: mirror step of beam 0.
    """

    name: str = "custom"
    n_beams: int
    angle_min_deg: float
    angle_increment_deg: float
    range_min_m: float
    range_max_m: float
    scan_period_s: float
    steps_per_rev: int | None = None
    first_step: int = 0

    def __post_init__(self):
        if int(self.n_beams) != self.n_beams or self.n_beams < 1:
            raise ValueError(f"n_beams must be a positive integer, got {self.n_beams!r}")
        for field in ("angle_min_deg", "angle_increment_deg", "range_min_m", "range_max_m",
                      "scan_period_s"):
            value = getattr(self, field)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{field} must be a finite number, got {value!r}")
        if self.angle_increment_deg <= 0:
            raise ValueError(
                f"angle_increment_deg must be > 0, got {self.angle_increment_deg}")
        if (self.n_beams - 1) * self.angle_increment_deg > 360.0 + 1e-9:
            raise ValueError(
                f"field of view (n_beams - 1) * angle_increment_deg = "
                f"{(self.n_beams - 1) * self.angle_increment_deg:g} deg exceeds 360 deg")
        if self.range_min_m < 0:
            raise ValueError(f"range_min_m must be >= 0, got {self.range_min_m}")
        if self.range_min_m >= self.range_max_m:
            raise ValueError(
                f"range_min_m must be less than range_max_m, got range_min_m="
                f"{self.range_min_m} and range_max_m={self.range_max_m}")
        if self.scan_period_s <= 0:
            raise ValueError(f"scan_period_s must be > 0, got {self.scan_period_s}")
        if self.steps_per_rev is not None:
            if int(self.steps_per_rev) != self.steps_per_rev or self.steps_per_rev < 1:
                raise ValueError(
                    f"steps_per_rev must be a positive integer or None, got {self.steps_per_rev!r}")
            if self.first_step < 0 or self.first_step + self.n_beams > self.steps_per_rev:
                raise ValueError(
                    f"first_step + n_beams must fit in steps_per_rev={self.steps_per_rev}, got "
                    f"first_step={self.first_step}, n_beams={self.n_beams}")

    @property
    def fov_deg(self) -> float:
        """Angle from the first to the last beam, degrees."""
        return (self.n_beams - 1) * self.angle_increment_deg

    def beam_angles_rad(self) -> np.ndarray:
        """Beam angles in the lidar frame. Returns (n_beams,) float64, radians."""
        return np.deg2rad(self.angle_min_deg + self.angle_increment_deg * np.arange(self.n_beams))

    def beam_time_offsets_s(self) -> np.ndarray:
        """Time of each beam after the line's time stamp. Returns (n_beams,) float64, s.

        With an angular encoder (``steps_per_rev``) beam i is taken at step
        ``first_step + i`` of the mirror turn (URG-04LX SCIP 2.0 manual: step k
        at t0 + k/1024 x 100 ms). Without one, the beams are spread over the
        field of view's share of a turn.
        """
        if self.steps_per_rev is not None:
            steps = self.first_step + np.arange(self.n_beams)
            return steps / self.steps_per_rev * self.scan_period_s
        return np.arange(self.n_beams) * (self.angle_increment_deg / 360.0) * self.scan_period_s

    def replace(self, **changes) -> "LidarSpec":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


# Hokuyo URG-04LX-UG01, from the SCIP 2.0 "PP" parameters: DMIN 20 mm,
# DMAX 5600 mm, ARES 1024 steps/turn, AMIN 44, AMAX 725, AFRT 384, SCAN 600 rpm
# (../shared/notes/sensor-hokuyo-urg04lx.md). Beam 0 is step 44, i.e.
# (44 - 384) x 360/1024 = -119.53 deg from the front. The notes give both
# "AMIN 44 .. AMAX 725" (682 steps) and "682 intervals, 683 beams" (239.77 deg);
# we keep the 683 beams the field of view and the benchmark name, so
# the last beam is step 726 at +120.23 deg.
URG_04LX_UG01 = LidarSpec(
    name="urg-04lx-ug01",
    n_beams=683,
    angle_min_deg=(44 - 384) * 360.0 / 1024,
    angle_increment_deg=360.0 / 1024,
    range_min_m=0.020,
    range_max_m=5.600,
    scan_period_s=0.100,
    steps_per_rev=1024,
    first_step=44,
)

PRESETS: dict[str, LidarSpec] = {URG_04LX_UG01.name: URG_04LX_UG01}


def lidar_preset(name: str) -> LidarSpec:
    """Looks up a preset by name (case-insensitive)."""
    key = name.strip().lower()
    if key not in PRESETS:
        raise ValueError(f"unknown LiDAR preset {name!r}; valid presets: {', '.join(sorted(PRESETS))}")
    return PRESETS[key]
