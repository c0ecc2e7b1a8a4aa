"""A flat target in the scan plane: the geometry of a calibration recording, and its simulation.

The classic way to characterise a 2D LiDAR (Ye and Borenstein 2002; Kneip et
al. 2009; Okubo et al. 2009) is to point it at a flat plate at known distances
and angles and record many scans. A plate seen by beam angle ``a`` has, in the
lidar frame, the line ``x cos(phi) + y sin(phi) = d`` (``d`` its perpendicular
distance from the optical centre, ``phi`` the beam angle of its normal); the
beam meets it at the true range

    r(a) = d / cos(a - phi),    cos(incidence) = cos(a - phi),

while ``|d tan(a - phi) - c|`` is within the plate's half-width ``w`` of its
centre offset ``c`` (measured along the plate from the foot of the
perpendicular).

:func:`simulate_flat_target` runs the sensor model on that geometry, so a
fit (:mod:`plantsim.sensor.fit`) can be tested against known parameters and
the validation tables (``scripts/sensor_validation.py``) come from the same
code a scan uses.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from plantsim.sensor.model import SensorModel, apply_sensor, received_power
from plantsim.sensor.spec import BeamStatus, LidarSpec


def _per_line(name: str, value, n_lines: int) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(n_lines, float(arr))
    if arr.shape != (n_lines,):
        raise ValueError(f"{name} must be a number or an array of shape ({n_lines},), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class FlatTarget:
    """Where a flat plate stood for each line of a recording (lidar frame, scan plane).

    Attributes:
      distance_m: (n_lines,) float64, perpendicular distance from the optical
        centre to the plate's plane, metres (> 0).
      normal_angle_rad: (n_lines,) float64, beam angle of the plate's normal
        (the beam that meets it head-on), radians.
      half_width_m: (n_lines,) float64, half the plate's width along the scan
        plane, metres (> 0).
      center_offset_m: (n_lines,) float64, the plate centre's offset along the
        plate from the foot of the perpendicular, metres (0: the normal beam
        hits the centre; a plate turned by ``t`` about its centre at range
        ``R`` has ``d = R cos t``, ``phi = t``, offset ``-R sin t``).
      reflectance: (n_lines,) float64 in [0, 1], the plate's Lambertian
        reflectance (matte white paper about 0.9).
    """

    distance_m: np.ndarray
    normal_angle_rad: np.ndarray
    half_width_m: np.ndarray
    center_offset_m: np.ndarray
    reflectance: np.ndarray

    @classmethod
    def make(cls, n_lines: int, *, distance_m, normal_angle_rad=0.0, half_width_m=0.25,
             center_offset_m=0.0, reflectance=0.9) -> "FlatTarget":
        """A target from scalars or per-line arrays (each broadcast to ``n_lines``)."""
        return cls(distance_m=_per_line("distance_m", distance_m, n_lines),
                   normal_angle_rad=_per_line("normal_angle_rad", normal_angle_rad, n_lines),
                   half_width_m=_per_line("half_width_m", half_width_m, n_lines),
                   center_offset_m=_per_line("center_offset_m", center_offset_m, n_lines),
                   reflectance=_per_line("reflectance", reflectance, n_lines))

    def __post_init__(self):
        n = np.asarray(self.distance_m).shape
        if len(n) != 1:
            raise ValueError(f"distance_m must have shape (n_lines,), got shape {n}")
        for field in ("distance_m", "normal_angle_rad", "half_width_m", "center_offset_m",
                      "reflectance"):
            object.__setattr__(self, field, _per_line(field, getattr(self, field), n[0]))
        if np.any(self.distance_m <= 0):
            raise ValueError("distance_m must be > 0 on every line")
        if np.any(self.half_width_m <= 0):
            raise ValueError("half_width_m must be > 0 on every line")
        if np.any((self.reflectance < 0) | (self.reflectance > 1)):
            raise ValueError("reflectance must be in [0, 1] on every line")

    @property
    def n_lines(self) -> int:
        return len(self.distance_m)

    def truth(self, beam_angles_rad: np.ndarray, *, edge_margin_m: float = 0.0
              ) -> tuple[np.ndarray, np.ndarray]:
        """True range and cos(incidence) of every beam on the plate.

        Args:
          beam_angles_rad: (n_beams,) float64 radians, lidar frame.
          edge_margin_m: also leave out beams within this distance of the
            plate's edges (their footprints straddle the edge: mixed pixels).

        Returns:
          range_m (n_lines, n_beams) float64 metres, NaN off the plate;
          cos_incidence (n_lines, n_beams) float64 (NaN off the plate).
        """
        a = np.asarray(beam_angles_rad, dtype=np.float64)[None, :]
        rel = a - self.normal_angle_rad[:, None]
        cos = np.cos(rel)
        along = self.distance_m[:, None] * np.tan(np.where(cos > 1e-9, rel, 0.0))
        on = (cos > 1e-9) & (np.abs(along - self.center_offset_m[:, None])
                             <= self.half_width_m[:, None] - edge_margin_m)
        range_m = np.where(on, self.distance_m[:, None] / np.where(on, cos, 1.0), np.nan)
        return range_m, np.where(on, cos, np.nan)


def simulate_flat_target(target: FlatTarget, beam_angles_rad: np.ndarray, line_time_s: np.ndarray,
                         lidar: LidarSpec, model: SensorModel, rng: np.random.Generator
                         ) -> tuple[np.ndarray, np.ndarray]:
    """What the sensor model reports for a flat target (nothing else in view).

    One ray per beam (a footprint wholly on a plane returns its axis range;
    beams near the plate's edges are the fit's to leave out). The model's
    ``power_on_age_s`` is the time since power-on of line 0.

    Args:
      target: the plate per line.
      beam_angles_rad: (n_beams,) float64 radians.
      line_time_s: (n_lines,) float64, seconds since the recording's first line.
      lidar: the sensor (its noise, bias and drift parameters).
      model: which effects.
      rng: the generator (one normal draw of (n_lines, n_beams) with noise on).

    Returns:
      range_m (n_lines, n_beams) float64, NaN unless OK; status uint8 BeamStatus.
    """
    true, cos = target.truth(beam_angles_rad)
    rho = np.broadcast_to(target.reflectance[:, None], true.shape)
    power = np.where(np.isfinite(true), received_power(np.nan_to_num(true, nan=1.0),
                                                       np.nan_to_num(cos), rho), 0.0)
    range_m, status, _ = apply_sensor(true, power, cos, np.zeros(true.shape), lidar,
                                      dataclasses.replace(model, intensity=False), rng,
                                      reflectance=rho, line_time_s=np.asarray(line_time_s, float))
    status = np.where(np.isfinite(true) | (status != BeamStatus.NO_ECHO), status, BeamStatus.NO_ECHO)
    return range_m, status.astype(np.uint8)
