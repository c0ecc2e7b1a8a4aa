"""DynamixelTurntable over the real dynamixel_sdk, against the emulator."""

import math

import pytest

from plantsim.turntable import servo
from plantsim.turntable import units
from plantsim.hardware.dynamixel.driver import DynamixelTurntable
from plantsim.hardware.dynamixel.emulator import OVERLOAD, DynamixelEmulator
from plantsim.errors import HardwareError, ServoAlarmError, ServoCommunicationError

CONFIG = servo.ServoConfig(
    position_p_gain=3200 / units.P_GAIN_DIVISOR * units.SI_PER_KP,
    position_i_gain=2000 / units.I_GAIN_DIVISOR * units.SI_PER_KI,
    velocity_feedforward_gain=0.26,
    profile_velocity=2.0,
    profile_acceleration=10.0,
)


@pytest.fixture
def emulator():
    # The bus clock: simulated time advances with the exchanges, so a move takes the
    # same number of polls and a fault lands at the same one however busy the machine.
    with DynamixelEmulator(ids=(1,), clock="bus", load_inertia=0.002) as emu:
        yield emu


# Scheduler allowance on top of the protocol's status timeout, s: the emulator thread
# shares the machine with the tests and whatever loads its cores. It costs nothing
# while statuses come; tests that expect a missing status set it to 0.
ALLOWANCE_S = 1.0


def make_turntable(emulator, **options):
    turntable = DynamixelTurntable(retries=2, scheduler_allowance_s=ALLOWANCE_S, **options)
    turntable.connect(emulator.port_path, baud_bps=57_600, dxl_id=1)
    return turntable


@pytest.fixture
def turntable(emulator):
    with make_turntable(emulator) as table:
        yield table


def test_connect_verifies_model_and_reads_firmware(turntable):
    assert turntable.ping() == 1020
    assert turntable.firmware_version == 46
    assert turntable.temperature() == 30.0
    assert turntable.hardware_error_status() == 0


def test_connect_refuses_another_model():
    with DynamixelEmulator(model="xl430-w250", clock="bus") as emu:
        with pytest.raises(ServoCommunicationError, match=r"model 1060 \(XL430-W250; pass model='xl430-w250'\)"):
            DynamixelTurntable(scheduler_allowance_s=ALLOWANCE_S).connect(emu.port_path)
        with DynamixelTurntable(model="xl430-w250", scheduler_allowance_s=ALLOWANCE_S) as table:
            table.connect(emu.port_path)
            with pytest.raises(HardwareError, match="has no current sensor"):
                table.current()


def test_wrong_baud_or_id_gives_actionable_error(emulator):
    with pytest.raises(ServoCommunicationError, match=r"There is no status packet.*baud rate and ID match"):
        DynamixelTurntable().connect(emulator.port_path, baud_bps=1_000_000)
    with pytest.raises(ServoCommunicationError, match=r"ID 5 at 57600 bps failed"):
        DynamixelTurntable().connect(emulator.port_path, dxl_id=5)
    with pytest.raises(ValueError, match="baud_bps must be one of"):
        DynamixelTurntable().connect(emulator.port_path, baud_bps=12345)
    with pytest.raises(ServoCommunicationError, match="cannot open /nonexistent"):
        DynamixelTurntable().connect("/nonexistent")


def test_configure_writes_registers_in_raw_units(turntable):
    turntable.configure(CONFIG)
    registers = CONFIG.to_registers()
    assert turntable.read_register("Position P Gain") == registers["Position P Gain"] == 3200
    assert turntable.read_register("Profile Velocity") == registers["Profile Velocity"]
    assert turntable.read_register("Operating Mode") == 3


def test_signed_registers_through_the_driver(turntable):
    turntable.write_register("Homing Offset", -2048)
    assert turntable.read_register("Homing Offset") == -2048
    assert turntable.position() == pytest.approx(-math.pi)


def test_eeprom_write_refused_while_torque_on(turntable):
    turntable.torque_on()
    with pytest.raises(ServoCommunicationError, match="EEPROM while torque is on"):
        turntable.write_register("Operating Mode", 4)
    turntable.torque_off()
    turntable.write_register("Operating Mode", 4)


def test_move_to_reaches_goal_and_reads_state(turntable):
    turntable.configure(CONFIG)
    turntable.torque_on()
    final = turntable.move_to(math.pi / 2, timeout_s=5, tolerance_rad=4 * units.RAD_PER_TICK)
    assert final == pytest.approx(math.pi / 2, abs=4 * units.RAD_PER_TICK)
    assert turntable.position() == pytest.approx(math.pi / 2, abs=4 * units.RAD_PER_TICK)
    assert abs(turntable.velocity()) < units.velocity_units_to_rad_s(10)  # Moving Threshold
    assert abs(turntable.current()) < 0.5


def test_move_to_validates_goal_and_torque(turntable):
    with pytest.raises(HardwareError, match="torque off; call torque_on"):
        turntable.move_to(1.0)
    turntable.torque_on()
    with pytest.raises(ValueError, match=r"angle_rad must be within the position limits \[0.0000, 6.2817\]"):
        turntable.move_to(-0.5)
    with pytest.raises(ValueError, match="angle_rad must be finite"):
        turntable.move_to(math.nan)


def test_move_times_out_with_position_in_message(emulator, turntable):
    turntable.configure(servo.ServoConfig(profile_velocity=0.5, profile_acceleration=5.0))
    turntable.torque_on()
    start = emulator.sim_time
    with pytest.raises(ServoCommunicationError, match=r"did not reach 3.1416 rad within 0.05 s \(at 0\.0"):
        turntable.move_to(math.pi, timeout_s=0.05)
    # Counted on the servo's clock: the move gave up 0.05 s (plus the setup reads and a
    # poll, about 0.1 s of bus time; a status retried under load adds a few ms) into a
    # 6 s move. On the wall clock it would have polled for an arbitrary simulated time.
    assert 0.05 < emulator.sim_time - start < 0.3


def test_move_timeout_counts_the_servos_clock_across_its_wrap(emulator, turntable):
    """Realtime Tick wraps at 32768 ms: the timeout still counts 0.2 s across the wrap."""
    turntable.configure(servo.ServoConfig(profile_velocity=0.5, profile_acceleration=5.0))
    turntable.torque_on()
    start = emulator.advance(32.7)  # the tick is 68 ms from its wrap
    with pytest.raises(ServoCommunicationError, match=r"within 0.2 s"):
        turntable.move_to(math.pi, timeout_s=0.2)
    # 0.2 s and the setup's exchanges (about 0.24 s in all; a retried status adds a few
    # ms): neither cut short at the wrap (a jump of 32.768 s) nor run on past it (a
    # negative step) to the end of the 6 s move.
    assert 0.2 < emulator.sim_time - start < 0.5 and emulator.sim_time > 32.768


def test_no_reply_and_corrupt_crc_become_hardware_errors(emulator, turntable):
    turntable.scheduler_allowance_s = 0.0  # every status is lost: no need to wait longer
    emulator.inject_no_reply(1, count=None)
    with pytest.raises(ServoCommunicationError, match=r"read Present Position on /dev/pts/\d+ ID 1 .*no status"):
        turntable.position()
    emulator.clear_faults()
    turntable.scheduler_allowance_s = ALLOWANCE_S  # a corrupt status comes: wait for it
    emulator.inject_corrupt_crc(1, count=None)
    with pytest.raises(ServoCommunicationError, match="Incorrect status packet"):
        turntable.position()
    emulator.clear_faults()
    assert turntable.ping() == 1020  # the port is usable afterwards


def test_retries_hide_one_lost_status_and_log_it(emulator, turntable, caplog):
    emulator.inject_no_reply(1, count=1)
    assert turntable.read_register("Model Number") == 1020
    assert "no status packet" in caplog.text and "attempt 1 of 3" in caplog.text


def test_a_garbled_instruction_is_sent_again_and_runs_once(emulator, turntable, caplog):
    """Noise on the bus: the servo answers a CRC error and did not run the instruction, so the
    driver sends it again (the bus is in step: no resynchronisation), within its retries."""
    emulator.inject_garbled_instruction(1, count=2)
    turntable.write_register("Profile Velocity", 77)
    with emulator.lock:
        assert emulator.servo(1).get("Profile Velocity") == 77 and emulator.servo(1).garble_count == 0
    assert caplog.text.count("garbled instruction") == 2 and "attempt 2 of 3" in caplog.text
    assert "discarded" not in caplog.text and "resynchronising" not in caplog.text
    emulator.inject_garbled_instruction(1, count=1)
    assert turntable.read_register("Model Number") == 1020


def test_a_bus_that_garbles_every_instruction_is_a_clear_error(emulator, turntable):
    emulator.inject_garbled_instruction(1, count=None)
    with pytest.raises(ServoCommunicationError, match=r"write Profile Velocity=5 on /dev/pts/\d+ ID 1: the servo "
                       r"received a garbled instruction \(CRC .*\) and did not run it\. Noise on the bus: check "
                       r"the cable"):
        turntable.write_register("Profile Velocity", 5)
    with emulator.lock:
        assert emulator.servo(1).get("Profile Velocity") != 5
    emulator.clear_faults()
    assert turntable.ping() == 1020


def test_overload_refused_without_permission(emulator, turntable):
    turntable.configure(CONFIG)
    turntable.torque_on()
    emulator.inject_hardware_error(1, OVERLOAD)
    with pytest.raises(ServoAlarmError, match="overload error.*allow_reboot=True") as caught:
        turntable.move_to(1.0, timeout_s=2)
    assert caught.value.hardware_error_status == OVERLOAD
    with pytest.raises(ServoAlarmError, match="overload error"):
        turntable.torque_on()  # refused by the servo; reported as the shutdown it is
    with pytest.raises(HardwareError, match="reboot of servo ID 1 refused"):
        turntable.reboot()


def test_overload_mid_move_recovers_by_reboot_when_allowed(emulator, caplog):
    with make_turntable(emulator, allow_reboot=True) as turntable:
        turntable.configure(CONFIG)
        turntable.torque_on()
        # 0.3 s of simulated time into a move of 1.7 s: mid-move however loaded the machine.
        start = emulator.sim_time
        fault_at = []
        emulator.call_at(start + 0.3, lambda: (emulator.inject_hardware_error(1, OVERLOAD),
                                               fault_at.append(emulator.servo(1).shaft.position)))
        final = turntable.move_to(3.0, timeout_s=30, tolerance_rad=4 * units.RAD_PER_TICK)
        assert "shut down during a move; rebooting" in caplog.text
        assert 0.05 < fault_at[0] < 1.0  # the shutdown came mid-move, well short of the goal
        assert final == pytest.approx(3.0, abs=4 * units.RAD_PER_TICK)
        assert turntable.hardware_error_status() == 0
        # The configuration survived the reboot (RAM is reset by the firmware).
        assert turntable.read_register("Position P Gain") == 3200


def test_disconnect_mid_move_releases_the_port(emulator, turntable):
    turntable.configure(CONFIG)
    turntable.torque_on()
    emulator.call_at(emulator.sim_time + 0.3, emulator.disconnect)  # a move of 3.5 s simulated
    with pytest.raises(ServoCommunicationError, match="the port failed.*connect\\(\\) again"):
        turntable.move_to(6.0, timeout_s=30)
    assert not turntable.connected
    with pytest.raises(ServoCommunicationError, match="not connected; call connect"):
        turntable.position()
    # A new bus on a new pty: the same object connects again.
    with DynamixelEmulator() as other:
        turntable.connect(other.port_path)
        assert turntable.ping() == 1020


def test_driver_arguments_are_validated():
    with pytest.raises(ValueError, match="retries must be an integer >= 0"):
        DynamixelTurntable(retries=-1)
    with pytest.raises(ValueError, match="model must be one of"):
        DynamixelTurntable(model="ax-12a")
    with pytest.raises(ValueError, match=r"dxl_id must be in \[0, 252\]"):
        DynamixelTurntable().connect("/dev/null", dxl_id=300)
