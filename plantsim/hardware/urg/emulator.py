"""A Hokuyo URG-04LX on a pseudo-terminal, speaking SCIP 2.0 byte for byte.

The emulator opens a pty, keeps the master end and hands out the slave's path
(:attr:`UrgEmulator.port_path`), which a driver opens as the sensor's
``/dev/ttyACM0``. A background thread answers commands: VV, PP, II, BM, QT, RS,
GD/GS, MD/MS (streaming at one scan per mirror turn, 100 ms), TM0/TM1/TM2, the
SCIP 1.1 start-up mode and its ``SCIP2.0`` switch; echo with the ``;tag``, status
and checksums, 64-character data lines, the 2/3/4-character encodings and the
24-bit millisecond timestamps, as :mod:`.protocol` documents from the vendor's
specification.

Ranges come from ``scan_provider(t_scan_start_s) -> (range_m, status)``, called
once per scan with the emulator clock's time of that scan's step 0; both arrays
are indexed by step (``UrgEmulator.N_STEPS`` = 769, steps 0..768). Step ``k`` of
that scan is measured at ``t_scan_start_s + k / 1024 * 0.1 s``: a provider that
sees a turning plant evaluates each beam at its own instant.

Time: every time comes from ``clock`` (:class:`VirtualClock` for tests,
:class:`RealTimeClock` for the command line). The sensor's timer reads
``clock.now() + timestamp_offset_s`` (ms, mod 2^24); scans start at the clock's
multiples of 100 ms. With a :class:`VirtualClock` the emulator advances the clock
itself, and only while the client has read everything sent: to the next scan while
streaming, to a reply's ready time (``latency_s``) otherwise. Tests so never wait on
wall time, and a streamed scan is never lost to a slow reader.

Deviations, on purpose: CR, SS, HS and DB answer "0E" (not emulated); the motor
speed is fixed at 600 rpm; SCIP 1.1 answers "E" to everything except ``SCIP2.0``;
a cluster of error codes sends the first code; GD returns the latest scan complete
over the requested steps that started after the laser came on.

Usage::

    clock = VirtualClock()
    with UrgEmulator(clock=clock) as emulator, UrgLidar.connect(emulator.port_path,
            host_clock=clock.now, sleep=clock.sleep) as lidar:
        scan = lidar.scan()
"""

from __future__ import annotations

import errno
import fcntl
import logging
import math
import os
import select
import struct
import termios
import threading
import tty
from typing import Callable

import numpy as np

from plantsim.hardware.pty import close_fds
from plantsim.hardware.urg import protocol as p
from plantsim.hardware.urg.clock import RealTimeClock, VirtualClock  # noqa: F401 - VirtualClock re-exported here too
from plantsim.sensor.spec import BeamStatus

_log = logging.getLogger(__name__)

ScanProvider = Callable[[float], "tuple[np.ndarray, np.ndarray]"]


# --- the sensor ---------------------------------------------------------------------

def wall_provider(range_m: float = 1.0) -> ScanProvider:
    """A provider for tests: every step in AMIN..AMAX sees a surface at ``range_m``;
    the steps outside the field of view (the sensor's dead zone) return no echo."""
    if not (math.isfinite(range_m) and range_m > 0):
        raise ValueError(f"range_m must be finite and > 0, got {range_m!r}")

    def provide(t_scan_start_s: float):
        ranges = np.full(UrgEmulator.N_STEPS, range_m)
        status = np.full(UrgEmulator.N_STEPS, BeamStatus.OK, dtype=np.int8)
        outside = np.ones(UrgEmulator.N_STEPS, bool)
        outside[UrgEmulator.AMIN:UrgEmulator.AMAX + 1] = False
        status[outside] = BeamStatus.NO_ECHO
        ranges[outside] = np.nan
        return ranges, status

    return provide


def preset_provider(line_fn: Callable[[np.ndarray], "tuple[np.ndarray, np.ndarray]"],
                    spec=None) -> ScanProvider:
    """A provider from a line source that works on a preset's beams.

    Args:
        line_fn: ``f(beam_times_s) -> (range_m, status)``: given the (n_beams,) clock
            times at which the preset's beams are measured (step ``first_step + i`` at
            ``t_scan_start_s + (first_step + i) / 1024 * 0.1 s``), the beams' ranges (m,
            NaN for none) and BeamStatus values, each (n_beams,). The simulated LiDAR
            seeing the emulated turntable at each beam's instant fits here.
        spec: the :class:`~plantsim.sensor.spec.LidarSpec` (default URG_04LX_UG01);
            its beams must be steps of the URG-04LX (1024 per turn, 100 ms).

    Steps outside the preset's beams return no echo.
    """
    from plantsim.sensor.spec import URG_04LX_UG01

    spec = URG_04LX_UG01 if spec is None else spec
    if spec.steps_per_rev != UrgEmulator.ARES or abs(spec.scan_period_s - UrgEmulator.SCAN_PERIOD_S) > 1e-12:
        raise ValueError(f"spec {spec.name!r} is not a URG-04LX grid (1024 steps per 100 ms turn)")
    first, last = spec.first_step, spec.first_step + spec.n_beams - 1
    if last > UrgEmulator.LAST_STEP:
        raise ValueError(f"spec {spec.name!r} reaches step {last}, beyond the URG-04LX's last step 768")
    offsets_s = spec.beam_time_offsets_s()

    def provide(t_scan_start_s: float):
        ranges_m, status = line_fn(t_scan_start_s + offsets_s)
        all_ranges = np.full(UrgEmulator.N_STEPS, np.nan)
        all_status = np.full(UrgEmulator.N_STEPS, BeamStatus.NO_ECHO, dtype=np.int8)
        all_ranges[first:last + 1] = ranges_m
        all_status[first:last + 1] = status
        return all_ranges, all_status

    return provide


class UrgEmulator:
    """A URG-04LX behind a pseudo-terminal.

    Args:
        scan_provider: ``f(t_scan_start_s) -> (range_m, status)``, each (769,) indexed
            by step: metres (NaN for no return) and BeamStatus values. Default: a
            surface 1 m away all round (:func:`wall_provider`).
        clock: :class:`VirtualClock` (tests) or :class:`RealTimeClock` (default, speed 1).
        timestamp_offset_s: the sensor timer's reading, s, when the clock reads 0
            (the host/sensor clock offset a driver must estimate).
        latency_s: one-way delay of the link, s: a command is taken in after it,
            the reply leaves ``2 * latency_s`` after it was read.
        clock_drift_ppm: how fast the sensor's timer runs against the clock, parts
            per million (a crystal's tens of ppm).
        start_in_scip11: boot in SCIP 1.1, as some URG-04LX firmware does.
        model, serial, firmware: what PP/VV/II report.
        semicolon_in_checksum: sum the ``;`` of VV/PP/II lines (later sensors);
            the URG-04LX does not.
    """

    ARES = 1024
    AMIN = 44
    AMAX = 725
    AFRT = 384
    LAST_STEP = 768  # "Step D", the last measurement point ([SCIP] 5, table 2)
    N_STEPS = LAST_STEP + 1
    DMIN_MM = 20
    DMAX_MM = 5600
    SCAN_RPM = 600
    SCAN_PERIOD_S = 60.0 / SCAN_RPM

    def __init__(self, scan_provider: ScanProvider | None = None, *, clock=None,
                 timestamp_offset_s: float = 0.0, latency_s: float = 0.0, clock_drift_ppm: float = 0.0,
                 start_in_scip11: bool = False,
                 model: str = "URG-04LX", serial: str = "H0000001",
                 firmware: str = "3.3.00(22/Feb./2008)", semicolon_in_checksum: bool = False):
        if scan_provider is not None and not callable(scan_provider):
            raise ValueError(f"scan_provider must be callable, got {scan_provider!r}")
        for name, value in (("timestamp_offset_s", timestamp_offset_s), ("latency_s", latency_s),
                            ("clock_drift_ppm", clock_drift_ppm)):
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        if latency_s < 0:
            raise ValueError(f"latency_s must be >= 0, got {latency_s}")
        self.scan_provider = scan_provider or wall_provider()
        self.clock = clock if clock is not None else RealTimeClock()
        self.timestamp_offset_s = float(timestamp_offset_s)
        self.latency_s = float(latency_s)
        self.clock_drift_ppm = float(clock_drift_ppm)
        self.model, self.serial, self.firmware = model, serial, firmware
        self.semicolon_in_checksum = semicolon_in_checksum
        self.scip2 = not start_in_scip11
        self.laser_on = False
        self.time_adjust = False
        self.commands: list[str] = []  # every command line received, for tests
        self._laser_on_since_s = math.inf
        self._stream: dict | None = None
        self._queue: list[tuple[float, bytes]] = []  # (ready time, reply bytes), in order
        self._out = bytearray()
        self._in = bytearray()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._unplugged = threading.Event()
        self._thread: threading.Thread | None = None
        self._master = self._slave = None
        self.port_path: str | None = None
        # Faults.
        self._corrupt_every: int | None = None
        self._line_count = 0
        self._stall_after: int | None = None
        self._stalled = False

    # --- lifecycle ------------------------------------------------------------------

    def start(self) -> "UrgEmulator":
        if self._thread is not None:
            raise RuntimeError("emulator already started")
        self._master, self._slave = os.openpty()
        tty.setraw(self._master)
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port_path = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._run, name=f"urg-emulator {self.port_path}", daemon=True)
        self._thread.start()
        _log.info("URG emulator on %s", self.port_path)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        close_fds(self._master, self._slave)
        self._master = self._slave = None

    def __enter__(self) -> "UrgEmulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- fault injection ------------------------------------------------------------

    def inject_checksum_errors(self, every_n_lines: int | None) -> None:
        """From now on, every ``every_n_lines``-th line with a checksum (status or data)
        carries a wrong one (1: every line). None turns it off."""
        if every_n_lines is not None and not (isinstance(every_n_lines, int) and every_n_lines >= 1):
            raise ValueError(f"every_n_lines must be an integer >= 1 or None, got {every_n_lines!r}")
        with self._lock:
            self._corrupt_every = every_n_lines
            self._line_count = 0

    def inject_stall(self, after_scans: int = 0) -> None:
        """The stream stops mid-scan after ``after_scans`` more streamed scans: part of
        the next scan is sent, then nothing at all (replies included) until :meth:`clear_faults`."""
        if not (isinstance(after_scans, int) and after_scans >= 0):
            raise ValueError(f"after_scans must be an integer >= 0, got {after_scans!r}")
        with self._lock:
            self._stall_after = after_scans

    def clear_faults(self) -> None:
        with self._lock:
            self._corrupt_every = None
            self._stall_after = None
            self._stalled = False

    def unplug(self) -> None:
        """Closes the pty's master end, as if the USB cable were pulled: the client's
        next read or write fails. The slave end stays open until :meth:`stop`, so the
        kernel does not hand the pty's number to another program meanwhile."""
        self._unplugged.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        with self._lock:
            if self._master is not None:
                os.close(self._master)
                self._master = None

    @classmethod
    def step_angles_rad(cls) -> np.ndarray:
        """Beam angle of every step 0..768 in the lidar frame: (k - AFRT) * 2 pi / ARES. (769,) float64."""
        return (np.arange(cls.N_STEPS) - cls.AFRT) * (2 * math.pi / cls.ARES)

    @classmethod
    def step_time_offsets_s(cls) -> np.ndarray:
        """When each step is measured after the scan's step 0: k / ARES * 100 ms. (769,) float64, s."""
        return np.arange(cls.N_STEPS) / cls.ARES * cls.SCAN_PERIOD_S

    @property
    def streaming(self) -> bool:
        with self._lock:
            return self._stream is not None

    @property
    def replies_waiting(self) -> int:
        """Replies and scans made but not yet handed to the pty (their ready time not reached)."""
        with self._lock:
            return len(self._queue)

    def sensor_ms(self, t_s: float) -> int:
        """The sensor timer's reading at clock time ``t_s``: ms mod 2^24."""
        # Rounded to ns first: (t + offset) * 1000 of a whole ms must not floor to the ms before.
        sensor_s = t_s * (1.0 + 1e-6 * self.clock_drift_ppm) + self.timestamp_offset_s
        return math.floor(round(sensor_s * 1000.0, 6)) % p.TIMESTAMP_MODULUS_MS

    # --- the loop -------------------------------------------------------------------

    def _client_pending(self) -> int:
        """Bytes sent but not yet read by the client (the slave's input queue)."""
        try:
            return struct.unpack("i", fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0"))[0]
        except OSError:
            return 0

    def _run(self) -> None:
        try:
            while not self._stop.is_set() and not self._unplugged.is_set():
                with self._lock:
                    now = self.clock.now()
                    self._schedule_stream(now)
                    while self._queue and self._queue[0][0] <= now:
                        self._out += self._queue.pop(0)[1]
                    if self._stalled:
                        self._out.clear()
                wrote = self._write()
                readable, _, _ = select.select([self._master], [], [], 0 if wrote else 0.0005)
                if readable:
                    try:
                        data = os.read(self._master, 4096)
                    except OSError as exc:
                        if exc.errno not in (errno.EIO, errno.EAGAIN):
                            raise
                        data = b""
                    if data:
                        self._in += data
                        self._handle_input()
                        continue
                if getattr(self.clock, "is_virtual", False):
                    self._advance_virtual_clock()
        except Exception:  # the thread must not die silently
            _log.exception("URG emulator on %s crashed", self.port_path)

    def _write(self) -> bool:
        if not self._out or self._master is None:
            return False
        try:
            n = os.write(self._master, bytes(self._out[:4096]))
        except BlockingIOError:
            return False
        except OSError:
            self._out.clear()
            return False
        del self._out[:n]
        return n > 0

    def _advance_virtual_clock(self) -> None:
        with self._lock:
            if self._out or self._in.count(b"\n") or self._client_pending():
                return
            events = [t for t, _ in self._queue[:1]]
            if self._stream is not None and not self._stalled:
                events.append(self._stream_ready_s(self._stream["next_n"]))
        if events:
            self.clock.advance_to(min(events))

    # --- commands -------------------------------------------------------------------

    def _handle_input(self) -> None:
        while True:
            ends = [i for i in (self._in.find(b"\n"), self._in.find(b"\r")) if i >= 0]
            if not ends:
                return
            end = min(ends)
            line = bytes(self._in[:end]).decode("latin-1")
            del self._in[:end + 1]
            if not line:
                continue  # the LF of a CR LF, or an empty line
            with self._lock:
                self.commands.append(line)
                now = self.clock.now()
                if self._stalled:
                    continue
                reply = self._command(line, now + self.latency_s)
                if reply is not None:
                    ready_s, data = reply
                    self._queue.append((max(ready_s, now + 2 * self.latency_s), data))

    def _line(self, data: str) -> str:
        """``data`` + its checksum, corrupted when a fault says so."""
        line = data + p.checksum(data)
        self._line_count += 1
        if self._corrupt_every and self._line_count % self._corrupt_every == 0:
            wrong = chr((ord(line[-1]) - 0x30 + 1) % 64 + 0x30)
            line = line[:-1] + wrong
        return line

    def _reply(self, echo: str, status: str, lines: list[str] = ()) -> bytes:
        text = echo + "\n" + self._line(status) + "\n" + "".join(line + "\n" for line in lines) + "\n"
        return text.encode("latin-1")

    def _data(self, data: str) -> list[str]:
        return [self._line(data[i:i + p.MAX_LINE_CHARS]) for i in range(0, len(data), p.MAX_LINE_CHARS)]

    def _kv(self, pairs: dict[str, str]) -> list[str]:
        lines = p.key_value_lines(pairs, semicolon_in_checksum=self.semicolon_in_checksum)
        return [self._corrupt_kv(line) for line in lines]

    def _corrupt_kv(self, line: str) -> str:
        self._line_count += 1
        if self._corrupt_every and self._line_count % self._corrupt_every == 0:
            return line[:-1] + chr((ord(line[-1]) - 0x30 + 1) % 64 + 0x30)
        return line

    def _command(self, line: str, t_s: float):
        """(ready time, reply bytes) for a command line taken in at clock time ``t_s``, or None."""
        if not self.scip2:
            if line == "SCIP2.0":
                self.scip2 = True
                return t_s, b"SCIP2.0\n0\n\n"
            return t_s, (line + "\nE\n\n").encode("latin-1")
        body, _, tag = line.partition(";")
        if len(tag) > p.MAX_TAG_CHARS:
            return t_s, self._reply(line, "0G")
        try:
            p.check_tag(tag)
        except ValueError:
            return t_s, self._reply(line, "0H")
        symbol, params = body[:2], body[2:]
        if self.time_adjust and symbol != "TM":
            return t_s, self._reply(line, "0E")
        handler = {"VV": self._vv, "PP": self._pp, "II": self._ii, "BM": self._bm, "QT": self._qt,
                   "RS": self._rs, "TM": self._tm, "GD": self._gd, "GS": self._gd,
                   "MD": self._md, "MS": self._md}.get(symbol)
        if handler is None:
            return t_s, self._reply(line, "0E")
        return handler(line, symbol, params, tag, t_s)

    def _no_params(self, line, params, t_s):
        return (t_s, self._reply(line, "0C")) if params else None

    def _vv(self, line, symbol, params, tag, t_s):
        return self._no_params(line, params, t_s) or (t_s, self._reply(line, "00", self._kv({
            "VEND": "Hokuyo Automatic Co.,Ltd.", "PROD": f"SOKUIKI Sensor {self.model}",
            "FIRM": self.firmware, "PROT": "SCIP 2.0", "SERI": self.serial})))

    def _pp(self, line, symbol, params, tag, t_s):
        return self._no_params(line, params, t_s) or (t_s, self._reply(line, "00", self._kv({
            "MODL": f"{self.model}(Hokuyo Automatic Co.,Ltd.)", "DMIN": str(self.DMIN_MM),
            "DMAX": str(self.DMAX_MM), "ARES": str(self.ARES), "AMIN": str(self.AMIN),
            "AMAX": str(self.AMAX), "AFRT": str(self.AFRT), "SCAN": str(self.SCAN_RPM)})))

    def _ii(self, line, symbol, params, tag, t_s):
        # TIME: the 24-bit timer as 6 hex digits (the urgnetwork wiki's example "081615").
        return self._no_params(line, params, t_s) or (t_s, self._reply(line, "00", self._kv({
            "MODL": f"{self.model}(Hokuyo Automatic Co.,Ltd.)", "LASR": "ON" if self.laser_on else "OFF",
            "SCSP": f"Initial({self.SCAN_RPM}[rpm])", "MESM": "Measuring" if self._stream else "IDLE",
            "SBPS": "USB only", "TIME": f"{self.sensor_ms(t_s):06X}", "STAT": "Sensor works well."})))

    def _set_laser(self, on: bool, t_s: float) -> None:
        if on and not self.laser_on:
            self._laser_on_since_s = t_s
        if not on:
            self._laser_on_since_s = math.inf
        self.laser_on = on

    def _bm(self, line, symbol, params, tag, t_s):
        if params:
            return t_s, self._reply(line, "0C")
        status = "02" if self.laser_on else "00"
        self._set_laser(True, t_s)
        return t_s, self._reply(line, status)

    def _qt(self, line, symbol, params, tag, t_s):
        if params:
            return t_s, self._reply(line, "0C")
        self._stream = None
        self._queue = [(t, d) for t, d in self._queue if b"\n99b\n" not in d[:40]]  # streamed scans not yet sent
        self._set_laser(False, t_s)
        return t_s, self._reply(line, "00")

    def _rs(self, line, symbol, params, tag, t_s):
        if params:
            return t_s, self._reply(line, "0C")
        self._qt(line, "QT", "", tag, t_s)
        self.timestamp_offset_s = -t_s * (1.0 + 1e-6 * self.clock_drift_ppm)  # RS resets the timer ([SCIP] 8.5)
        return t_s, self._reply(line, "00")

    def _tm(self, line, symbol, params, tag, t_s):
        if params not in ("0", "1", "2"):
            return t_s, self._reply(line, "01")
        if params == "0":
            if self.time_adjust:
                return t_s, self._reply(line, "02")
            self._qt(line, "QT", "", tag, t_s)  # the laser is off in time-adjust mode ([SCIP] 8.6)
            self.time_adjust = True
            return t_s, self._reply(line, "00")
        if params == "2":
            if not self.time_adjust:
                return t_s, self._reply(line, "03")
            self.time_adjust = False
            return t_s, self._reply(line, "00")
        if not self.time_adjust:
            return t_s, self._reply(line, "04")
        return t_s, self._reply(line, "00", [self._line(p.encode(self.sensor_ms(t_s), 4))])

    def _range_request(self, params: str, n: int):
        """(start, end, cluster) or an error status."""
        fields = [params[0:4], params[4:8], params[8:10]]
        if len(params) < n:
            return "0C"
        if len(params) > n:
            return "0F"
        for code, field in zip(("01", "02", "03"), fields):
            if not field.isdigit():
                return code
        start, end, cluster = (int(f) for f in fields)
        if end > self.LAST_STEP:
            return "04"
        if end < start:
            return "05"
        return start, end, max(cluster, 1)

    def _gd(self, line, symbol, params, tag, t_s):
        request = self._range_request(params, 10)
        if isinstance(request, str):
            return t_s, self._reply(line, request)
        if not self.laser_on:
            return t_s, self._reply(line, "10")
        start, end, cluster = request
        sweep_s = (end + 1) / self.ARES * self.SCAN_PERIOD_S
        n = math.floor((t_s - sweep_s) / self.SCAN_PERIOD_S)
        n = max(n, math.ceil(self._laser_on_since_s / self.SCAN_PERIOD_S - 1e-9))
        ready_s = n * self.SCAN_PERIOD_S + sweep_s
        return max(ready_s, t_s), self._scan_reply(line, "00", symbol, n, start, end, cluster)

    def _md(self, line, symbol, params, tag, t_s):
        request = self._range_request(params[:10], 10) if len(params) >= 10 else "0C"
        if isinstance(request, str):
            return t_s, self._reply(line, request)
        if len(params) != 13:
            return t_s, self._reply(line, "0C" if len(params) < 13 else "0F")
        if not params[10].isdigit():
            return t_s, self._reply(line, "06")
        if not params[11:13].isdigit():
            return t_s, self._reply(line, "07")
        start, end, cluster = request
        n_scans = int(params[11:13])
        self._stream = {"symbol": symbol, "start": start, "end": end, "cluster": cluster,
                        "skip": int(params[10]), "remaining": n_scans if n_scans else None, "tag": tag,
                        "next_n": math.ceil(t_s / self.SCAN_PERIOD_S - 1e-9), "laser_was_on": self.laser_on}
        self._set_laser(True, t_s)  # MD switches the laser on by itself ([SCIP] 8.1)
        return t_s, self._reply(line, "00")

    def _stream_ready_s(self, n: int) -> float:
        s = self._stream
        return n * self.SCAN_PERIOD_S + (s["end"] + 1) / self.ARES * self.SCAN_PERIOD_S

    def _schedule_stream(self, now: float) -> None:
        # One scan per pass of the loop at most: a provider slower than the stream (a heavy
        # plant cast at --speed-factor 20, or on a starved core) then sends its scans late
        # but one by one, and commands (QT) are still read and answered between them. Casting
        # every scan due at once made the backlog grow with each batch (a batch's cast time
        # makes more scans due), and nothing was sent: the host saw the stream stall.
        s = self._stream
        if s is not None and not self._stalled and self._stream_ready_s(s["next_n"]) <= now:
            n = s["next_n"]
            if s["remaining"] is not None:
                s["remaining"] -= 1
            remaining = s["remaining"] or 0
            echo = (f"{s['symbol']}{s['start']:04d}{s['end']:04d}{s['cluster']:02d}{s['skip']}{remaining:02d}"
                    + (f";{s['tag']}" if s["tag"] else ""))
            data = self._scan_reply(echo, "99", s["symbol"], n, s["start"], s["end"], s["cluster"])
            if self._stall_after is not None:
                if self._stall_after == 0:
                    data = data[: len(data) // 2]  # part of the scan, then silence
                    self._stalled = True
                else:
                    self._stall_after -= 1
            self._queue.append((self._stream_ready_s(n), data))
            s["next_n"] = n + s["skip"] + 1
            if s["remaining"] == 0:
                self._stream = None
                if not s["laser_was_on"]:
                    self._set_laser(False, now)

    def _scan_reply(self, echo: str, status: str, symbol: str, n: int, start: int, end: int,
                    cluster: int) -> bytes:
        t_scan_s = n * self.SCAN_PERIOD_S
        ranges_m, beam_status = self.scan_provider(t_scan_s)
        ranges_m = np.asarray(ranges_m, dtype=np.float64)
        beam_status = np.asarray(beam_status)
        if ranges_m.shape != (self.N_STEPS,) or beam_status.shape != (self.N_STEPS,):
            raise ValueError(f"scan_provider must return two ({self.N_STEPS},) arrays indexed by step, got "
                             f"{ranges_m.shape} and {beam_status.shape}")
        n_chars = p.range_chars(symbol[0] + ("D" if symbol[1] == "D" else "S"))
        raw = p.raw_from_ranges(ranges_m, beam_status, n_chars=n_chars)[start:end + 1]
        if cluster > 1:
            raw = np.array([_cluster_value(raw[i:i + cluster]) for i in range(0, len(raw), cluster)])
        data = p.encode_array(raw, n_chars)
        lines = [self._line(p.encode(self.sensor_ms(t_scan_s), 4))] + self._data(data)
        return self._reply(echo, status, lines)


def _cluster_value(raw: np.ndarray) -> int:
    """The nearest valid range of a cluster, else its first error code ([SCIP] 8.1)."""
    valid = raw[raw >= p.ERROR_CODE_LIMIT_MM]
    return int(valid.min()) if valid.size else int(raw[0])
