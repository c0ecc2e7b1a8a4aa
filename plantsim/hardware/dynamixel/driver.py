"""Driver for the turntable servo through the official ``dynamixel_sdk``.

:class:`DynamixelTurntable` is the narrow interface the scanner needs: connect and
verify the model, configure it from a :class:`plantsim.servo.ServoConfig`, torque
on/off, move and wait, read the state, reboot after a shutdown (only if allowed).

Every communication failure becomes a :class:`plantsim.errors.ServoCommunicationError`
naming the SDK's result text, the port, the ID and what to check; a hardware alert
becomes a :class:`plantsim.errors.ServoAlarmError`. The SDK is not thread-safe, so
calls are serialised by a lock; after the port vanishes (adapter unplugged, emulator
gone) the port is released so that :meth:`DynamixelTurntable.connect` works again.
"""

from __future__ import annotations

import logging
import math
import select
import termios
import threading
import time

from plantsim.turntable import servo
from plantsim.hardware.dynamixel import control_table as ct
from plantsim.hardware.dynamixel import protocol
from plantsim.turntable import units
from plantsim.errors import HardwareError, ServoAlarmError, ServoCommunicationError

_log = logging.getLogger(__name__)

_CHECKLIST = (
    "Check that the servo is powered (12 V), that the baud rate and ID match the servo's "
    "Baud Rate and ID registers, and that the cable and USB adapter are connected."
)
# The SDK's status timeout (port_handler.setPacketTimeout): 2 x the 16 ms USB latency
# timer + 2 ms + the packet's transmission time. A real servo answers within the Return
# Delay Time (0.5 ms by default), so this is the floor of ``status_timeout_s``.
_SDK_LATENCY_MS = 2 * 16.0 + 2.0
# Longest wait in one poll of the port while a status is due: the SDK spins on the
# port without sleeping; waiting in select instead frees the CPU (and the GIL, which
# an emulator in the same process needs to answer).
_POLL_WAIT_S = 0.002
# Resynchronisation markers: READs from address 0 of 8 .. 15 bytes (lengths no other
# request of the driver uses; byte 7 of the answer is the servo's ID), one a resync (a
# failed resync counts as a failed attempt of the request, whose next attempt sends
# another marker, of another length).
_MARKER_FIRST_LENGTH, _MARKER_LENGTHS = 8, 8
# Attempts of a safety stop's torque-off write and read-back before it is reported
# unconfirmed.
_STOP_ATTEMPTS = 3
# Block read for polling a move: Realtime Tick (120..121), Moving (122) .. Present
# Position (132..135): the servo's own clock comes with every sample.
_POLL_ADDRESS, _POLL_LENGTH = 120, 16
# Realtime Tick wraps at 32768 ms (e-Manual, "Realtime Tick(120)").
_TICK_PERIOD_MS = 32768
#: The default scheduler allowance added to the protocol's status timeout, s: a host
#: busy with other work (a scan writing files, a desktop) reads a status late by this
#: much at most; a later status is discarded and the request retried.
DEFAULT_SCHEDULER_ALLOWANCE_S = 0.05


class _LostStatus(Exception):
    """A status packet timed out or was corrupt (COMM_RX_TIMEOUT / COMM_RX_CORRUPT)."""


class _GarbledInstruction(Exception):
    """The servo answered with a CRC error: the instruction was garbled on the way and not run."""


def _sdk():
    try:
        import dynamixel_sdk
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError(
            "the Dynamixel driver needs the official SDK: pip install 'plantsim[rig]' (dynamixel-sdk)"
        ) from exc
    return dynamixel_sdk


def port_handler(port: str, *, status_timeout_s: float = _SDK_LATENCY_MS / 1e3,
                 scheduler_allowance_s: float = 0.0):
    """The SDK's ``PortHandler`` with protocol-derived status timeouts and a waiting (not spinning) read.

    The time it waits for a status is :func:`protocol.status_timeout_s`: the last
    instruction's and the expected status's bytes at the port's baud, the servo's
    Return Delay Time (attribute ``return_delay_s``, s; factory 500 us), two USB
    latency periods, plus ``scheduler_allowance_s`` (attribute ``allowance_s``). Its
    ``min_timeout_ms`` attribute (settable) is a floor, ms.
    """
    sdk = _sdk()

    class _PortHandler(sdk.PortHandler):
        min_timeout_ms = 1e3 * status_timeout_s
        allowance_s = scheduler_allowance_s
        return_delay_s = 250 * 2e-6  # factory Return Delay Time until the driver reads it
        _instruction_bytes = 0

        def writePort(self, packet):
            self._instruction_bytes = len(packet)
            return super().writePort(packet)

        def setPacketTimeout(self, packet_length):
            super().setPacketTimeout(packet_length)  # also starts the clock
            derived_s = protocol.status_timeout_s(
                self.baudrate, instruction_bytes=self._instruction_bytes, status_bytes=packet_length,
                return_delay_s=self.return_delay_s, allowance_s=self.allowance_s)
            self.packet_timeout = max(1e3 * derived_s, self.min_timeout_ms)

        def readPort(self, length):
            if length > 0 and self.ser is not None and not self.ser.in_waiting:
                select.select([self.ser.fileno()], [], [], _POLL_WAIT_S)
            return super().readPort(length)

    return _PortHandler(port)


def _port_errors() -> tuple[type[BaseException], ...]:
    import serial

    return (OSError, termios.error, serial.SerialException)


class DynamixelTurntable:
    """The turntable's Dynamixel servo.

    Args:
        model: expected model, "xm430-w350" (default) or "xl430-w250"; connect()
            refuses a servo that reports another model number.
        allow_reboot: allow :meth:`reboot`, and let :meth:`move_to` reboot the servo
            once after a hardware shutdown (overload, ...) and retry. Off by default:
            a reboot re-enables torque, and a jammed plant or hand can be in the way.
        retries: times to repeat a read or register write whose status packet was
            missing or corrupt (each retry is logged as a warning). Reads and register
            writes are idempotent; 0 surfaces every lost packet. Before a retry the bus
            is resynchronised (see :meth:`resync`), so a late status is never taken
            for the answer to a later request.
        status_timeout_s: the least time to wait for a status packet, s (a floor
            under the protocol-derived timeout; raise it for a servo behind a slow link).
        scheduler_allowance_s: added to the protocol-derived status timeout (the
            packets' bytes at the baud, the servo's Return Delay Time, two USB latency
            periods; see :func:`protocol.status_timeout_s`), s: how late a host whose
            cores are busy may read a status that did come in time. An emulator in
            the same process needs more (its thread waits for the scheduler too).
            Only a missing status costs it; a later one is discarded and retried.
    """

    def __init__(self, *, model: str = "xm430-w350", allow_reboot: bool = False, retries: int = 0,
                 status_timeout_s: float = _SDK_LATENCY_MS / 1e3,
                 scheduler_allowance_s: float = DEFAULT_SCHEDULER_ALLOWANCE_S):
        if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
            raise ValueError(f"retries must be an integer >= 0, got {retries!r}")
        if isinstance(status_timeout_s, bool) or not isinstance(status_timeout_s, (int, float)) or not (
                math.isfinite(status_timeout_s) and 0 < status_timeout_s <= 10):
            raise ValueError(f"status_timeout_s must be in (0, 10] s, got {status_timeout_s!r}")
        if isinstance(scheduler_allowance_s, bool) or not isinstance(scheduler_allowance_s, (int, float)) or not (
                math.isfinite(scheduler_allowance_s) and 0 <= scheduler_allowance_s <= 10):
            raise ValueError(f"scheduler_allowance_s must be in [0, 10] s, got {scheduler_allowance_s!r}")
        self._scheduler_allowance_s = float(scheduler_allowance_s)
        self.table = ct.control_table(model)
        self.allow_reboot = allow_reboot
        self.retries = retries
        self._status_timeout_s = float(status_timeout_s)
        # Set when an SDK call did not return (KeyboardInterrupt, SIGTERM, ...): the
        # SDK's busy flag may be left set and a status may still be on its way.
        self._interrupted = False
        self._lock = threading.Lock()
        self._port = None
        self._packet = None
        self.port_name: str | None = None
        self.baud_bps: int | None = None
        self.dxl_id: int | None = None
        self.firmware_version: int | None = None
        self._config: servo.ServoConfig | None = None
        self._operating_mode: int = 3
        self._resync_failure = ""  # the SDK's text for the last resync's failure
        self._marker = 0  # the last resynchronisation marker sent (its length is 8 + this)

    # --- connection -------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._port is not None

    @property
    def status_timeout_s(self) -> float:
        """The least time to wait for a status packet, s (settable)."""
        return self._status_timeout_s

    @status_timeout_s.setter
    def status_timeout_s(self, value: float) -> None:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value) and 0 < value <= 10):
            raise ValueError(f"status_timeout_s must be in (0, 10] s, got {value!r}")
        self._status_timeout_s = float(value)
        if self._port is not None:
            self._port.min_timeout_ms = 1e3 * value

    @property
    def scheduler_allowance_s(self) -> float:
        """Scheduler allowance added to the protocol-derived status timeout, s (settable)."""
        return self._scheduler_allowance_s

    @scheduler_allowance_s.setter
    def scheduler_allowance_s(self, value: float) -> None:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value) and 0 <= value <= 10):
            raise ValueError(f"scheduler_allowance_s must be in [0, 10] s, got {value!r}")
        self._scheduler_allowance_s = float(value)
        if self._port is not None:
            self._port.allowance_s = float(value)

    def connect(self, port: str, *, baud_bps: int = 57_600, dxl_id: int = 1) -> None:
        """Opens ``port``, pings ``dxl_id`` and verifies its model number.

        The ping is retried ``retries`` times (a lost status).

        Raises:
            ValueError: for an unsupported baud or an ID outside [0, 252].
            ServoCommunicationError: if the port cannot be opened or the servo does
                not answer, or answers with another model number.
        """
        if baud_bps not in ct.BAUD_RATES_BPS.values() or baud_bps == 4_500_000:
            valid = sorted(b for b in ct.BAUD_RATES_BPS.values() if b != 4_500_000)
            raise ValueError(f"baud_bps must be one of {valid} (the SDK refuses 4.5 M), got {baud_bps}")
        if not 0 <= dxl_id <= protocol.MAX_ID:
            raise ValueError(f"dxl_id must be in [0, 252], got {dxl_id}")
        self._connect(port, baud_bps=baud_bps, dxl_id=dxl_id, retry=True)

    def _connect(self, port: str, *, baud_bps: int, dxl_id: int, retry: bool) -> None:
        sdk = _sdk()
        if self._port is not None:
            self.close()
        handler = port_handler(port, status_timeout_s=self._status_timeout_s,
                               scheduler_allowance_s=self.scheduler_allowance_s)
        try:
            handler.openPort()
            if not handler.setBaudRate(baud_bps):
                raise ServoCommunicationError(f"the SDK refused baud {baud_bps} on {port}")
        except _port_errors() as exc:
            raise ServoCommunicationError(
                f"cannot open {port}: {exc}. Check the port path (ls /dev/ttyUSB* /dev/ttyACM*), "
                "that no other program holds it, and that you may access it (group dialout)."
            ) from exc
        self._port, self._packet = handler, sdk.PacketHandler(2.0)
        self._interrupted = False
        self.port_name, self.baud_bps, self.dxl_id = port, baud_bps, dxl_id
        try:
            # A status still owed to an earlier program (or an interrupted connect) on
            # this bus must not be taken for the answer: resynchronise first.
            self.resync(raise_on_failure=False)
            model_number = self._call("ping", "ping", retry=retry)
            if model_number != self.table.model_number:
                other = ct.CONTROL_TABLES_BY_NUMBER.get(model_number)
                hint = f" ({other.model_name}; pass model={other.model_name.lower()!r})" if other else ""
                raise ServoCommunicationError(
                    f"ID {dxl_id} on {port} is model {model_number}{hint}, expected "
                    f"{self.table.model_name} ({self.table.model_number})"
                )
            self.firmware_version = self.read_register("Firmware Version")
            self._operating_mode = self.read_register("Operating Mode")
            # The status timeout counts the servo's own delay before it answers.
            self._port.return_delay_s = 2e-6 * self.read_register("Return Delay Time")
        except BaseException:  # a failure, or Ctrl-C: do not leave the port open and busy
            self.close()
            raise
        _log.info("connected to %s ID %d on %s at %d bps (firmware %s)", self.table.model_name, dxl_id,
                  port, baud_bps, self.firmware_version)

    def close(self) -> None:
        """Releases the port (torque is left as it is)."""
        with self._lock:
            self._release_port()

    def __enter__(self) -> "DynamixelTurntable":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _release_port(self) -> None:
        if self._port is None:
            return
        self._port.is_using = False
        try:
            self._port.closePort()
        except _port_errors() + (AttributeError,) as exc:
            _log.debug("closing %s: %s", self.port_name, exc)
        self._port = None

    # --- low level --------------------------------------------------------------------

    def _call(self, what: str, method: str, *args, check_alert: bool = False, retry: bool = True):
        """Runs one SDK call; returns its value(s) without the result/error codes."""
        attempts = 1 + (self.retries if retry else 0)
        for attempt in range(1, attempts + 1):
            try:
                return self._call_once(what, method, *args, check_alert=check_alert)
            except _LostStatus as lost:
                if attempt == attempts:
                    self._mark_unsynced()
                    raise ServoCommunicationError(str(lost)) from None
                _log.warning("%s (attempt %d of %d); retrying", lost, attempt, attempts)
                # Out of step until shown otherwise: the next attempt resynchronises first.
                self._mark_unsynced()
            except _GarbledInstruction as garbled:
                # The status came (the bus is in step) and says the instruction was not run.
                if attempt == attempts:
                    raise ServoCommunicationError(str(garbled)) from None
                _log.warning("%s (attempt %d of %d); retrying", garbled, attempt, attempts)
        raise AssertionError("unreachable")

    def _mark_unsynced(self) -> None:
        self._interrupted = True

    def resync(self, *, raise_on_failure: bool = True) -> bool:
        """Brings the bus back in step after a lost, late or interrupted exchange.

        Protocol 2.0 status packets carry no sequence number, and the SDK takes the
        first status with the right ID as the answer: a late reply to a lost request
        would be read as the answer to the next one (wrong values, silently). The
        servo answers in order, so a marker request sent now is answered after every
        status still owed. The marker is a READ from address 0 whose length (8 to
        15 bytes, a new one each time) no other request of the driver uses, and whose
        answer carries the servo's ID at byte 7: its status is told from any other by
        its identity, not by when it comes. Every status before it is discarded. When
        the marker's status does not come in time, False: the bus is still out of
        step, and the next resync's marker (another length) discards the stale one
        too. Also clears the SDK's busy flag that an interrupted call leaves.

        Returns:
            True when the marker's status arrived (the bus is in step).

        Raises:
            ServoCommunicationError: when ``raise_on_failure`` and no marker status
                arrived within the protocol's status timeout.
        """
        sdk = _sdk()
        with self._lock:
            if self._port is None:
                if raise_on_failure:
                    raise ServoCommunicationError("resync: not connected; call connect() first")
                return False
            port = self._port
            port.is_using = False
            discarded = 0
            try:
                self._marker = (self._marker + 1) % _MARKER_LENGTHS
                length = _MARKER_FIRST_LENGTH + self._marker
                packet = [0] * 14
                packet[4], packet[5], packet[6], packet[7] = self.dxl_id, 7, 0, sdk.INST_READ
                packet[8:12] = [0, 0, length & 0xFF, length >> 8]
                sent = self._packet.txPacket(port, packet)
                if sent != sdk.COMM_SUCCESS:
                    self._resync_failure = self._packet.getTxRxResult(sent)
                else:
                    while True:
                        port.setPacketTimeout(11 + length)
                        rx, result = self._packet.rxPacket(port, False)
                        if result != sdk.COMM_SUCCESS:
                            self._resync_failure = self._packet.getTxRxResult(result)
                            break
                        # LEN = instruction + error + params + CRC; the ID register is param 7.
                        if (rx[4] == self.dxl_id and rx[5] | (rx[6] << 8) == length + 4
                                and rx[9 + 7] == self.dxl_id):
                            port.is_using = False
                            self._interrupted = False
                            if discarded:
                                _log.warning("discarded %d late status packet(s) from ID %d on %s",
                                             discarded, self.dxl_id, self.port_name)
                            return True
                        discarded += 1
                port.is_using = False
            except _port_errors() as exc:
                name = self.port_name
                self._release_port()
                if raise_on_failure:
                    raise ServoCommunicationError(f"resync on {name}: the port failed ({exc!r})") from exc
                return False
            except BaseException:
                port.is_using = False
                raise
        if raise_on_failure:
            raise ServoCommunicationError(
                f"servo ID {self.dxl_id} on {self.port_name} does not answer after a lost status. "
                f"{_CHECKLIST}")
        return False

    def _call_once(self, what: str, method: str, *args, check_alert: bool):
        if self._interrupted and self._port is not None:
            # A previous call did not return (Ctrl-C, a signal): its status may still be
            # on the way and the SDK's busy flag is set. Without this, every later
            # call, the safety stop's torque-off included, is refused "Port is in use!".
            in_step = self.resync(raise_on_failure=False)
            if self._port is None:  # the port vanished while a status was awaited
                raise ServoCommunicationError(
                    f"{what} on {self.port_name} ID {self.dxl_id}: the port failed after a lost status; "
                    f"the adapter was unplugged or the port closed. {_CHECKLIST} Then call connect() again.")
            if not in_step and not method.startswith("write"):
                # Out of step, a read could be answered by a stale status: count it as
                # lost (and retried). A write still goes out (a safety stop's torque-off
                # must, whatever the bus's state); the servo runs it in order.
                raise _LostStatus(f"{what} on {self.port_name} ID {self.dxl_id} at {self.baud_bps} bps failed: "
                                  f"{self._resync_failure} (while resynchronising after a lost status; not sent) "
                                  f"{_CHECKLIST}")
        with self._lock:
            if self._port is None:
                raise ServoCommunicationError(f"{what}: not connected; call connect() first")
            try:
                self._interrupted = True
                if method == "ping":
                    out = self._ping_checked()
                else:
                    out = getattr(self._packet, method)(self._port, self.dxl_id, *args)
                self._interrupted = False
            except _port_errors() as exc:
                port = self.port_name
                self._release_port()
                raise ServoCommunicationError(
                    f"{what} on {port} ID {self.dxl_id}: the port failed ({exc!r}); the adapter was "
                    f"unplugged or the port closed. {_CHECKLIST} Then call connect() again."
                ) from exc
        if isinstance(out, tuple) and len(out) == 3:
            value, result, error = out
        else:
            (result, error), value = out, None
        if result == 0 and method == "ping" and value is None:
            raise _LostStatus(
                f"{what} on {self.port_name} ID {self.dxl_id}: a status that is not a PING's (a late reply to "
                "an earlier request)")
        if result == 0 and method == "readTxRx" and len(value) != args[-1]:
            # The SDK does not check the length: a status of another length is the
            # late reply to an earlier request, not this one's.
            raise _LostStatus(
                f"{what} on {self.port_name} ID {self.dxl_id}: a status with {len(value)} data bytes "
                f"instead of {args[-1]} (a late reply to an earlier request)")
        if result != 0:
            if result == -1000:  # COMM_PORT_BUSY: a previous call left the flag set
                self._port.is_using = False
            error_class = _LostStatus if result in (-3001, -3002) else ServoCommunicationError
            raise error_class(
                f"{what} on {self.port_name} ID {self.dxl_id} at {self.baud_bps} bps failed: "
                f"{self._packet.getTxRxResult(result)} {_CHECKLIST}"
            )
        if error & protocol.ERROR_ALERT_BIT and check_alert:
            # The shutdown is the cause worth reporting, even when the instruction
            # was refused because of it (torque on during a shutdown).
            self._raise_alarm(what)
        code = error & 0x7F
        if code == protocol.ErrorCode.CRC:
            raise _GarbledInstruction(
                f"{what} on {self.port_name} ID {self.dxl_id}: the servo received a garbled instruction "
                f"({protocol.describe_error(code)}) and did not run it. Noise on the bus: check the cable, "
                "its length and the termination")
        if code:
            raise ServoCommunicationError(
                f"{what} on {self.port_name} ID {self.dxl_id} refused: {self._packet.getRxPacketError(code)} "
                f"({protocol.describe_error(code)})"
            )
        return value

    def _raise_alarm(self, what: str) -> None:
        status = self.hardware_error_status()
        names = ", ".join(ct.hardware_error_names(status)) or f"status 0x{status:02x}"
        action = (
            "reboot() is allowed and will be tried"
            if self.allow_reboot
            else "remove the cause, then reboot it: construct DynamixelTurntable(allow_reboot=True) "
            "and call reboot(), or power-cycle the servo"
        )
        raise ServoAlarmError(
            f"{what}: servo ID {self.dxl_id} on {self.port_name} reports {names} and has dropped torque; "
            f"check the load (jammed turntable, heavy pot), the supply and the temperature; {action}.",
            hardware_error_status=status,
        )

    def _ping_checked(self):
        """The SDK's ping, but a status without exactly 3 parameters is not taken (value None).

        The SDK's own ``ping`` reads the model number from whatever status comes first.
        """
        sdk = _sdk()
        packet = [0] * 10
        packet[4], packet[5], packet[6], packet[7] = self.dxl_id, 3, 0, sdk.INST_PING
        rx, result, error = self._packet.txRxPacket(self._port, packet)
        if result != sdk.COMM_SUCCESS:
            return 0, result, error
        if rx[5] | (rx[6] << 8) != 7:
            return None, result, error
        return rx[9] | (rx[10] << 8), result, error

    def ping(self) -> int:
        """Pings the servo; returns its model number."""
        return self._call("ping", "ping")

    def read_register(self, name: str) -> int:
        """Reads a register by name; signed registers come back signed."""
        register = self.table[name]
        # readTxRx, not read{1,2,4}ByteTxRx: those raise IndexError on an error status
        # that carries no data.
        data = self._call(f"read {name}", "readTxRx", register.address, register.size)
        raw = int.from_bytes(bytes(data), "little")
        return units.to_signed(raw, register.size) if register.signed else raw

    def write_register(self, name: str, value: int) -> None:
        """Writes a register by name (raw units; signed values allowed where signed).

        Raises:
            ValueError: if ``value`` is outside the register's static range.
            ServoCommunicationError: if the servo refuses (EEPROM with torque on, limit).
        """
        register = self.table[name]
        if not register.writable:
            raise ValueError(f"{name} is read-only")
        if not register.accepts(int(value)):
            raise ValueError(f"value for {name} must be in [{register.minimum}, {register.maximum}], got {value}")
        raw = units.to_unsigned(int(value), register.size) if register.signed else int(value)
        self._call(f"write {name}={value}", f"write{register.size}ByteTxRx", register.address, raw,
                   check_alert=register.name in ("Torque Enable", "Goal Position"))
        if name == "Return Delay Time" and self._port is not None:
            self._port.return_delay_s = 2e-6 * int(value)

    def read_registers(self, *names: str) -> dict[str, int]:
        """Reads several registers in one READ instruction spanning them; signed ones come back signed.

        One exchange, so the values are one instant's (the servo samples them when
        the instruction arrives). The span may cross reserved bytes (read, ignored).

        Raises:
            ValueError: for no names.
            KeyError: for a name the model lacks (the message lists the valid names).
        """
        if not names:
            raise ValueError("read_registers needs at least one register name")
        registers = [self.table[name] for name in names]
        start = min(r.address for r in registers)
        length = max(r.address + r.size for r in registers) - start
        data = bytes(self._call(f"read {names[0]}..{names[-1]}", "readTxRx", start, length))
        values = {}
        for r in registers:
            raw = int.from_bytes(data[r.address - start : r.address - start + r.size], "little")
            values[r.name] = units.to_signed(raw, r.size) if r.signed else raw
        return values

    # --- configuration ------------------------------------------------------------

    def configure(self, config: servo.ServoConfig, *, operating_mode: str = "position") -> None:
        """Writes the operating mode, PWM limit, position gains and profile.

        Torque is switched off for the EEPROM writes and restored afterwards.

        Raises:
            ValueError: for an operating mode this model lacks.
        """
        if operating_mode not in ct.OPERATING_MODES:
            raise ValueError(f"operating_mode must be one of {sorted(ct.OPERATING_MODES)}, got {operating_mode!r}")
        mode = ct.OPERATING_MODES[operating_mode]
        if not self.table["Operating Mode"].accepts(mode):
            raise ValueError(f"{self.table.model_name} has no {operating_mode!r} mode")
        registers = config.to_registers()
        was_on = self.read_register("Torque Enable") == 1
        if was_on:
            self.torque_off()
        self.write_register("Operating Mode", mode)
        self.write_register("PWM Limit", registers.pop("PWM Limit"))
        for name, value in registers.items():
            self.write_register(name, value)
        self._config, self._operating_mode = config, mode
        if was_on:
            self.torque_on()

    def torque_on(self) -> None:
        self.write_register("Torque Enable", 1)

    def torque_off(self) -> None:
        self.write_register("Torque Enable", 0)

    def torque_enabled(self) -> bool:
        """Reads Torque Enable back from the servo (True: the motor is powered)."""
        return self.read_register("Torque Enable") == 1

    def emergency_stop(self) -> None:
        """Stops the servo by switching its torque off, whatever state the link is in.

        For a safety stop after Ctrl-C, a signal, an exception or a lost link: frees
        the port an interrupted call left busy and resynchronises the bus, reconnects
        if the port was lost (same port, baud and ID), then writes Torque Enable = 0
        (the motor stops driving; the turntable coasts to rest). Confirm it with
        :meth:`torque_enabled`.

        Raises:
            HardwareError: if the servo cannot be reached or refuses the write.
        """
        if self._port is None:
            if self.port_name is None:
                raise ServoCommunicationError("emergency stop: never connected; nothing to stop")
            _log.warning("emergency stop: reconnecting to %s to switch torque off", self.port_name)
            # One ping, not ``retries``: the callers repeat the whole stop (see below), and a
            # retried ping inside each of their attempts multiplied the wait on a silent servo.
            self._connect(self.port_name, baud_bps=self.baud_bps, dxl_id=self.dxl_id, retry=False)
        self.resync(raise_on_failure=False)
        register = self.table["Torque Enable"]
        # No retries here: the callers (ServoTurntable.close, a SafeStop) repeat the
        # whole stop and read the torque back, and nested retries would keep a user
        # waiting minutes on a servo that has gone silent.
        self._call("emergency stop: write Torque Enable=0", "write1ByteTxRx", register.address, 0, retry=False)

    # --- motion -------------------------------------------------------------------

    def move_to(self, angle_rad: float, *, timeout_s: float = 10.0, tolerance_rad: float = 2 * units.RAD_PER_TICK,
                poll_interval_s: float = 0.002) -> float:
        """Moves to ``angle_rad`` along the servo's profile and waits until it stops there.

        Done when the Moving flag is 0 and the position is within ``tolerance_rad``.

        Args:
            angle_rad: goal, rad (raw 0 = 0 rad). In position mode it must lie within
                the position limits (0 .. 2 pi by default); nothing is wrapped.
            timeout_s: limit on the servo's own clock (Realtime Tick, read with every
                poll), s: the move's duration, whatever the host's scheduling.
            tolerance_rad: accepted final error, rad.

        Returns:
            The final present position, rad.

        Raises:
            ValueError: for a goal outside the limits or non-finite input.
            ServoAlarmError: on a hardware shutdown (after one reboot and retry when
                ``allow_reboot``).
            ServoCommunicationError: if the servo stops answering or the move times out.
        """
        goal_ticks = units.rad_to_ticks(angle_rad)
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be finite and > 0, got {timeout_s!r}")
        if not (math.isfinite(tolerance_rad) and tolerance_rad > 0):
            raise ValueError(f"tolerance_rad must be finite and > 0, got {tolerance_rad!r}")
        if self._operating_mode in (3, 5):
            low, high = self.read_register("Min Position Limit"), self.read_register("Max Position Limit")
            if not low <= goal_ticks <= high:
                raise ValueError(
                    f"angle_rad must be within the position limits [{units.ticks_to_rad(low):.4f}, "
                    f"{units.ticks_to_rad(high):.4f}] rad in position mode, got {angle_rad}; use "
                    "operating_mode='extended_position' for multi-turn goals"
                )
        try:
            return self._move(goal_ticks, timeout_s, tolerance_rad, poll_interval_s)
        except ServoAlarmError:
            if not self.allow_reboot:
                raise
            _log.warning("servo ID %d shut down during a move; rebooting (allow_reboot=True)", self.dxl_id)
            self.reboot()
            self.torque_on()
            return self._move(goal_ticks, timeout_s, tolerance_rad, poll_interval_s)

    def _move(self, goal_ticks: int, timeout_s: float, tolerance_rad: float, poll_interval_s: float) -> float:
        if self.read_register("Torque Enable") != 1:
            if self.hardware_error_status():
                self._raise_alarm("move")
            raise HardwareError(f"servo ID {self.dxl_id} has torque off; call torque_on() before move_to()")
        self.write_register("Goal Position", goal_ticks)
        tolerance_ticks = tolerance_rad / units.RAD_PER_TICK
        elapsed_ms, last_tick = 0, None
        while True:
            data = bytes(self._call("poll move", "readTxRx", _POLL_ADDRESS, _POLL_LENGTH, check_alert=True))
            tick = int.from_bytes(data[0:2], "little")
            moving = data[2]
            position_ticks = units.to_signed(int.from_bytes(data[12:16], "little"), 4)
            if last_tick is not None:
                elapsed_ms += (tick - last_tick) % _TICK_PERIOD_MS
            last_tick = tick
            if not moving and abs(position_ticks - goal_ticks) <= tolerance_ticks:
                return units.ticks_to_rad(position_ticks)
            if elapsed_ms > 1e3 * timeout_s:
                raise ServoCommunicationError(
                    f"servo ID {self.dxl_id} did not reach {units.ticks_to_rad(goal_ticks):.4f} rad within "
                    f"{timeout_s} s (at {units.ticks_to_rad(position_ticks):.4f} rad, moving={moving}); "
                    "check for a jam or too heavy a load, the profile velocity, and tolerance_rad"
                )
            time.sleep(poll_interval_s)

    def reboot(self) -> None:
        """Reboots the servo to clear a shutdown, then restores the configuration.

        Torque stays off afterwards; call :meth:`torque_on`.

        Raises:
            HardwareError: if ``allow_reboot`` is False.
        """
        if not self.allow_reboot:
            raise HardwareError(
                f"reboot of servo ID {self.dxl_id} refused: construct DynamixelTurntable(allow_reboot=True) "
                "once the cause is removed (a reboot lets the turntable move again)"
            )
        self._call("reboot", "reboot", retry=False)
        deadline = time.monotonic() + 2.0
        while True:  # the firmware needs a moment before it answers again
            try:
                self.ping()
                break
            except ServoCommunicationError:
                if time.monotonic() > deadline or self._port is None:
                    raise
                time.sleep(0.05)
        if self._config is not None:
            mode = {v: k for k, v in ct.OPERATING_MODES.items()}[self._operating_mode]
            self.configure(self._config, operating_mode=mode)

    # --- state --------------------------------------------------------------------

    def position(self) -> float:
        """Present position, rad (raw 0 = 0 rad)."""
        return units.ticks_to_rad(self.read_register("Present Position"))

    def velocity(self) -> float:
        """Present velocity, rad/s."""
        return units.velocity_units_to_rad_s(self.read_register("Present Velocity"))

    def current(self) -> float:
        """Present current, A (XM430; the XL430 reports load instead)."""
        if "Present Current" not in self.table:
            raise HardwareError(f"{self.table.model_name} has no current sensor")
        return units.current_units_to_a(self.read_register("Present Current"))

    def temperature(self) -> float:
        """Present temperature, degC."""
        return float(self.read_register("Present Temperature"))

    def hardware_error_status(self) -> int:
        """Hardware Error Status bits (see ``control_table.HARDWARE_ERROR_BITS``)."""
        return self.read_register("Hardware Error Status")
