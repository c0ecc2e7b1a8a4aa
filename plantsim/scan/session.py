"""One scan session for the simulated and the physical rig.

A session turns a :class:`~plantsim.turntable.Turntable` through a
:class:`~plantsim.scan.StepScan` schedule and takes one line from a
:class:`LineSource` at each stop, journaling each line as it arrives
(:mod:`plantsim.journal`). The same loop runs

* a simulated scan: :class:`~plantsim.turntable.SimulatedTurntable` +
  :class:`SimulatedLidar` (bit for bit the lines of :func:`plantsim.scan.step_and_shoot`);
* a hardware-in-the-loop scan: :class:`~plantsim.turntable.ServoTurntable` (a real
  servo, or the emulator) + :class:`SimulatedLidar` cast at the servo's *reported*
  angle;
* a real scan, once a real LiDAR driver exists: :class:`UrgLidar` is its place, and
  today it says it is not available.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Callable, NamedTuple, Protocol, runtime_checkable

import numpy as np

from plantsim.errors import HardwareError, ScanInterruptedError
from plantsim.scan.journal import Journal, JournalLine
from plantsim.scan.raw import RawScan
from plantsim.sensor.casting import RayCaster, gate_ranges
from plantsim.scan.schedule import StepScan
from plantsim.rig.scene import Scene
from plantsim.sensor.spec import LidarSpec
from plantsim.turntable.table import Turntable

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]


class Line(NamedTuple):
    """One scan line from a :class:`LineSource`; arrays are (n_beams,).

    range_m float64 metres (NaN: no return), status uint8 BeamStatus, hit_class
    uint8 HitClass (NONE for a real sensor), geom_id int32 (-1 for a real sensor),
    cast_angle_rad: the turntable angle the rays were cast at (NaN for a real sensor).
    """

    range_m: np.ndarray
    status: np.ndarray
    hit_class: np.ndarray
    geom_id: np.ndarray
    cast_angle_rad: float


@runtime_checkable
class LineSource(Protocol):
    """A 2D LiDAR that takes one line on request.

    Attributes:
      beam_angle_rad: (n_beams,) float64, lidar frame.
      beam_time_offsets_s: (n_beams,) float64 s, each beam's time after the line's start.
      T_base_lidar: (4, 4) float64, where the sensor is mounted.
    """

    beam_angle_rad: np.ndarray
    beam_time_offsets_s: np.ndarray
    T_base_lidar: np.ndarray

    def read_line(self, *, turntable_angle_rad: float) -> Line:
        """Takes one line with the turntable at rest.

        Args:
          turntable_angle_rad: where the turntable reports it is. A simulated sensor
            casts its rays there; a real sensor ignores it.
        """

    def describe(self) -> dict:
        """JSON-able facts for the sidecar."""

    def identity(self) -> dict:
        """The facts that must match for a journal to be resumed with this source."""


class SimulatedLidar:
    """A simulated LiDAR: casts one line in the MuJoCo scene at the given angle."""

    def __init__(self, scene: Scene, lidar: LidarSpec, *, caster: RayCaster | None = None,
                 nthread: int | None = None):
        self.scene = scene
        self.lidar = lidar
        self.caster = caster or RayCaster(scene, lidar, nthread=nthread)
        self.beam_angle_rad = self.caster.beam_angles_rad
        self.beam_time_offsets_s = lidar.beam_time_offsets_s()
        self.T_base_lidar = scene.T_base_lidar

    def read_line(self, *, turntable_angle_rad: float) -> Line:
        dist, geom = self.caster.cast(np.array([turntable_angle_rad], dtype=np.float64))
        range_m, status = gate_ranges(dist[0], self.lidar)
        return Line(range_m=range_m, status=status, hit_class=self.scene.geom_class[geom[0]],
                    geom_id=geom[0], cast_angle_rad=float(turntable_angle_rad))

    def describe(self) -> dict:
        return {"kind": "simulated", "model": self.lidar.name,
                "cast_at": "the turntable's reported angle",
                "ranges": "exact first hit, one geometric ray per beam (no sensor noise model)"}

    def identity(self) -> dict:
        return {"kind": "simulated"}


class UrgLidar:
    """A real Hokuyo URG LiDAR (SCIP 2.0 over USB): not implemented yet.

    The interface is :class:`LineSource`; a driver would send ``GD`` for one line
    at rest and fill ``range_m``/``status`` (``hit_class`` NONE, ``geom_id`` -1,
    ``cast_angle_rad`` NaN). Until then, constructing one says so.
    """

    def __init__(self, port: str | None = None, **_options):
        raise HardwareError(
            "a real URG LiDAR is not available yet: plantsim has no SCIP 2.0 driver. Scan with the "
            "simulated LiDAR (lidar='sim', the default), which casts at the servo's reported angle")


def _line_time_s(turntable: Turntable, schedule: StepScan, index: int, started_unix_s: float) -> float:
    if turntable.kinematic:
        return index * schedule.step_time_s
    return time.time() - started_unix_s


def run_session(*, turntable: Turntable, source: LineSource, schedule: StepScan,
                journal_path: str | Path, identity: dict, resume: bool = False,
                settle_s: float = 0.0, progress: Progress | None = None) -> tuple[RawScan, Journal]:
    """Runs a scan, journaling each line, and returns its raw record built from the journal.

    Args:
      turntable: the table (simulated or servo); the caller closes it.
      source: the LiDAR.
      schedule: the angles (and, for a simulated table, the line times).
      journal_path: the journal file; created (or, with ``resume``, continued).
      identity: what determines the lines (configuration, plant, table and source
        identities); a journal is resumed only under the same identity.
      resume: continue the journal at ``journal_path`` from its last complete
        line (a missing journal starts a new scan, with a warning).
      settle_s: wait after each move before the line, s (a swaying plant).
      progress: called with (lines done, lines total), also once at the start.

    Returns:
      (raw, journal): the :class:`RawScan` of every line, each exactly once, read
      from the journal; the (closed) journal.

    Raises:
      ValueError: angles out of the table's reach, bad ``settle_s``.
      JournalError: an unfinished journal is in the way (without ``resume``), or
        the one to resume is damaged or from another configuration.
      ScanInterruptedError: the table or sensor failed mid-scan; the journal keeps
        every complete line (the message says how many).
    """
    if not (math.isfinite(settle_s) and settle_s >= 0):
        raise ValueError(f"settle_s must be finite and >= 0, got {settle_s!r}")
    angles_rad = schedule.angles_rad()
    turntable.check_angles(angles_rad)
    n_lines, n_beams = schedule.n_lines, len(source.beam_angle_rad)
    header = Journal.make_header(identity, n_lines=n_lines, n_beams=n_beams, started_unix_s=time.time())
    journal_path = Path(journal_path)
    if resume and not journal_path.exists():
        log.warning("no journal at %s to resume; starting a new scan", journal_path)
        resume = False
    journal = Journal.resume(journal_path, header) if resume else Journal.create(journal_path, header)
    with journal:
        start = len(journal.lines)
        if resume:
            log.info("resuming %s at line %d of %d", journal_path, start + 1, n_lines)
        if progress is not None:
            progress(start, n_lines)
        for index in range(start, n_lines):
            commanded = float(angles_rad[index])
            try:
                reported = float(turntable.move_to(commanded))
                if settle_s:
                    time.sleep(settle_s)
                t0 = _line_time_s(turntable, schedule, index, journal.header["started_unix_s"])
                line = source.read_line(turntable_angle_rad=reported)
            except HardwareError as exc:
                raise ScanInterruptedError(
                    f"{exc} [scan stopped at line {index + 1} of {n_lines} ({math.degrees(commanded):g} deg); "
                    f"the {index} complete lines are safe in {journal_path}]",
                    journal_path=str(journal_path), lines_done=index, n_lines=n_lines) from exc
            journal.append(JournalLine(
                index=index, commanded_angle_rad=commanded, reported_angle_rad=reported,
                cast_angle_rad=line.cast_angle_rad, time_s=t0, range_m=line.range_m,
                status=line.status, hit_class=line.hit_class, geom_id=line.geom_id))
            if progress is not None:
                progress(index + 1, n_lines)
    return raw_from_lines(journal.lines, source), journal


def raw_from_lines(lines: list[JournalLine], source: LineSource) -> RawScan:
    """The :class:`RawScan` of journaled lines (in order, one row per line).

    The reconstruction's angle (``turntable_angle_rad``) is each line's reported
    angle; ``true_turntable_angle_rad`` is where the rays were cast.
    """
    n_beams = len(source.beam_angle_rad)
    ones = np.ones(n_beams)
    if not lines:
        empty = np.empty((0, n_beams))
        return RawScan(turntable_angle_rad=empty, true_turntable_angle_rad=empty,
                       beam_angle_rad=source.beam_angle_rad, range_m=empty,
                       status=np.empty((0, n_beams), np.uint8), hit_class=np.empty((0, n_beams), np.uint8),
                       geom_id=np.empty((0, n_beams), np.int32), time_s=empty,
                       T_base_lidar=source.T_base_lidar)
    return RawScan(
        turntable_angle_rad=np.array([line.reported_angle_rad for line in lines])[:, None] * ones,
        true_turntable_angle_rad=np.array([line.cast_angle_rad for line in lines])[:, None] * ones,
        beam_angle_rad=source.beam_angle_rad,
        range_m=np.stack([line.range_m for line in lines]),
        status=np.stack([line.status for line in lines]),
        hit_class=np.stack([line.hit_class for line in lines]),
        geom_id=np.stack([line.geom_id for line in lines]),
        time_s=np.array([line.time_s for line in lines])[:, None] + source.beam_time_offsets_s[None, :],
        T_base_lidar=source.T_base_lidar,
    )
