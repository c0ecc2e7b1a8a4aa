"""The real URG LiDAR as a line source of the one scan pipeline.

:class:`UrgLineSource` wraps a connected :class:`~plantsim.hardware.urg.driver.UrgLidar`
so that a rig scan (:mod:`plantsim.scan.session`, :mod:`plantsim.scan.continuous_rig`)
takes its lines from the sensor instead of the simulated LiDAR, and the lines become
the same :class:`~plantsim.scan.raw.RawScan` (and ROS 2 bag, and cloud) as a
simulated scan's:

* the ranges are what the sensor sent (1 mm steps, as float32 metres like every
  raw record), NaN where it sent an error code, and the code's
  :class:`~plantsim.sensor.spec.BeamStatus` (:func:`plantsim.hardware.urg.protocol.ranges_from_raw`);
* each beam's time is the sensor's step-0 timestamp plus ``step / ARES`` of a
  mirror turn, put on the host's clock by the TM-estimated
  :class:`~plantsim.hardware.urg.clock.ClockOffset` (``UrgScan.beam_host_times_s``);
* GD/MD of the URG-04LX carry no intensity (only ME does, on other models), so
  the lines have none; hit classes are unknown (``HitClass.NONE``) and there is
  no ground truth.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from plantsim.errors import LidarError
from plantsim.sensor.spec import LidarSpec

_log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, eq=False)
class UrgLine:
    """One line as the real sensor gave it, on the pipeline's beam grid.

    Attributes:
        range_m: (n_beams,) float64 (float32 values), metres; NaN unless OK.
        status: (n_beams,) uint8 BeamStatus.
        raw_mm: (n_beams,) int64, the values sent (mm, or error codes < 20).
        beam_host_times_s: (n_beams,) float64, host clock of each beam, s.
        timestamp_ms: the sensor's 24-bit stamp of the scan's step 0.
        intensity: None (GD/MD carry none).
    """

    range_m: np.ndarray
    status: np.ndarray
    raw_mm: np.ndarray
    beam_host_times_s: np.ndarray
    timestamp_ms: int
    intensity: np.ndarray | None = None

    @property
    def first_beam_host_s(self) -> float:
        return float(self.beam_host_times_s[0])


def line_from_scan(scan, n_beams: int) -> UrgLine:
    """An :class:`UrgLine` from an ``UrgScan`` of the preset's steps (one value per beam).

    Raises:
        LidarError: the scan has another number of values, or no host times
            (the clock was never synchronised).
    """
    if len(scan.ranges_m) != n_beams:
        raise LidarError(f"the LiDAR sent {len(scan.ranges_m)} values, the preset has {n_beams} beams")
    if scan.beam_host_times_s is None:
        raise LidarError("the LiDAR's clock offset is unknown: connect with sync_clock=True or call sync_clock()")
    range_m = np.asarray(scan.ranges_m, dtype=np.float32).astype(np.float64)
    return UrgLine(range_m=range_m, status=np.asarray(scan.status).astype(np.uint8),
                   raw_mm=np.asarray(scan.raw_mm, dtype=np.int64),
                   beam_host_times_s=np.asarray(scan.beam_host_times_s, dtype=np.float64),
                   timestamp_ms=int(scan.timestamp_ms))


class UrgLineSource:
    """A connected URG as the scan pipeline's line source.

    Args:
        lidar: a connected :class:`~plantsim.hardware.urg.driver.UrgLidar` whose clock
            was synchronised (``UrgLidar.connect`` does both); the caller closes it.
        spec: the preset the lines are read on (its steps); must be the one the
            driver checked the sensor against.

    Attributes:
        kind: "urg" (the simulated LiDAR's is "simulated").
        ideal: False: a real sensor is never ideal.
        host_clock: the driver's host clock (beam times are on it).
    """

    kind = "urg"
    ideal = False

    def __init__(self, lidar, spec: LidarSpec):
        if lidar.info is None:
            raise ValueError("lidar must be connected (UrgLidar.connect) before it becomes a line source")
        if lidar.preset is None or lidar.preset.name != spec.name:
            raise ValueError(f"lidar was checked against {getattr(lidar.preset, 'name', None)!r}, not the "
                             f"scan's preset {spec.name!r}: connect it with preset=spec")
        self.lidar = lidar
        self.spec = spec
        self.host_clock = lidar.host_clock

    @property
    def port(self) -> str | None:
        return self.lidar.port

    def take_line(self, *, after_host_s: float | None = None) -> UrgLine:
        """One GD scan whose first beam was measured at or after ``after_host_s`` (host clock).

        Raises:
            LidarError: the sensor failed (timeout, garbled replies, unplugged, refused).
        """
        if self.lidar.clock_offset is None:
            self.lidar.sync_clock()
        return line_from_scan(self.lidar.scan(after_host_s=after_host_s), self.spec.n_beams)

    def stream(self):
        """MD scans until the generator is closed (each an :class:`UrgLine`); closing it sends QT."""
        if self.lidar.clock_offset is None:
            self.lidar.sync_clock()
        stream = self.lidar.stream()
        try:
            for scan in stream:
                yield line_from_scan(scan, self.spec.n_beams)
        finally:
            stream.close()

    def clock_uncertainty_s(self) -> float:
        """The host/sensor offset's uncertainty, s (inf before a sync)."""
        offset = self.lidar.clock_offset
        return math.inf if offset is None else float(offset.uncertainty_s)

    def identity(self) -> dict:
        """What a journal resumes under: the sensor's model and serial (not its port)."""
        info = self.lidar.info
        return {"kind": "urg", "model": info.model, "serial": info.serial, "preset": self.spec.name}

    def describe(self) -> dict:
        """For the sidecar's ``simulated.lidar``: a real sensor, what it said about itself."""
        info, offset = self.lidar.info, self.lidar.clock_offset
        out = {"kind": "urg", "real": True, "model": info.model, "product": info.product,
               "vendor": info.vendor, "serial": info.serial, "firmware": info.firmware,
               "protocol": info.protocol, "port": self.lidar.port, "preset": self.spec.name,
               "simulated": "nothing: ranges, error codes and time stamps are the sensor's own",
               "intensity": "none (GD/MD carry no intensity)",
               "statuses": "URG error codes mapped to BeamStatus (1-2 low_intensity, 7-8 edge, others no_echo)",
               "hit_classes": "unknown (a real sensor does not know what it hit)",
               "dropped_scans": self.lidar.dropped_scans}
        if offset is not None:
            out["clock_offset"] = {"offset_s": offset.offset_s, "uncertainty_s": offset.uncertainty_s,
                                   "round_trip_s": offset.round_trip_s, "drift": offset.drift,
                                   "method": "TM1 round trips, minimum-delay filter"}
        return out
