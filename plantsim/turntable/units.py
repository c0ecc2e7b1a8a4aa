"""Pure conversions between Dynamixel X-series register units and SI.

Source: ROBOTIS e-Manual, XM430-W350 and XL430-W250 control tables
(https://emanual.robotis.com/docs/en/dxl/x/xm430-w350/), and the notes in
``/work/shared/notes/dynamixel-protocol2.md``.

Conventions:

* Position: raw 0 is 0 rad, 4096 ticks per revolution, counter-clockwise (seen
  from the horn) positive. With this choice the position-mode range 0..4095
  maps onto [0, 2 pi) and extended-position mode needs no offset. Centre 2048
  is therefore pi rad.
* Velocity: the firmware's native unit is 1/64 tick per ms; the datasheet rounds
  it to 0.229 rpm (exactly 0.2289 rpm). We use the exact value so that the
  profile ramp time ``t1 = 64 * PV / PA`` ms holds exactly.
* Acceleration: 1/4096 tick per ms^2 = 214.577 rpm^2 (exact).
* Current: 2.69 mA per unit. PWM: 885 units = 100 % duty (0.113 % per unit).

The unit conversions accept a Python scalar or a NumPy array and return the same
kind. Conversions to raw integers round to the nearest unit and raise
``ValueError`` for non-finite input; nothing is clipped or wrapped silently.
"""

from __future__ import annotations

import math

import numpy as np

TICKS_PER_REV = 4096
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV

# Native firmware units, expressed in ticks and milliseconds (e-Manual).
VELOCITY_UNIT_TICK_PER_MS = 1.0 / 64.0
ACCELERATION_UNIT_TICK_PER_MS2 = 1.0 / 4096.0
RAD_S_PER_VELOCITY_UNIT = VELOCITY_UNIT_TICK_PER_MS * 1e3 * RAD_PER_TICK
RAD_S2_PER_ACCELERATION_UNIT = ACCELERATION_UNIT_TICK_PER_MS2 * 1e6 * RAD_PER_TICK
VELOCITY_UNIT_RPM = RAD_S_PER_VELOCITY_UNIT * 60.0 / (2.0 * math.pi)  # 0.2289
ACCELERATION_UNIT_RPM2 = RAD_S2_PER_ACCELERATION_UNIT * 3600.0 / (2.0 * math.pi)  # 214.577

AMPERE_PER_CURRENT_UNIT = 2.69e-3
PWM_FULL_SCALE = 885  # raw PWM that means 100 % duty

# Firmware gain scaling (e-Manual, "Position PID Gain"): KP = P/128, KI = I/65536,
# KD = D/16, KFF2 = FF2/4, KFF1 = FF1/4.
P_GAIN_DIVISOR = 128
I_GAIN_DIVISOR = 65536
D_GAIN_DIVISOR = 16
FF_GAIN_DIVISOR = 4

# The firmware's loop runs on errors in ticks and (we assume) a 1 ms control
# cycle: ROBOTIS documents the gain scaling but not the time base, so the
# integral is taken as a sum of tick errors per ms and derivatives as ticks per ms.
CONTROL_PERIOD_S = 1e-3


def _finite(value, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return array


def _like(value, array: np.ndarray, *, integer: bool):
    """Returns ``array`` as a Python scalar when ``value`` was a scalar."""
    if np.ndim(value) == 0:
        return int(array) if integer else float(array)
    return array.astype(np.int64) if integer else array


def _to_raw(value, scale: float, name: str):
    array = _finite(value, name)
    return _like(value, np.rint(array / scale), integer=True)


def _from_raw(raw, scale: float):
    array = np.asarray(raw, dtype=float) * scale
    return _like(raw, array, integer=False)


# --- position -----------------------------------------------------------------


def ticks_to_rad(position_ticks):
    """Converts a position in ticks (raw 0 = 0 rad) to radians."""
    return _from_raw(position_ticks, RAD_PER_TICK)


def rad_to_ticks(angle_rad):
    """Converts radians to the nearest position tick (raw 0 = 0 rad).

    Raises:
        ValueError: if ``angle_rad`` is not finite.
    """
    return _to_raw(angle_rad, RAD_PER_TICK, "angle_rad")


# --- velocity, acceleration -------------------------------------------------


def velocity_units_to_rad_s(velocity_units):
    """Converts velocity register units (0.229 rpm = 1/64 tick/ms) to rad/s."""
    return _from_raw(velocity_units, RAD_S_PER_VELOCITY_UNIT)


def rad_s_to_velocity_units(velocity_rad_s):
    """Converts rad/s to the nearest velocity register unit."""
    return _to_raw(velocity_rad_s, RAD_S_PER_VELOCITY_UNIT, "velocity_rad_s")


def acceleration_units_to_rad_s2(acceleration_units):
    """Converts acceleration register units (214.577 rpm^2) to rad/s^2."""
    return _from_raw(acceleration_units, RAD_S2_PER_ACCELERATION_UNIT)


def rad_s2_to_acceleration_units(acceleration_rad_s2):
    """Converts rad/s^2 to the nearest acceleration register unit."""
    return _to_raw(acceleration_rad_s2, RAD_S2_PER_ACCELERATION_UNIT, "acceleration_rad_s2")


# --- current, PWM -------------------------------------------------------------


def current_units_to_a(current_units):
    """Converts current register units (2.69 mA) to amperes."""
    return _from_raw(current_units, AMPERE_PER_CURRENT_UNIT)


def a_to_current_units(current_a):
    """Converts amperes to the nearest current register unit."""
    return _to_raw(current_a, AMPERE_PER_CURRENT_UNIT, "current_a")


def pwm_units_to_duty(pwm_units):
    """Converts PWM register units to a duty fraction (885 -> 1.0)."""
    return _from_raw(pwm_units, 1.0 / PWM_FULL_SCALE)


def duty_to_pwm_units(duty):
    """Converts a duty fraction in [-1, 1] to PWM register units.

    Raises:
        ValueError: if ``duty`` is outside [-1, 1] or not finite.
    """
    array = _finite(duty, "duty")
    if np.any(np.abs(array) > 1.0):
        raise ValueError(f"duty must be within [-1, 1], got {duty!r}")
    return _to_raw(duty, 1.0 / PWM_FULL_SCALE, "duty")


# --- two's complement ---------------------------------------------------------


def to_signed(value, size: int):
    """Reinterprets an unsigned register value (as the SDK returns it) as signed.

    Args:
        value: int or integer array, 0 <= value < 2**(8*size).
        size: register size in bytes: 1, 2 or 4.

    Raises:
        ValueError: if ``size`` is not 1, 2 or 4, or ``value`` does not fit.
    """
    bits = _bits(size)
    array = np.asarray(value, dtype=np.int64)
    if np.any(array < 0) or np.any(array >= (1 << bits)):
        raise ValueError(f"value must be an unsigned {bits}-bit integer, got {value!r}")
    signed = np.where(array >= (1 << (bits - 1)), array - (1 << bits), array)
    return _like(value, signed, integer=True)


def to_unsigned(value, size: int):
    """Encodes a signed value as the unsigned two's-complement register value.

    Raises:
        ValueError: if ``size`` is not 1, 2 or 4, or ``value`` does not fit.
    """
    bits = _bits(size)
    array = np.asarray(value, dtype=np.int64)
    low, high = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    if np.any(array < low) or np.any(array > high):
        raise ValueError(f"value must be a signed {bits}-bit integer in [{low}, {high}], got {value!r}")
    unsigned = np.where(array < 0, array + (1 << bits), array)
    return _like(value, unsigned, integer=True)


def _bits(size: int) -> int:
    if size not in (1, 2, 4):
        raise ValueError(f"size must be 1, 2 or 4 bytes, got {size!r}")
    return 8 * size


# --- firmware gains -----------------------------------------------------------


def position_gains_from_registers(p_gain: int, i_gain: int, d_gain: int) -> tuple[float, float, float]:
    """Returns the firmware's (KP, KI, KD) from the Position P/I/D Gain registers.

    KP = P/128, KI = I/65536, KD = D/16 (e-Manual). The result multiplies errors in
    ticks (KP), tick-ms (KI) and ticks per ms (KD) and gives PWM units.
    """
    return p_gain / P_GAIN_DIVISOR, i_gain / I_GAIN_DIVISOR, d_gain / D_GAIN_DIVISOR


def position_gains_to_registers(kp: float, ki: float, kd: float) -> tuple[int, int, int]:
    """Inverse of :func:`position_gains_from_registers`, rounded to integers."""
    for name, value in (("kp", kp), ("ki", ki), ("kd", kd)):
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return (
        round(kp * P_GAIN_DIVISOR),
        round(ki * I_GAIN_DIVISOR),
        round(kd * D_GAIN_DIVISOR),
    )


def feedforward_gain_from_register(ff_gain: int) -> float:
    """Returns KFF = FF/4 for either feed-forward register (e-Manual)."""
    return ff_gain / FF_GAIN_DIVISOR


def feedforward_gain_to_register(kff: float) -> int:
    """Inverse of :func:`feedforward_gain_from_register`, rounded."""
    if not math.isfinite(kff) or kff < 0:
        raise ValueError(f"kff must be finite and >= 0, got {kff!r}")
    return round(kff * FF_GAIN_DIVISOR)


# Scale from a firmware gain (PWM units per tick-based error) to an SI gain
# (duty fraction per radian-based error): errors in rad become ticks (1/RAD_PER_TICK),
# PWM units become duty (1/885), and each ms of the firmware's time base becomes s.
_DUTY_PER_RAD = 1.0 / (RAD_PER_TICK * PWM_FULL_SCALE)
SI_PER_KP = _DUTY_PER_RAD  # duty/rad        per (PWM/tick)
SI_PER_KI = _DUTY_PER_RAD / CONTROL_PERIOD_S  # duty/(rad s)  per (PWM/(tick ms))
SI_PER_KD = _DUTY_PER_RAD * CONTROL_PERIOD_S  # duty s/rad    per (PWM/(tick/ms))
SI_PER_KFF1 = _DUTY_PER_RAD * CONTROL_PERIOD_S  # duty s/rad  per (PWM/(tick/ms))
SI_PER_KFF2 = _DUTY_PER_RAD * CONTROL_PERIOD_S**2  # duty s^2/rad per (PWM/(tick/ms^2))


# --- profile ------------------------------------------------------------------


def profile_ramp_time_ms(profile_velocity: int, profile_acceleration: int) -> float:
    """Ramp (acceleration) time t1 = 64 * PV / PA in ms (e-Manual, "Profile").

    Raises:
        ValueError: if ``profile_acceleration`` is 0 (infinite acceleration, no ramp)
            or either value is negative.
    """
    if profile_velocity < 0:
        raise ValueError(f"profile_velocity must be >= 0, got {profile_velocity}")
    if profile_acceleration <= 0:
        raise ValueError(
            f"profile_acceleration must be > 0 for a ramp (0 means infinite), got {profile_acceleration}"
        )
    return 64.0 * profile_velocity / profile_acceleration


def is_triangular_profile(distance_ticks: float, profile_velocity: int, profile_acceleration: int) -> bool:
    """True when a rest-to-rest move of ``distance_ticks`` never reaches the velocity cap.

    The firmware makes the profile triangular when |d| <= PV^2 / PA (e-Manual).
    A zero profile value means "no limit": PV = 0 never caps (triangle whenever PA
    is finite), PA = 0 gives a rectangle or step, never a triangle.
    """
    if profile_acceleration == 0:
        return False
    if profile_velocity == 0:
        return True
    return abs(distance_ticks) <= profile_velocity**2 / profile_acceleration
