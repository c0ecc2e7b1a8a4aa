"""Which parts a scan runs, decided once from the whole configuration.

Nothing is silently ignored: a setting the chosen parts would not use is refused
with one line that names it and says what to change; where the intent is clear
the scan switches to the parts that honour it and says so (a note, logged and
written to the sidecar). :func:`plan_scan` is the only place that decides.

A setting counts as given when it was in the TOML file or on the command line
(``RunConfig.explicit``) or, for a configuration built in Python, when it differs
from its default.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from plantsim.errors import ConfigError
from plantsim.scan.config import RunConfig
from plantsim.sensor.model import SensorModel
from plantsim.sensor.spec import PRESETS
from plantsim.turntable.dynamics import JitterConfig, TurntableDynamics
from plantsim.turntable.encoder import EncoderConfig

# LidarSpec fields that only the realistic sensor model uses.
REALISTIC_LIDAR_FIELDS = ("beam_divergence_rad", "beam_exit_diameter_m", "range_resolution_m",
                          "range_sigma_m", "range_sigma_rel", "range_sigma_incidence_gain",
                          "detection_range_white_m", "edge_range_spread_m", "noise_law", "range_bias_m",
                          "range_bias_rel", "range_bias_dark_m", "warmup_drift_m", "warmup_time_constant_s")
# Settings of the realistic sensor that only some of its effects use ([sensor_model]
# switches; plantsim.sensor.model.apply_sensor, plantsim.sensor.lidar): (paths, whether the
# model uses them, what turns them off, what to change). Given while unused, they would
# change nothing. detection_range_white_m is the dropouts' threshold and also the weakest
# power the noise law admits (sensor.model.weakest_power); one ray a beam has no footprint
# (its divergence and exit diameter) and nothing to adapt.
EFFECT_RULES = (
    (tuple(f"lidar.{f}" for f in ("range_sigma_m", "range_sigma_rel", "range_sigma_incidence_gain", "noise_law")),
     lambda m: m.range_noise, "range_noise is false", "set range_noise = true"),
    (tuple(f"lidar.{f}" for f in ("range_bias_m", "range_bias_rel", "range_bias_dark_m", "warmup_drift_m",
                                  "warmup_time_constant_s"))
     + tuple(f"sensor_model.{f}" for f in ("range_bias_plant_m", "range_bias_turntable_m", "range_bias_rig_m",
                                           "power_on_age_s")),
     lambda m: m.systematic_error, "systematic_error is false", "set systematic_error = true"),
    (("lidar.range_resolution_m",), lambda m: m.quantise, "quantise is false", "set quantise = true"),
    (("lidar.edge_range_spread_m",), lambda m: m.dropouts, "dropouts is false", "set dropouts = true"),
    (("lidar.detection_range_white_m",), lambda m: m.dropouts or m.range_noise,
     "dropouts and range_noise are false", "set dropouts = true or range_noise = true"),
    (("sensor_model.saturation_range_m",), lambda m: m.intensity, "intensity is false", "set intensity = true"),
    (("lidar.beam_divergence_rad", "lidar.beam_exit_diameter_m", "sensor_model.adaptive_footprint"),
     lambda m: m.footprint_rings > 0, "footprint_rings = 0 (one ray a beam)", "set footprint_rings = 1 or more"),
    # A hit's reflectance sets its received power (the noise law, the dropouts, the
    # intensity), the bias's reflectance walk, and a footprint's weights.
    (tuple(f"sensor_model.reflectance_{c}" for c in ("plant", "turntable", "rig")),
     lambda m: m.range_noise or m.dropouts or m.intensity or m.systematic_error or m.footprint_rings > 0,
     "range_noise, dropouts, intensity and systematic_error are false and footprint_rings = 0",
     "turn one of them on"),
    (("sensor_model.flat_tolerance_m",), lambda m: m.footprint_rings > 0 and m.adaptive_footprint,
     "footprint_rings = 0 or adaptive_footprint = false", "set footprint_rings = 1 or more and adaptive_footprint "
     "= true"),
)
# [turntable] settings that only the servo's physics uses.
PHYSICS_SCALARS = tuple(f.name for f in dataclasses.fields(TurntableDynamics)
                        if f.name not in ("servo", "jitter"))
# Beams a scan may record: the raw record keeps about BYTES_PER_BEAM a beam (range,
# status, intensity, hit class, geom, true angle) before the cloud and footprints.
MAX_BEAMS = 100_000_000
BYTES_PER_BEAM = 32
STEP_ONLY_PHYSICS = ("settle_tolerance_rad", "settle_velocity_rad_s", "settle_timeout_s")
CONTINUOUS_ONLY_PHYSICS = ("spinup_margin_s",)


@dataclasses.dataclass(frozen=True)
class ScanPlan:
    """The parts a scan runs.

    Attributes:
      mode: "step" or "continuous".
      sensor: "ideal" or "realistic".
      motion: "kinematic", "physics" or "hardware".
      encoder: the encoder the simulated motion is read through (None on hardware).
      dynamics: the servo physics settings (None unless motion is "physics").
      angle_mode: how the reconstruction gets each beam's turntable angle
        (:data:`plantsim.scan.raw.ANGLE_MODES`).
      notes: what was switched and why, said aloud.
    """

    mode: str
    sensor: str
    motion: str
    encoder: EncoderConfig | None
    dynamics: TurntableDynamics | None
    angle_mode: str
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"mode": self.mode, "sensor": self.sensor, "motion": self.motion,
                "angle_mode": self.angle_mode, "notes": list(self.notes)}


_DEFAULT = RunConfig()


def _value(obj, path: str):
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def given(config: RunConfig, path: str) -> bool:
    """Whether the user set the setting at a dotted path (``turntable.jitter.backlash_deg``)."""
    # TOML writes the [turntable] dynamics scalars as turntable.X; the dataclass holds them
    # at turntable.dynamics.X.
    paths = (path, path.replace("turntable.dynamics.", "turntable.", 1))
    if any(p in config.explicit or any(k.startswith(p + ".") for k in config.explicit) for p in paths):
        return True
    try:
        return _value(config, path) != _value(_DEFAULT, path)
    except AttributeError:
        return False


def _given_under(config: RunConfig, section: str, fields) -> list[str]:
    return [f"{section}.{f}" for f in fields if given(config, f"{section}.{f}")]


def _physics_settings(config: RunConfig) -> list[str]:
    """The given settings that need the servo's physics."""
    keys = [k for k in sorted(config.explicit) if k.startswith(("turntable.servo.", "turntable.registers.",
                                                                 "turntable.jitter."))
            or k == "turntable.servo_preset"]
    dyn = config.turntable.dynamics
    if not keys:
        if dyn.servo != _DEFAULT.turntable.dynamics.servo:
            keys.append("turntable.servo")
        for f in dataclasses.fields(JitterConfig):
            if getattr(dyn.jitter, f.name) != getattr(JitterConfig(), f.name):
                keys.append(f"turntable.jitter.{f.name}")
    keys += [k for k in _given_under(config, "turntable.dynamics", PHYSICS_SCALARS)]
    if given(config, "plant.areal_density_kg_m2"):  # the plant's inertia: only physics uses it
        keys.append("plant.areal_density_kg_m2")
    return [k.replace("turntable.dynamics.", "turntable.") for k in keys]


def _key_name(path: str) -> str:
    section, _, key = path.rpartition(".")
    return f"[{section}] {key}" if section else key


def _check_range_filter(config: RunConfig, *, real_lidar: bool) -> None:
    """Refuses range filter settings with the filter off, and the filter on exact ranges."""
    rf = config.range_filter
    if not rf.enabled:
        fields = [f.name for f in dataclasses.fields(rf) if f.name != "enabled"]
        unused = _given_under(config, "range_filter", fields)
        if unused:
            raise ConfigError(f"{_key_name(unused[0])} is set but the range filter is off and would not use it: "
                              "set [range_filter] enabled = true (--range-filter), or remove it")
        return
    if not real_lidar and (config.ideal or config.sensor == "ideal"):
        why = "--ideal" if config.ideal else "sensor = \"ideal\""
        raise ConfigError(f"the range filter denoises measured ranges, but the sensor is ideal ({why}) and its "
                          "ranges are exact: remove --range-filter, or use --sensor realistic")


def _set_by_user(config: RunConfig, path: str) -> bool:
    """Whether a [lidar] or [sensor_model] field was set, not merely taken from its preset
    (a TOML or command-line key; in Python, a value other than the preset's or the default's)."""
    if config.explicit:
        return path in config.explicit
    section, field = path.split(".")
    reference = SensorModel() if section == "sensor_model" else PRESETS.get(config.lidar.name)
    return reference is not None and getattr(getattr(config, section), field) != getattr(reference, field)


def _check_sensor_effects(config: RunConfig) -> None:
    """Refuses a realistic sensor's setting that only switched-off effects use (``EFFECT_RULES``)."""
    for paths, used, off, fix in EFFECT_RULES:
        if used(config.sensor_model):
            continue
        for path in paths:
            if _set_by_user(config, path):
                raise ConfigError(f"{_key_name(path)} is set but [sensor_model] {off}, which turns off what uses "
                                  f"it: remove it, or {fix}")


def plan_scan(config: RunConfig, *, hardware_turntable: bool = False, real_lidar: bool = False) -> ScanPlan:
    """Decides the parts of a scan, refusing settings they would not use.

    Args:
      config: the resolved configuration.
      hardware_turntable: the table is a real (or emulated) servo, driven line by line.
      real_lidar: (with ``hardware_turntable``) the lines come from the real URG LiDAR.

    Raises:
      ConfigError: one line naming the setting and what to change.
    """
    tt = config.turntable
    mode = tt.mode
    notes: list[str] = []
    _check_range_filter(config, real_lidar=real_lidar)
    if real_lidar:
        return _plan_real_lidar(config)

    # --- the sensor ---------------------------------------------------------
    if config.ideal and given(config, "sensor") and config.sensor == "realistic":
        raise ConfigError("ideal = true makes everything perfect but sensor = \"realistic\" asks for the "
                          "sensor model: drop one (--sensor ideal --turntable dynamic keeps only the table "
                          "imperfect)")
    sensor = "ideal" if config.ideal else config.sensor
    if sensor == "ideal":
        unused = sorted(k for k in config.explicit if k.startswith("sensor_model.")
                        or k in {f"lidar.{f}" for f in REALISTIC_LIDAR_FIELDS})
        if not unused and not config.explicit and config.sensor_model != _DEFAULT.sensor_model:
            unused = ["sensor_model"]
        if unused:
            why = "--ideal" if config.ideal else "sensor = \"ideal\""
            raise ConfigError(f"{_key_name(unused[0])} is set but the sensor is ideal ({why}) and would not "
                              f"use it: remove it, or use --sensor realistic")
    else:
        _check_sensor_effects(config)

    # --- the schedule ---------------------------------------------------------
    if mode == "continuous":
        for key, what in (("scan.step_deg", "--step-deg"), ("scan.step_time_s", "step_time_s")):
            if given(config, key):
                raise ConfigError(
                    f"{what} applies to step scans; a continuous scan's lines are rpm x scan period apart "
                    f"({config.turntable.rpm * 6 * config.lidar.scan_period_s:.3g} deg at {config.turntable.rpm:g}"
                    f" rpm): set --rpm instead, or use --mode step")
        wrong = _given_under(config, "turntable.dynamics", STEP_ONLY_PHYSICS)
        if wrong:
            raise ConfigError(f"{_key_name(wrong[0].replace('dynamics.', ''))} applies to step scans (settling "
                              f"after each move); remove it, or use --mode step")
    else:
        if given(config, "turntable.rpm"):
            raise ConfigError("--rpm applies to continuous scans; a step scan moves by --step-deg: remove "
                              "--rpm, or use --mode continuous")
        wrong = _given_under(config, "turntable.dynamics", CONTINUOUS_ONLY_PHYSICS)
        if wrong:
            raise ConfigError("[turntable] spinup_margin_s applies to continuous scans; remove it, or use "
                              "--mode continuous")

    # --- what the rig can do ----------------------------------------------------
    rig, lidar = config.rig, config.lidar
    nearest_m = rig.lidar_distance_m - rig.disk_radius_m
    if nearest_m > lidar.range_max_m:
        raise ConfigError(f"the LiDAR stands {rig.lidar_distance_m:g} m from the axis, {nearest_m:g} m from the "
                          f"disk's edge, beyond its range_max_m ({lidar.range_max_m:g} m): it would see nothing; "
                          f"set [rig] lidar_distance_m below {lidar.range_max_m + rig.disk_radius_m:g}")
    n_lines = (config.scan.n_lines if mode == "step" else
               math.ceil(math.radians(config.scan.sweep_deg) / (tt.rpm * 2 * math.pi / 60 * lidar.scan_period_s)))
    beams = n_lines * lidar.n_beams
    if beams > MAX_BEAMS:
        fix = ("a larger --step-deg" if mode == "step" else "a higher --rpm or a smaller --sweep-deg")
        raise ConfigError(f"this scan has {n_lines:,} lines x {lidar.n_beams} beams = {beams:,} beams, more than "
                          f"{MAX_BEAMS:,} (about {beams * BYTES_PER_BEAM / 2**30:.0f} GiB for the raw record alone): "
                          f"use {fix}")

    # --- the turntable --------------------------------------------------------
    physics_keys = _physics_settings(config)
    encoder_keys = sorted(k for k in config.explicit if k.startswith("turntable.encoder."))
    if not encoder_keys and tt.encoder != EncoderConfig():
        encoder_keys = ["turntable.encoder"]
    if hardware_turntable:
        if config.ideal:
            raise ConfigError("--ideal cannot make a real servo perfect: use --sensor ideal for an ideal "
                              "simulated LiDAR on the rig")
        simulated_only = physics_keys + encoder_keys + [
            k for k in ("turntable.physics", "turntable.ideal", "turntable.rpm", "scan.step_time_s")
            if given(config, k)]
        if simulated_only:
            raise ConfigError(f"{_key_name(simulated_only[0])} describes the simulated turntable; a rig scan "
                              f"turns the real servo (its own encoder, gains and timing): remove it")
        if mode == "continuous":
            raise ConfigError("continuous rig scans need a LiDAR that streams on its own clock (the real URG); "
                              "the simulated LiDAR takes lines at rest: use --lidar urg --lidar-port PORT, "
                              "or --mode step")
        angle_mode = "line" if tt.deskew else "commanded"
        return ScanPlan(mode=mode, sensor=sensor, motion="hardware", encoder=None, dynamics=None,
                        angle_mode=angle_mode, notes=tuple(notes))

    table_ideal = config.ideal or tt.ideal
    if table_ideal and (physics_keys and any(k.startswith("turntable.jitter") for k in physics_keys)
                        or encoder_keys):
        key = next(k for k in physics_keys + encoder_keys if k.startswith(("turntable.jitter", "turntable.encoder")))
        why = "--ideal" if config.ideal else "[turntable] ideal = true"
        raise ConfigError(f"{_key_name(key)} is set but {why} makes the turntable perfect (no jitter, exact "
                          f"encoder): remove it, or drop {why} (--sensor ideal keeps the LiDAR perfect alone)")
    if tt.physics == "kinematic" and physics_keys:
        raise ConfigError(f"{_key_name(physics_keys[0])} needs the servo's physics, but physics = \"kinematic\" "
                          f"(a perfect motor): set physics = \"dynamic\" (--turntable dynamic), or remove it")
    if tt.physics == "dynamic":
        motion = "physics"
    elif tt.physics == "kinematic" or table_ideal:
        motion = "kinematic"
    elif physics_keys:
        motion = "physics"
        notes.append(f"{_key_name(physics_keys[0])} is set: this {mode} scan runs the servo's physics (MuJoCo) "
                     f"to honour it (physics = \"dynamic\")")
    else:
        motion = "physics" if mode == "continuous" else "kinematic"
    if motion == "kinematic" and physics_keys:
        raise ConfigError(f"{_key_name(physics_keys[0])} needs the servo's physics: remove it, or set physics = "
                          f"\"dynamic\"")
    if motion == "physics" and mode == "step" and given(config, "scan.step_time_s"):
        raise ConfigError("step_time_s is the kinematic table's line spacing; with the servo's physics each "
                          "step takes as long as the servo needs to settle: remove it")

    if table_ideal:
        encoder = EncoderConfig.ideal(read_rate_hz=tt.encoder.read_rate_hz)
        dynamics = tt.dynamics.replace(jitter=JitterConfig()) if motion == "physics" else None
    elif motion == "kinematic" and not encoder_keys:
        # A perfect motor at rest, and nobody asked for an imperfect encoder.
        encoder = EncoderConfig.ideal(read_rate_hz=tt.encoder.read_rate_hz)
        dynamics = None
    else:
        encoder = tt.encoder
        dynamics = tt.dynamics if motion == "physics" else None
    if mode == "continuous":
        angle_mode = "interpolate" if tt.deskew else "line"
    else:
        angle_mode = "interpolate" if tt.deskew else "commanded"
    return ScanPlan(mode=mode, sensor=sensor, motion=motion, encoder=encoder, dynamics=dynamics,
                    angle_mode=angle_mode, notes=tuple(notes))


def _plan_real_lidar(config: RunConfig) -> ScanPlan:
    """The plan of a rig scan whose lines come from the real URG: every setting of the
    simulated sensor or turntable is refused (one line: what to remove)."""
    tt = config.turntable
    if config.ideal:
        raise ConfigError("--ideal describes simulated parts; with --lidar urg both the servo and the LiDAR are "
                          "real: remove --ideal")
    if given(config, "sensor"):
        raise ConfigError(f"--sensor {config.sensor} chooses the simulated LiDAR's model; with --lidar urg the "
                          "ranges are the real sensor's: remove --sensor (or use --lidar sim)")
    sensor_keys = sorted(k for k in config.explicit if k.startswith("sensor_model.") or k == "sensor_model"
                         or k in {f"lidar.{f}" for f in REALISTIC_LIDAR_FIELDS})
    if not sensor_keys and not config.explicit and config.sensor_model != _DEFAULT.sensor_model:
        sensor_keys = ["sensor_model"]
    if sensor_keys:
        raise ConfigError(f"{_key_name(sensor_keys[0])} describes the simulated sensor model; a real URG "
                          "measures for itself: remove it (or use --lidar sim)")
    if config.output.plant_only:
        raise ConfigError("--plant-only needs to know which points are on the plant; a real LiDAR does not "
                          "know what it hit: remove --plant-only and crop the cloud afterwards")
    physics_keys = _physics_settings(config)
    encoder_keys = sorted(k for k in config.explicit if k.startswith("turntable.encoder."))
    simulated_only = physics_keys + encoder_keys + [
        k for k in ("turntable.physics", "turntable.ideal", "scan.step_time_s") if given(config, k)]
    if simulated_only:
        raise ConfigError(f"{_key_name(simulated_only[0])} describes the simulated turntable; a rig scan turns "
                          "the real servo (its own encoder, gains and timing): remove it")
    if tt.mode == "continuous":
        if given(config, "scan.step_deg"):
            raise ConfigError("--step-deg applies to step scans; a continuous scan's lines are rpm x scan period "
                              "apart: set --rpm instead, or use --mode step")
        angle_mode = "interpolate" if tt.deskew else "line"
    else:
        if given(config, "turntable.rpm"):
            raise ConfigError("--rpm applies to continuous scans; a step scan moves by --step-deg: remove --rpm, "
                              "or use --mode continuous")
        angle_mode = "line" if tt.deskew else "commanded"
    return ScanPlan(mode=tt.mode, sensor="urg", motion="hardware", encoder=None, dynamics=None,
                    angle_mode=angle_mode, notes=())
