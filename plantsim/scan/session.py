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
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Callable

import numpy as np

from plantsim.errors import HardwareError, ScanInterruptedError
from plantsim.scan.journal import Journal, JournalLine
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
                settle_s: float = 0.0, progress: Progress | None = None) -> tuple[RawScan, Journal]:
    """Runs a scan, journaling each line, and returns its raw record built from the journal.

    Args:
      turntable: the table (simulated or servo); the caller closes it.
      source: the line source (:class:`plantsim.sensor.lidar.SimulatedLidar`).
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
    header = Journal.make_header(identity, n_lines=n_lines, n_beams=grid.n_beams, started_unix_s=time.time())
    journal_path = Path(journal_path)
    if resume and not journal_path.exists():
        log.warning("no journal at %s to resume; starting a new scan", journal_path)
        resume = False
    journal = Journal.resume(journal_path, header) if resume else Journal.create(journal_path, header)
    started = journal.header["started_unix_s"]
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
                t0 = index * schedule.step_time_s if turntable.kinematic else time.time() - started
                t0 += first_beam_s
                table_rad = reported - encoder_offset_rad
                lines = source.cast_lines(np.array([table_rad]), line_rng(seed, index),
                                          beam_time_s=t0 + grid.beam_offsets_s()[None, :])
            except HardwareError as exc:
                raise ScanInterruptedError(
                    f"{exc} [scan stopped at line {index + 1} of {n_lines} ({math.degrees(commanded):g} deg); "
                    f"the {index} complete lines are safe in {journal_path}]",
                    journal_path=str(journal_path), lines_done=index, n_lines=n_lines) from exc
            journal.append(JournalLine(
                index=index, commanded_angle_rad=commanded, reported_angle_rad=reported,
                cast_angle_rad=table_rad, stamp_ns=int(s_to_ns(t0)), range_m=lines.range_m[0],
                status=lines.status[0], hit_class=lines.hit_class[0], geom_id=lines.geom_id[0],
                intensity=None if lines.intensity is None else lines.intensity[0]))
            if progress is not None:
                progress(index + 1, n_lines)
    raw = raw_from_lines(journal.lines, grid=grid, T_base_lidar=source.scene.T_base_lidar,
                         angle_mode=angle_mode, start_unix_ns=int(started * 1e9),
                         encoder_offset_rad=encoder_offset_rad)
    return raw, journal


def raw_from_lines(lines: list[JournalLine], *, grid: BeamGrid, T_base_lidar: np.ndarray,
                   angle_mode: str, start_unix_ns: int = 0, encoder_offset_rad: float = 0.0) -> RawScan:
    """The :class:`RawScan` of journaled lines (in order, one row per line).

    The encoder log is the reported angle of each line at its stamp; the ground
    truth is where the rays were cast.
    """
    n = grid.n_beams
    stack = lambda name, dtype: (np.stack([getattr(line, name) for line in lines]).astype(dtype)  # noqa: E731
                                 if lines else np.empty((0, n), dtype))
    intensity = None
    if lines and all(line.intensity is not None for line in lines):
        intensity = stack("intensity", np.float32)
    stamps = np.array([line.stamp_ns for line in lines], dtype=np.int64)
    ones = np.ones(n)
    return RawScan(
        grid=grid, line_stamp_ns=stamps, range_m=stack("range_m", np.float64),
        status=stack("status", np.uint8), intensity=intensity,
        encoder_stamp_ns=stamps.copy(),
        encoder_angle_rad=np.array([line.reported_angle_rad for line in lines], dtype=np.float64),
        commanded_rad=np.array([line.commanded_angle_rad for line in lines], dtype=np.float64),
        angle_mode=angle_mode, lidar_pose=lidar_pose_of(T_base_lidar),
        true_turntable_angle_rad=np.array([line.cast_angle_rad for line in lines])[:, None] * ones
        if lines else np.empty((0, n)),
        hit_class=stack("hit_class", np.uint8), geom_id=stack("geom_id", np.int32),
        start_unix_ns=start_unix_ns, encoder_offset_rad=encoder_offset_rad)
