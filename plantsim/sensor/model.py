"""A LiDAR that behaves like the real one: footprint, noise, bias, drift, intensity, dropouts.

The sensor's own numbers (divergence, noise, bias, drift, resolution, detection
threshold) are in its :class:`plantsim.sensor.spec.LidarSpec` preset; this
module holds what the simulation does with them (:class:`SensorModel`, TOML
section ``[sensor_model]``) and applies them to combined footprint returns
(:func:`apply_sensor`). Each effect can be switched off; the run's ``ideal``
flag bypasses this module altogether (perfect geometry).

A datasheet's accuracy band ("+-30 mm") is bias plus noise, so the range error
is split as the physics splits it (Kneip et al., ICRA 2009: the URG-04LX's
accuracy depends on the target and drifts while it warms up, its repeatability
matches a SICK LMS 200; SICK quotes its LMS1xx as +-30 mm systematic and 12 mm
statistical):

    measured = true + bias(unit, reflectance, material) + drift(t) + sigma(P) z

Per beam, in order:

1. Footprint: sub-rays (:mod:`plantsim.sensor.footprint`) are cast with
   surface normals; their returns combine into one range (power-weighted:
   mixed pixels), one received power ``P`` and one mean incidence.
2. Dropouts: no sub-ray echo is NO_ECHO; ``P`` below the sensor's threshold is
   LOW_INTENSITY (URG error codes 1-2); a footprint spread over more than
   ``edge_range_spread_m`` is EDGE (URG error code 7; the threshold is an
   assumption with a knob, see :class:`plantsim.sensor.spec.LidarSpec`).
3. Systematic error (:func:`range_bias`): the unit's offset and scale, a
   reflectance-dependent walk, a per-material offset, and the warm-up drift
   (:func:`warmup_drift`), all deterministic.
4. Random noise: Gaussian, standard deviation a function of the received
   power alone (:func:`range_sigma`), so range, reflectance and incidence act
   through one physical quantity, with a floor, and bounded because a return
   weaker than the detection threshold is dropped, not ranged.
5. Quantisation to the sensor's range resolution.
6. Range limits on the measured range: below ``range_min_m`` is TOO_NEAR,
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

# The "datasheet-band" law only (the worst case): beyond 80 degrees of
# incidence its 1/cos factor is held constant (5.8 times the head-on sigma).
COS_INCIDENCE_FLOOR = math.cos(math.radians(80.0))

_BOOL_FIELDS = ("range_noise", "quantise", "adaptive_footprint", "intensity", "dropouts",
                "systematic_error")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SensorModel:
    """Which sensor imperfections a (non-ideal) scan simulates, and the scene's materials.

    TOML section ``[sensor_model]``.

    Attributes:
      range_noise: add random range noise (:func:`range_sigma`).
      systematic_error: add the systematic range error (:func:`range_bias`):
        the sensor's bias, reflectance walk and warm-up drift, and the
        per-material offsets below.
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
      range_bias_plant_m, range_bias_turntable_m, range_bias_rig_m: a
        material's own range offset, metres, on top of the sensor's
        reflectance walk (Kneip et al. 2009 found the URG-04LX's reading
        depends on material as well as colour; a leaf's near-infrared
        subsurface scattering is one such case). 0: none; fit on your targets.
      power_on_age_s: how long the sensor has been on when the scan's first
        line is taken, seconds; the warm-up drift decays with it
        (:func:`warmup_drift`). The default, an hour, is a warmed-up sensor.
      saturation_range_m: the receiver saturates (intensity 1) for a white
        target seen head-on nearer than this; intensity is
        ``min(1, power * saturation_range_m^2)``.
    """

    range_noise: bool = True
    systematic_error: bool = True
    quantise: bool = True
    footprint_rings: int = 2
    adaptive_footprint: bool = True
    flat_tolerance_m: float = 0.002
    intensity: bool = True
    dropouts: bool = True
    reflectance_plant: float = 0.5
    reflectance_turntable: float = 0.5
    reflectance_rig: float = 0.2
    range_bias_plant_m: float = 0.0
    range_bias_turntable_m: float = 0.0
    range_bias_rig_m: float = 0.0
    power_on_age_s: float = 3600.0
    saturation_range_m: float = 0.1

    def __post_init__(self):
        for field in _BOOL_FIELDS:
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
        for field in ("range_bias_plant_m", "range_bias_turntable_m", "range_bias_rig_m"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value)):
                raise ValueError(f"{field} must be a finite number (metres), got {value!r}")
        age = self.power_on_age_s
        if (isinstance(age, bool) or not isinstance(age, (int, float)) or not math.isfinite(age)
                or age < 0):
            raise ValueError(f"power_on_age_s must be a finite number of seconds >= 0, got {age!r}")

    @classmethod
    def off(cls) -> "SensorModel":
        """Every effect off: one ray per beam, exact ranges, no intensity."""
        return cls(range_noise=False, systematic_error=False, quantise=False, footprint_rings=0,
                   intensity=False, dropouts=False)

    def reflectance_by_class(self) -> np.ndarray:
        """(len(HitClass),) float64 reflectance indexed by :class:`HitClass` (NONE: 0)."""
        table = np.zeros(len(HitClass))
        table[HitClass.PLANT] = self.reflectance_plant
        table[HitClass.TURNTABLE] = self.reflectance_turntable
        table[HitClass.RIG] = self.reflectance_rig
        return table

    def range_bias_by_class(self) -> np.ndarray:
        """(len(HitClass),) float64 material range offset, metres, indexed by :class:`HitClass`."""
        table = np.zeros(len(HitClass))
        table[HitClass.PLANT] = self.range_bias_plant_m
        table[HitClass.TURNTABLE] = self.range_bias_turntable_m
        table[HitClass.RIG] = self.range_bias_rig_m
        return table


def received_power(range_m, cos_incidence, reflectance) -> np.ndarray:
    """Lambertian range equation, P = rho cos(theta) / r^2 (m^-2; 1 for white, head-on, 1 m)."""
    r = np.asarray(range_m, dtype=np.float64)
    return (np.asarray(reflectance, dtype=np.float64) * np.asarray(cos_incidence, dtype=np.float64)
            / np.maximum(r, 1e-6) ** 2)


def weakest_power(lidar: LidarSpec) -> float:
    """The least received power the sensor ranges on, m^-2: a white target head-on at
    ``detection_range_white_m`` (or at ``range_max_m`` without a threshold)."""
    d = lidar.detection_range_white_m if lidar.detection_range_white_m is not None else lidar.range_max_m
    return 1.0 / d ** 2


def white_equivalent_range(power: np.ndarray, lidar: LidarSpec) -> np.ndarray:
    """The range of a white head-on target returning the same power, ``1 / sqrt(P)``, metres.

    Bounded by the detection threshold: a weaker return is dropped
    (LOW_INTENSITY), never ranged, so the noise it implies never grows further.
    """
    p = np.maximum(np.asarray(power, dtype=np.float64), weakest_power(lidar))
    return 1.0 / np.sqrt(p)


def range_sigma(range_m: np.ndarray, cos_incidence: np.ndarray, lidar: LidarSpec, *,
                reflectance: np.ndarray | float = 1.0, power: np.ndarray | None = None
                ) -> np.ndarray:
    """Standard deviation of the random range noise, metres.

    ``noise_law = "received-power"`` (the presets):

        sigma = sqrt(range_sigma_m^2 + (range_sigma_rel * r_eq)^2),
        r_eq = 1 / sqrt(P),  P = rho cos(theta) / r^2

    A phase-measuring rangefinder's phase noise falls with the signal-to-noise
    ratio, and in the shot-noise limit SNR grows as sqrt(P): sigma ~ 1/sqrt(P),
    i.e. linear in range for a white target head-on (the URG-04LX datasheet's
    "+-3 % of range" beyond 1 m has that form). ``r_eq`` is that white target's
    range. Range, reflectance and incidence all act through P; the floor
    ``range_sigma_m`` is the electronics' own jitter (strong returns); the
    detection threshold bounds ``r_eq`` (:func:`white_equivalent_range`), so
    grazing incidence never blows the noise up without limit.

    ``noise_law = "datasheet-band"`` (the worst case, the model before
    issue 10): the datasheet's accuracy band read as one sigma and grown by
    incidence, ``max(range_sigma_m, range_sigma_rel r) (1 + gain (1/cos - 1))``,
    cos floored at :data:`COS_INCIDENCE_FLOOR`; ``power`` and ``reflectance``
    are ignored.

    Args:
      range_m: (...) float64 metres, the true range.
      cos_incidence: (...) float64 in [0, 1].
      lidar: the sensor's noise parameters.
      reflectance: (...) or scalar Lambertian reflectance (received-power law).
      power: (...) received power, m^-2; computed from the three above when None
        (a footprint's combined power is passed here).

    Returns:
      (...) float64 metres.
    """
    r = np.asarray(range_m, dtype=np.float64)
    if lidar.noise_law == "datasheet-band":
        cos = np.maximum(np.asarray(cos_incidence, dtype=np.float64), COS_INCIDENCE_FLOOR)
        base = np.maximum(lidar.range_sigma_m, lidar.range_sigma_rel * r)
        return base * (1.0 + lidar.range_sigma_incidence_gain * (1.0 / cos - 1.0))
    if power is None:
        power = received_power(r, cos_incidence, reflectance)
    r_eq = white_equivalent_range(power, lidar)
    return np.hypot(lidar.range_sigma_m, lidar.range_sigma_rel * r_eq)


def warmup_drift(time_since_power_on_s, lidar: LidarSpec) -> np.ndarray:
    """Range offset while the sensor warms up, metres: ``A exp(-t / tau)``.

    Kneip et al. (ICRA 2009) and the 2022 comparison of the URG-04LX, RPLidar A1
    and UTM-30LX (Sensors 22(15), PMC9333273) both measure a drift of the range
    during the first minutes after power-on that settles as the unit reaches
    its working temperature; a first-order (exponential) settling is the
    simplest law with that shape. A = ``warmup_drift_m``, tau =
    ``warmup_time_constant_s``.

    Args:
      time_since_power_on_s: (...) float64 seconds (>= 0).
      lidar: the sensor.
    """
    t = np.asarray(time_since_power_on_s, dtype=np.float64)
    if lidar.warmup_drift_m == 0.0:
        return np.zeros_like(t)
    return lidar.warmup_drift_m * np.exp(-np.maximum(t, 0.0) / lidar.warmup_time_constant_s)


def range_bias(range_m: np.ndarray, reflectance: np.ndarray | float, lidar: LidarSpec, *,
               time_since_power_on_s: np.ndarray | float = math.inf,
               material_bias_m: np.ndarray | float = 0.0) -> np.ndarray:
    """Systematic range error (measured minus true), metres.

        bias = range_bias_m + range_bias_rel r + range_bias_dark_m (1 - rho)
               + material_bias_m + warmup_drift(t)

    The unit's offset and scale (Okubo, Ye and Borenstein 2009 calibrate the
    URG-04LX with a range-dependent correction of this kind; SICK's "systematic
    error" of the LMS1xx), a walk with the target's reflectance (Kneip et al.
    2009: the reading depends on colour and brightness), a per-material offset
    and the warm-up drift.

    Args:
      range_m: (...) float64 metres, true range.
      reflectance: (...) or scalar in [0, 1].
      lidar: the sensor.
      time_since_power_on_s: (...) or scalar, seconds (inf: warmed up).
      material_bias_m: (...) or scalar, metres.

    Returns:
      (...) float64 metres.
    """
    r = np.asarray(range_m, dtype=np.float64)
    rho = np.clip(np.asarray(reflectance, dtype=np.float64), 0.0, 1.0)
    bias = (lidar.range_bias_m + lidar.range_bias_rel * r + lidar.range_bias_dark_m * (1.0 - rho)
            + np.asarray(material_bias_m, dtype=np.float64))
    t = np.asarray(time_since_power_on_s, dtype=np.float64)
    if lidar.warmup_drift_m != 0.0:
        bias = bias + warmup_drift(np.where(np.isfinite(t), t, 1e300), lidar)
    return np.broadcast_to(bias, np.broadcast_shapes(r.shape, rho.shape, t.shape)).copy()


def range_sigma_at_least(range_m: np.ndarray, lidar: LidarSpec, *, intensity: np.ndarray | None = None,
                         model: SensorModel | None = None) -> np.ndarray:
    """The least standard deviation :func:`range_sigma` can have had at returns a cloud records.

    ``"received-power"``: the power is read back from the intensity
    (:func:`intensity_from_power` is ``min(1, P saturation_range_m^2)``, exact below
    saturation); a missing intensity takes the most power a target can return at that
    range, a white one head-on, ``1 / r^2``, and a saturated one at least the
    saturation's. ``"datasheet-band"``: the
    band at normal incidence, ``max(range_sigma_m, range_sigma_rel r)`` (the incidence is
    not recorded). Either way no return had less noise than this.

    Args:
      range_m: (n,) float64 metres, the measured ranges.
      lidar: the sensor's noise parameters.
      intensity: (n,) intensity in [0, 1] as the sensor model wrote it, or None.
      model: the sensor model that wrote the intensity (its ``saturation_range_m``);
        needed with ``intensity``.

    Returns:
      (n,) float64 metres.
    """
    r = np.maximum(np.asarray(range_m, dtype=np.float64), 1e-6)
    if lidar.noise_law == "datasheet-band":
        return np.maximum(lidar.range_sigma_m, lidar.range_sigma_rel * r)
    power = 1.0 / r ** 2  # a white target head-on: the most power, the least noise
    if intensity is not None:
        if model is None:
            raise ValueError("range_sigma_at_least: an intensity needs the model that wrote it")
        i = np.asarray(intensity, dtype=np.float64)
        below = np.isfinite(i) & (i < 1.0)
        saturated = np.maximum(power, 1.0 / model.saturation_range_m ** 2)
        power = np.where(below, np.where(below, i, 0.0) / model.saturation_range_m ** 2, saturated)
    return range_sigma(r, np.ones_like(r), lidar, power=power)


def intensity_from_power(power: np.ndarray, model: SensorModel) -> np.ndarray:
    """Received power (m^-2) to intensity in [0, 1]; 1 is receiver saturation."""
    return np.minimum(1.0, power * model.saturation_range_m ** 2)


def apparent_reflectance(range_m: np.ndarray, power: np.ndarray, cos_incidence: np.ndarray
                         ) -> np.ndarray:
    """A footprint's power-weighted reflectance, ``P r^2 / cos``, from its combined return.

    Exact for a footprint on one surface; for a mixed pixel, the reflectance a
    single surface at the combined range would need to return the same power.
    """
    cos = np.maximum(np.asarray(cos_incidence, dtype=np.float64), 1e-6)
    rho = np.asarray(power, dtype=np.float64) * np.asarray(range_m, dtype=np.float64) ** 2 / cos
    return np.clip(np.nan_to_num(rho, nan=1.0), 0.0, 1.0)


def apply_sensor(range_m: np.ndarray, power: np.ndarray, cos_incidence: np.ndarray,
                 spread_m: np.ndarray, lidar: LidarSpec, model: SensorModel,
                 rng: np.random.Generator, *, hit_class: np.ndarray | None = None,
                 reflectance: np.ndarray | None = None,
                 line_time_s: np.ndarray | None = None,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Dropouts, systematic error, noise, quantisation and range limits on footprint returns.

    Args:
      range_m: (n_lines, n_beams) float64 metres, combined true range, NaN: no echo.
      power: (n_lines, n_beams) float64 received power, m^-2.
      cos_incidence: (n_lines, n_beams) float64, mean cos(incidence).
      spread_m: (n_lines, n_beams) float64, footprint range spread, metres.
      lidar: the sensor.
      model: which effects.
      rng: the run's generator; with range noise on, exactly one
        ``standard_normal((n_lines, n_beams))`` draw is taken from it.
      hit_class: (n_lines, n_beams) uint8 :class:`HitClass` of each beam's
        dominant return, for the per-material offsets; None: no material offset.
      reflectance: (n_lines, n_beams) float64 reflectance of each beam's target
        (for the reflectance walk); None: the footprint's apparent reflectance
        from its power (:func:`apparent_reflectance`), exact on one surface.
      line_time_s: (n_lines,) or (n_lines, n_beams) float64 seconds since the
        scan's first line (a beam's own time when given per beam); the time
        since power-on is ``model.power_on_age_s`` plus this. None: every beam
        at ``power_on_age_s``.

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
    true = np.where(echo, range_m, 0.0)
    safe_power = np.where(echo, power, 1.0)
    safe_cos = np.where(echo, cos_incidence, 1.0)
    measured = true
    if model.systematic_error:
        rho = (apparent_reflectance(true, safe_power, safe_cos) if reflectance is None
               else np.asarray(reflectance, dtype=np.float64))
        t = model.power_on_age_s
        if line_time_s is not None:
            lt = np.asarray(line_time_s, dtype=np.float64)
            t = t + (lt[:, None] if lt.ndim == 1 else lt)
        material = 0.0
        if hit_class is not None:
            material = model.range_bias_by_class()[np.asarray(hit_class, dtype=np.intp)]
        measured = measured + range_bias(true, rho, lidar, time_since_power_on_s=t,
                                         material_bias_m=material)
    if model.range_noise:
        z = rng.standard_normal(measured.shape)
        measured = measured + range_sigma(true, safe_cos, lidar, power=safe_power) * z
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
