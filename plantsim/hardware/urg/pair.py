"""The emulated rig: a Dynamixel servo and a URG LiDAR on two ptys, sharing one turntable.

:class:`EmulatorPair` runs a :class:`~plantsim.hardware.dynamixel.emulator.DynamixelEmulator`
and a :class:`~plantsim.hardware.urg.emulator.UrgEmulator` in one process:

* **one clock**: the URG emulator's clock is the servo emulator's simulated time
  (:class:`ServoSimClock`), so the sensor's timestamps and the servo's Realtime Tick
  count the same seconds (the sensor's timer is offset by ``timestamp_offset_s``,
  as a real sensor's is, for the driver to estimate);
* **one turntable**: :class:`TurntableHistory` records the servo shaft's true angle
  in the servo emulator's own thread (``call_at`` every millisecond of simulated
  time), and the LiDAR's provider casts the simulated LiDAR (ideal, or realistic
  with a sensor model) at the angle interpolated to each beam's instant;
* **faults** on the LiDAR from Python: ``pair.lidar.inject_checksum_errors(n)``,
  ``pair.lidar.inject_stall(after_scans)``, ``pair.lidar.unplug()``; on the servo the
  servo emulator's own (``pair.servo.inject_no_reply``, ``disconnect``, ...).

``plantsim emulator --lidar`` starts one and prints ``servo: /dev/pts/N`` and
``lidar: /dev/pts/M``.

The servo emulator runs in (scaled) real time, so the instants at which the host
reads the servo or asks for a scan depend on the machine's load; what does not is
where the table truly was when each beam was measured (the history) and the
devices' own time stamps (sensor timestamp, Realtime Tick), which the rig's drivers
use. A client that wants the emulators' time as its host clock uses
:meth:`EmulatorPair.host_clock` (``UrgLidar.connect(..., host_clock=pair.host_clock)``).
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np

from plantsim.hardware.urg.emulator import UrgEmulator, preset_provider
from plantsim.scan.raw import BeamGrid
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.sensor.spec import URG_04LX_UG01, LidarSpec

_log = logging.getLogger(__name__)


class ServoSimClock:
    """The servo emulator's simulated time as a clock for the URG emulator.

    It moves on by itself (with the servo's physics, in scaled real time);
    ``advance_to`` waits for it.
    """

    is_virtual = False

    def __init__(self, servo_emulator):
        self.servo_emulator = servo_emulator

    def now(self) -> float:
        return float(self.servo_emulator.sim_time)

    def advance_to(self, t_s: float) -> None:
        while self.now() < t_s:
            time.sleep(0.0005)

    def sleep(self, dt_s: float) -> None:
        self.advance_to(self.now() + max(0.0, dt_s))


class TurntableHistory:
    """The servo shaft's true angle over simulated time, sampled in the servo emulator's thread.

    Args:
        servo_emulator: a started :class:`~plantsim.hardware.dynamixel.emulator.DynamixelEmulator`.
        dxl_id: the turntable's servo.
        period_s: sampling period of simulated time, s (samples fall at the end of
            each physics chunk at or after it: at most the emulator's chunk apart).
        keep_s: history kept, s of simulated time.
    """

    def __init__(self, servo_emulator, dxl_id: int = 1, *, period_s: float = 1e-3, keep_s: float = 30.0):
        self.servo_emulator = servo_emulator
        self.dxl_id = dxl_id
        self.period_s = float(period_s)
        self.keep_s = float(keep_s)
        self._t: list[float] = []
        self._a: list[float] = []
        self._lock = threading.Condition()
        servo_emulator.call_at(servo_emulator.sim_time, self._record)

    def _record(self) -> None:
        # In the emulator's thread, under its lock: the shafts are at sim_time.
        emulator = self.servo_emulator
        t = float(emulator.sim_time)
        angle = float(emulator.servo(self.dxl_id).shaft.position)
        with self._lock:
            if not self._t or t > self._t[-1]:
                self._t.append(t)
                self._a.append(angle)
            if len(self._t) > 4096 and self._t[0] < t - self.keep_s:
                cut = int(np.searchsorted(self._t, t - self.keep_s))
                del self._t[:cut], self._a[:cut]
            self._lock.notify_all()
        emulator.call_at(t + self.period_s, self._record)

    def angles_at(self, times_s: np.ndarray, *, timeout_s: float = 10.0) -> np.ndarray:
        """The shaft's true angle at simulated times, rad (waits until the history covers them).

        Raises:
            TimeoutError: the servo emulator's time did not reach them within ``timeout_s``
                of wall time (it stopped).
        """
        times_s = np.asarray(times_s, dtype=np.float64)
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while not self._t or self._t[-1] < times_s.max():
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"the servo emulator's time did not reach {times_s.max():.4f} s")
                self._lock.wait(min(left, 0.05))
            if times_s.min() < self._t[0]:
                raise ValueError(f"time {times_s.min():.4f} s is older than the history kept ({self._t[0]:.4f} s)")
            return np.interp(times_s, self._t, self._a)


def turntable_provider(history: TurntableHistory, scene, spec: LidarSpec = URG_04LX_UG01, *,
                       model=None, seed: int = 0, encoder_offset_rad: float = 0.0, record: list | None = None):
    """The URG emulator's scan provider: the simulated LiDAR sees the scene on the
    emulated turntable at the servo's true angle at each beam's instant.

    Args:
        history: the servo shaft's angle over time.
        scene: the compiled rig scene (plant on the disk).
        spec: the LiDAR preset (a URG-04LX grid).
        model: the sensor model (realistic), or None (ideal).
        seed: the sensor model's noise: scan ``n`` draws from ``default_rng([seed, n])``.
        encoder_offset_rad: the servo's reading at turntable angle 0 (the rig's
            ``encoder_offset_deg``): the table's angle is the shaft's minus it.
        record: when a list, each scan appends ``(beam_times_s, true_angle_rad, lines)``
            (the ground truth, for tests).
    """
    source = SimulatedLidar(scene, spec, BeamGrid.of(spec).beam_angles_rad(), model=model)

    def line_fn(beam_times_s: np.ndarray):
        table_rad = history.angles_at(beam_times_s) - encoder_offset_rad
        n = int(round(beam_times_s[0] / spec.scan_period_s))
        lines = source.cast_lines(table_rad[None, :], np.random.default_rng([seed, n]),
                                  beam_time_s=beam_times_s[None, :])
        if record is not None:
            record.append((np.array(beam_times_s), table_rad, lines))
        return lines.range_m[0], lines.status[0]

    return preset_provider(line_fn, spec)


class EmulatorPair:
    """An emulated rig: servo and LiDAR on two ptys, one turntable, one clock.

    Args:
        scene: the compiled rig scene the LiDAR sees (:func:`plantsim.rig.scene.build_scene`).
        spec: the LiDAR preset (default the URG-04LX-UG01).
        model: the sensor model for a realistic LiDAR, or None (ideal).
        seed: the sensor model's seed.
        encoder_offset_rad: the servo's reading at turntable angle 0.
        servo_model, dxl_id, baud_bps, speed_factor, load_inertia: the servo
            emulator's (:class:`~plantsim.hardware.dynamixel.emulator.DynamixelEmulator`).
        timestamp_offset_s: the LiDAR timer's reading when the servo's time is 0.
        record: keep each scan's beam times and true angles in :attr:`scans`.

    Attributes:
        servo: the :class:`DynamixelEmulator`; ``servo.port_path`` is the servo's port.
        lidar: the :class:`UrgEmulator`; ``lidar.port_path`` is the LiDAR's port.
        history: the :class:`TurntableHistory`.
        scans: with ``record``, ``(beam_times_s, true_angle_rad, lines)`` of each scan sent.
    """

    def __init__(self, scene, spec: LidarSpec = URG_04LX_UG01, *, model=None, seed: int = 0,
                 encoder_offset_rad: float = 0.0, servo_model: str = "xm430-w350", dxl_id: int = 1,
                 baud_bps: int = 57_600, speed_factor: float = 1.0, load_inertia: float = 0.0,
                 timestamp_offset_s: float = 1234.567, record: bool = False):
        self.scene, self.spec, self.model, self.seed = scene, spec, model, seed
        self.encoder_offset_rad = float(encoder_offset_rad)
        self.dxl_id = dxl_id
        self._servo_options = dict(ids=(dxl_id,), model=servo_model, baud_bps=baud_bps,
                                   speed_factor=speed_factor, load_inertia=load_inertia)
        self.timestamp_offset_s = float(timestamp_offset_s)
        self.scans: list | None = [] if record else None
        self.servo = self.lidar = self.history = None

    def start(self) -> "EmulatorPair":
        from plantsim.hardware.dynamixel.emulator import DynamixelEmulator

        self.servo = DynamixelEmulator(**self._servo_options).start()
        try:
            self.history = TurntableHistory(self.servo, self.dxl_id)
            provider = turntable_provider(self.history, self.scene, self.spec, model=self.model, seed=self.seed,
                                          encoder_offset_rad=self.encoder_offset_rad, record=self.scans)
            self.lidar = UrgEmulator(provider, clock=ServoSimClock(self.servo),
                                     timestamp_offset_s=self.timestamp_offset_s).start()
        except BaseException:
            self.servo.stop()
            raise
        return self

    def replug(self) -> str:
        """A new LiDAR on a new pty (after :meth:`UrgEmulator.unplug`), seeing the same
        turntable on the same clock, as a re-plugged sensor; returns its port."""
        old = self.lidar
        self.lidar = UrgEmulator(old.scan_provider, clock=old.clock, timestamp_offset_s=self.timestamp_offset_s).start()
        old.stop()
        return self.lidar.port_path

    def stop(self) -> None:
        if self.lidar is not None:
            self.lidar.stop()
        if self.servo is not None:
            self.servo.stop()

    def __enter__(self) -> "EmulatorPair":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def servo_port(self) -> str:
        return self.servo.port_path

    @property
    def lidar_port(self) -> str:
        return self.lidar.port_path

    def host_clock(self) -> float:
        """The emulators' simulated time, s: a host clock that runs as the rig's devices do."""
        return float(self.servo.sim_time)

    def true_angle_rad(self, sim_time_s) -> np.ndarray:
        """The turntable's true angle at simulated times (the servo's shaft minus the encoder offset)."""
        return self.history.angles_at(np.atleast_1d(sim_time_s)) - self.encoder_offset_rad
