"""How the turntable moves during a scan: the ``[turntable]`` settings."""

from __future__ import annotations

import dataclasses
import math

from plantsim.turntable.dynamics import JitterConfig, TurntableDynamics
from plantsim.turntable.encoder import EncoderConfig


MODES = ("step", "continuous")
PHYSICS = ("auto", "kinematic", "dynamic")


@dataclasses.dataclass(frozen=True, kw_only=True)
class TurntableOptions:
    """How the turntable moves during a scan (the ``[turntable]`` TOML section).

    Which motion runs (and why) is decided with the sensor and the rest of the
    configuration by :func:`plantsim.scan.plan.plan_scan`; these are the settings.

    Attributes:
      mode: "step" (move, settle, scan one line) or "continuous" (the table
        turns at ``rpm`` while the LiDAR scans at its own rate).
      physics: "kinematic" (a perfect motor: exactly at each commanded angle,
        or exactly at ``rpm``), "dynamic" (the servo in MuJoCo: PID, friction,
        jitter, backlash) or "auto" (kinematic for step scans and ideal runs,
        dynamic for continuous scans and whenever servo or jitter settings are
        given).
      ideal: a perfect turntable: kinematic motion, exact encoder, no jitter.
      rpm: continuous mode's turntable speed, revolutions per minute.
      deskew: reconstruct with encoder readings interpolated to each beam's
        time; False uses one angle per line (the commanded angle in step mode,
        the reading at the line's first beam in continuous mode).
      dynamics: servo, jitter, integrator and settling (physics only).
      encoder: the encoder and how it is read.
    """

    mode: str = "step"
    physics: str = "auto"
    ideal: bool = False
    rpm: float = 1.0
    deskew: bool = True
    dynamics: TurntableDynamics = TurntableDynamics()
    encoder: EncoderConfig = EncoderConfig()

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"turntable mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.physics not in PHYSICS:
            raise ValueError(f"turntable physics must be one of {', '.join(PHYSICS)}, got {self.physics!r}")
        for name in ("deskew", "ideal"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"turntable {name} must be true or false, got {getattr(self, name)!r}")
        if (isinstance(self.rpm, bool) or not isinstance(self.rpm, (int, float))
                or not math.isfinite(self.rpm) or self.rpm <= 0):
            raise ValueError(f"turntable rpm must be a positive number, got {self.rpm!r}")
        top_rpm = self.dynamics.servo.top_speed_rad_s() * 60 / (2 * math.pi)
        if self.rpm > top_rpm:
            raise ValueError(f"turntable rpm ({self.rpm:g}) exceeds the servo's no-load speed in this model "
                             f"({top_rpm:.3g} rpm at full duty, less the gearbox's friction); choose rpm <= "
                             f"{0.99 * top_rpm:.3g} or a faster servo")

    def replace(self, **changes) -> "TurntableOptions":
        return dataclasses.replace(self, **changes)


_REGISTER_FIELDS = {
    "Position P Gain": "position_p_gain", "Position I Gain": "position_i_gain",
    "Position D Gain": "position_d_gain", "Feedforward 1st Gain": "velocity_feedforward_gain",
    "Feedforward 2nd Gain": "acceleration_feedforward_gain", "Profile Velocity": "profile_velocity",
    "Profile Acceleration": "profile_acceleration", "PWM Limit": "torque_limit",
}


_SUBTABLES = ("servo", "registers", "jitter", "encoder")


def _fields(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def _unknown(values: dict, valid: list[str], where: str) -> None:
    unknown = sorted(set(values) - set(valid))
    if unknown:
        raise ValueError(f"unknown key(s) {', '.join(unknown)} in [{where}]; valid keys: {', '.join(valid)}")


def turntable_options_from_dict(data: dict) -> TurntableOptions:
    """Builds :class:`TurntableOptions` from a parsed ``[turntable]`` section.

    Layout: top-level keys ``mode``, ``physics``, ``rpm``, ``deskew``,
    ``servo_preset`` ("xm430-w350" or "xl430-w250") and the
    :class:`TurntableDynamics` scalars (``timestep_s``, ``integrator``,
    ``settle_*``, ...); sub-tables ``[turntable.servo]`` (:class:`ServoConfig`
    fields, SI), ``[turntable.registers]`` (Dynamixel register names and raw
    values, e.g. ``"Position P Gain" = 800``, converted by
    :meth:`ServoConfig.with_registers`), ``[turntable.jitter]`` and
    ``[turntable.encoder]`` (``ticks_per_rev = 0`` means exact).

    Raises:
      ValueError: for unknown keys, a quantity given both in SI and as a
        register, or invalid values.
    """
    from plantsim.turntable.dynamics import DEFAULT_SERVO, SERVO_PRESETS
    from plantsim.turntable.servo import ServoConfig

    data = dict(data)
    dyn_scalars = [f for f in _fields(TurntableDynamics) if f not in ("servo", "jitter")]
    top = ["mode", "physics", "ideal", "rpm", "deskew", "servo_preset"] + dyn_scalars
    _unknown({k: v for k, v in data.items() if k not in _SUBTABLES}, top + list(_SUBTABLES), "turntable")
    preset = data.pop("servo_preset", "xm430-w350")
    if preset not in SERVO_PRESETS:
        raise ValueError(f"turntable servo_preset must be one of {', '.join(SERVO_PRESETS)}, got {preset!r}")
    servo_si = dict(data.pop("servo", {}))
    registers = dict(data.pop("registers", {}))
    _unknown(servo_si, _fields(ServoConfig), "turntable.servo")
    _unknown(registers, list(_REGISTER_FIELDS), "turntable.registers")
    both = sorted(r for r in registers if _REGISTER_FIELDS[r] in servo_si)
    if both:
        raise ValueError(f"{', '.join(both)} set both in [turntable.registers] and as "
                         f"{', '.join(_REGISTER_FIELDS[r] for r in both)} in [turntable.servo]; give one")
    for name, value in registers.items():
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"register {name!r} must be an integer (raw units), got {value!r}")
    servo = SERVO_PRESETS[preset](profile_velocity=DEFAULT_SERVO.profile_velocity,
                                  profile_acceleration=DEFAULT_SERVO.profile_acceleration)
    servo = dataclasses.replace(servo, **servo_si).with_registers(registers)
    jitter = dict(data.pop("jitter", {}))
    _unknown(jitter, _fields(JitterConfig), "turntable.jitter")
    encoder = dict(data.pop("encoder", {}))
    _unknown(encoder, _fields(EncoderConfig), "turntable.encoder")
    if encoder.get("ticks_per_rev") == 0:
        encoder["ticks_per_rev"] = None
    dynamics = TurntableDynamics(servo=servo, jitter=JitterConfig(**jitter),
                                 **{k: data.pop(k) for k in dyn_scalars if k in data})
    return TurntableOptions(dynamics=dynamics, encoder=EncoderConfig(**encoder), **data)
