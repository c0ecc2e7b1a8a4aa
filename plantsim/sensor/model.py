"""A LiDAR that behaves like the real one: footprint, noise, intensity, dropouts.

The sensor's own numbers (divergence, accuracy, resolution, detection
threshold) are in its :class:`plantsim.sensor.LidarSpec` preset; this module
holds what the simulation does with them (:class:`SensorModel`, TOML section
``[sensor_model]``) and the scan that applies them
(:func:`realistic_step_and_shoot`). Each effect can be switched off; the
run's ``ideal`` flag bypasses this module altogether (perfect geometry).

Per beam, in order:

1. Footprint: sub-rays (:mod:`plantsim.beam`) are cast with surface normals;
   their returns combine into one range (power-weighted: mixed pixels), one
   received power and one mean incidence.
2. Dropouts: no sub-ray echo is NO_ECHO; a received power below the sensor's
   threshold is LOW_INTENSITY (URG error codes 1-2); a footprint spread over
   more than ``edge_range_spread_m`` is EDGE (URG error code 7).
3. Range noise: Gaussian, sigma(r, theta) from :func:`range_sigma`.
4. Quantisation to the sensor's range resolution.
5. Range limits on the measured range: below ``range_min_m`` is TOO_NEAR,
   beyond ``range_max_m`` NO_ECHO. Never a clamped point.

Intensity (received power) is kept for every beam with an echo.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from plantsim.rig.scene import HitClass
from plantsim.sensor.spec import BeamStatus, LidarSpec

log = logging.getLogger(__name__)

# Beyond 80 degrees of incidence the noise law is held constant (at most
# 5.8 times the head-on sigma for gain 1); most such grazing returns are
# dropped by the power threshold anyway.
COS_INCIDENCE_FLOOR = math.cos(math.radians(80.0))


@dataclasses.dataclass(frozen=True, kw_only=True)
class SensorModel:
    """Which sensor imperfections a (non-ideal) scan simulates, and the scene's reflectances.

    TOML section ``[sensor_model]``.

    Attributes:
      range_noise: add Gaussian range noise (:func:`range_sigma`).
      quantise: round ranges to the sensor's ``range_resolution_m``.
      footprint_rings: rings of sub-rays across the beam footprint
        (0: one ray, 1: 7, 2: 19, 3: 37); the quality setting of mixed pixels.
      adaptive_footprint: cast the full footprint only where its probe rays
        (axis + 4 outer) do not land on one flat surface; elsewhere the axis
        ray stands for the whole footprint. False casts every sub-ray of every
        beam (the reference; several times slower).
      flat_tolerance_m: how far a probe's hit may lie off the axis hit's
        tangent plane for the footprint to count as flat, metres.
      intensity: record the received power as intensity.
      dropouts: drop weak returns (LOW_INTENSITY) and spread footprints (EDGE).
      reflectance_plant: Lambertian reflectance of the plant at the laser's
        wavelength. 0.5: green leaves reflect about half of near-infrared
        light (the NIR plateau, 750-1300 nm; Jacquemoud and Baret 1990, PROSPECT).
      reflectance_turntable: of the turntable disk (0.5: assumed grey plastic).
      reflectance_rig: of the bench, post and pedestal (0.2: assumed dark
        painted or anodised metal).
      saturation_range_m: the receiver saturates (intensity 1) for a white
        target seen head-on nearer than this; intensity is
        ``min(1, power * saturation_range_m^2)``.
    """

    range_noise: bool = True
    quantise: bool = True
    footprint_rings: int = 2
    adaptive_footprint: bool = True
    flat_tolerance_m: float = 0.002
    intensity: bool = True
    dropouts: bool = True
    reflectance_plant: float = 0.5
    reflectance_turntable: float = 0.5
    reflectance_rig: float = 0.2
    saturation_range_m: float = 0.1

    def __post_init__(self):
        for field in ("range_noise", "quantise", "adaptive_footprint", "intensity", "dropouts"):
            if not isinstance(getattr(self, field), bool):
                raise ValueError(f"{field} must be true or false, got {getattr(self, field)!r}")
        rings = self.footprint_rings
        if isinstance(rings, bool) or not isinstance(rings, int) or not 0 <= rings <= 10:
            raise ValueError(f"footprint_rings must be an integer from 0 to 10, got {rings!r}")
        for field in ("reflectance_plant", "reflectance_turntable", "reflectance_rig"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not 0.0 <= value <= 1.0):
                raise ValueError(f"{field} must be a number in [0, 1], got {value!r}")
        for field in ("flat_tolerance_m", "saturation_range_m"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value <= 0):
                raise ValueError(f"{field} must be a finite number > 0, got {value!r}")

    @classmethod
    def off(cls) -> "SensorModel":
        """Every effect off: one ray per beam, exact ranges, no intensity."""
        return cls(range_noise=False, quantise=False, footprint_rings=0, intensity=False,
                   dropouts=False)

    def reflectance_by_class(self) -> np.ndarray:
        """(len(HitClass),) float64 reflectance indexed by :class:`HitClass` (NONE: 0)."""
        table = np.zeros(len(HitClass))
        table[HitClass.PLANT] = self.reflectance_plant
        table[HitClass.TURNTABLE] = self.reflectance_turntable
        table[HitClass.RIG] = self.reflectance_rig
        return table


def range_sigma(range_m: np.ndarray, cos_incidence: np.ndarray, lidar: LidarSpec) -> np.ndarray:
    """Standard deviation of the range noise.

    sigma = max(range_sigma_m, range_sigma_rel * r) * (1 + gain * (1/cos(theta) - 1))

    The first factor is the datasheet's accuracy bands (URG-04LX: +-30 mm to
    1 m, 3 % of range beyond); the second makes the noise grow as the return
    weakens with incidence (1/cos law at gain 1; Soudarissanane et al. 2009).
    cos(theta) is floored at :data:`COS_INCIDENCE_FLOOR`.

    Args:
      range_m: (...) float64 metres.
      cos_incidence: (...) float64 in [0, 1].
      lidar: the sensor's noise parameters.

    Returns:
      (...) float64 metres.
    """
    r = np.asarray(range_m, dtype=np.float64)
    cos = np.maximum(np.asarray(cos_incidence, dtype=np.float64), COS_INCIDENCE_FLOOR)
    base = np.maximum(lidar.range_sigma_m, lidar.range_sigma_rel * r)
    return base * (1.0 + lidar.range_sigma_incidence_gain * (1.0 / cos - 1.0))


def intensity_from_power(power: np.ndarray, model: SensorModel) -> np.ndarray:
    """Received power (m^-2) to intensity in [0, 1]; 1 is receiver saturation."""
    return np.minimum(1.0, power * model.saturation_range_m ** 2)


def apply_sensor(range_m: np.ndarray, power: np.ndarray, cos_incidence: np.ndarray,
                 spread_m: np.ndarray, lidar: LidarSpec, model: SensorModel,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Dropouts, noise, quantisation and range limits on combined footprint returns.

    Args:
      range_m: (n_lines, n_beams) float64 metres, combined true range, NaN: no echo.
      power: (n_lines, n_beams) float64 received power, m^-2.
      cos_incidence: (n_lines, n_beams) float64, mean cos(incidence).
      spread_m: (n_lines, n_beams) float64, footprint range spread, metres.
      lidar: the sensor.
      model: which effects.
      rng: the run's generator; with range noise on, exactly one
        ``standard_normal((n_lines, n_beams))`` draw is taken from it.

    Returns:
      range_m (NaN unless OK), status uint8 :class:`BeamStatus`, and intensity
      (float32 in [0, 1], NaN without echo) or None when intensity is off.
    """
    echo = np.isfinite(range_m)
    status = np.where(echo, BeamStatus.OK, BeamStatus.NO_ECHO).astype(np.uint8)
    if model.dropouts:
        if lidar.detection_range_white_m is not None:
            # The weakest return the sensor ranges on: a white Lambertian target
            # head-on at detection_range_white_m, P = 1 / d^2.
            weak = echo & (power < 1.0 / lidar.detection_range_white_m ** 2)
            status[weak] = BeamStatus.LOW_INTENSITY
        if lidar.edge_range_spread_m is not None:
            status[(status == BeamStatus.OK) & (spread_m > lidar.edge_range_spread_m)] = BeamStatus.EDGE
    measured = np.where(echo, range_m, 0.0)
    if model.range_noise:
        z = rng.standard_normal(measured.shape)
        measured = measured + range_sigma(measured, np.where(echo, cos_incidence, 1.0), lidar) * z
    if model.quantise and lidar.range_resolution_m > 0:
        measured = np.round(measured / lidar.range_resolution_m) * lidar.range_resolution_m
    ok = status == BeamStatus.OK
    status[ok & (measured < lidar.range_min_m)] = BeamStatus.TOO_NEAR
    status[ok & (measured > lidar.range_max_m)] = BeamStatus.NO_ECHO
    range_out = np.where(status == BeamStatus.OK, measured, np.nan)
    intensity = None
    if model.intensity:
        intensity = np.where(echo, intensity_from_power(power, model), np.nan).astype(np.float32)
    return range_out, status, intensity




