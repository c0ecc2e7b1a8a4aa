"""Continuous rig scans: the servo turns at a set speed while the real LiDAR streams.

The loop of a continuous scan on the physical rig (a Dynamixel servo and a Hokuyo
URG), the counterpart of :mod:`plantsim.scan.session`'s step loop:

1. The servo is switched to extended-position mode (operating mode 4: multi-turn,
   the profile's velocity cap is the turning speed; the X-series velocity mode would
   turn as well, but gives no end point, so a lost host would leave it spinning) and
   sent to a goal past the end of the sweep at ``rpm`` (Profile Velocity, 0.229 rpm
   units: the speed actually used is the nearest multiple).
2. A poller thread reads the servo's Realtime Tick and Present Position in one read
   (address 120, 16 bytes), as fast as the bus allows; each reading's host time comes
   from its tick, the servo clock put on the host clock by intersecting the bounds of
   every read's round trip (:class:`TickClock`). These readings are the encoder log.
3. The LiDAR streams (MD, started before the table turns); each line's beams are
   on the host clock through the TM-estimated offset. A line is journaled once the
   encoder log has a reading after its last beam: first the new readings, then the
   line. Lines are kept from the first one whose start is past the lead-in and
   that a reading before it shows the table at speed (six spin-ups from where it
   started), one every half line spacing or more, until the scan has ``n_lines``;
   the reconstruction interpolates the encoder readings to every beam
   (``angle_mode = "interpolate"``, de-skew).
4. Every exit path stops the servo: a fault or Ctrl-C switches its torque off at
   once (the :class:`~plantsim.hardware.safety.SafeStop` of the command checks it
   again); a normal end holds it where it is, then restores position mode.

Resume: the journal keeps the encoder readings and lines; a resumed run turns the
table back before the last journaled line (its angle modulo one turn, in the
journal's frame) by a lead-in to come up to speed and ten line periods (at least
another lead-in) for a reading to show it and goes on until the scan has all its lines, so a fault loses at most the line
in flight and the coverage is the full sweep.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np

from plantsim.errors import HardwareError, ScanInterruptedError
from plantsim.interrupts import raise_if_signalled
from plantsim.scan.journal import Journal, open_journal
from plantsim.scan.raw import BeamGrid, RawScan
from plantsim.scan.session import raw_from_lines, real_line
from plantsim.turntable import units

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]

#: The servo's Realtime Tick wraps at 32768 ms.
TICK_MODULUS_MS = 32768
#: Profile Velocity's unit, rpm (X series).
RPM_PER_VELOCITY_UNIT = 0.229
#: Profile Acceleration's unit, rev/min^2 (X series, velocity-based profile).
RPM2_PER_ACCELERATION_UNIT = 214.577
_READ_ADDRESS, _READ_LENGTH = 120, 16  # Realtime Tick .. Present Position (X-series RAM)
_POSITION_OFFSET = 12  # Present Position (132) within that block
_EXTENDED_POSITION_MODE = 4
_POSITION_MODE = 3


def profile_velocity_units(rpm: float) -> int:
    """The Profile Velocity register value nearest ``rpm`` (at least 1).

    Raises:
        ValueError: rpm not finite and > 0.
    """
    if not (math.isfinite(rpm) and rpm > 0):
        raise ValueError(f"rpm must be finite and > 0, got {rpm!r}")
    return max(1, round(rpm / RPM_PER_VELOCITY_UNIT))


def servo_rpm(rpm: float) -> float:
    """The speed the servo really turns at for a requested ``rpm`` (0.229 rpm steps)."""
    return profile_velocity_units(rpm) * RPM_PER_VELOCITY_UNIT


def continuous_line_count(sweep_deg: float, rpm: float, scan_period_s: float) -> int:
    """Lines of a continuous rig scan: the sweep over the turn per line at the servo's real speed."""
    per_line_deg = servo_rpm(rpm) * 6.0 * scan_period_s
    return max(1, math.ceil(sweep_deg / per_line_deg - 1e-9))


class TickClock:
    """The servo's Realtime Tick (ms, wrapping at 32768) on the host clock.

    Every read brackets the servo's reading: it happened between the host's clock
    before the request (``sent``) and after the reply (``received``), and the servo's
    clock then read ``tick`` to ``tick + 1`` ms. So the servo-minus-host offset ``c``
    lies in ``[tick - received, tick + 1 ms - sent]`` for every read, and the
    intersection over all reads is the estimate (its middle; half its width is the
    uncertainty); reads with short round trips narrow it most.

    A stale reply (a late status taken as the answer to the next request, which
    Protocol 2.0 cannot tell apart: it has no sequence number) carries an older tick:
    its lower bound is still valid, but its upper bound falls below the others' lower
    bound. :meth:`is_stale` says so, and such a reply is dropped (and the bus
    resynchronised) instead of narrowing the estimate; upper bounds below the lower
    one are ignored.
    """

    STALE_MARGIN_S = 2e-3

    def __init__(self):
        self._low = -math.inf
        self._highs: list[float] = []
        self._last_raw: int | None = None
        self._unwrapped_ms = 0

    def unwrap(self, tick_ms: int) -> int | None:
        """The tick unwrapped against the previous one (reads less than 16 s apart);
        None for a tick that went backwards (a stale reply: the reading is not used)."""
        if self._last_raw is None:
            self._unwrapped_ms = int(tick_ms)
        else:
            step = (int(tick_ms) - self._last_raw) % TICK_MODULUS_MS
            if step > TICK_MODULUS_MS // 2:
                return None
            self._unwrapped_ms += step
        self._last_raw = int(tick_ms)
        return self._unwrapped_ms

    def is_stale(self, sent_s: float, servo_s: float) -> bool:
        """Whether a read's tick is older than its request can allow (given the reads so far),
        by more than :attr:`STALE_MARGIN_S` (the jitter between a servo's tick and its
        position sample, and the emulator's physics step)."""
        return servo_s + 1e-3 - sent_s < self._low - self.STALE_MARGIN_S

    def add(self, sent_s: float, servo_s: float, received_s: float) -> None:
        """One read: host clock before and after, the servo's unwrapped tick in s."""
        self._low = max(self._low, servo_s - received_s)
        self._highs.append(servo_s + 1e-3 - sent_s)

    def estimate(self) -> tuple[float, float]:
        """(offset, uncertainty), s: servo clock minus host clock, and half the interval's width.

        Raises:
            ValueError: before the first read.
        """
        if not self._highs:
            raise ValueError("no reading yet")
        highs = np.asarray(self._highs)
        valid = highs[highs >= self._low]
        high = float(valid.min()) if len(valid) else self._low + 1e-3
        return 0.5 * (self._low + high), 0.5 * (high - self._low)

    @property
    def offset_s(self) -> float:
        """Servo clock minus host clock, s."""
        return self.estimate()[0]

    @property
    def uncertainty_s(self) -> float:
        """Half the width of the offset's interval, s."""
        return self.estimate()[1] if self._highs else math.inf


@dataclasses.dataclass(frozen=True)
class Reading:
    """One encoder reading: host clock around the read, the servo's tick (unwrapped, s), angle (rad)."""

    sent_s: float
    servo_s: float
    received_s: float
    angle_rad: float


class EncoderPoller:
    """Reads the servo's tick and position in a thread until stopped.

    Args:
        driver: a connected :class:`~plantsim.hardware.dynamixel.driver.DynamixelTurntable`
            (used by this thread only while it runs).
        host_clock: the host clock (the LiDAR driver's).
    """

    def __init__(self, driver, host_clock: Callable[[], float]):
        self.driver = driver
        self.host_clock = host_clock
        self.clock = TickClock()
        self.readings: list[Reading] = []
        self.min_interval_s = 0.003
        self.stale_replies = 0
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._new = threading.Condition()
        self._thread: threading.Thread | None = None

    def read_once(self) -> Reading | None:
        """One reading, or None when the servo's tick went backwards (logged)."""
        sent = self.host_clock()
        # One READ of Realtime Tick .. Present Position: the tick and the position of one instant.
        data = bytes(self.driver._call("read tick and position", "readTxRx", _READ_ADDRESS, _READ_LENGTH,
                                       check_alert=True))
        received = self.host_clock()
        tick = int.from_bytes(data[0:2], "little")
        ticks = units.to_signed(int.from_bytes(data[_POSITION_OFFSET:_POSITION_OFFSET + 4], "little"), 4)
        unwrapped = self.clock.unwrap(tick)
        if unwrapped is None or self.clock.is_stale(sent, unwrapped / 1000.0):
            # A reply to an earlier request: drop it and bring the bus back in step.
            log.warning("servo ID %s: a stale reply (Realtime Tick %d ms, older than the request); reading "
                        "dropped, bus resynchronised", self.driver.dxl_id, tick)
            self.stale_replies += 1
            self.driver.resync(raise_on_failure=False)
            return None
        servo_s = unwrapped / 1000.0
        self.clock.add(sent, servo_s, received)
        return Reading(sent, servo_s, received, float(units.ticks_to_rad(ticks)))

    def start(self) -> "EncoderPoller":
        self._thread = threading.Thread(target=self._run, name="encoder-poller", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                reading = self.read_once()
                if reading is not None:
                    with self._new:
                        self.readings.append(reading)
                        self._new.notify_all()
                # Leave the bus (and the CPU) some air: about 300 readings a second at most.
                self._stop.wait(self.min_interval_s)
        except BaseException as exc:  # noqa: BLE001 - handed to the scan's thread, which raises it
            with self._new:
                self.error = exc
                self._new.notify_all()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)

    def host_times(self, readings: list[Reading]) -> np.ndarray:
        """The readings' host times, s: each tick through the offset, within its own round trip."""
        offset, _ = self.clock.estimate()
        servo = np.array([r.servo_s for r in readings])
        sent = np.array([r.sent_s for r in readings])
        received = np.array([r.received_s for r in readings])
        return np.clip(servo + 0.5e-3 - offset, sent, received)

    def wait_past(self, host_s: float, timeout_s: float) -> None:
        """Waits until a reading was taken after host time ``host_s``.

        Raises:
            HardwareError: the poller failed (its error), or no such reading within
                ``timeout_s`` of wall time (the servo stopped answering).
        """
        deadline = time.monotonic() + timeout_s
        with self._new:
            while True:
                if self.error is not None:
                    if isinstance(self.error, HardwareError):
                        raise self.error
                    raise HardwareError(f"reading the servo failed: {self.error}") from self.error
                if self.readings and self.readings[-1].sent_s > host_s:
                    return
                left = deadline - time.monotonic()
                if left <= 0:
                    raise HardwareError(f"servo ID {self.driver.dxl_id} on {self.driver.port_name}: no position "
                                        f"reading for {timeout_s:g} s during a continuous scan")
                self._new.wait(min(left, 0.05))


def encoder_log(readings: dict) -> tuple[np.ndarray, np.ndarray, float]:
    """The encoder log of journaled servo readings: each reading's host time from its tick.

    Each run of a (resumed) scan has its own servo-clock epoch: its offset is estimated
    from all of that run's readings (:class:`TickClock`), and each reading's time is its
    tick through that offset, within its own round trip. Readings whose time does not
    are put in time order, one per stamp.

    Args:
      readings: :func:`plantsim.scan.journal.encode_encoder_chunk`'s arrays.

    Returns:
      (stamps ns since the scan's start, int64 increasing; angles rad; the largest
      run's offset uncertainty plus the tick's half millisecond, s).
    """
    stamps, angles, uncertainty = [], [], 0.0
    for run in np.unique(readings["run"]):
        mine = readings["run"] == run
        sent, device, received = (readings[k][mine] / 1e9 for k in ("sent_ns", "device_ns", "received_ns"))
        clock = TickClock()
        keep = np.ones(len(sent), bool)
        for i in range(len(sent)):
            if clock.is_stale(sent[i], device[i]):
                keep[i] = False
            else:
                clock.add(sent[i], device[i], received[i])
        offset, u = clock.estimate()
        uncertainty = max(uncertainty, u + 0.5e-3)
        times = np.clip(device + 0.5e-3 - offset, sent, received)[keep]
        stamps.append(np.round(times * 1e9).astype(np.int64))
        angles.append(readings["angle_rad"][mine][keep])
    if not stamps:
        return np.empty(0, np.int64), np.empty(0), math.inf
    stamp, angle = np.concatenate(stamps), np.concatenate(angles)
    # In time order (a reading clipped into its own long round trip may land after the next one's
    # time), and one reading per stamp.
    order = np.argsort(stamp, kind="stable")
    stamp, angle = stamp[order], angle[order]
    first = np.ones(len(stamp), bool)
    first[1:] = stamp[1:] > stamp[:-1]
    return stamp[first], angle[first], uncertainty


class ContinuousServo:
    """What a continuous scan needs from the servo that :class:`ServoTurntable` lacks:
    extended-position mode, a turning speed, a goal beyond one turn, a hold.

    Args:
        turntable: a connected :class:`~plantsim.hardware.dynamixel.turntable.ServoTurntable`.
    """

    def __init__(self, turntable):
        self.turntable = turntable
        self.driver = turntable.driver
        self._saved_velocity: int | None = None

    def extended_mode(self) -> None:
        """Operating mode 4 (torque off for the EEPROM write, then on again: it holds where it is)."""
        d = self.driver
        self._saved_velocity = d.read_register("Profile Velocity")
        d.torque_off()
        d.write_register("Operating Mode", _EXTENDED_POSITION_MODE)
        d.torque_on()

    def spinup_rad(self, velocity_units: int) -> float:
        """The turn the profile needs to reach ``velocity_units`` from rest, rad
        (v^2 / 2a; 0 when Profile Acceleration is 0, the servo's "as fast as it can")."""
        accel_units = self.driver.read_register("Profile Acceleration")
        if accel_units <= 0:
            return 0.0
        v = velocity_units * RPM_PER_VELOCITY_UNIT * 2 * math.pi / 60.0
        a = accel_units * RPM2_PER_ACCELERATION_UNIT * 2 * math.pi / 3600.0
        return v * v / (2 * a)

    def position_rad(self) -> float:
        return self.driver.position()

    def go(self, goal_rad: float, *, velocity_units: int | None = None) -> None:
        """Sends the servo towards ``goal_rad`` (multi-turn) at ``velocity_units`` (or the saved profile)."""
        d = self.driver
        velocity = velocity_units if velocity_units is not None else self._saved_velocity
        d.write_register("Profile Velocity", velocity)
        goal = units.rad_to_ticks(goal_rad)
        d.write_register("Goal Position", goal)
        # Read back: a write whose status was lost and retried on a noisy bus must still have landed.
        got = (d.read_register("Profile Velocity"), d.read_register("Goal Position"))
        if got != (velocity, goal):
            raise HardwareError(f"servo ID {d.dxl_id} reads back Profile Velocity {got[0]}, Goal Position {got[1]} "
                                f"after writing {velocity}, {goal}; check the bus (cable, termination)")

    def move_and_wait(self, goal_rad: float, timeout_s: float) -> float:
        """Moves to ``goal_rad`` at the saved (gentle) profile and waits until it is there."""
        self.go(goal_rad)
        goal_ticks = units.rad_to_ticks(goal_rad)
        deadline = time.monotonic() + timeout_s
        while True:
            ticks = self.driver.read_register("Present Position")
            if abs(ticks - goal_ticks) <= 2 and self.driver.read_register("Moving") == 0:
                return units.ticks_to_rad(ticks)
            if time.monotonic() > deadline:
                raise HardwareError(f"servo ID {self.driver.dxl_id} did not reach {goal_rad:.4f} rad within "
                                    f"{timeout_s:g} s before the continuous scan; check for a jam")
            time.sleep(0.005)

    def hold(self) -> None:
        """Stops turning: the goal becomes the present position."""
        d = self.driver
        d.write_register("Goal Position", d.read_register("Present Position"))

    def restore_position_mode(self) -> None:
        """Back to position mode with the saved profile, torque on (as ``ServoTurntable.connect`` left it)."""
        d = self.driver
        d.torque_off()
        d.write_register("Operating Mode", _POSITION_MODE)
        if self._saved_velocity is not None:
            d.write_register("Profile Velocity", self._saved_velocity)
        d.torque_on()


def check_lidar_clock_rate(source) -> None:
    """Refuses a LiDAR whose clock does not run at the host's rate (before anything moves).

    A continuous scan puts every beam on the host clock through the sensor's
    timestamps (the TM offset) and the servo's readings through its Realtime Tick;
    both assume device clocks that run at the host's rate (within ppm). An emulated
    pair started with ``--speed-factor N`` runs its clocks N times faster than a host
    on the wall clock: its beams would be placed at the wrong angles, and its LiDAR
    must cast N x 10 scans per wall second, more than a machine can, so the stream
    falls behind. The rate bounds of the last clock sync
    (:attr:`~plantsim.hardware.urg.clock.ClockOffset.rate_low`, ``rate_high``) decide.

    Raises:
        HardwareError: the bounds exclude the host's rate (by more than
            :data:`~plantsim.hardware.urg.clock.RATE_TOLERANCE`).
    """
    from plantsim.hardware.urg.clock import RATE_TOLERANCE

    lidar = getattr(source, "lidar", None)
    offset = getattr(lidar, "clock_offset", None)
    if offset is None or offset.runs_at_host_rate():
        return
    rate = f"{offset.rate_low:.3g} to {offset.rate_high:.3g}" if math.isfinite(offset.rate_high) else \
        f"at least {offset.rate_low:.3g}"
    raise HardwareError(
        f"the LiDAR on {getattr(lidar, 'port', 'its port')} counts {rate} s of its time per second of the host's "
        f"(a sensor runs at 1 within {RATE_TOLERANCE:.0%}): a continuous scan times every beam on the host's clock, "
        "so it needs the devices in real time. Is it an emulator started with --speed-factor? Restart it with "
        "--speed-factor 1 for continuous scans (step scans work at any speed factor)")


def run_continuous_session(*, turntable, source, grid: BeamGrid, rpm: float, sweep_deg: float,
                           journal_path: str | Path, identity: dict, angle_mode: str, T_base_lidar: np.ndarray,
                           encoder_offset_rad: float = 0.0, resume: bool = False,
                           lead_in_deg: float = 10.0, move_timeout_s: float = 120.0,
                           reading_timeout_s: float = 10.0,
                           progress: Progress | None = None) -> tuple[RawScan, Journal, dict]:
    """A continuous rig scan with the real LiDAR, journaled line by line.

    Args:
      turntable: a connected :class:`~plantsim.hardware.dynamixel.turntable.ServoTurntable`;
        the caller closes it (torque off).
      source: the real LiDAR (:class:`~plantsim.hardware.urg.source.UrgLineSource`).
      grid: the sensor's beam grid.
      rpm: the turning speed asked for (the servo turns at the nearest 0.229 rpm step).
      sweep_deg: the turn to cover, degrees.
      journal_path, identity, resume: as :func:`plantsim.scan.session.run_session`.
      angle_mode: "interpolate" (de-skew) or "line".
      T_base_lidar: (4, 4) the sensor's pose.
      encoder_offset_rad: the encoder's reading at turntable angle 0.
      lead_in_deg: least turn before the first line (at least 6 x the profile's spin-up), deg.
      move_timeout_s: limit of the move to the resume point, s (wall clock).
      reading_timeout_s: a fault when the servo gives no reading for this long, s (wall clock).
      progress: called with (lines done, lines total).

    Returns:
      (raw record, journal, timing): timing says how well this run's clocks were
      known: ``servo_clock_uncertainty_s`` (the Realtime Tick's offset, plus half its
      1 ms tick), ``lidar_clock_uncertainty_s`` (the TM offset's), ``servo_rpm``
      (the speed used), ``encoder_readings`` (this run's).

    Raises:
      JournalError: as in a step scan.
      ScanInterruptedError: the servo or LiDAR failed (or Ctrl-C: KeyboardInterrupt
        propagates); the servo's torque is off, the journal keeps every complete line.
    """
    if not (math.isfinite(sweep_deg) and 0 < sweep_deg):
        raise ValueError(f"sweep_deg must be finite and > 0, got {sweep_deg!r}")
    check_lidar_clock_rate(source)
    velocity_units = profile_velocity_units(rpm)
    omega = servo_rpm(rpm) * 2 * math.pi / 60.0
    per_line_rad = omega * grid.scan_period_s
    n_lines = continuous_line_count(sweep_deg, rpm, grid.scan_period_s)
    journal_path = Path(journal_path)
    journal = open_journal(journal_path, identity, n_lines=n_lines, n_beams=grid.n_beams,
                           started_unix_s=time.time(), resume=resume)
    started = journal.header["started_unix_s"]
    servo = ContinuousServo(turntable)
    host_clock = source.host_clock
    timing = {"servo_rpm": servo_rpm(rpm), "lidar_clock_uncertainty_s": source.clock_uncertainty_s()}
    with journal:
        start = len(journal.lines)
        if progress is not None:
            progress(start, n_lines)
        if start < n_lines:
            timing.update(_turn_and_stream(journal, servo, source, grid, n_lines=n_lines, velocity_units=velocity_units,
                             per_line_rad=per_line_rad, sweep_rad=math.radians(sweep_deg),
                             lead_in_rad=math.radians(lead_in_deg), host_clock=host_clock,
                             move_timeout_s=move_timeout_s, reading_timeout_s=reading_timeout_s,
                             progress=progress))
    stamp_ns, angle_rad, servo_uncertainty_s = encoder_log(journal.encoder_readings())
    timing["servo_clock_uncertainty_s"] = servo_uncertainty_s
    raw = raw_from_lines(journal.lines, grid=grid, T_base_lidar=T_base_lidar, angle_mode=angle_mode,
                         start_unix_ns=int(started * 1e9), encoder_offset_rad=encoder_offset_rad,
                         encoder=(stamp_ns, angle_rad))
    return raw, journal, timing


def _turn_and_stream(journal: Journal, servo: ContinuousServo, source, grid: BeamGrid, *, n_lines: int,
                     velocity_units: int, per_line_rad: float, sweep_rad: float, lead_in_rad: float,
                     host_clock, move_timeout_s: float, reading_timeout_s: float, progress) -> dict:
    path = journal.path
    done = journal.encoder_readings()
    last_stamp_s = max([journal.lines[-1].stamp_ns / 1e9 if journal.lines else -1.0,
                        done["received_ns"].max() / 1e9 if len(done["received_ns"]) else -1.0])
    run = int(done["run"].max()) + 1 if len(done["run"]) else 0
    poller = None
    stream = None
    finished = False
    try:
        try:
            servo.extended_mode()
            # Lines start once the table is at speed: the spin-up, with a margin, or lead_in_rad.
            # (The shaft lags its profile and overshoots a little: six times the profile's spin-up.)
            at_speed_rad = 6.0 * servo.spinup_rad(velocity_units)
            lead_in_rad = max(lead_in_rad, at_speed_rad)
            present = servo.position_rad()
            if journal.lines:
                # The journal's frame: the present angle plus whole turns, near the last line.
                last = journal.lines[-1].reported_angle_rad
                frame_rad = 2 * math.pi * round((last - present) / (2 * math.pi))
                begin = last + 0.5 * per_line_rad  # the next line starts past the last one
                # Back by a lead-in (to come up to speed) and ten line periods more (1 s on the URG; at
                # least another lead-in): a reading has that long to show the table at speed before
                # `begin`, so the first line past it is kept even when a busy host reads the servo late
                # (with one lead-in, a busy host's late readings left a gap of 7 lines there).
                back_rad = lead_in_rad + max(lead_in_rad, 10 * per_line_rad)
                present = servo.move_and_wait(last - frame_rad - back_rad, move_timeout_s)
                first_line_rad = journal.lines[0].reported_angle_rad
            else:
                frame_rad = 0.0
                begin = present + lead_in_rad
                first_line_rad = None
            # Lines count from where a reading shows the table at speed (journal frame).
            at_speed_rad += present + frame_rad
            no_progress_limit = 20 + 2 * (begin - present - frame_rad) / per_line_rad
            # Well past the end of the sweep (one more turn): the table turns at constant speed through
            # the last line and beyond, however sparse the readings of a busy host, and is held as soon
            # as the scan has its lines; were the host to die, the servo still stops there (in velocity
            # mode it would turn on).
            end_rad = (first_line_rad if first_line_rad is not None else begin) + sweep_rad + 2 * math.pi
            zero_s = host_clock() - (last_stamp_s + 1.0)  # scan time continues after the journal's
            # The LiDAR streams before the table turns (its first scan is in): a host slow to start the
            # stream cannot miss the lines of the turn's start (they are skipped while the table is at rest).
            stream = source.stream()
            first = next(stream)
            # The table starts turning before the poller owns the bus (one thread at a time on the port).
            servo.go(end_rad - frame_rad, velocity_units=velocity_units)
            poller = EncoderPoller(servo.driver, host_clock)
            poller.start()
            poller.wait_past(host_clock(), reading_timeout_s)
            next_min = begin
            journaled_readings = 0
            stalled = skipped = 0
            begun = False
            for line in itertools.chain([first], stream):
                raise_if_signalled()  # a SIGTERM the interpreter swallowed still stops the scan here
                poller.wait_past(float(line.beam_host_times_s[-1]), reading_timeout_s)
                with poller._new:
                    n_readings = len(poller.readings)
                    # The recent readings only: those not yet journaled, and back to before the line began
                    # (a host that fell behind journaled readings from after the line's first beam).
                    lo = journaled_readings
                    while lo > 0 and poller.readings[lo - 1].received_s >= line.first_beam_host_s - 0.01:
                        lo = max(0, lo - 64)
                    lo = max(0, lo - 2)
                    readings = poller.readings[lo:n_readings]
                times = poller.host_times(readings)
                angles = np.array([r.angle_rad for r in readings]) + frame_rad
                order = np.argsort(times, kind="stable")  # np.interp needs increasing times
                first_angle = float(np.interp(line.first_beam_host_s, times[order], angles[order]))
                if not begun:
                    # A run's first line only once a reading *before* it shows the table past the lead-in
                    # (at speed): an interpolation across the spin-up would misplace it.
                    begun = bool(np.any((times <= line.first_beam_host_s) & (angles >= at_speed_rad)))
                if not begun or first_angle < next_min:
                    skipped += 1
                    stalled += 1
                    if stalled > no_progress_limit:
                        raise HardwareError(
                            f"the turntable does not turn: {stalled} LiDAR lines without progress at "
                            f"{math.degrees(first_angle):.2f} deg; check the servo's Velocity Limit and load")
                    continue
                stalled = 0
                # The readings not yet journaled, up to the newest, as read (their times are derived
                # from all of this run's readings when the raw record is built), then the line.
                fresh = readings[journaled_readings - lo:]
                ns = lambda values: np.round((np.asarray(values) - zero_s) * 1e9).astype(np.int64)  # noqa: E731
                journal.append_encoder({
                    "sent_ns": ns([r.sent_s for r in fresh]), "received_ns": ns([r.received_s for r in fresh]),
                    "device_ns": np.round(np.array([r.servo_s for r in fresh]) * 1e9).astype(np.int64),
                    "angle_rad": np.array([r.angle_rad for r in fresh]) + frame_rad,
                    "run": np.full(len(fresh), run, np.int32)})
                journaled_readings = n_readings
                index = len(journal.lines)
                journal.append(real_line(index, math.nan, first_angle, line.first_beam_host_s - zero_s, line))
                next_min = first_angle + 0.5 * per_line_rad
                if progress is not None:
                    progress(index + 1, n_lines)
                if index + 1 >= n_lines:
                    break
            finished = True
            return {"host_clock_zero_s": zero_s, "encoder_readings": len(poller.readings),
                    "lidar_lines_skipped": skipped, "lidar_scans_dropped": source.lidar.dropped_scans,
                    "servo_stale_replies_dropped": poller.stale_replies}
        except HardwareError as exc:
            done = len(journal.lines)
            raise ScanInterruptedError(
                f"{exc} [continuous scan stopped after line {done} of {n_lines}; the {done} complete lines "
                f"are safe in {path}]", journal_path=str(path), lines_done=done, n_lines=n_lines) from exc
    finally:
        if stream is not None:
            stream.close()  # QT: the laser off, the stream stopped
        if poller is not None:
            poller.stop()
        _stop_servo(servo, finished)


def _stop_servo(servo: ContinuousServo, finished: bool) -> None:
    """Every exit: a normal end holds the table and restores position mode; anything
    else switches the torque off at once (the command's SafeStop checks it again)."""
    if finished:
        try:
            servo.hold()
            servo.restore_position_mode()
            return
        except HardwareError as exc:
            log.warning("stopping the servo after the scan: %s; switching its torque off", exc)
    try:
        servo.driver.emergency_stop()
    except HardwareError as exc:
        log.error("servo torque off after the continuous scan NOT confirmed: %s", exc)
