"""Tests of the pure unit conversions and the control tables."""

import math

import numpy as np
import pytest

from plantsim.hardware.dynamixel import control_table
from plantsim.turntable import units


def test_position_round_trip_and_convention():
    assert units.ticks_to_rad(0) == 0.0
    assert units.ticks_to_rad(2048) == pytest.approx(math.pi)
    assert units.ticks_to_rad(4096) == pytest.approx(2 * math.pi)
    assert units.rad_to_ticks(math.pi / 2) == 1024
    ticks = np.arange(-5000, 5000, 37)
    np.testing.assert_array_equal(units.rad_to_ticks(units.ticks_to_rad(ticks)), ticks)
    assert isinstance(units.rad_to_ticks(1.0), int)


def test_non_finite_is_refused():
    with pytest.raises(ValueError, match="angle_rad must be finite"):
        units.rad_to_ticks(float("nan"))


def test_velocity_and_acceleration_units_match_datasheet():
    assert units.VELOCITY_UNIT_RPM == pytest.approx(0.229, abs=5e-4)
    assert units.ACCELERATION_UNIT_RPM2 == pytest.approx(214.577, abs=1e-3)
    # 1 unit = 1/64 tick/ms.
    assert units.velocity_units_to_rad_s(64) == pytest.approx(units.RAD_PER_TICK * 1e3)
    assert units.rad_s_to_velocity_units(units.velocity_units_to_rad_s(200)) == 200
    assert units.rad_s2_to_acceleration_units(units.acceleration_units_to_rad_s2(-77)) == -77


def test_current_and_pwm():
    assert units.current_units_to_a(1193) == pytest.approx(3.209, abs=1e-3)
    assert units.a_to_current_units(2.69e-3 * 100) == 100
    assert units.pwm_units_to_duty(885) == 1.0
    assert units.duty_to_pwm_units(-0.5) == -442
    with pytest.raises(ValueError, match=r"duty must be within \[-1, 1\]"):
        units.duty_to_pwm_units(1.2)


@pytest.mark.parametrize("size", [1, 2, 4])
def test_twos_complement_round_trip(size):
    bits = 8 * size
    values = np.array([-(1 << (bits - 1)), -1, 0, 1, (1 << (bits - 1)) - 1])
    raw = units.to_unsigned(values, size)
    assert np.all(raw >= 0)
    np.testing.assert_array_equal(units.to_signed(raw, size), values)


def test_twos_complement_examples_and_overflow():
    assert units.to_signed(0xFFFFFFFF, 4) == -1
    assert units.to_signed(0xFFFE, 2) == -2
    assert units.to_unsigned(-2, 2) == 0xFFFE
    with pytest.raises(ValueError, match="signed 16-bit"):
        units.to_unsigned(40000, 2)
    with pytest.raises(ValueError, match="size must be 1, 2 or 4"):
        units.to_signed(1, 3)


def test_gains_both_ways():
    kp, ki, kd = units.position_gains_from_registers(800, 65536, 32)
    assert (kp, ki, kd) == (6.25, 1.0, 2.0)
    assert units.position_gains_to_registers(kp, ki, kd) == (800, 65536, 32)
    assert units.feedforward_gain_from_register(100) == 25.0
    assert units.feedforward_gain_to_register(25.0) == 100


def test_profile_ramp_time_and_triangle_condition():
    assert units.profile_ramp_time_ms(100, 20) == 320.0
    assert units.is_triangular_profile(500, 100, 20)
    assert not units.is_triangular_profile(501, 100, 20)
    assert units.is_triangular_profile(10_000, 0, 20)
    assert not units.is_triangular_profile(1, 100, 0)
    with pytest.raises(ValueError, match="profile_acceleration must be > 0"):
        units.profile_ramp_time_ms(100, 0)


def test_control_table_lookups():
    table = control_table.control_table("XM430-W350")
    assert table.model_number == 1020
    goal = table["Goal Position"]
    assert (goal.address, goal.size, goal.access, goal.area, goal.signed) == (116, 4, "RW", "RAM", True)
    assert table["Operating Mode"].area == "EEPROM"
    assert table["Present Temperature"].address == 146
    assert table.at(132).name == "Present Position"
    assert table.covering(134).name == "Present Position"
    assert table.covering(66) is None
    assert table.size == 147
    with pytest.raises(KeyError, match="no register 'Goal Pos'"):
        table["Goal Pos"]
    xl = control_table.control_table("xl430-w250")
    assert xl.model_number == 1060 and "Present Load" in xl and "Goal Current" not in xl
    assert xl["Position P Gain"].default == 640
    with pytest.raises(ValueError, match="model must be one of"):
        control_table.control_table("ax-12")


def test_hardware_error_names():
    assert control_table.hardware_error_names(0b100001) == ["input voltage error", "overload error"]
