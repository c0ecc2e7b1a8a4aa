"""The Hokuyo URG-04LX over SCIP 2.0 with ``pyserial``: :class:`UrgLidar`.

``pyserial`` is imported when a port is opened, so ``import plantsim`` (and this
module) work without the ``rig`` extra.

What the driver does, and why:

* **Connect**: ``QT`` first (stops a stream left running, switches the laser off);
  an ``E`` status means SCIP 1.1, so ``SCIP2.0`` is sent; ``0E`` means time-adjust
  mode, left with ``TM2`` (as ``urg_library`` does). Then VV, PP and II, and the
  model and its geometry are checked against a :class:`~plantsim.sensor.spec.LidarSpec`.
* **Every command carries a ``;tag``** that the sensor echoes: a late reply to an
  earlier command, or a scan of an old stream, is recognised and dropped.
* **Retries**: a reply that fails its checksum or framing, or does not come within
  ``timeout_s``, is asked for again (``retries`` times) for the commands that can be
  repeated safely (VV, PP, II, GD, TM, BM, QT); then a
  :class:`~plantsim.errors.LidarChecksumError` or
  :class:`~plantsim.errors.LidarTimeoutError` names the port. A streamed scan cannot
  be asked for again: a bad one is dropped (counted in :attr:`UrgLidar.dropped_scans`)
  and more than ``retries`` bad scans in a row end the stream with an error.
* **Time**: the sensor stamps each scan with its 24-bit millisecond timer at step 0
  ([SCIP] 8.1); step ``k`` is measured ``k / ARES`` of a mirror turn later. The
  host/sensor offset comes from TM1 round trips (:meth:`UrgLidar.sync_clock`); the
  round trip with the least delay bounds the offset best (its half round trip is the
  uncertainty). Each scan's beams get host times from it.
* **Safety**: :meth:`UrgLidar.close` (and leaving a ``with`` block) always sends QT;
  :meth:`UrgLidar.laser_off` is best effort on a half-dead link and says whether it
  could confirm.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import time
from typing import Callable, Iterator

import numpy as np

from plantsim.errors import (LidarChecksumError, LidarDisconnectedError, LidarError, LidarModelError,
                             LidarStatusError, LidarTimeoutError)
from plantsim.hardware.urg import protocol as p
from plantsim.hardware.urg.clock import ClockOffset, estimate_offset
from plantsim.sensor.spec import URG_04LX_UG01, BeamStatus, LidarSpec

_log = logging.getLogger(__name__)

_LASER_ADVICE = "unplug the LiDAR's USB cable to stop it (its class 1 laser is eye-safe)"
_PORT_ADVICE = ("check the cable, that the port is the LiDAR's (ls -l /dev/serial/by-id) and that you "
                "may open it (group dialout)")


@dataclasses.dataclass(frozen=True)
class UrgInfo:
    """What the sensor says about itself (VV, PP, II).

    Attributes:
        model: PP's MODL up to the vendor's name in brackets ("URG-04LX").
        vendor, product, firmware, protocol, serial: VV's VEND, PROD, FIRM, PROT, SERI.
        dmin_mm, dmax_mm: range limits, mm.
        ares: steps per mirror turn; amin, amax: first and last step of the
            measurement range; afrt: the front step (beam angle 0).
        scan_rpm: mirror speed, rpm.
        vv, pp, ii: every key:value line as sent.
    """

    model: str
    vendor: str
    product: str
    firmware: str
    protocol: str
    serial: str
    dmin_mm: int
    dmax_mm: int
    ares: int
    amin: int
    amax: int
    afrt: int
    scan_rpm: int
    vv: dict
    pp: dict
    ii: dict

    @property
    def scan_period_s(self) -> float:
        return 60.0 / self.scan_rpm

    def step_angle_rad(self, step) -> np.ndarray:
        """Beam angle of a step in the lidar frame: (step - AFRT) * 2 pi / ARES, radians."""
        return (np.asarray(step, dtype=np.float64) - self.afrt) * (2 * math.pi / self.ares)


def info_from_replies(vv: dict, pp: dict, ii: dict) -> UrgInfo:
    """An :class:`UrgInfo` from VV/PP/II key:value dicts.

    Raises:
        LidarError: a PP field is missing or not an integer.
    """
    try:
        numbers = {key: int(pp[key].strip()) for key in ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN")}
    except (KeyError, ValueError) as exc:
        raise LidarError(f"the LiDAR's PP reply lacks a numeric field ({exc}): {pp}") from exc
    return UrgInfo(model=pp.get("MODL", "").split("(", 1)[0].strip(), vendor=vv.get("VEND", ""),
                   product=vv.get("PROD", ""), firmware=vv.get("FIRM", ""), protocol=vv.get("PROT", ""),
                   serial=vv.get("SERI", ""), dmin_mm=numbers["DMIN"], dmax_mm=numbers["DMAX"],
                   ares=numbers["ARES"], amin=numbers["AMIN"], amax=numbers["AMAX"], afrt=numbers["AFRT"],
                   scan_rpm=numbers["SCAN"], vv=dict(vv), pp=dict(pp), ii=dict(ii))


def spec_steps(spec: LidarSpec) -> tuple[int, int, int]:
    """(first step, last step, front step) of a preset with an angular encoder.

    Raises:
        ValueError: the preset has no ``steps_per_rev``.
    """
    if spec.steps_per_rev is None:
        raise ValueError(f"LiDAR preset {spec.name!r} has no angular encoder (steps_per_rev); "
                         "a Hokuyo preset has one")
    front = spec.first_step - spec.angle_min_deg * spec.steps_per_rev / 360.0
    return spec.first_step, spec.first_step + spec.n_beams - 1, round(front)


def check_model(info: UrgInfo, spec: LidarSpec, *, port: str = "the port") -> None:
    """Raises :class:`~plantsim.errors.LidarModelError` unless the sensor is the preset's.

    The model's name must match (one a prefix of the other, ignoring case, so
    "URG-04LX" fits "urg-04lx-ug01"), and the geometry exactly: steps per turn,
    front step, first step, range limits (to 1 mm) and scan period.
    """
    first, last, front = spec_steps(spec)
    model, name = info.model.lower(), spec.name.lower()
    problems = []
    if not model or not (name.startswith(model) or model.startswith(name)):
        problems.append(f"model {info.model!r}")
    expected = {"ARES": (info.ares, spec.steps_per_rev), "AFRT": (info.afrt, front),
                "DMIN": (info.dmin_mm, round(spec.range_min_m * 1000)),
                "DMAX": (info.dmax_mm, round(spec.range_max_m * 1000)),
                "SCAN": (info.scan_rpm, round(60.0 / spec.scan_period_s))}
    problems += [f"{key}={got} (expected {want})" for key, (got, want) in expected.items() if got != want]
    if first < info.amin:
        problems.append(f"AMIN={info.amin} (the preset's first beam is step {first})")
    if problems:
        error = LidarModelError(
            f"the LiDAR on {port} is a {info.model or 'unknown model'} (PP: ARES={info.ares}, AMIN={info.amin}, "
            f"AMAX={info.amax}, AFRT={info.afrt}, DMIN={info.dmin_mm}, DMAX={info.dmax_mm}, SCAN={info.scan_rpm}), "
            f"but the preset {spec.name!r} expects otherwise: {', '.join(problems)}; choose the preset of this "
            "sensor ([lidar] preset / --lidar-preset) or connect the right one")
        error.info = info  # what the sensor said, for a command to name the preset that fits
        raise error
    if last > info.amax:
        _log.info("preset %s reads up to step %d, beyond AMAX=%d: those beams lie outside the sensor's "
                  "specified field of view", spec.name, last, info.amax)


@dataclasses.dataclass(frozen=True)
class UrgScan:
    """One scan line as the sensor sent it, with angles and times.

    Attributes:
        ranges_m: (n,) float64, metres; NaN where there is no return.
        status: (n,) int8 :class:`~plantsim.sensor.spec.BeamStatus` per beam.
        raw_mm: (n,) int64, the values sent: mm, or an error code below 20.
        angles_rad: (n,) float64, beam angles in the lidar frame (the preset's
            convention: (step - AFRT) * 2 pi / ARES; 0 = front, counter-clockwise).
        steps: (n,) float64, each value's mirror step (a cluster's middle step).
        timestamp_ms: the sensor's 24-bit timestamp of step 0, as sent.
        sensor_time_s: that timestamp unwrapped, s.
        host_receive_s: host clock when the scan had arrived, s.
        scan_period_s: one mirror turn, s.
        steps_per_rev: ARES.
        beam_host_times_s: (n,) float64, host time each beam was measured, s
            (None without a clock offset: call :meth:`UrgLidar.sync_clock`).
        first_step, last_step, cluster: the request.
    """

    ranges_m: np.ndarray
    status: np.ndarray
    raw_mm: np.ndarray
    angles_rad: np.ndarray
    steps: np.ndarray
    timestamp_ms: int
    sensor_time_s: float
    host_receive_s: float
    scan_period_s: float
    steps_per_rev: int
    beam_host_times_s: np.ndarray | None
    first_step: int
    last_step: int
    cluster: int = 1

    @property
    def n_valid(self) -> int:
        """Beams with a range."""
        return int(np.count_nonzero(self.status == BeamStatus.OK))

    def beam_sensor_times_s(self) -> np.ndarray:
        """Sensor time of each beam, s: the step-0 stamp plus step / ARES of a turn. (n,) float64."""
        return self.sensor_time_s + 0.0005 + self.steps / self.steps_per_rev * self.scan_period_s


class UrgLidar:
    """A Hokuyo URG (SCIP 2.0) on a serial port.

    Args:
        preset: the :class:`~plantsim.sensor.spec.LidarSpec` the sensor must match
            (model and geometry; None: no check). Its beams are what :meth:`scan`
            and :meth:`stream` request by default.
        timeout_s: wait for a reply (wall time), s.
        retries: repeats of a command whose reply was lost or garbled; also the bad
            streamed scans tolerated in a row.
        host_clock: the host's clock, s (``time.monotonic``; tests share a virtual clock).
        sleep: the host's pause (tests advance their virtual clock).
        clock_sync_round_trips: TM1 round trips per :meth:`sync_clock`.
        drift_baseline_s: two clock syncs at least this far apart (host s) also
            estimate the sensor clock's drift (:attr:`ClockOffset.drift`).
    """

    def __init__(self, *, preset: LidarSpec | None = URG_04LX_UG01, timeout_s: float = 1.0, retries: int = 2,
                 host_clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep,
                 clock_sync_round_trips: int = 10, drift_baseline_s: float = 10.0):
        if not (isinstance(timeout_s, (int, float)) and 0 < timeout_s <= 60):
            raise ValueError(f"timeout_s must be in (0, 60] s, got {timeout_s!r}")
        if not (isinstance(retries, int) and 0 <= retries <= 10):
            raise ValueError(f"retries must be an integer in [0, 10], got {retries!r}")
        if not (isinstance(clock_sync_round_trips, int) and clock_sync_round_trips >= 1):
            raise ValueError(f"clock_sync_round_trips must be an integer >= 1, got {clock_sync_round_trips!r}")
        if preset is not None:
            spec_steps(preset)
        self.preset = preset
        self.timeout_s = float(timeout_s)
        self.retries = retries
        self.host_clock = host_clock
        self.sleep = sleep
        self.clock_sync_round_trips = clock_sync_round_trips
        self.drift_baseline_s = float(drift_baseline_s)
        self.port: str | None = None
        self.baud_bps = 115_200
        self.info: UrgInfo | None = None
        self.clock_offset: ClockOffset | None = None
        self.dropped_scans = 0
        self.laser_is_on = False
        self._serial = None
        self._parser = p.ReplyParser()
        self._tags = itertools.count(1)
        self._last_sensor_ms: int | None = None
        self._pending_blocks: list[bytes] = []
        self._closed_confirmed = False

    # --- connection -------------------------------------------------------------------

    @classmethod
    def connect(cls, port: str, *, baud_bps: int = 115_200, sync_clock: bool = True, safety=None,
                **options) -> "UrgLidar":
        """Opens ``port``, brings the sensor to SCIP 2.0 with its laser off, reads VV/PP/II,
        checks the model against ``preset`` and (``sync_clock``) estimates the clock offset.

        Args:
            port: ``/dev/ttyACM0``, ``/dev/serial/by-id/usb-Hokuyo...``, an emulator's pty.
            baud_bps: RS-232 units only; ignored over USB.
            safety: a :class:`~plantsim.hardware.safety.SafeStop` to register the laser's
                stop action with, as soon as the port is open.
            **options: :class:`UrgLidar`'s arguments.

        Raises:
            LidarError: the port cannot be opened, the sensor does not answer, or it is
                not the preset's model.
        """
        lidar = cls(**options)
        lidar.open(port, baud_bps=baud_bps)
        if safety is not None:
            safety.register(lidar.stop_action())
        try:
            lidar.handshake()
            if sync_clock:
                lidar.sync_clock()
            return lidar
        except BaseException:
            lidar.close()
            raise

    def open(self, port: str, *, baud_bps: int = 115_200) -> None:
        """Opens the serial port (no command sent)."""
        try:
            import serial
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise LidarError("the LiDAR driver needs pyserial: pip install 'plantsim[rig]'") from exc
        self.port, self.baud_bps = port, baud_bps
        try:
            self._serial = serial.Serial(port, baudrate=baud_bps, timeout=0.02, write_timeout=self.timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LidarDisconnectedError(f"cannot open the LiDAR's port {port}: {exc}; {_PORT_ADVICE}") from exc
        self._parser.clear()
        self._pending_blocks = []
        self._closed_confirmed = False

    def handshake(self) -> UrgInfo:
        """QT (SCIP 1.1 / time-adjust recovery), VV, PP, II and the model check."""
        reply = self._command("QT", accept=None)
        if reply.status == "E":
            _log.info("LiDAR on %s speaks SCIP 1.1: switching to SCIP 2.0", self.port)
            self._write(b"SCIP2.0\n")
            switched = self._read_reply(lambda echo: echo == "SCIP2.0", self.timeout_s)
            if switched.status not in ("0", "00"):
                raise LidarStatusError(f"the LiDAR on {self.port} refused to switch to SCIP 2.0 (status "
                                       f"{switched.status!r}); update its firmware", command="SCIP2.0",
                                       status=switched.status)
            self._command("QT")
        elif reply.status == "0E":
            _log.info("LiDAR on %s was in time-adjust mode: leaving it", self.port)
            self._command("TM", "2", accept=("00", "03"))
            self._command("QT")
        elif reply.status != "00":
            raise self._status_error(reply)
        self.laser_is_on = False
        vv = p.parse_key_values(self._command("VV"))
        pp = p.parse_key_values(self._command("PP"))
        ii = p.parse_key_values(self._command("II"))
        self.info = info_from_replies(vv, pp, ii)
        if self.preset is not None:
            check_model(self.info, self.preset, port=self.port)
        _log.info("LiDAR on %s: %s, firmware %s, serial %s", self.port, self.info.model, self.info.firmware,
                  self.info.serial)
        return self.info

    def close(self) -> bool:
        """Laser off (QT, best effort) and the port released. Returns True when QT was confirmed."""
        confirmed = True
        if self._serial is not None:
            confirmed = self.laser_off()
            try:
                self._serial.close()
            except Exception:  # noqa: BLE001 - closing a dead port must not hide the real error
                _log.debug("closing %s failed", self.port, exc_info=True)
            self._serial = None
            self._closed_confirmed = confirmed
        return confirmed

    def __enter__(self) -> "UrgLidar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- laser ------------------------------------------------------------------------

    def laser_on(self) -> None:
        """BM: the laser on, the sensor measuring (needed before :meth:`scan`)."""
        self._command("BM", accept=("00", "02"))
        self.laser_is_on = True

    def laser_off(self) -> bool:
        """QT: the laser off and any stream stopped, best effort on a half-dead link.

        Returns:
            True when the sensor confirmed (status 00, or time-adjust mode, in which
            the laser is off); False, logged as a warning, when it could not be.
        """
        if self._serial is None and self._closed_confirmed:
            return True  # closed after a confirmed QT
        if self._serial is None and self.port is not None:
            try:
                self.open(self.port, baud_bps=self.baud_bps)
            except LidarError as exc:
                _log.warning("LiDAR laser off NOT confirmed: %s", exc)
                return False
        if self._serial is None:
            return True  # never opened
        try:
            reply = self._command("QT", accept=("00", "0E"))
            if reply.status == "0E":
                self._command("TM", "2", accept=("00", "03"))
            self.laser_is_on = False
            return True
        except LidarError as exc:
            _log.warning("LiDAR laser off NOT confirmed on %s: %s; %s", self.port, exc, _LASER_ADVICE)
            return False

    def stop_action(self):
        """The LiDAR's :class:`~plantsim.hardware.safety.StopAction` (laser off, confirmed)."""
        from plantsim.hardware.safety import StopAction

        def stop() -> None:
            if not self.laser_off():
                raise LidarError(f"no confirmation of QT from the LiDAR on {self.port}")

        return StopAction("LiDAR laser", stop, None, advice=_LASER_ADVICE)

    # --- clock ------------------------------------------------------------------------

    def sync_clock(self, n_round_trips: int | None = None) -> ClockOffset:
        """Estimates the host/sensor offset with TM0, ``n_round_trips`` x TM1, TM2.

        The laser goes off in time-adjust mode ([SCIP] 8.6); it is switched back on
        afterwards if it was on. Not while streaming.
        """
        n = self.clock_sync_round_trips if n_round_trips is None else n_round_trips
        if not (isinstance(n, int) and n >= 1):
            raise ValueError(f"n_round_trips must be an integer >= 1, got {n!r}")
        was_on = self.laser_is_on
        self._command("TM", "0", accept=("00", "02"))
        samples = []
        try:
            for _ in range(n):
                sent = self.host_clock()
                reply = self._command("TM", "1")
                received = self.host_clock()
                samples.append((sent, self._unwrap(p.parse_timestamp(reply)), received))
        finally:
            self._command("TM", "2", accept=("00", "03"))
        self.laser_is_on = False
        offset = estimate_offset(samples)
        previous = self.clock_offset
        if previous is not None and offset.host_time_s - previous.host_time_s >= self.drift_baseline_s:
            drift = (offset.offset_s - previous.offset_s) / (offset.host_time_s - previous.host_time_s)
            if abs(drift) < 1e-3:  # a crystal is off by ppm, not per mille: anything more is a glitch
                offset = dataclasses.replace(offset, drift=drift)
            else:
                _log.warning("LiDAR clock drift of %.0f ppm is implausible (a reset?); ignored", drift * 1e6)
        self.clock_offset = offset
        _log.info("LiDAR clock offset %.4f s +- %.4f s (best round trip %.4f s of %d), drift %.1f ppm",
                  offset.offset_s, offset.uncertainty_s, offset.round_trip_s, n, offset.drift * 1e6)
        if was_on:
            self.laser_on()
        return self.clock_offset

    def _unwrap(self, raw_ms: int) -> int:
        reference = raw_ms if self._last_sensor_ms is None else self._last_sensor_ms
        self._last_sensor_ms = p.unwrap_timestamp_ms(raw_ms, reference)
        return self._last_sensor_ms

    # --- scans ------------------------------------------------------------------------

    def _steps(self, start_step, end_step) -> tuple[int, int]:
        if start_step is None or end_step is None:
            if self.preset is not None:
                first, last, _ = spec_steps(self.preset)
            elif self.info is not None:
                first, last = self.info.amin, self.info.amax
            else:
                raise ValueError("start_step and end_step are needed without a preset or a handshake")
            start_step = first if start_step is None else start_step
            end_step = last if end_step is None else end_step
        return start_step, end_step

    def scan(self, *, start_step: int | None = None, end_step: int | None = None, cluster: int = 1,
             after_host_s: float | None = None, encoding: str = "GD") -> UrgScan:
        """One scan (GD, or GS for 2-character ranges), switching the laser on if needed.

        Args:
            start_step, end_step: steps to read (default: the preset's beams).
            cluster: adjacent steps merged into one value (the nearest).
            after_host_s: a scan whose first beam was measured at or after this host
                time (e.g. after the turntable settled): older ones are asked for again.

        Raises:
            LidarStatusError: the sensor refused the request (the status named).
        """
        if encoding not in ("GD", "GS"):
            raise ValueError(f"encoding must be 'GD' or 'GS', got {encoding!r}")
        start_step, end_step = self._steps(start_step, end_step)
        params = p.range_params(start_step, end_step, cluster)
        if not self.laser_is_on:
            self.laser_on()
        for _ in range(1000):
            reply = self._command(encoding, params)
            scan = self._make_scan(reply, start_step, end_step, cluster)
            if after_host_s is None or scan.beam_host_times_s is None or scan.beam_host_times_s[0] >= after_host_s:
                return scan
            self.sleep(min(self.info.scan_period_s, max(0.0, after_host_s - scan.beam_host_times_s[0])))
        raise LidarTimeoutError(f"the LiDAR on {self.port} sent no scan after host time {after_host_s}")

    def stream(self, *, n_scans: int = 0, skip: int = 0, start_step: int | None = None,
               end_step: int | None = None, cluster: int = 1, encoding: str = "MD") -> Iterator[UrgScan]:
        """Streams scans (MD, or MS): a generator; leaving it (``break``, an error,
        ``close()``) sends QT.

        Args:
            n_scans: scans to take, 1-99; 0 streams until the generator is closed.
            skip: scans skipped between two sent (0: every 100 ms).

        Raises:
            LidarTimeoutError: the stream stopped (no scan within 2 periods + timeout_s).
            LidarChecksumError: more than ``retries`` garbled scans in a row.
        """
        if encoding not in ("MD", "MS"):
            raise ValueError(f"encoding must be 'MD' or 'MS', got {encoding!r}")
        start_step, end_step = self._steps(start_step, end_step)
        params = p.stream_params(start_step, end_step, cluster, skip, n_scans)
        was_on = self.laser_is_on
        ack = self._command(encoding, params, retry=False)
        self.laser_is_on = True
        prefix, tag = ack.echo[:13], ack.tag
        period = self.info.scan_period_s if self.info else 0.1
        wait_s = 2 * period * (skip + 1) + self.timeout_s
        finished = False
        try:
            taken = bad = 0
            while n_scans == 0 or taken < n_scans:
                try:
                    reply = self._read_reply(lambda echo: echo[:13] == prefix and echo.partition(";")[2] == (tag or ""),
                                             wait_s)
                except p.ScipError as exc:
                    taken += 1
                    bad += 1
                    self.dropped_scans += 1
                    _log.warning("LiDAR on %s: dropped a garbled scan (%s)", self.port, exc)
                    if bad > self.retries:
                        raise LidarChecksumError(
                            f"the LiDAR on {self.port} sent {bad} garbled scans in a row ({exc}); "
                            f"{_PORT_ADVICE}, and try a shorter or shielded USB cable") from exc
                    continue
                except LidarTimeoutError as exc:
                    raise LidarTimeoutError(f"the LiDAR on {self.port} stopped streaming: no scan for "
                                            f"{wait_s:.1f} s after {taken} scans; {_PORT_ADVICE}") from exc
                if reply.status != "99":
                    raise self._status_error(reply)
                taken += 1
                bad = 0
                yield self._make_scan(reply, start_step, end_step, cluster)
            finished = n_scans != 0
        finally:
            if not finished:
                self.laser_off()
            else:
                self.laser_is_on = was_on  # after the last scan the laser is as before MD ([SCIP] 8.1)

    def _make_scan(self, reply: p.Reply, start_step: int, end_step: int, cluster: int) -> UrgScan:
        received = self.host_clock()
        raw_ms = p.parse_timestamp(reply)
        raw = p.parse_ranges_mm(reply)
        cluster = max(cluster, 1)
        expected = math.ceil((end_step - start_step + 1) / cluster)
        if raw.size != expected:
            raise LidarChecksumError(f"the LiDAR on {self.port} sent {raw.size} values for steps "
                                     f"{start_step}..{end_step} (expected {expected})")
        info = self.info
        ares = info.ares if info else 1024
        afrt = info.afrt if info else 384
        period = info.scan_period_s if info else 0.1
        ranges_m, status = p.ranges_from_raw(raw, range_max_mm=info.dmax_mm if info else None)
        firsts = start_step + cluster * np.arange(raw.size)
        steps = 0.5 * (firsts + np.minimum(firsts + cluster - 1, end_step))
        sensor_ms = self._unwrap(raw_ms)
        scan = UrgScan(ranges_m=ranges_m, status=status, raw_mm=raw,
                       angles_rad=(steps - afrt) * (2 * math.pi / ares), steps=steps, timestamp_ms=raw_ms,
                       sensor_time_s=sensor_ms / 1000.0, host_receive_s=received, scan_period_s=period,
                       steps_per_rev=ares, beam_host_times_s=None, first_step=start_step, last_step=end_step,
                       cluster=cluster)
        if self.clock_offset is not None:
            scan = dataclasses.replace(scan, beam_host_times_s=self.clock_offset.host_from_sensor(
                scan.beam_sensor_times_s()))
        return scan

    # --- the link ---------------------------------------------------------------------

    def _status_error(self, reply: p.Reply) -> LidarStatusError:
        meaning = p.status_meaning(reply.command, reply.status)
        return LidarStatusError(f"the LiDAR on {self.port} answered {reply.echo!r} with status {reply.status} "
                                f"({meaning})", command=reply.command, status=reply.status)

    def _write(self, data: bytes) -> None:
        if self._serial is None:
            raise LidarDisconnectedError(f"the LiDAR's port {self.port} is not open; connect first")
        import serial

        try:
            self._serial.write(data)
            self._serial.flush()
        except (serial.SerialException, OSError) as exc:
            raise LidarDisconnectedError(f"writing to the LiDAR on {self.port} failed (unplugged?): {exc}; "
                                         f"{_PORT_ADVICE}") from exc

    def _read_reply(self, match: Callable[[str], bool], timeout_s: float) -> p.Reply:
        """The next reply block whose echo ``match``es; other blocks are dropped.

        Raises:
            LidarTimeoutError: none within ``timeout_s`` (wall time).
            ScipError: the matching block fails its checksums or framing.
            LidarDisconnectedError: the port failed.
        """
        import serial

        deadline = time.monotonic() + timeout_s
        while True:
            for block in self._pending_blocks:
                self._pending_blocks = self._pending_blocks[1:]
                echo = block.split(b"\n", 1)[0].decode("latin-1")
                if match(echo):
                    return p.parse_reply(block)
                _log.debug("LiDAR on %s: dropped a reply to %r", self.port, echo)
            if time.monotonic() > deadline:
                raise LidarTimeoutError(f"no reply from the LiDAR on {self.port} within {timeout_s:.2f} s")
            try:
                data = self._serial.read(max(1, self._serial.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                raise LidarDisconnectedError(f"the LiDAR on {self.port} vanished (unplugged?): {exc}; "
                                             f"{_PORT_ADVICE}") from exc
            if data:
                self._pending_blocks = self._pending_blocks + self._parser.feed(data)

    def _command(self, symbol: str, params: str = "", *, accept: tuple[str, ...] | None = ("00",),
                 retry: bool = True) -> p.Reply:
        """Sends a tagged command and returns its reply, retrying lost or garbled ones.

        Args:
            accept: statuses taken as success (None: any); others raise LidarStatusError.
        """
        attempts = 1 + (self.retries if retry else 0)
        last: Exception | None = None
        for attempt in range(attempts):
            tag = f"p{next(self._tags)}"
            line = p.format_command(symbol, params, tag)
            echo = line.decode("ascii").rstrip("\n")
            self._write(line)
            try:
                reply = self._read_reply(lambda e, echo=echo: e == echo, self.timeout_s)
            except (p.ScipError, LidarTimeoutError) as exc:
                last = exc
                _log.info("LiDAR on %s: %s failed (%s), attempt %d of %d", self.port, echo, exc, attempt + 1,
                          attempts)
                continue
            if accept is not None and reply.status not in accept:
                raise self._status_error(reply)
            return reply
        if isinstance(last, LidarTimeoutError):
            raise LidarTimeoutError(f"no reply from the LiDAR on {self.port} to {symbol}{params} within "
                                    f"{self.timeout_s:.2f} s ({attempts} attempts): is it powered, and is this "
                                    f"its port? {_PORT_ADVICE}") from last
        raise LidarChecksumError(f"the LiDAR on {self.port} kept sending garbled replies to {symbol}{params} "
                                 f"({attempts} attempts; last: {last}); {_PORT_ADVICE}") from last
