"""The real dynamixel_sdk against the emulator on a pty: protocol behaviour."""

import math
import time

import numpy as np
import pytest
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    Protocol2PacketHandler,
)

from plantsim.turntable import servo
from plantsim.turntable import units
from plantsim.hardware.dynamixel.driver import port_handler
from plantsim.hardware.dynamixel.emulator import OVERLOAD, DynamixelEmulator

@pytest.fixture
def emulator():
    # The bus clock: simulated time advances with the exchanges, not the wall clock.
    with DynamixelEmulator(ids=(1, 2), clock="bus", load_inertia=0.002) as emu:
        yield emu


# Scheduler allowance on top of the protocol's status timeout, s: an emulator thread on
# a machine whose cores are busy can be kept waiting by the scheduler. It costs
# nothing while statuses come (NoReplyExpected drops it where none will).
ALLOWANCE_S = 1.0


def open_port(path):
    handler = port_handler(path, scheduler_allowance_s=ALLOWANCE_S)
    assert handler.openPort() and handler.setBaudRate(57_600)
    return handler


@pytest.fixture
def port(emulator):
    handler = open_port(emulator.port_path)
    yield handler
    handler.closePort()


class NoReplyExpected(Protocol2PacketHandler):
    """The real SDK handler without the scheduler allowance, for exchanges whose status
    is certainly missing (wrong baud, absent ID, status return level 0)."""

    def txRxPacket(self, port, txpacket):
        saved, port.allowance_s = port.allowance_s, 0.0
        try:
            return super().txRxPacket(port, txpacket)
        finally:
            port.allowance_s = saved


@pytest.fixture
def ph():
    return PacketHandler(2.0)


@pytest.fixture
def plain_ph():
    return NoReplyExpected()


def test_ping_reports_xm430(port, ph, plain_ph):
    assert ph.ping(port, 1) == (1020, COMM_SUCCESS, 0)
    assert ph.ping(port, 2)[0] == 1020
    assert plain_ph.ping(port, 9)[1] == COMM_RX_TIMEOUT


def test_reads_writes_and_signed_values(port, ph):
    assert ph.read1ByteTxRx(port, 1, 11) == (3, COMM_SUCCESS, 0)  # Operating Mode
    assert ph.read2ByteTxRx(port, 1, 84)[0] == 800  # Position P Gain
    assert ph.write4ByteTxRx(port, 1, 20, units.to_unsigned(-1000, 4)) == (COMM_SUCCESS, 0)
    raw, result, _ = ph.read4ByteTxRx(port, 1, 20)
    assert units.to_signed(raw, 4) == -1000
    # Homing offset shifts Present Position: signed and negative now.
    raw, _, _ = ph.read4ByteTxRx(port, 1, 132)
    assert units.to_signed(raw, 4) == -1000
    assert ph.write2ByteTxRx(port, 1, 100, units.to_unsigned(-300, 2)) == (COMM_SUCCESS, 0)
    assert units.to_signed(ph.read2ByteTxRx(port, 1, 100)[0], 2) == -300


def test_protocol_errors(port, ph):
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)  # torque on
    assert ph.write1ByteTxRx(port, 1, 11, 4) == (COMM_SUCCESS, 7)  # EEPROM with torque on: access
    assert ph.read1ByteTxRx(port, 1, 11)[0] == 3
    assert ph.write1ByteTxRx(port, 1, 146, 20)[1] == 7  # read-only
    assert ph.write1ByteTxRx(port, 1, 65, 2)[1] == 4  # LED: range
    assert ph.write4ByteTxRx(port, 1, 116, 5000)[1] == 6  # beyond Max Position Limit: limit
    assert ph.write2ByteTxRx(port, 1, 116, 100)[1] == 5  # half a register: length
    assert ph.write1ByteTxRx(port, 1, 66, 0)[1] == 7  # reserved gap
    # Beyond the table: an access error and no data. (The SDK's read4ByteTxRx raises
    # IndexError on such a status and readTxRx returns the CRC bytes as data, so the
    # driver checks the error byte before it looks at data.)
    assert ph.readTxRx(port, 1, 200, 4)[1:] == (COMM_SUCCESS, 7)


def test_baud_mismatch_gets_no_reply(port, ph, plain_ph):
    assert port.setBaudRate(1_000_000)
    assert plain_ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
    assert port.setBaudRate(57_600)
    assert ph.ping(port, 1)[1] == COMM_SUCCESS


def test_baud_register_change_takes_effect_after_reply(port, ph, plain_ph):
    assert ph.write1ByteTxRx(port, 1, 8, 3) == (COMM_SUCCESS, 0)  # 1 Mbps
    assert plain_ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
    assert port.setBaudRate(1_000_000)
    assert ph.ping(port, 1)[1] == COMM_SUCCESS
    assert plain_ph.ping(port, 2)[1] == COMM_RX_TIMEOUT  # still at 57600


def test_status_return_level_and_return_delay(emulator, port, ph, plain_ph):
    assert ph.write1ByteTxRx(port, 1, 68, 1) == (COMM_SUCCESS, 0)  # answered under the old level
    assert plain_ph.write1ByteTxRx(port, 1, 65, 1)[0] == COMM_RX_TIMEOUT  # writes no longer answered
    assert ph.read1ByteTxRx(port, 1, 65) == (1, COMM_SUCCESS, 0)  # but the write happened
    assert ph.write1ByteTxRx(port, 2, 9, 0) == (COMM_SUCCESS, 0)
    # On the bus clock a PING exchange takes the host's gap, the 10-byte instruction,
    # the Return Delay Time and the 14-byte status at 57600 bps (10 bits a byte).
    for dxl_id, delay_s in ((1, 500e-6), (2, 0.0)):
        start = emulator.sim_time
        for _ in range(20):
            assert ph.ping(port, dxl_id)[1] == COMM_SUCCESS
        per_ping_s = (emulator.sim_time - start) / 20
        assert per_ping_s == pytest.approx(emulator.host_gap_s + (10 + 14) * 10 / 57_600 + delay_s, abs=1e-9)


def test_return_delay_is_waited_in_real_time_on_the_wall_clock():
    with DynamixelEmulator(ids=(1,)) as emu:
        port = open_port(emu.port_path)
        ph = PacketHandler(2.0)
        start = time.perf_counter()
        for _ in range(20):
            assert ph.ping(port, 1)[1] == COMM_SUCCESS
        assert (time.perf_counter() - start) / 20 >= 500e-6  # a lower bound: holds however loaded
        port.closePort()


def analytic_ticks(t_ms, distance_ticks, pv, pa):
    """Firmware profile in ticks and ms: v = PV/64 tick/ms, a = PA/4096 tick/ms^2."""
    v, a, d = pv / 64.0, pa / 4096.0, abs(distance_ticks)
    if d <= pv**2 / pa:
        t1, t_cruise, v_peak = math.sqrt(d / a), 0.0, math.sqrt(d * a)
    else:
        t1, t_cruise, v_peak = v / a, (d - v * v / a) / v, v
    total = 2 * t1 + t_cruise
    t = np.clip(t_ms, 0, total)
    p = np.where(t < t1, 0.5 * a * t**2,
                 np.where(t < t1 + t_cruise, 0.5 * a * t1**2 + v_peak * (t - t1), d - 0.5 * a * (total - t) ** 2))
    return np.sign(distance_ticks) * p


TUNED = servo.ServoConfig(
    position_p_gain=3200 / units.P_GAIN_DIVISOR * units.SI_PER_KP,
    position_i_gain=2000 / units.I_GAIN_DIVISOR * units.SI_PER_KI,
    velocity_feedforward_gain=(servo.ServoConfig().damping + servo.ServoConfig().back_emf_damping) / 4.1,
    profile_velocity=units.velocity_units_to_rad_s(100),
    profile_acceleration=units.acceleration_units_to_rad_s2(20),
)


@pytest.fixture
def slow_port():
    # The bus clock: a sample per exchange (about 6 ms of simulated time at 57600 bps),
    # as many per move however loaded the machine.
    with DynamixelEmulator(ids=(1,), clock="bus", load_inertia=0.002) as emu:
        handler = open_port(emu.port_path)
        yield handler
        handler.closePort()


@pytest.mark.parametrize("goal_ticks", [1500, 400])  # trapezoid, triangle (d <= PV^2/PA = 500)
def test_goal_reached_along_the_profile(slow_port, ph, goal_ticks):
    port = slow_port
    for name, value in TUNED.to_registers().items():
        address, size = {"Position P Gain": (84, 2), "Position I Gain": (82, 2), "Position D Gain": (80, 2),
                         "Feedforward 1st Gain": (90, 2), "Feedforward 2nd Gain": (88, 2),
                         "Profile Velocity": (112, 4), "Profile Acceleration": (108, 4),
                         "PWM Limit": (36, 2)}[name]
        assert getattr(ph, f"write{size}ByteTxRx")(port, 1, address, value) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    tick_before = ph.read2ByteTxRx(port, 1, 120)[0]
    assert ph.write4ByteTxRx(port, 1, 116, goal_ticks) == (COMM_SUCCESS, 0)
    tick_after = ph.read2ByteTxRx(port, 1, 120)[0]
    samples = []
    for _ in range(5000):  # about 30 s simulated: far beyond either move
        data, result, _ = ph.readTxRx(port, 1, 120, 24)  # Realtime Tick .. Position Trajectory
        assert result == COMM_SUCCESS
        raw = bytes(data)
        tick = int.from_bytes(raw[0:2], "little")
        moving, moving_status = raw[2], raw[3]
        present = units.to_signed(int.from_bytes(raw[12:16], "little"), 4)
        trajectory = units.to_signed(int.from_bytes(raw[20:24], "little"), 4)
        samples.append((tick, present, trajectory))
        if not moving and len(samples) > 3:
            break
    assert not moving and moving_status & 0x01  # in position
    expected_kind = 2 if goal_ticks <= 500 else 3
    assert (moving_status >> 4) & 0x3 == expected_kind
    tick, present, trajectory = (np.array(x, dtype=float) for x in zip(*samples))
    tick = np.unwrap(tick, period=32768)
    # One free parameter, the start tick, bracketed by reads before and after the write.
    candidates = np.arange(tick_before - 1, tick_after + 1, 0.1)
    errors = [np.max(np.abs(trajectory - analytic_ticks(tick - t0, goal_ticks, 100, 20))) for t0 in candidates]
    t0 = candidates[int(np.argmin(errors))]
    assert min(errors) <= 3  # Position Trajectory is the firmware profile
    reference = analytic_ticks(tick - t0, goal_ticks, 100, 20)
    assert np.max(np.abs(present - reference)) <= 10
    assert abs(present[-1] - goal_ticks) <= 4  # Moving drops at the end of the profile
    assert len(samples) >= 6


def group_txrx(group):
    """A group read (the port's timeout margin covers a descheduled emulator)."""
    return group.txRxPacket()


def test_sync_read_and_sync_write_two_servos(port, ph):
    writer = GroupSyncWrite(port, ph, 65, 1)  # LED
    assert writer.addParam(1, [1]) and writer.addParam(2, [1])
    assert writer.txPacket() == COMM_SUCCESS
    reader = GroupSyncRead(port, ph, 64, 2)  # Torque Enable, LED
    assert reader.addParam(1) and reader.addParam(2)
    assert group_txrx(reader) == COMM_SUCCESS
    assert reader.getData(1, 65, 1) == 1 and reader.getData(2, 65, 1) == 1
    assert reader.addParam(7)
    port.allowance_s = 0.0  # ID 7's status will not come: no need to allow for the scheduler
    assert reader.txRxPacket() == COMM_RX_TIMEOUT  # one absent ID fails the group


def test_bulk_read(port, ph):
    assert ph.write1ByteTxRx(port, 2, 65, 1)[0] == COMM_SUCCESS
    reader = GroupBulkRead(port, ph)
    assert reader.addParam(1, 0, 2) and reader.addParam(2, 65, 1)
    assert group_txrx(reader) == COMM_SUCCESS
    assert reader.getData(1, 0, 2) == 1020
    assert reader.getData(2, 65, 1) == 1


def test_reg_write_action_and_factory_reset(port, ph):
    assert ph.regWriteTxRx(port, 1, 65, 1, [1]) == (COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 1, 69)[0] == 1  # Registered Instruction
    assert ph.read1ByteTxRx(port, 1, 65)[0] == 0
    ph.action(port, 1)
    assert ph.read1ByteTxRx(port, 1, 65)[0] == 1
    assert ph.write2ByteTxRx(port, 1, 84, 1234)[0] == COMM_SUCCESS
    assert ph.factoryReset(port, 1, 0x02) == (COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 1, 84)[0] == 800


def test_injected_faults(emulator, port, ph, plain_ph):
    emulator.inject_no_reply(1, count=1)
    assert plain_ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
    assert ph.ping(port, 1)[1] == COMM_SUCCESS
    emulator.inject_corrupt_crc(1)
    assert ph.ping(port, 1)[1] == COMM_RX_CORRUPT
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    emulator.inject_hardware_error(1, OVERLOAD)
    model, result, error = ph.ping(port, 1)
    assert error & 0x80  # alert in every status
    assert ph.read1ByteTxRx(port, 1, 70)[0] == OVERLOAD
    assert ph.read1ByteTxRx(port, 1, 64)[0] == 0  # torque dropped
    assert ph.write1ByteTxRx(port, 1, 64, 1)[1] == 0x80 | 1  # refused until reboot
    assert ph.reboot(port, 1) == (COMM_SUCCESS, 0x80)  # answered before rebooting
    assert ph.read1ByteTxRx(port, 1, 70) == (0, COMM_SUCCESS, 0)


def test_fault_injection_validates(emulator):
    with pytest.raises(ValueError, match="count must be an integer >= 1"):
        emulator.inject_no_reply(1, count=0)
    with pytest.raises(ValueError, match="bits must be a non-zero Hardware Error Status byte"):
        emulator.inject_hardware_error(1, 0)
    with pytest.raises(KeyError, match="no servo with ID 9"):
        emulator.inject_corrupt_crc(9)


def test_bad_crc_instruction_gets_crc_error(emulator, port):
    from plantsim.hardware.dynamixel import protocol

    packet = bytearray(protocol.build_instruction(1, protocol.Instruction.PING))
    packet[-1] ^= 0xFF
    port.clearPort()
    port.writePort(bytes(packet))
    deadline = time.monotonic() + 10  # only a broken emulator waits this long
    received = b""
    while time.monotonic() < deadline and len(received) < 11:
        received += port.readPort(64)
    status = protocol.parse_packet(received)
    assert status.error == protocol.ErrorCode.CRC


def test_broadcast_ping_and_broadcast_write(port, ph):
    found, result = ph.broadcastPing(port)
    assert result == COMM_SUCCESS and found == {1: [1020, 46], 2: [1020, 46]}
    assert ph.write1ByteTxOnly(port, 254, 65, 1) == COMM_SUCCESS  # no status expected
    assert ph.read1ByteTxRx(port, 1, 65)[0] == 1 and ph.read1ByteTxRx(port, 2, 65)[0] == 1


def test_stuffed_values_round_trip_through_the_sdk(port, ph):
    value = -131073  # little endian FF FF FD FF: stuffed on the way in and on the way out
    assert units.to_unsigned(value, 4).to_bytes(4, "little") == b"\xff\xff\xfd\xff"
    assert ph.write4ByteTxRx(port, 1, 20, units.to_unsigned(value, 4)) == (COMM_SUCCESS, 0)
    assert units.to_signed(ph.read4ByteTxRx(port, 1, 20)[0], 4) == value


def test_emulator_arguments_are_validated():
    with pytest.raises(ValueError, match=r"ids must be distinct integers in \[0, 252\]"):
        DynamixelEmulator(ids=(1, 1))
    with pytest.raises(ValueError, match="speed_factor must be finite and > 0"):
        DynamixelEmulator(speed_factor=0)
    with pytest.raises(ValueError, match="baud_bps must be one of"):
        DynamixelEmulator(baud_bps=12345)
    with pytest.raises(ValueError, match="model must be one of"):
        DynamixelEmulator(model="ax-12a")
