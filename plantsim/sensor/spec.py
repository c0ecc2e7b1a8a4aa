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


# How the random range noise grows (:func:`plantsim.sensor.model.range_sigma`).
NOISE_LAWS = ("received-power", "datasheet-band")


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
      beam_divergence_rad: full angle of the beam's 1/e^2 cone, radians; the
        footprint's 1/e^2 diameter at range r is
        ``beam_exit_diameter_m + r * beam_divergence_rad``. 0: a thin ray.
      beam_exit_diameter_m: 1/e^2 beam diameter at the optical centre, metres.
      range_resolution_m: step of the reported range (quantisation); 0: none.
      noise_law: how the random noise grows: "received-power" (the presets:
        sigma = hypot(range_sigma_m, range_sigma_rel / sqrt(P)), P the
        received power) or "datasheet-band" (the worst case: the datasheet's
        accuracy band read as one sigma, times a 1/cos incidence law).
        :func:`plantsim.sensor.model.range_sigma` has both.
      range_sigma_m: random noise standard deviation floor (strong returns), metres.
      range_sigma_rel: "received-power": noise standard deviation per metre of
        white-equivalent range 1/sqrt(P) (a white target head-on at r has
        sigma = hypot(range_sigma_m, range_sigma_rel * r));
        "datasheet-band": fraction of the range, sigma(r) =
        max(range_sigma_m, range_sigma_rel * r) at normal incidence.
      range_sigma_incidence_gain: "datasheet-band" only: sigma is multiplied by
        ``1 + gain * (1 / cos(theta) - 1)``; 0 turns it off, 1 is the 1/cos law.
      range_bias_m: systematic range offset of the unit (measured minus true), metres.
      range_bias_rel: systematic scale error, fraction of the range.
      range_bias_dark_m: extra offset of a black target against a white one,
        metres; the bias grows linearly with (1 - reflectance).
      warmup_drift_m: range offset right after power-on, metres, settling as
        ``exp(-t / warmup_time_constant_s)`` (:func:`plantsim.sensor.model.warmup_drift`).
      warmup_time_constant_s: the drift's time constant, seconds (> 0).
      detection_range_white_m: range at which a white (reflectance 1)
        Lambertian target seen head-on returns the least power the sensor can
        range on; weaker returns are LOW_INTENSITY. None: no threshold.
      edge_range_spread_m: a beam whose footprint returns spread in range
        (power-weighted standard deviation) by more than this gives EDGE instead
        of a mixed-pixel range. None: never.
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
    beam_divergence_rad: float = 0.0
    beam_exit_diameter_m: float = 0.0
    range_resolution_m: float = 0.0
    range_sigma_m: float = 0.0
    range_sigma_rel: float = 0.0
    range_sigma_incidence_gain: float = 0.0
    noise_law: str = "received-power"
    range_bias_m: float = 0.0
    range_bias_rel: float = 0.0
    range_bias_dark_m: float = 0.0
    warmup_drift_m: float = 0.0
    warmup_time_constant_s: float = 600.0
    detection_range_white_m: float | None = None
    edge_range_spread_m: float | None = None

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

        for field in ("beam_divergence_rad", "beam_exit_diameter_m", "range_resolution_m",
                      "range_sigma_m", "range_sigma_rel", "range_sigma_incidence_gain"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value < 0):
                raise ValueError(f"{field} must be a finite number >= 0, got {value!r}")
        if self.noise_law not in NOISE_LAWS:
            raise ValueError(f"noise_law must be one of {', '.join(NOISE_LAWS)}, got {self.noise_law!r}")
        for field in ("range_bias_m", "range_bias_dark_m", "warmup_drift_m"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or abs(value) > 1.0):
                raise ValueError(f"{field} must be a finite number of metres within +-1 m, got {value!r}")
        rel = self.range_bias_rel
        if isinstance(rel, bool) or not isinstance(rel, (int, float)) or not abs(rel) < 0.5:
            raise ValueError(f"range_bias_rel must be a fraction of the range within +-0.5, got {rel!r}")
        tau = self.warmup_time_constant_s
        if (isinstance(tau, bool) or not isinstance(tau, (int, float)) or not math.isfinite(tau)
                or tau <= 0):
            raise ValueError(f"warmup_time_constant_s must be a finite number of seconds > 0, got {tau!r}")
        for field in ("detection_range_white_m", "edge_range_spread_m"):
            value = getattr(self, field)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                      or not math.isfinite(value) or value <= 0):
                raise ValueError(f"{field} must be a finite number > 0 or None, got {value!r}")

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

    # Sensor model (same notes; datasheet figures unverified against the PDF):
    # - range resolution 1 mm;
    # - the datasheet's accuracy, +-30 mm for 60-1000 mm and +-3 % of range
    #   beyond, is bias plus noise (Kneip et al., ICRA 2009: accuracy depends on
    #   the target, repeatability matches a SICK LMS 200). Random noise: a
    #   10 mm floor (Iman and Md Rashid, IIUM Eng. J. 17(1) 2016: 10.54 mm
    #   average standard deviation at close range; the ROS/Gazebo URG models use
    #   sigma = 10 mm), growing as 1/sqrt(received power) at 1 % of the
    #   white-equivalent range (the "3 % of range" band beyond 1 m read as
    #   +-3 sigma): a matte target at 0.1-1 m has sigma 10-14 mm;
    # - systematic error: per unit and per target (Kneip et al. 2009; Okubo,
    #   Ye and Borenstein 2009 fit a calibration model); its sign is not
    #   transferable between units, so the preset's bias is 0: fit your unit
    #   (``plantsim sensor fit``);
    # - warm-up drift: measured by Kneip et al. 2009 and the Sensors 2022
    #   comparison (PMC9333273); 10 mm settling with a 10 min time constant is
    #   an assumed figure of that order (fit your unit); a scan starts an hour
    #   after power-on by default ([sensor_model] power_on_age_s), so it is
    #   negligible unless you say the sensor was just switched on;
    # - footprint under 20 mm at 2 m and up to 40 mm at 4 m: a line through
    #   both figures is 10 mrad full divergence from a ~0 mm exit diameter;
    # - 4 m guaranteed on white paper, DMAX 5.6 m: a white target head-on is
    #   detected out to 5.6 m (the detection threshold);
    # - edge error (code 7) for footprints spread over more than 0.1 m: an
    #   assumed figure, not a datasheet one (the firmware's rule is not
    #   published; real URG clouds keep many mixed pixels, Okubo et al. 2009).
    beam_divergence_rad=0.010,
    beam_exit_diameter_m=0.0,
    range_resolution_m=0.001,
    noise_law="received-power",
    range_sigma_m=0.010,
    range_sigma_rel=0.01,
    warmup_drift_m=0.010,
    warmup_time_constant_s=600.0,
    detection_range_white_m=5.6,
    edge_range_spread_m=0.10,
)

# The URG-04LX as it was modelled before issue 10, kept as a named worst case:
# the datasheet's +-30 mm / 3 % accuracy band read as one standard deviation of
# random noise, multiplied by 1/cos(incidence) up to 5.8x at 80 degrees.
# A flat plate at 0.3 m has a 30 mm standard deviation: far noisier than any
# published characterisation of the sensor (see docs/sensor-validation.md).
URG_04LX_UG01_WORST_CASE = dataclasses.replace(
    URG_04LX_UG01,
    name="urg-04lx-ug01-worst-case",
    noise_law="datasheet-band",
    range_sigma_m=0.030,
    range_sigma_rel=0.03,
    range_sigma_incidence_gain=1.0,
    warmup_drift_m=0.0,
)

# Hokuyo UTM-30LX. Grid from the SCIP 2.0 specification (Hokuyo C-42-03320B,
# table 2): 1440 steps/turn, steps 0..1080, front step 540, 270.25 deg; 40 Hz
# (25 ms) scan, range 0.1-30 m, 1 mm resolution, accuracy +-30 mm at
# 0.1-10 m and +-50 mm at 10-30 m (datasheet, unverified): bias plus noise.
# Random noise: a 10 mm floor (the same class of phase sensor as the URG;
# libpointmatcher's empirical model of it, Pomerleau et al. 2012, gives a
# similar close-range radius), growing at 0.05 % of the white-equivalent
# range (the extra +-20 mm at 30 m read as +-3 sigma); bias per unit, 0 here. The
# vendor gives no divergence; these beam figures are libpointmatcher's
# SimpleSensorNoise ones for this sensor (half-angle 0.6 mrad, 1.5 mm beam
# constant, taken as the radius), an estimate to fit.
UTM_30LX = LidarSpec(
    name="utm-30lx",
    n_beams=1081,
    angle_min_deg=(0 - 540) * 360.0 / 1440,
    angle_increment_deg=360.0 / 1440,
    range_min_m=0.100,
    range_max_m=30.0,
    scan_period_s=0.025,
    steps_per_rev=1440,
    first_step=0,
    beam_divergence_rad=0.0012,
    beam_exit_diameter_m=0.003,
    range_resolution_m=0.001,
    noise_law="received-power",
    range_sigma_m=0.010,
    range_sigma_rel=0.0005,
    detection_range_white_m=30.0,
    edge_range_spread_m=0.10,
)

# SICK LMS111-10100 at 0.25 deg / 25 Hz: 270 deg, 1081 beams, 0.5-20 m
# working range, 1 mm output resolution (datasheet, unverified). SICK's
# support article "Measurement Errors LMSxxx" gives the LMS1xx a typical
# systematic error of +-30 mm and a typical statistical error of 12 mm (one
# standard deviation): a 12 mm floor, growing little with received power over
# the working range (0.1 % of the white-equivalent range, assumed); the
# systematic part is a per-unit bias (range_bias_m, 0 here: fit it). Beam: "distance x 0.015 rad + 8 mm" (LMS1xx operating
# instructions 8012471, section 3.6.2). No encoder steps: the 25 Hz mirror
# spends 270/360 of its turn on the field of view.
SICK_LMS111 = LidarSpec(
    name="sick-lms111",
    n_beams=1081,
    angle_min_deg=-135.0,
    angle_increment_deg=0.25,
    range_min_m=0.5,
    range_max_m=20.0,
    scan_period_s=0.040,
    beam_divergence_rad=0.015,
    beam_exit_diameter_m=0.008,
    range_resolution_m=0.001,
    noise_law="received-power",
    range_sigma_m=0.012,
    range_sigma_rel=0.001,
    detection_range_white_m=20.0,
    edge_range_spread_m=0.10,
)

# The default first: error messages list the presets in this order.
PRESETS: dict[str, LidarSpec] = {spec.name: spec for spec in (
    URG_04LX_UG01, UTM_30LX, SICK_LMS111, URG_04LX_UG01_WORST_CASE)}


def lidar_preset(name: str) -> LidarSpec:
    """Looks up a preset by name (case-insensitive)."""
    key = name.strip().lower()
    if key not in PRESETS:
        raise ValueError(f"unknown LiDAR preset {name!r}; valid presets: {', '.join(PRESETS)}")
    return PRESETS[key]
