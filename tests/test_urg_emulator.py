"""The URG emulator's bytes, read by a minimal SCIP reader written here (not protocol.py).

The reader opens the pty itself, sends command lines and splits what comes back at
LF LF; it decodes and checks sums with its own arithmetic. Wall time is only a
generous deadline for bytes that must come; the emulator runs on a virtual clock.
"""

import os
import select
import time
import tty

import numpy as np
import pytest

from plantsim.hardware.urg.emulator import UrgEmulator, VirtualClock
from plantsim.sensor.spec import BeamStatus

DEADLINE_S = 10.0


def dec(chars: str) -> int:
    value = 0
    for c in chars:
        value = value * 64 + (ord(c) - 48)
    return value


def summed(text: str) -> str:
    return chr((sum(text.encode()) & 63) + 48)


class Reader:
    """Sends lines to the pty and returns whole replies as lists of lines."""

    def __init__(self, path):
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.buffer = b""

    def close(self):
        os.close(self.fd)

    def ask(self, line: str) -> list[str]:
        os.write(self.fd, line.encode() + b"\n")
        return self.reply()

    def reply(self) -> list[str]:
        end = time.monotonic() + DEADLINE_S
        while b"\n\n" not in self.buffer:
            assert time.monotonic() < end, f"no complete reply; got {self.buffer[:80]!r}"
            if select.select([self.fd], [], [], 0.05)[0]:
                self.buffer += os.read(self.fd, 4096)
        block, self.buffer = self.buffer.split(b"\n\n", 1)
        return block.decode().split("\n")


def provider(t):
    """Step k reads 500 + k mm; a few statuses; the time goes into step 768's range."""
    ranges = (500 + np.arange(UrgEmulator.N_STEPS)) / 1000.0
    status = np.full(UrgEmulator.N_STEPS, BeamStatus.OK, dtype=np.int8)
    status[100], status[101], status[102] = BeamStatus.NO_ECHO, BeamStatus.LOW_INTENSITY, BeamStatus.EDGE
    ranges[768] = 1.0 + t
    return ranges, status


@pytest.fixture
def sensor():
    clock = VirtualClock()
    with UrgEmulator(provider, clock=clock, timestamp_offset_s=100.0) as emulator:
        reader = Reader(emulator.port_path)
        yield emulator, reader, clock
        reader.close()


def check_sums(lines, *, key_values=False):
    """The URG-04LX leaves the ';' of KEY:value; lines out of their sums."""
    for line in lines:
        body = line[:-1]
        if key_values:
            assert body.endswith(";"), line
            body = body[:-1]
        assert summed(body) == line[-1], line


def test_vv_pp_ii_lines_and_checksums(sensor):
    emulator, reader, _ = sensor
    vv = reader.ask("VV;hello")
    assert vv[0] == "VV;hello" and vv[1] == "00P"
    check_sums(vv[2:], key_values=True)
    assert [line.split(":")[0] for line in vv[2:]] == ["VEND", "PROD", "FIRM", "PROT", "SERI"]
    pp = reader.ask("PP")
    check_sums(pp[2:], key_values=True)
    values = {line.split(":")[0]: line.split(":", 1)[1][:-2] for line in pp[2:]}
    assert values["ARES"] == "1024" and values["AMIN"] == "44" and values["AMAX"] == "725"
    assert values["AFRT"] == "384" and values["DMIN"] == "20" and values["DMAX"] == "5600" and values["SCAN"] == "600"
    ii = reader.ask("II")
    check_sums(ii[2:], key_values=True)
    assert "LASR:OFF" in ii[3]


def test_gd_bytes(sensor):
    emulator, reader, clock = sensor
    assert reader.ask("GD0044072501") == ["GD0044072501", "10" + summed("10")]  # laser off
    assert reader.ask("BM;x") == ["BM;x", "00P"]
    assert reader.ask("BM") == ["BM", "02" + summed("02")]  # already on
    lines = reader.ask("GD0044072501;tag.1")
    assert lines[0] == "GD0044072501;tag.1" and lines[1] == "00P"
    assert len(lines[2]) == 5 and summed(lines[2][:4]) == lines[2][4]
    stamp_ms = dec(lines[2][:4])
    assert all(len(line) <= 65 for line in lines[3:]) and all(len(line) == 65 for line in lines[3:-1])
    check_sums(lines[2:])
    data = "".join(line[:-1] for line in lines[3:])
    assert len(data) == 682 * 3
    values = [dec(data[i:i + 3]) for i in range(0, len(data), 3)]
    steps = np.arange(44, 726)
    expected = 500 + steps
    expected[steps == 100], expected[steps == 101], expected[steps == 102] = 0, 1, 7
    assert values == list(expected)
    # The scan started on a 100 ms mirror turn after BM; the stamp is the sensor's ms timer.
    assert stamp_ms % 100 == 0 and stamp_ms >= 100_000
    assert clock.now() >= (stamp_ms / 1000 - 100.0) + 726 / 1024 * 0.1 - 1e-9


def test_gs_two_character_and_cluster(sensor):
    emulator, reader, _ = sensor
    reader.ask("BM")
    lines = reader.ask("GS0200020903")
    data = "".join(line[:-1] for line in lines[3:])
    values = [dec(data[i:i + 2]) for i in range(0, len(data), 2)]
    assert values == [700, 703, 706, 709]  # the nearest of each 3 steps; the last cluster is 1 step


def test_md_streams_every_turn_with_remaining_count(sensor):
    emulator, reader, _ = sensor
    ack = reader.ask("MD0044004501003;s")
    assert ack == ["MD0044004501003;s", "00P"]
    scans = [reader.reply() for _ in range(3)]
    assert [s[0] for s in scans] == ["MD0044004501002;s", "MD0044004501001;s", "MD0044004501000;s"]
    assert all(s[1] == "99" + summed("99") == "99b" for s in scans)
    stamps = [dec(s[2][:4]) for s in scans]
    assert np.diff(stamps).tolist() == [100, 100]
    assert not emulator.streaming and not emulator.laser_on  # off again after the last scan


def test_md_skip_and_qt(sensor):
    emulator, reader, _ = sensor
    reader.ask("MD0044004501100")
    a, b = reader.reply(), reader.reply()
    assert dec(b[2][:4]) - dec(a[2][:4]) == 200  # every other turn
    os.write(reader.fd, b"QT\n")
    while True:  # scans already on their way may come before the QT echo
        reply = reader.reply()
        if reply[0] == "QT":
            break
    assert reply == ["QT", "00P"] and not emulator.streaming


def test_provider_sees_each_scans_start_time(sensor):
    emulator, reader, _ = sensor
    reader.ask("BM")
    lines = reader.ask("GD0768076800")
    t_scan = dec(lines[2][:4]) / 1000 - 100.0
    assert dec(lines[3][:3]) == round(1000 * (1.0 + t_scan))


def test_tm_mode(sensor):
    emulator, reader, clock = sensor
    assert reader.ask("TM1") == ["TM1", "04" + summed("04")]
    assert reader.ask("TM0") == ["TM0", "00P"]
    assert reader.ask("GD0044072501")[1] == "0E" + summed("0E")  # nothing else in time-adjust mode
    clock.advance(1.234)
    lines = reader.ask("TM1;q")
    assert lines[1] == "00P" and summed(lines[2][:4]) == lines[2][4]
    assert dec(lines[2][:4]) == 101_234
    assert reader.ask("TM2") == ["TM2", "00P"]
    assert reader.ask("TM2") == ["TM2", "03" + summed("03")]


def test_rs_resets_the_timer(sensor):
    emulator, reader, clock = sensor
    clock.advance(5.0)
    assert reader.ask("RS") == ["RS", "00P"]
    clock.advance(0.25)
    reader.ask("TM0")
    assert dec(reader.ask("TM1")[2][:4]) == 250


@pytest.mark.parametrize("line, status", [("GD00440725", "0C"), ("GD004407250", "0C"), ("GDx044072501", "01"),
                                          ("GD0044099901", "04"), ("GD0700004401", "05"), ("XX", "0E"),
                                          ("VV;" + "a" * 17, "0G"), ("VV;a;b", "0H"), ("MD0044072501x00", "06")])
def test_error_statuses(sensor, line, status):
    emulator, reader, _ = sensor
    reader.ask("BM")
    assert reader.ask(line) == [line, status + summed(status)]


def test_scip11_start():
    with UrgEmulator(clock=VirtualClock(), start_in_scip11=True) as emulator:
        reader = Reader(emulator.port_path)
        assert reader.ask("QT") == ["QT", "E"]
        assert reader.ask("SCIP2.0") == ["SCIP2.0", "0"]
        assert reader.ask("QT") == ["QT", "00P"]
        reader.close()


def test_cr_terminated_commands(sensor):
    emulator, reader, _ = sensor
    os.write(reader.fd, b"QT;a\r\nQT;b\r")
    assert reader.reply() == ["QT;a", "00P"]
    assert reader.reply() == ["QT;b", "00P"]


def test_injected_checksum_errors_every_nth_line(sensor):
    emulator, reader, _ = sensor
    emulator.inject_checksum_errors(2)
    lines = reader.ask("BM")[1:] + reader.ask("QT")[1:]
    assert lines[0] == "00P" and lines[1] != "00P"  # the 2nd line with a checksum is wrong


def test_latency_delays_replies_on_the_virtual_clock():
    clock = VirtualClock()
    with UrgEmulator(clock=clock, latency_s=0.005) as emulator:
        reader = Reader(emulator.port_path)
        reader.ask("TM0")
        t0 = clock.now()
        stamp = dec(reader.ask("TM1")[2][:4])
        assert clock.now() == pytest.approx(t0 + 0.010)
        assert stamp == int((t0 + 0.005) * 1000)
        reader.close()
