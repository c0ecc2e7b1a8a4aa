"""A scan on a turntable that is driven line by line: move, settle, take a line, journal it.

This is the scan pipeline's loop for a real turntable (a Dynamixel servo, or its
emulator) and for :class:`~plantsim.turntable.table.SimulatedTurntable`: each
line's commanded angle goes to the table, the angle the table *reports* is the
encoder reading of the line, and the line source takes one line at rest. Every
line is journaled (:mod:`plantsim.scan.journal`) as soon as it is taken, so a
fault loses at most the line in flight and ``resume`` continues after the last
complete line; the raw record is built from the journal, each line once.

With the simulated LiDAR the rays are cast at the reported angle (hardware in
the loop); the sensor model draws its noise from a generator seeded by the run's
seed and the line's index, so a resumed scan is the scan that was not interrupted.

With the real LiDAR (:class:`~plantsim.hardware.urg.source.UrgLineSource`) the line is
one GD scan whose first beam was measured after the table came to rest; its stamp is
that beam's time on the host clock (the sensor's timestamp through the TM-estimated
clock offset), and the journal keeps what the sensor sent (ranges, statuses; no hit
classes, no ground truth). Continuous rig scans are :mod:`plantsim.scan.continuous_rig`.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Callable

import numpy as np

from plantsim.errors import HardwareError, ScanInterruptedError
from plantsim.interrupts import raise_if_signalled
from plantsim.scan.journal import Journal, JournalLine, open_journal
from plantsim.scan.raw import BeamGrid, RawScan, lidar_pose_of, s_to_ns
from plantsim.scan.schedule import StepScan
from plantsim.turntable.table import Turntable

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]


def line_rng(seed: int, index: int) -> np.random.Generator:
    """The sensor model's generator for one line of a journaled scan."""
    return np.random.default_rng([seed, index])


def run_session(*, turntable: Turntable, source, grid: BeamGrid, schedule: StepScan, seed: int,
                first_beam_s: float, journal_path: str | Path, identity: dict, angle_mode: str,
                encoder_offset_rad: float = 0.0, resume: bool = False,
                settle_s: float = 0.0, progress: Progress | None = None,
                T_base_lidar: np.ndarray | None = None) -> tuple[RawScan, Journal]:
    """Runs a scan, journaling each line, and returns its raw record built from the journal.

    Args:
      turntable: the table (simulated or servo); the caller closes it.
      source: the line source (:class:`plantsim.sensor.lidar.SimulatedLidar`, or the real
        LiDAR: :class:`plantsim.hardware.urg.source.UrgLineSource`).
      grid: the sensor's beam grid.
      schedule: the angles (and, for a simulated table, the line times).
      seed: the run's seed.
      first_beam_s: the line's first beam after the line is requested, s.
      journal_path: the journal file; created (or, with ``resume``, continued).
      identity: what determines the lines; a journal is resumed only under the same identity.
      angle_mode: the reconstruction's angle rule ("line" or "commanded").
      encoder_offset_rad: the table's reading at turntable angle 0 (the simulated
        LiDAR casts at the reported angle minus it).
      resume: continue the journal from its last complete line (a missing
        journal starts a new scan, with a warning).
      settle_s: wait after each move before the line, s (a swaying plant).
      progress: called with (lines done, lines total), also once at the start.
      T_base_lidar: (4, 4) the sensor's pose (default: the simulated source's scene's).

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
    n_lines = schedule.n_lines
    journal_path = Path(journal_path)
    journal = open_journal(journal_path, identity, n_lines=n_lines, n_beams=grid.n_beams,
                           started_unix_s=time.time(), resume=resume)
    started = journal.header["started_unix_s"]
    real = getattr(source, "kind", "simulated") == "urg"
    if real:
        # Stamps on the sensor's host clock; a resumed run continues after the journal's last line.
        last_s = journal.lines[-1].stamp_ns / 1e9 if journal.lines else -1.0
        zero_s = source.host_clock() - (last_s + 1.0)
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
                if real:
                    # A line measured wholly after the table came to rest (and settled).
                    line = source.take_line(after_host_s=source.host_clock() + source.clock_uncertainty_s())
                    t0 = line.first_beam_host_s - zero_s
                    table_rad = math.nan  # no ground truth: where the table really was is unknown
                else:
                    t0 = index * schedule.step_time_s if turntable.kinematic else time.time() - started
                    t0 += first_beam_s
                    table_rad = reported - encoder_offset_rad
                    line = source.cast_lines(np.array([table_rad]), line_rng(seed, index),
                                             beam_time_s=t0 + grid.beam_offsets_s()[None, :])
            except HardwareError as exc:
                raise ScanInterruptedError(
                    f"{exc} [scan stopped at line {index + 1} of {n_lines} ({math.degrees(commanded):g} deg); "
                    f"the {index} complete lines are safe in {journal_path}]",
                    journal_path=str(journal_path), lines_done=index, n_lines=n_lines) from exc
            journal.append(real_line(index, commanded, reported, t0, line) if real else JournalLine(
                index=index, commanded_angle_rad=commanded, reported_angle_rad=reported,
                cast_angle_rad=table_rad, stamp_ns=int(s_to_ns(t0)), range_m=line.range_m[0],
                status=line.status[0], hit_class=line.hit_class[0], geom_id=line.geom_id[0],
                intensity=None if line.intensity is None else line.intensity[0]))
            if progress is not None:
                progress(index + 1, n_lines)
            raise_if_signalled()  # a SIGTERM the interpreter swallowed still stops the scan here
    raw = raw_from_lines(journal.lines, grid=grid,
                         T_base_lidar=source.scene.T_base_lidar if T_base_lidar is None else T_base_lidar,
                         angle_mode=angle_mode, start_unix_ns=int(started * 1e9),
                         encoder_offset_rad=encoder_offset_rad)
    return raw, journal


def real_line(index: int, commanded: float, reported: float, t0_s: float, line) -> JournalLine:
    """The journal record of a line the real sensor gave (an
    :class:`~plantsim.hardware.urg.source.UrgLine`): its ranges and statuses as sent,
    no hit classes, no cast angle (NaN)."""
    n = len(line.range_m)
    return JournalLine(index=index, commanded_angle_rad=commanded, reported_angle_rad=reported,
                       cast_angle_rad=math.nan, stamp_ns=int(s_to_ns(t0_s)), range_m=line.range_m,
                       status=line.status, hit_class=np.zeros(n, np.uint8), geom_id=np.full(n, -1, np.int32),
                       intensity=line.intensity)


def raw_from_lines(lines: list[JournalLine], *, grid: BeamGrid, T_base_lidar: np.ndarray,
                   angle_mode: str, start_unix_ns: int = 0, encoder_offset_rad: float = 0.0,
                   encoder: tuple[np.ndarray, np.ndarray] | None = None) -> RawScan:
    """The :class:`RawScan` of journaled lines (in order, one row per line).

    The encoder log is the reported angle of each line at its stamp, or
    ``encoder`` = (stamps ns, angles rad) when the table was read on its own
    (continuous rig scans); the ground truth is where the rays were cast (none
    when a real LiDAR took the lines: their cast angles are NaN).
    """
    n = grid.n_beams
    stack = lambda name, dtype: (np.stack([getattr(line, name) for line in lines]).astype(dtype)  # noqa: E731
                                 if lines else np.empty((0, n), dtype))
    intensity = None
    if lines and all(line.intensity is not None for line in lines):
        intensity = stack("intensity", np.float32)
    stamps = np.array([line.stamp_ns for line in lines], dtype=np.int64)
    ones = np.ones(n)
    cast = np.array([line.cast_angle_rad for line in lines], dtype=np.float64)
    truth = cast[:, None] * ones if lines else np.empty((0, n))
    if lines and np.isnan(cast).all():
        truth = None  # a real LiDAR: no ground truth
    if encoder is None:
        encoder = (stamps.copy(), np.array([line.reported_angle_rad for line in lines], dtype=np.float64))
    return RawScan(
        grid=grid, line_stamp_ns=stamps, range_m=stack("range_m", np.float64),
        status=stack("status", np.uint8), intensity=intensity,
        encoder_stamp_ns=np.asarray(encoder[0], dtype=np.int64),
        encoder_angle_rad=np.asarray(encoder[1], dtype=np.float64),
        commanded_rad=np.array([line.commanded_angle_rad for line in lines], dtype=np.float64),
        angle_mode=angle_mode, lidar_pose=lidar_pose_of(T_base_lidar),
        true_turntable_angle_rad=truth,
        hit_class=stack("hit_class", np.uint8), geom_id=stack("geom_id", np.int32),
        start_unix_ns=start_unix_ns, encoder_offset_rad=encoder_offset_rad)
