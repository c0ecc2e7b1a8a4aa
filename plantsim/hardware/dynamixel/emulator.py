"""A Protocol 2.0 servo bus on a pseudo-terminal, for the real ``dynamixel_sdk``.

The emulator opens a pty, keeps the master end and hands out the slave's path
(:attr:`DynamixelEmulator.port_path`), which the SDK opens as if it were a USB
serial adapter. A background thread answers instruction packets for one or more
servos and steps each servo's :class:`plantsim.servo.ShaftSim` in (scaled) real time,
so Present Position/Velocity/Current/Moving/Realtime Tick come from physics.

What a real X-series servo does and the emulator copies (e-Manual, protocol 2.0 and
XM430-W350 pages): CRC and stuffing checked (a bad CRC gets a CRC-error status);
read-only, undefined and EEPROM-with-torque-on writes refused with an access error;
range and limit errors; Status Return Level and Return Delay Time honoured; no reply
at all when the port's baud differs from the Baud Rate register; the alert bit in
every status while Hardware Error Status is set, with torque off until REBOOT.

Deviations, on purpose: unicast ACTION gets no status (the SDK does not read it and a
late one would be taken for the next reply); only the position modes (3, 4, 5) are
simulated, other modes leave the shaft free; CLEAR and the FAST_* reads answer with an
instruction error; temperature and input voltage are constant; Drive Mode (reverse,
time-based profile), Bus Watchdog and the Velocity Limit cap on the profile are not
emulated; REBOOT is instantaneous.

Clocks. ``clock="wall"`` (the default, and ``plantsim emulator``): simulated time
follows the wall clock times ``speed_factor``, as a real servo's does, so a program
(or the URG emulator beside it) sees moves take their real time. ``clock="bus"``
(for tests): simulated time advances only with the bus traffic, by what each
exchange takes on a real bus: the host's turnaround (``host_gap_s``), the
instruction's bytes at the port's baud (10 bits a byte), the Return Delay Time and
the status's bytes; :meth:`DynamixelEmulator.advance` moves it on while the bus is
idle. A move then takes the same number of exchanges, and a fault scheduled with
:meth:`DynamixelEmulator.call_at` lands at the same exchange, however busy the
machine is: nothing depends on how fast the emulator thread is scheduled. A late
status (:meth:`DynamixelEmulator.inject_late_reply`) is held until the host's next
packet, after the host gave up on it, which is what a late status is.

What is left to the wall clock in both modes is the driver's wait for a status that
does come: its timeout is a margin derived from the protocol plus a scheduler
allowance (:class:`~plantsim.hardware.dynamixel.driver.DynamixelTurntable`'s
``scheduler_allowance_s``), and a status that comes later still is discarded by the
driver's resynchronisation and the request retried.

Usage::

    with DynamixelEmulator(ids=(1,), speed_factor=10) as emulator:
        port = PortHandler(emulator.port_path)
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import math
import os
import select
import termios
import threading
import time
import tty
from typing import Iterable

from plantsim.turntable import servo
from plantsim.hardware.pty import close_fds
from plantsim.hardware.dynamixel import control_table as ct
from plantsim.hardware.dynamixel import protocol
from plantsim.turntable import units
from plantsim.hardware.dynamixel.protocol import ErrorCode, Instruction

_log = logging.getLogger(__name__)

OVERLOAD = 1 << 5
_POSITION_MODES = (3, 4, 5)
_TEMPERATURE_C = 30
_INPUT_VOLTAGE_DV = 120  # 12.0 V
_IN_POSITION_TICKS = 10
# Physics steps per loop iteration at most, so the port is served at least every
# few hundred microseconds even when the simulation runs behind.
_MAX_STEPS_PER_ITERATION = 10
CLOCKS = ("wall", "bus")
# Bits per byte on the bus: start bit, 8 data bits, stop bit (8N1).
_BITS_PER_BYTE = 10
# Instruction packet bytes besides the parameters: header 4, ID, length 2, instruction, CRC 2.
_INSTRUCTION_OVERHEAD_BYTES = 10


def _termios_bauds() -> dict[int, int]:
    bauds = {}
    for bps in ct.BAUD_RATES_BPS.values():
        constant = getattr(termios, f"B{bps}", None)
        if constant is not None:
            bauds[constant] = bps
    return bauds


_TERMIOS_BAUDS = _termios_bauds()


class EmulatedServo:
    """One servo: its control-table memory and its simulated shaft.

    Not thread-safe on its own: :class:`DynamixelEmulator` calls it under its lock.
    """

    def __init__(self, table: ct.ControlTable, *, dxl_id: int, baud_bps: int, config: servo.ServoConfig,
                 load_inertia: float, timestep: float, initial_position: float):
        self.table = table
        self.base_config = config
        self.memory = bytearray(table.size)
        self._load_inertia = load_inertia
        self._timestep = timestep
        self.shaft = servo.ShaftSim(config, load_inertia=load_inertia, timestep=timestep,
                                    initial_position=initial_position)
        self.pending_write: tuple[int, bytes] | None = None
        self.silent_count: int | None = 0  # replies to drop; None = forever
        self.corrupt_count: int | None = 0
        self.garble_count: int | None = 0  # instructions to receive with a bad CRC; None = forever
        self.late_count: int = 0  # replies to send late
        self.late_s: float = 0.0
        self._reset_registers(keep=())
        self.set("ID", dxl_id)
        self.set("Baud Rate", _baud_index(baud_bps))
        self._apply_config()

    # --- memory -----------------------------------------------------------------

    def get(self, name: str) -> int:
        register = self.table[name]
        raw = int.from_bytes(self.memory[register.address : register.address + register.size], "little")
        return units.to_signed(raw, register.size) if register.signed else raw

    def set(self, name: str, value: int) -> None:
        register = self.table[name]
        if register.signed:
            high = (1 << (8 * register.size - 1)) - 1
            value = units.to_unsigned(min(max(int(value), -high - 1), high), register.size)
        self.memory[register.address : register.address + register.size] = int(value).to_bytes(
            register.size, "little"
        )

    def _reset_registers(self, keep: Iterable[str]) -> None:
        kept = {name: self.get(name) for name in keep}
        for register in self.table:
            self.set(register.name, register.default or 0)
        for name, value in kept.items():
            self.set(name, value)
        self.set("Goal Position", self._position_ticks())

    @property
    def dxl_id(self) -> int:
        return self.get("ID")

    @property
    def baud_bps(self) -> int:
        return ct.BAUD_RATES_BPS[self.get("Baud Rate")]

    @property
    def torque_on(self) -> bool:
        return self.get("Torque Enable") == 1

    @property
    def alert(self) -> int:
        return protocol.ERROR_ALERT_BIT if self.get("Hardware Error Status") else 0

    # --- physics ------------------------------------------------------------------

    def _position_ticks(self) -> int:
        return units.rad_to_ticks(self.shaft.position) + self.get("Homing Offset")

    def _apply_config(self) -> None:
        names = ("Position P Gain", "Position I Gain", "Position D Gain", "Feedforward 1st Gain",
                 "Feedforward 2nd Gain", "Profile Velocity", "Profile Acceleration")
        registers = {name: self.get(name) for name in names}
        registers["PWM Limit"] = min(self.get("PWM Limit"), abs(self.get("Goal PWM")))
        self.shaft.set_config(self.base_config.with_registers(registers))

    def advance(self, t: float) -> None:
        self.shaft.run_until(t)

    def refresh_present(self) -> None:
        """Writes the shaft's state into the Present/Moving/Trajectory registers."""
        shaft = self.shaft
        controller = shaft.controller
        t = shaft.time
        self.set("Realtime Tick", int(t * 1000) % 32768)
        position_ticks = self._position_ticks()
        velocity_units = units.rad_s_to_velocity_units(shaft.velocity)
        self.set("Present Position", position_ticks)
        self.set("Present Velocity", velocity_units)
        self.set("Present PWM", round(controller.duty * units.PWM_FULL_SCALE))
        if "Present Current" in self.table:
            self.set("Present Current", units.a_to_current_units(controller.current))
        else:
            self.set("Present Load", round(1000 * controller.motor_torque / shaft.config.stall_torque))
        profile = controller.profile if controller.enabled else None
        offset = self.get("Homing Offset")
        if profile is not None:
            p_ref, v_ref, _ = profile.sample(t)
            self.set("Position Trajectory", units.rad_to_ticks(p_ref) + offset)
            self.set("Velocity Trajectory", units.rad_s_to_velocity_units(v_ref))
        running = profile is not None and not profile.finished(t)
        moving = running or abs(velocity_units) > self.get("Moving Threshold")
        self.set("Moving", int(moving))
        status = 0
        if profile is not None:
            if not running and abs(self.get("Goal Position") - position_ticks) <= _IN_POSITION_TICKS:
                status |= 0x01
            if running:
                status |= 0x02
            status |= profile.kind << 4
        self.set("Moving Status", status)
        self.set("Present Input Voltage", _INPUT_VOLTAGE_DV)
        self.set("Present Temperature", _TEMPERATURE_C)

    def fault(self, bits: int) -> None:
        """A shutdown: set Hardware Error Status bits and drop torque."""
        self.set("Hardware Error Status", self.get("Hardware Error Status") | bits)
        self.set("Torque Enable", 0)
        self.shaft.disable()
        _log.info("servo %d: hardware error 0x%02x, torque off", self.dxl_id, bits)

    def reboot(self) -> None:
        self.shaft.disable()
        eeprom = [r.name for r in self.table if r.area == ct.EEPROM]
        self._reset_registers(keep=eeprom)
        self.pending_write = None
        if self.get("Operating Mode") != 4:
            # The firmware re-reads the single-turn encoder: position within one turn.
            self.shaft.data.qpos[0] = math.fmod(self.shaft.position, 2 * math.pi) % (2 * math.pi)
            self.set("Goal Position", self._position_ticks())
        self._apply_config()

    def factory_reset(self, option: int) -> None:
        keep = {0x01: ("ID",), 0x02: ("ID", "Baud Rate")}.get(option, ())
        self.shaft.disable()
        self._reset_registers(keep=keep)
        self._apply_config()

    # --- instructions ---------------------------------------------------------------

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        if length == 0 or address + length > self.table.size:
            return ErrorCode.ACCESS, b""
        self.refresh_present()
        return 0, bytes(self.memory[address : address + length])

    def check_write(self, address: int, data: bytes) -> int:
        """Error code for writing ``data`` at ``address`` (0 when allowed)."""
        end = address + len(data)
        if not data or end > self.table.size:
            return ErrorCode.ACCESS
        i = address
        while i < end:
            register = self.table.covering(i)
            if register is None:
                return ErrorCode.ACCESS
            if register.address != i or i + register.size > end:
                return ErrorCode.DATA_LENGTH
            if not register.writable or (register.area == ct.EEPROM and self.torque_on):
                return ErrorCode.ACCESS
            raw = int.from_bytes(data[i - address : i - address + register.size], "little")
            value = units.to_signed(raw, register.size) if register.signed else raw
            if not register.accepts(value):
                return ErrorCode.DATA_RANGE
            if self._over_limit(register.name, value):
                return ErrorCode.DATA_LIMIT
            if register.name == "Torque Enable" and value == 1 and self.get("Hardware Error Status"):
                return ErrorCode.RESULT_FAIL
            i += register.size
        return 0

    def _over_limit(self, name: str, value: int) -> bool:
        if name == "Goal Position" and self.get("Operating Mode") in (3, 5):
            return not self.get("Min Position Limit") <= value <= self.get("Max Position Limit")
        limits = {"Goal PWM": "PWM Limit", "Goal Current": "Current Limit", "Goal Velocity": "Velocity Limit"}
        if name in limits:
            return abs(value) > self.get(limits[name])
        return False

    def write(self, address: int, data: bytes) -> None:
        """Applies a write already accepted by :meth:`check_write`."""
        before_torque = self.torque_on
        self.memory[address : address + len(data)] = data
        written = {r.name for r in self.table if address <= r.address < address + len(data)}
        if written & {"Position P Gain", "Position I Gain", "Position D Gain", "Feedforward 1st Gain",
                      "Feedforward 2nd Gain", "Profile Velocity", "Profile Acceleration", "PWM Limit",
                      "Goal PWM"}:
            self._apply_config()
        if "Torque Enable" in written and self.torque_on != before_torque:
            if self.torque_on:
                if self.get("Operating Mode") in _POSITION_MODES:
                    self.shaft.enable()
                else:
                    _log.warning("servo %d: operating mode %d is not simulated; shaft left free",
                                 self.dxl_id, self.get("Operating Mode"))
                # The firmware starts holding where it is: Goal Position follows.
                self.set("Goal Position", self._position_ticks())
            else:
                self.shaft.disable()
        elif "Goal Position" in written and self.torque_on and self.shaft.controller.enabled:
            goal = units.ticks_to_rad(self.get("Goal Position") - self.get("Homing Offset"))
            self.shaft.set_goal(goal)


def _baud_index(baud_bps: int) -> int:
    for index, bps in ct.BAUD_RATES_BPS.items():
        if bps == baud_bps:
            return index
    raise ValueError(f"baud_bps must be one of {sorted(ct.BAUD_RATES_BPS.values())}, got {baud_bps}")


class DynamixelEmulator:
    """Servos on an emulated RS-485 bus behind a pseudo-terminal.

    Args:
        ids: servo IDs on the bus.
        model: "xm430-w350" or "xl430-w250".
        baud_bps: initial Baud Rate register of every servo.
        speed_factor: simulated seconds per wall-clock second (10 makes a 1 s move
            take 0.1 s; Realtime Tick counts simulated ms).
        config: mechanics and initial controller of each shaft; the register
            defaults still come from the control table, as on a new servo.
        load_inertia: inertia carried by each shaft, kg m^2.
        timestep: physics step, s.
        initial_position: shaft angle at start, rad.
        clock: "wall" (simulated time follows the wall clock times
            ``speed_factor``) or "bus" (it advances only with the bus traffic and
            :meth:`advance`; ``speed_factor`` is then unused). See the module notes.
        host_gap_s: with ``clock="bus"``, the simulated time the host takes between
            two exchanges (its turnaround and polling), s.
    """

    def __init__(self, ids: Iterable[int] = (1,), *, model: str = "xm430-w350", baud_bps: int = 57_600,
                 speed_factor: float = 1.0, config: servo.ServoConfig | None = None,
                 load_inertia: float = 0.0, timestep: float = 1e-3, initial_position: float = 0.0,
                 clock: str = "wall", host_gap_s: float = 0.002):
        ids = list(ids)
        if clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, got {clock!r}")
        if isinstance(host_gap_s, bool) or not isinstance(host_gap_s, (int, float)) or not (
                math.isfinite(host_gap_s) and host_gap_s >= 0):
            raise ValueError(f"host_gap_s must be finite and >= 0, got {host_gap_s!r}")
        if not ids or len(set(ids)) != len(ids) or not all(0 <= i <= protocol.MAX_ID for i in ids):
            raise ValueError(f"ids must be distinct integers in [0, 252], got {ids}")
        if not (math.isfinite(speed_factor) and speed_factor > 0):
            raise ValueError(f"speed_factor must be finite and > 0, got {speed_factor!r}")
        table = ct.control_table(model)
        _baud_index(baud_bps)
        if config is None:
            config = servo.ServoConfig.xl430_w250() if table.model_number == 1060 else servo.ServoConfig()
        # Start from the factory registers, not from config's controller settings.
        config = config.with_registers({r.name: r.default for r in table if r.default is not None})
        self.speed_factor = speed_factor
        self.clock = clock
        self.host_gap_s = float(host_gap_s)
        self._held_statuses: list[bytes] = []  # late statuses held until the host's next packet (bus clock)
        self._servos = [
            EmulatedServo(table, dxl_id=i, baud_bps=baud_bps, config=config, load_inertia=load_inertia,
                          timestep=timestep, initial_position=initial_position)
            for i in ids
        ]
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._disconnect = threading.Event()
        self._thread: threading.Thread | None = None
        self._master = self._slave = None
        self.port_path: str | None = None
        self._parser = protocol.PacketParser()
        self._sim_time = 0.0
        self._scheduled: list[tuple[float, int, object]] = []  # (sim time, order, callable)

    # --- lifecycle ------------------------------------------------------------------

    def start(self) -> "DynamixelEmulator":
        if self._thread is not None:
            raise RuntimeError("emulator already started")
        self._master, self._slave = os.openpty()
        tty.setraw(self._master)
        self.port_path = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._run, name=f"dxl-emulator {self.port_path}", daemon=True)
        self._thread.start()
        _log.info("Dynamixel emulator on %s, ids %s", self.port_path, [s.dxl_id for s in self._servos])
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._close_fds()

    def __enter__(self) -> "DynamixelEmulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _close_master(self) -> None:
        if self._master is not None:
            try:
                os.close(self._master)
            except OSError:
                pass
            self._master = None

    def _close_fds(self) -> None:
        close_fds(self._master, self._slave)
        self._master = self._slave = None

    # --- access for tests and fault injection --------------------------------------

    def servo(self, dxl_id: int) -> EmulatedServo:
        with self._lock:
            for s in self._servos:
                if s.dxl_id == dxl_id:
                    return s
        raise KeyError(f"no servo with ID {dxl_id}; ids: {[s.dxl_id for s in self._servos]}")

    @property
    def lock(self) -> threading.RLock:
        """Hold this to read a servo's state consistently from another thread."""
        return self._lock

    @property
    def sim_time(self) -> float:
        return self._sim_time

    def call_at(self, sim_time_s: float, action) -> None:
        """Runs ``action()`` in the emulator's thread once simulated time reaches ``sim_time_s``.

        The clock a test controls: simulated time advances only with the physics, so
        a fault scheduled 0.3 s of simulated time after a move starts happens at the
        same point of the move however late the machine lets the emulator run (a
        wall-clock timer would not). ``action`` runs under :attr:`lock`.
        """
        if not (isinstance(sim_time_s, (int, float)) and math.isfinite(sim_time_s)):
            raise ValueError(f"sim_time_s must be a finite number, got {sim_time_s!r}")
        if not callable(action):
            raise ValueError(f"action must be callable, got {action!r}")
        with self._lock:
            self._scheduled.append((float(sim_time_s), len(self._scheduled), action))
            self._scheduled.sort(key=lambda event: event[:2])

    def _run_scheduled(self) -> None:
        while self._scheduled and self._scheduled[0][0] <= self._sim_time:
            _, _, action = self._scheduled.pop(0)
            action()

    def advance(self, seconds: float) -> float:
        """Moves simulated time on by ``seconds`` while the bus is idle (``clock="bus"`` only).

        The shafts move and actions scheduled with :meth:`call_at` run at their time,
        in this (the caller's) thread. Returns the new simulated time, s.

        Raises:
            ValueError: for a negative or non-finite ``seconds``.
            RuntimeError: with ``clock="wall"``, where the wall clock drives time.
        """
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not (
                math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"seconds must be finite and >= 0, got {seconds!r}")
        if self.clock != "bus":
            raise RuntimeError("advance() needs DynamixelEmulator(clock='bus'); with clock='wall' the "
                               "wall clock times speed_factor drives simulated time")
        with self._lock:
            self._advance_to(self._sim_time + seconds)
            return self._sim_time

    def _advance_to(self, t: float) -> None:
        """Steps the shafts to simulated time ``t``, stopping at each scheduled action (lock held)."""
        while True:
            stop = min(t, self._scheduled[0][0]) if self._scheduled else t
            if stop > self._sim_time:
                self._sim_time = stop
                for s in self._servos:
                    s.advance(stop)
            self._run_scheduled()
            if self._sim_time >= t or self._disconnect.is_set():
                return

    def inject_no_reply(self, dxl_id: int, *, count: int | None = 1) -> None:
        """The servo ignores the next ``count`` packets (None: until cleared), as if unplugged."""
        _check_count(count)
        with self._lock:
            self.servo(dxl_id).silent_count = count

    def inject_corrupt_crc(self, dxl_id: int, *, count: int | None = 1) -> None:
        """The servo's next ``count`` status packets carry a wrong CRC (None: until cleared)."""
        _check_count(count)
        with self._lock:
            self.servo(dxl_id).corrupt_count = count

    def inject_garbled_instruction(self, dxl_id: int, *, count: int | None = 1) -> None:
        """The next ``count`` instructions to the servo arrive garbled (None: until cleared).

        Noise on the bus: the servo finds the CRC wrong, does not run the
        instruction and answers with a CRC-error status, as a real one does.
        """
        _check_count(count)
        with self._lock:
            self.servo(dxl_id).garble_count = count

    def inject_late_reply(self, dxl_id: int, *, delay_s: float = 0.06, count: int = 1) -> None:
        """The servo's next ``count`` status packets leave ``delay_s`` late (the bus stalls meanwhile).

        Later than the driver's status timeout, such a status arrives while the
        driver waits for the answer to its next request. With ``clock="bus"`` the
        status is held until the host's next packet whatever ``delay_s`` (which then
        only adds to simulated time): late by construction, not by a race with the
        host's timeout.
        """
        _check_count(count)
        if count is None or not (math.isfinite(delay_s) and delay_s > 0):
            raise ValueError(f"delay_s must be finite and > 0 and count an integer, got {delay_s!r}, {count!r}")
        with self._lock:
            s = self.servo(dxl_id)
            s.late_count, s.late_s = count, delay_s

    def inject_hardware_error(self, dxl_id: int, bits: int = OVERLOAD) -> None:
        """Sets Hardware Error Status ``bits`` (default overload): torque off until REBOOT."""
        if not (isinstance(bits, int) and 0 < bits <= 0xFF):
            raise ValueError(f"bits must be a non-zero Hardware Error Status byte (e.g. OVERLOAD = 0x20), got {bits!r}")
        with self._lock:
            self.servo(dxl_id).fault(bits)

    def clear_faults(self) -> None:
        with self._lock:
            for s in self._servos:
                s.silent_count = 0
                s.corrupt_count = 0
                s.garble_count = 0
                s.late_count = 0

    def disconnect(self) -> None:
        """Closes the pty, as if the USB adapter were pulled; the SDK's next call fails.

        The servos keep their state (a servo whose adapter is pulled keeps its torque).
        """
        self._disconnect.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)

    # --- the bus --------------------------------------------------------------------

    def _port_baud(self) -> int | None:
        speed = termios.tcgetattr(self._master)[4]
        return _TERMIOS_BAUDS.get(speed)

    def _run(self) -> None:
        wall_start = time.perf_counter()
        sim_start = self._sim_time
        lagging = False
        steps = 0
        try:
            while not self._stop.is_set() and not self._disconnect.is_set():
                if self.clock == "wall":
                    target = sim_start + (time.perf_counter() - wall_start) * self.speed_factor
                    with self._lock:
                        timestep = self._servos[0].shaft.timestep
                        steps = int((target - self._sim_time) / timestep)
                        if steps > 100 * _MAX_STEPS_PER_ITERATION and not lagging:
                            _log.warning("emulator runs slower than speed_factor=%s", self.speed_factor)
                            lagging = True
                        steps = min(steps, _MAX_STEPS_PER_ITERATION)
                        if steps > 0:
                            self._sim_time += steps * timestep
                            for s in self._servos:
                                s.advance(self._sim_time)
                            self._run_scheduled()
                    if self._disconnect.is_set():
                        break
                    # Serve the port between short physics chunks; sleep in select when idle.
                    wait_s = 0.0 if steps > 0 else 0.0005
                else:
                    wait_s = 0.05  # bus clock: nothing to do until bytes come (or stop())
                readable, _, _ = select.select([self._master], [], [], wait_s)
                if readable:
                    try:
                        data = os.read(self._master, 4096)
                    except OSError as exc:
                        if exc.errno != errno.EIO:
                            raise
                        data = b""
                    if data:
                        for packet in self._parser.feed(data):
                            self._serve(packet)
                            if self._disconnect.is_set():
                                break
        except Exception:  # the thread must not die silently: log, then close the port
            _log.exception("Dynamixel emulator on %s crashed", self.port_path)
        finally:
            if self._disconnect.is_set() or not self._stop.is_set():
                _log.info("Dynamixel emulator on %s disconnected", self.port_path)
                # Only the master: the emulator's own slave fd stays open until stop(),
                # so the kernel cannot hand this pty's number to another program while
                # a client may still try to reopen the path (it finds no such file).
                self._close_master()

    def _bus_time_s(self, n_bytes: int, port_baud: int | None) -> float:
        """Time ``n_bytes`` take on the bus at the port's baud (the servos' when it matches none), s."""
        return n_bytes * _BITS_PER_BYTE / (port_baud or self._servos[0].baud_bps)

    def _serve(self, packet: protocol.Packet) -> None:
        if packet.is_status:
            return
        bus = self.clock == "bus"
        with self._lock:
            port_baud = self._port_baud()
            if bus:
                # The host's turnaround, then the instruction on the wire.
                self._advance_to(self._sim_time + self.host_gap_s + self._bus_time_s(
                    _INSTRUCTION_OVERHEAD_BYTES + len(packet.params), port_baud))
                if self._disconnect.is_set():
                    return
                # Statuses held back as late arrive now, after the host gave up on them.
                held, self._held_statuses = self._held_statuses, []
                for status in held:
                    self._write(status)
            listening = [s for s in self._servos if s.baud_bps == port_baud]
            replies = self._dispatch(packet, listening)
        for s, error, params in replies:
            delay_s = s.get("Return Delay Time") * 2e-6
            late = s.late_count > 0
            if late:
                s.late_count -= 1
                delay_s += s.late_s
            # The alert bit was taken when the instruction ran (a REBOOT clears it after).
            status = protocol.build_status(s.dxl_id, error, params)
            if s.corrupt_count is None or s.corrupt_count > 0:
                status = status[:-1] + bytes([status[-1] ^ 0x5A])
                if s.corrupt_count:
                    s.corrupt_count -= 1
            if bus:
                with self._lock:
                    self._advance_to(self._sim_time + delay_s + self._bus_time_s(len(status), port_baud))
                    if late:
                        self._held_statuses.append(status)
                        continue
            elif delay_s > 0:
                time.sleep(delay_s)
            self._write(status)

    def _write(self, status: bytes) -> None:
        try:
            os.write(self._master, status)
        except OSError:
            _log.debug("status to %s lost: port closed", self.port_path)

    def _dispatch(self, packet, listening):
        """Returns [(servo, error, params)] to send, in bus order."""
        by_id = {}
        for s in listening:
            if s.silent_count is None or s.silent_count > 0:
                if s.silent_count:
                    s.silent_count -= 1
                continue
            by_id[s.dxl_id] = s
        inst, params, dxl_id = packet.instruction, packet.params, packet.dxl_id
        broadcast = dxl_id == protocol.BROADCAST_ID
        target = by_id.get(dxl_id)
        if packet.crc_ok and target is not None and (target.garble_count is None or target.garble_count > 0):
            packet = dataclasses.replace(packet, crc_ok=False)
            if target.garble_count:
                target.garble_count -= 1
        if not packet.crc_ok:
            return [(by_id[dxl_id], ErrorCode.CRC | by_id[dxl_id].alert, b"")] if dxl_id in by_id else []
        if inst in (Instruction.SYNC_READ, Instruction.SYNC_WRITE, Instruction.BULK_READ,
                    Instruction.BULK_WRITE):
            return self._group(inst, params, by_id)
        targets = sorted(by_id.values(), key=lambda s: s.dxl_id) if broadcast else (
            [by_id[dxl_id]] if dxl_id in by_id else [])
        replies = []
        for s in targets:
            status_level = s.get("Status Return Level")  # a write to it answers under the old level
            reply = self._single(s, inst, params)
            if reply is None:
                continue
            error, out, level = reply
            # PING always answers; broadcast READ/WRITE never do.
            if inst == Instruction.PING or (not broadcast and status_level >= level):
                replies.append((s, error | s.alert, out))
            self._after_reply(s, inst, params, error)
        return replies

    def _single(self, s: EmulatedServo, inst: int, params: bytes):
        """(error, params, status level needed to answer), or None for no answer."""
        if inst == Instruction.PING:
            return 0, s.get("Model Number").to_bytes(2, "little") + bytes([s.get("Firmware Version")]), 0
        if inst == Instruction.READ:
            if len(params) != 4:
                return ErrorCode.DATA_LENGTH, b"", 1
            address, length = _u16(params, 0), _u16(params, 2)
            error, data = s.read(address, length)
            return error, data, 1
        if inst in (Instruction.WRITE, Instruction.REG_WRITE):
            if len(params) < 3:
                return ErrorCode.DATA_LENGTH, b"", 2
            address, data = _u16(params, 0), params[2:]
            error = s.check_write(address, data)
            if not error:
                if inst == Instruction.WRITE:
                    s.write(address, data)
                else:
                    s.pending_write = (address, data)
                    s.set("Registered Instruction", 1)
            return error, b"", 2
        if inst == Instruction.ACTION:
            if s.pending_write is not None:
                address, data = s.pending_write
                s.pending_write = None
                s.set("Registered Instruction", 0)
                if not s.check_write(address, data):
                    s.write(address, data)
            return None
        if inst == Instruction.REBOOT:
            return 0, b"", 2
        if inst == Instruction.FACTORY_RESET:
            if len(params) != 1 or params[0] not in (0x01, 0x02, 0xFF):
                return ErrorCode.DATA_RANGE, b"", 2
            if s.torque_on:
                return ErrorCode.ACCESS, b"", 2
            return 0, b"", 2
        return ErrorCode.INSTRUCTION, b"", 2

    def _after_reply(self, s: EmulatedServo, inst: int, params: bytes, error: int) -> None:
        # The firmware answers first, then reboots / resets (and changes baud).
        if error:
            return
        if inst == Instruction.REBOOT:
            s.reboot()
        elif inst == Instruction.FACTORY_RESET:
            s.factory_reset(params[0])

    def _group(self, inst: int, params: bytes, by_id: dict[int, EmulatedServo]):
        replies = []
        if inst in (Instruction.SYNC_READ, Instruction.SYNC_WRITE):
            if len(params) < 4:
                return []
            address, length = _u16(params, 0), _u16(params, 2)
            body = params[4:]
            if inst == Instruction.SYNC_READ:
                for dxl_id in body:
                    s = by_id.get(dxl_id)
                    if s is not None and s.get("Status Return Level") >= 1:
                        error, data = s.read(address, length)
                        replies.append((s, error | s.alert, data))
            else:
                stride = 1 + length
                for k in range(0, len(body) - stride + 1, stride):
                    s = by_id.get(body[k])
                    data = body[k + 1 : k + stride]
                    if s is not None and not s.check_write(address, data):
                        s.write(address, data)
            return replies
        if inst == Instruction.BULK_READ:
            for k in range(0, len(params) - 4, 5):
                s = by_id.get(params[k])
                if s is not None and s.get("Status Return Level") >= 1:
                    error, data = s.read(_u16(params, k + 1), _u16(params, k + 3))
                    replies.append((s, error | s.alert, data))
            return replies
        # BULK_WRITE: [id, address, length, data...] repeated.
        k = 0
        while k + 5 <= len(params):
            length = _u16(params, k + 3)
            s = by_id.get(params[k])
            data = params[k + 5 : k + 5 + length]
            address = _u16(params, k + 1)
            if s is not None and not s.check_write(address, data):
                s.write(address, data)
            k += 5 + length
        return []


def _check_count(count) -> None:
    if count is not None and not (isinstance(count, int) and count >= 1):
        raise ValueError(f"count must be an integer >= 1, or None for until clear_faults(), got {count!r}")


def _u16(data: bytes, offset: int) -> int:
    return data[offset] | (data[offset + 1] << 8)
