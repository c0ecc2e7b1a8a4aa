"""What a user reads on the rig, and the timing the driver derives from the protocol.

All against the emulator on its bus clock: simulated time moves only with the
exchanges, so a reading is compared with the emulated servo's registers and shaft
at the very instant it was taken, however busy the machine.
"""

import logging
import math

import pytest

from plantsim.hardware.dynamixel import protocol
from plantsim.hardware.dynamixel.driver import DynamixelTurntable, port_handler
from plantsim.hardware.dynamixel.emulator import OVERLOAD, DynamixelEmulator
from plantsim.hardware.dynamixel.turntable import ServoStatus, ServoTurntable
from plantsim.turntable import units

# Scheduler allowance on the protocol's status timeout, for an emulator thread the
# scheduler keeps waiting, s (it costs nothing while statuses come).
ALLOWANCE_S = 1.0
OPTIONS = dict(retries=2, profile_velocity_rad_s=2.0, profile_acceleration_rad_s2=10.0,
               driver_options={"scheduler_allowance_s": ALLOWANCE_S})


@pytest.fixture
def emulator():
    with DynamixelEmulator(ids=(1,), clock="bus", load_inertia=0.002) as emu:
        yield emu


def count_packets(driver):
    """Counts the instruction packets the driver writes from now on; returns a list to len()."""
    sent = []
    write = driver._port.writePort

    def write_port(packet):
        sent.append(bytes(packet))
        return write(packet)

    driver._port.writePort = write_port
    return sent


def test_status_mid_move_is_one_read_of_one_instant(emulator):
    with ServoTurntable.connect(emulator.port_path, **OPTIONS) as table:
        table.status()  # the first also reads the Current Limit (EEPROM), once
        table.driver.write_register("Goal Position", units.rad_to_ticks(3.0))
        emulator.advance(0.5)  # half a second into the move
        sent = count_packets(table.driver)
        status = table.status()
        assert len(sent) == 1  # one READ instruction for everything
        with emulator.lock:  # nothing moved since: the bus is idle on the bus clock
            servo = emulator.servo(1)
            registers = {name: servo.get(name) for name in (
                "Present Position", "Present Velocity", "Present Current", "Present Temperature",
                "Present Input Voltage")}
            shaft_velocity_rad_s = servo.shaft.velocity
    assert isinstance(status, ServoStatus)
    assert status.moving and status.torque_enabled and status.hardware_errors == ()
    assert status.position_rad == units.ticks_to_rad(registers["Present Position"])
    assert status.velocity_rad_s == units.velocity_units_to_rad_s(registers["Present Velocity"])
    # Half a second into a 2 rad/s, 10 rad/s^2 profile: cruising near 2 rad/s.
    assert status.velocity_rad_s == pytest.approx(shaft_velocity_rad_s, abs=units.velocity_units_to_rad_s(1))
    assert 1.5 < status.velocity_rad_s < 2.2
    assert status.current_a == units.current_units_to_a(registers["Present Current"])
    assert status.load_percent == pytest.approx(100 * registers["Present Current"] / 1193)
    assert status.temperature_c == 30.0 and status.input_voltage_v == pytest.approx(12.0)


def test_status_reports_every_hardware_error_bit_by_name(emulator):
    with ServoTurntable.connect(emulator.port_path, **OPTIONS) as table:
        emulator.inject_hardware_error(1, OVERLOAD | 0x01 | 0x04)
        status = table.status()
        assert status.hardware_errors == ("input voltage error", "overheating error", "overload error")
        assert not status.torque_enabled and not status.moving
        assert table.hardware_errors() == status.hardware_errors


def test_xl430_status_reports_its_load_register_and_no_current():
    with DynamixelEmulator(ids=(1,), model="xl430-w250", clock="bus") as emu:
        with ServoTurntable.connect(emu.port_path, model="xl430-w250", **OPTIONS) as table:
            table.driver.write_register("Goal Position", units.rad_to_ticks(2.0))
            emu.advance(0.3)  # accelerating: the motor pushes
            status = table.status()
            with emu.lock:
                load_register = emu.servo(1).get("Present Load")
    assert status.current_a is None
    assert load_register != 0 and status.load_percent == pytest.approx(0.1 * load_register)


def test_read_registers_spans_one_read_and_signs_values(emulator):
    with DynamixelTurntable(scheduler_allowance_s=ALLOWANCE_S) as driver:
        driver.connect(emulator.port_path)
        driver.write_register("Homing Offset", -1000)
        sent = count_packets(driver)
        values = driver.read_registers("Homing Offset", "Present Position", "Firmware Version")
        assert len(sent) == 1
        assert values == {"Homing Offset": -1000, "Present Position": -1000, "Firmware Version": 46}
        with pytest.raises(ValueError, match="read_registers needs at least one register name"):
            driver.read_registers()
        with pytest.raises(KeyError, match="no register 'Speed'; valid names: Model Number"):
            driver.read_registers("Speed")


def test_status_timeout_is_derived_from_the_protocol():
    # 14-byte READ, 15-byte status at 57600 bps, 10 bits a byte; 500 us Return Delay Time;
    # two 16 ms USB latency periods and the SDK's 2 ms; 0.1 s for the scheduler.
    expected_s = 29 * 10 / 57_600 + 500e-6 + 0.032 + 0.002 + 0.1
    assert protocol.status_timeout_s(57_600, instruction_bytes=14, status_bytes=15, return_delay_s=500e-6,
                                     allowance_s=0.1) == pytest.approx(expected_s, rel=1e-12)
    # At 1 Mbps the bytes hardly count: the USB adapter's latency dominates.
    assert protocol.status_timeout_s(1_000_000, instruction_bytes=14, status_bytes=15) == pytest.approx(
        0.034 + 29e-5)
    with pytest.raises(ValueError, match="return_delay_s and allowance_s must be >= 0"):
        protocol.status_timeout_s(57_600, instruction_bytes=14, status_bytes=15, allowance_s=-1)


def test_port_waits_the_derived_timeout_with_the_servos_return_delay(emulator):
    with DynamixelTurntable(scheduler_allowance_s=0.25) as driver:
        driver.connect(emulator.port_path)
        port = driver._port
        assert port.return_delay_s == pytest.approx(500e-6)  # read from the servo at connect
        driver.write_register("Return Delay Time", 0)
        assert port.return_delay_s == 0.0
        port._instruction_bytes = 14
        port.setPacketTimeout(15)
        expected_ms = 1e3 * protocol.status_timeout_s(57_600, instruction_bytes=14, status_bytes=15,
                                                      allowance_s=0.25)
        assert port.packet_timeout == pytest.approx(expected_ms)
        driver.scheduler_allowance_s = 0.0  # settable on a connected driver
        port.setPacketTimeout(15)
        assert port.packet_timeout == pytest.approx(expected_ms - 250)
    raw = port_handler("/dev/null", status_timeout_s=0.5)
    assert raw.min_timeout_ms == 500 and raw.allowance_s == 0.0


def test_a_late_status_of_the_markers_length_is_not_taken_for_it(emulator, caplog):
    """The resync's marker is told by its identity (length and the ID byte), not its time.

    An 8-byte read answered late has the length of the next marker; its byte 7 is not
    the servo's ID, so it is discarded like any other stale status.
    """
    with DynamixelTurntable(retries=2, scheduler_allowance_s=0.3) as driver:
        driver.connect(emulator.port_path)
        driver.write_register("Homing Offset", 1000)
        driver._marker = 7  # the next marker reads 8 bytes: the length of the late status
        emulator.inject_late_reply(1)
        caplog.set_level(logging.WARNING)
        assert driver.read_registers("Present Velocity", "Present Position") == {
            "Present Velocity": 0, "Present Position": 1000}
        assert driver.read_register("Firmware Version") == 46
        assert "discarded 1 late status packet(s)" in caplog.text


def test_emulator_clock_arguments_are_validated():
    with pytest.raises(ValueError, match=r"clock must be one of \('wall', 'bus'\), got 'fast'"):
        DynamixelEmulator(clock="fast")
    with pytest.raises(ValueError, match="host_gap_s must be finite and >= 0"):
        DynamixelEmulator(clock="bus", host_gap_s=-1e-3)
    with pytest.raises(RuntimeError, match="advance\\(\\) needs DynamixelEmulator\\(clock='bus'\\)"):
        DynamixelEmulator().advance(1.0)
    with pytest.raises(ValueError, match="seconds must be finite and >= 0"):
        DynamixelEmulator(clock="bus").advance(math.inf)
    with pytest.raises(ValueError, match="scheduler_allowance_s must be in \\[0, 10\\] s"):
        DynamixelTurntable(scheduler_allowance_s=-0.1)


def test_advance_runs_scheduled_actions_at_their_simulated_time():
    emulator = DynamixelEmulator(clock="bus")
    seen = []
    emulator.call_at(0.25, lambda: seen.append(emulator.sim_time))
    emulator.call_at(0.1, lambda: seen.append(emulator.sim_time))
    assert emulator.advance(0.2) == pytest.approx(0.2)
    assert seen == [pytest.approx(0.1)]
    emulator.advance(0.2)
    assert seen == [pytest.approx(0.1), pytest.approx(0.25)]
    assert emulator.sim_time == pytest.approx(0.4)
