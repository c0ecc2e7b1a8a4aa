"""Safety stops: whatever interrupts the servo, its torque ends off, read back from the emulator.

Moves are interrupted at many points of their packet exchanges (before a packet is
written, after it is written and before its status is read, while the status is being
read, between SDK calls), by ``KeyboardInterrupt`` (Ctrl-C) and by a real SIGTERM sent
to this process; a lost link is reported as unconfirmed in one line.
"""

import io
import math
import os
import signal
import sys
import weakref

import pytest

from plantsim.cli.rig import rig_safety
from plantsim.errors import Terminated, UnsafeStopError
from plantsim.hardware.dynamixel import driver as dxl_driver
from plantsim.hardware.dynamixel.emulator import DynamixelEmulator
from plantsim.hardware.dynamixel.turntable import ServoStatus, ServoTurntable
from plantsim.hardware.safety import SafeStop, StopAction
from plantsim.interrupts import raise_if_signalled

# The scheduler allowance for an emulator thread the scheduler keeps waiting (see test_dxl_driver).
ALLOWANCE_S = 1.0
FAST = dict(retries=2, profile_velocity_rad_s=3.0, profile_acceleration_rad_s2=20.0,
            driver_options={"scheduler_allowance_s": ALLOWANCE_S})
WHERE = ("before_write", "after_write", "in_read", "after_call")


def no_sleep(seconds):
    pass


class Tripwire:
    """Sends Ctrl-C (SIGINT) or another signal to this process at packet k.

    Installed on every port the driver opens while armed. Packets are counted by
    ``writePort``; ``where`` places the interruption within packet k's exchange.
    """

    def __init__(self, monkeypatch, k, where, fire=None):
        self.k, self.where, self.packets, self.fired, self.armed = k, where, 0, False, False
        self._fire = fire or self._raise
        original = dxl_driver.port_handler

        def port_handler(port, **options):
            handler = original(port, **options)
            self._install(handler)
            return handler

        monkeypatch.setattr(dxl_driver, "port_handler", port_handler)

    @staticmethod
    def _raise():
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C: KeyboardInterrupt at the next bytecode

    def _trip(self, where):
        if self.armed and not self.fired and self.packets == self.k and where == self.where:
            self.fired = True
            self._fire()

    def _install(self, handler):
        write, read, clear = handler.writePort, handler.readPort, handler.clearPort

        def write_port(packet):
            if self.armed:
                self.packets += 1
            self._trip("before_write")
            n = write(packet)
            self._trip("after_write")
            return n

        def read_port(length):
            self._trip("in_read")
            return read(length)

        def clear_port():
            # txPacket clears the port first: the previous exchange is over here.
            self._trip("after_call")
            return clear()

        handler.writePort, handler.readPort, handler.clearPort = write_port, read_port, clear_port


@pytest.fixture(autouse=True)
def ctrl_c_raises():
    """Ctrl-C raises KeyboardInterrupt, as in a terminal, even when the test run itself was
    started with SIGINT ignored (a background job of a non-interactive shell)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.fixture
def emulator():
    with DynamixelEmulator(ids=(1,), clock="bus") as emu:
        yield emu


def torque_on_in_emulator(emulator):
    with emulator.lock:
        return emulator.servo(1).torque_on


def send_swallowed(signum, monkeypatch):
    """Sends ``signum`` to this process from inside a weakref callback, where the
    interpreter prints the handler's exception and goes on ("Exception ignored in"), as
    it does for a signal landing in an import lock's callback. Returns the exception
    types the interpreter swallowed (so a test can show it did)."""
    swallowed = []
    monkeypatch.setattr(sys, "unraisablehook", lambda unraisable: swallowed.append(unraisable.exc_type))

    class Box:
        pass

    box = Box()
    refs = [weakref.ref(box, lambda _ref: signal.raise_signal(signum))]  # kept alive, so it fires
    del box  # the callback runs here, and the handler inside it
    assert refs[0]() is None
    return swallowed


def interrupted_moves(emulator, tripwire, goals=(1.0, 2.5, 0.5)):
    """Connects under a SafeStop, arms the tripwire, moves; returns the SafeStop."""
    safety = SafeStop(sleep=no_sleep)
    with pytest.raises(KeyboardInterrupt):
        with safety:
            table = ServoTurntable.connect(emulator.port_path, safety=safety, **FAST)
            assert torque_on_in_emulator(emulator)
            tripwire.armed = True
            for goal in goals:
                table.move_to(goal)
            tripwire.armed = False
            raise AssertionError(f"the tripwire at packet {tripwire.k} ({tripwire.where}) never fired")
    return safety


@pytest.mark.parametrize("where", WHERE)
def test_ctrl_c_at_any_packet_of_a_move_leaves_torque_off(emulator, monkeypatch, where):
    trials = 0
    for k in (1, 2, 3, 4, 5, 7, 10, 14, 19, 25):
        tripwire = Tripwire(monkeypatch, k, where)
        safety = interrupted_moves(emulator, tripwire)
        assert tripwire.fired
        assert safety.report.reason == "Ctrl-C"
        assert safety.report.safe, safety.report.warning()
        assert not torque_on_in_emulator(emulator), f"torque on after Ctrl-C at packet {k} ({where})"
        trials += 1
    assert trials == 10


@pytest.mark.parametrize("k", [2, 6, 11])
def test_sigterm_mid_move_unwinds_and_leaves_torque_off(emulator, monkeypatch, k):
    tripwire = Tripwire(monkeypatch, k, "after_write", fire=lambda: os.kill(os.getpid(), signal.SIGTERM))
    safety = SafeStop(sleep=no_sleep)
    with pytest.raises(Terminated, match="terminated by SIGTERM"):
        with safety:
            table = ServoTurntable.connect(emulator.port_path, safety=safety, **FAST)
            tripwire.armed = True
            for goal in (2.0, 0.3):
                table.move_to(goal)
    assert tripwire.fired and safety.report.reason == "SIGTERM" and safety.report.safe
    assert not torque_on_in_emulator(emulator)
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # handler restored


def test_ctrl_c_during_connect_and_configure_leaves_torque_off(emulator, monkeypatch):
    # From the PING of connect through the torque-on write: every packet of the setup.
    for k in range(1, 41):
        tripwire = Tripwire(monkeypatch, k, "after_write")
        tripwire.armed = True
        safety = SafeStop(sleep=no_sleep)
        try:
            with safety:
                ServoTurntable.connect(emulator.port_path, safety=safety, **FAST)
        except KeyboardInterrupt:
            pass
        if not tripwire.fired:
            # Past the setup: the servo is on, and the normal end switches it off.
            assert safety.report.safe and not torque_on_in_emulator(emulator)
            break
        assert safety.report is not None and safety.report.safe
        assert not torque_on_in_emulator(emulator), f"torque on after Ctrl-C at setup packet {k}"
    else:
        raise AssertionError("the setup took more than 40 packets")


def test_the_busy_port_left_by_an_interrupt_no_longer_refuses_torque_off(emulator, monkeypatch):
    """The reported fault: 'Port is in use!' after Ctrl-C, torque left on."""
    tripwire = Tripwire(monkeypatch, 3, "in_read")
    table = ServoTurntable.connect(emulator.port_path, **FAST)
    tripwire.armed = True
    with pytest.raises(KeyboardInterrupt):
        table.move_to(2.0)
    assert table.driver._port.is_using  # what the SDK leaves behind
    assert torque_on_in_emulator(emulator)
    assert table.close() is True  # plain close, no SafeStop: still off, read back
    assert not torque_on_in_emulator(emulator)


def test_lost_link_is_reported_unconfirmed_in_one_line(monkeypatch):
    stream = io.StringIO()
    with DynamixelEmulator(ids=(1,), clock="bus") as emulator:
        monkeypatch.setattr("plantsim.hardware.safety.time.sleep", no_sleep)
        with pytest.raises(Exception) as caught:
            with rig_safety(stream) as safety:
                table = ServoTurntable.connect(emulator.port_path, safety=safety, **FAST)
                emulator.call_at(emulator.sim_time + 0.2, emulator.disconnect)
                table.move_to(6.0)
        assert torque_on_in_emulator(emulator)  # the servo, unreachable, still holds
    line = stream.getvalue()
    assert line.count("\n") == 1
    assert line.startswith("plantsim: DANGER: servo torque NOT confirmed off after 3 attempts (")
    assert "switch off the servo's 12 V supply now" in line
    assert "the port failed" in str(caught.value)
    assert any("DANGER" in note for note in caught.value.__notes__)
    assert not safety.report.safe and safety.report.reason.startswith("error: ServoCommunicationError")


def test_unconfirmed_stop_at_a_normal_end_raises():
    calls = []
    with pytest.raises(UnsafeStopError, match=r"DANGER: laser NOT confirmed off after 2 attempts \(the read-back "
                       r"says it is still on\): unplug the LiDAR") as caught:
        with SafeStop(attempts=2, sleep=calls.append) as safety:
            safety.register("laser", lambda: None, lambda: False, advice="unplug the LiDAR")
    assert calls == [0.1]
    assert caught.value.report.outcomes[0].attempts == 2


def test_actions_run_last_first_with_retries_and_signals_held(monkeypatch):
    order = []
    failures = iter([RuntimeError("bus busy")])

    def flaky_stop():
        order.append("servo")
        failure = next(failures, None)
        if failure:
            raise failure

    def laser_stop():
        order.append("laser")
        os.kill(os.getpid(), signal.SIGINT)  # an impatient second Ctrl-C: held back

    with SafeStop(sleep=no_sleep) as safety:
        safety.register("servo torque", flaky_stop, lambda: True)
        safety.register(StopAction("LiDAR laser", laser_stop))
    assert order == ["laser", "servo", "servo"]
    report = safety.report
    assert report.safe and report.reason == "normal end"
    assert [(o.name, o.attempts) for o in report.outcomes] == [("LiDAR laser", 1), ("servo torque", 2)]
    assert report.summary() == "LiDAR laser off (confirmed), servo torque off (confirmed)"
    assert report.warning() == ""


def test_safe_stop_validates():
    with pytest.raises(ValueError, match="attempts must be an integer >= 1"):
        SafeStop(attempts=0)
    with pytest.raises(ValueError, match="stop must be callable"):
        StopAction("servo", None)
    with pytest.raises(ValueError, match="name must be a non-empty string"):
        StopAction("", lambda: None)


def test_status_readings(emulator):
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        table.move_to(1.0)
        status = table.status()
        assert isinstance(status, ServoStatus)
        assert status.position_rad == pytest.approx(1.0, abs=3 * 2 * math.pi / 4096)
        assert status.temperature_c == 30.0 and status.input_voltage_v == pytest.approx(12.0)
        assert status.hardware_errors == () and status.torque_enabled and not status.moving
        assert abs(status.velocity_rad_s) < 0.05
        assert status.current_a is not None and abs(status.load_percent) < 20
        assert table.load_percent() == pytest.approx(100 * table.current_a() / (1193 * 2.69e-3), abs=1.0)
        emulator.inject_hardware_error(1)
        assert table.hardware_errors() == ("overload error",)
        assert not table.torque_enabled()


def test_a_safety_stop_on_a_silent_servo_pings_once_per_attempt(emulator):
    """Each stop attempt that has to reconnect sends one marker and one ping, not the ping's
    retries too: the stop is already repeated, and nested retries multiplied the wait (each
    a whole status timeout) on a servo that has gone silent."""
    # retries=3 would be 4 pings per reconnect; no allowance: these statuses will not come.
    table = ServoTurntable.connect(emulator.port_path, retries=3, driver_options={"scheduler_allowance_s": 0.0})
    emulator.inject_no_reply(1, count=1000)
    table.driver.close()  # the port a lost link leaves released: the stop must reconnect
    safety = SafeStop(attempts=3, sleep=no_sleep)
    safety.register(table.stop_action())
    report = safety.stop_all("error: test")
    assert not report.safe and report.unconfirmed[0].attempts == 3
    assert "does not answer" in report.unconfirmed[0].detail or "no status packet" in report.unconfirmed[0].detail
    with emulator.lock:
        ignored = 1000 - emulator.servo(1).silent_count
    assert ignored == 3 * 2  # per attempt: the reconnect's marker and its single ping


@pytest.mark.parametrize("signum, interrupt, reason", [(signal.SIGTERM, Terminated, "SIGTERM"),
                                                        (signal.SIGHUP, Terminated, "SIGHUP"),
                                                        (signal.SIGINT, KeyboardInterrupt, "Ctrl-C")])
def test_a_swallowed_signal_is_raised_again_by_the_loop_check(monkeypatch, signum, interrupt, reason):
    stopped = []
    after = []
    with pytest.raises(interrupt) as raised:
        with SafeStop(sleep=no_sleep) as safety:
            safety.register("servo torque", lambda: stopped.append(True))
            assert send_swallowed(signum, monkeypatch) == [interrupt]  # the interpreter went on
            after.append("the block went on")
            raise_if_signalled()
            after.append("past the check")
    assert after == ["the block went on"]
    assert getattr(raised.value, "signum", signal.SIGINT) == signum
    assert stopped == [True] and safety.report.reason == reason and safety.report.safe
    raise_if_signalled()  # honoured: nothing is left over for the next block or loop
    with SafeStop(sleep=no_sleep):
        raise_if_signalled()


def test_a_block_ending_normally_after_a_swallowed_sigterm_stops_then_raises_it(monkeypatch):
    stopped = []
    with pytest.raises(Terminated) as raised:
        with SafeStop(sleep=no_sleep) as safety:
            safety.register("servo torque", lambda: stopped.append(True))
            send_swallowed(signal.SIGTERM, monkeypatch)
    assert raised.value.signum == signal.SIGTERM
    assert stopped == [True] and safety.report.reason == "SIGTERM"
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_a_swallowed_sigterm_then_an_unconfirmed_stop_says_both(monkeypatch):
    with pytest.raises(Terminated) as raised:
        with SafeStop(attempts=1, sleep=no_sleep) as safety:
            safety.register("servo torque", lambda: None, lambda: False)
            send_swallowed(signal.SIGTERM, monkeypatch)
    assert any("DANGER: servo torque NOT confirmed off" in note for note in raised.value.__notes__)


def test_a_swallowed_sigterm_under_another_error_is_noted_on_it(monkeypatch):
    with pytest.raises(ValueError) as raised:
        with SafeStop(sleep=no_sleep) as safety:
            send_swallowed(signal.SIGTERM, monkeypatch)
            raise ValueError("the servo said no")
    assert safety.report.reason == "SIGTERM"
    assert raised.value.__notes__ == ["SIGTERM had arrived as well"]


def test_the_loop_check_does_nothing_without_a_signal_or_outside_a_block():
    raise_if_signalled()
    with SafeStop(sleep=no_sleep):
        raise_if_signalled()
    # Outside a block SIGTERM keeps its own handling: the check has nothing recorded.
    previous = signal.signal(signal.SIGTERM, lambda *_: None)
    try:
        signal.raise_signal(signal.SIGTERM)
        raise_if_signalled()
    finally:
        signal.signal(signal.SIGTERM, previous)
