"""A rig scan, end to end: configuration + turntable -> journaled lines -> point cloud.

:func:`run_rig_scan` is :func:`plantsim.pipeline.run_scan` for a turntable you
hand it (simulated, a Dynamixel servo, or the servo emulator): it builds the
scene, runs a journaled :func:`plantsim.session.run_session` with the simulated
LiDAR cast at the table's reported angle, and reconstructs the cloud from the
journal. :func:`write_rig_result` writes the cloud and sidecar with the same
writer as ``plantsim scan`` and then removes the journal (unless asked to keep it):
the cloud, sidecar and journal are never all missing at once.

The journal is ``<output>.journal`` (``scan.las.journal``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import time
from pathlib import Path

from plantsim.scan.config import RunConfig
from plantsim.cloud.export import check_output_path, write_cloud
from plantsim.scan.pipeline import ScanResult, finish_scan, load_configured_plant, sidecar
from plantsim.rig.scene import build_scene
from plantsim.scan.session import LineSource, Progress, SimulatedLidar, run_session
from plantsim.turntable.table import Turntable

log = logging.getLogger(__name__)


def journal_path_for(output: str | os.PathLike) -> Path:
    """The journal beside an output: ``scan.las`` -> ``scan.las.journal``."""
    output = Path(output)
    return output.with_name(output.name + ".journal")


def scan_identity(config: RunConfig, plant, turntable: Turntable, source: LineSource) -> dict:
    """What determines a scan's lines: a journal resumes only under the same identity.

    Every section of the resolved configuration counts (so a section added later
    counts too) except the output options and the thread count; the port is not
    part of it either. The plant is identified by its placed geometry (a hash), not
    its file path, so a relative path from another directory still resumes.
    """
    digest = hashlib.sha256()
    for array in (plant.vertices_mesh, plant.faces, plant.T_turntable_mesh):
        digest.update(array.tobytes())
    identity = {k: v for k, v in config.to_dict().items() if k not in ("output", "threads")}
    identity["plant"] = {k: v for k, v in identity["plant"].items() if k != "mesh"}
    identity["plant_geometry_sha256"] = digest.hexdigest()
    identity["rig_turntable"] = turntable.identity()
    identity["line_source"] = source.identity()
    return identity


@dataclasses.dataclass(frozen=True, eq=False)
class RigScanResult:
    """A rig scan's result.

    Attributes:
      result: the cloud and its raw record, as from :func:`plantsim.pipeline.run_scan`.
      rig: the turntable's and line source's descriptions (for the sidecar).
      journal_path: the journal the lines were read from.
      lines_resumed: lines that came from an earlier, interrupted run.
    """

    result: ScanResult
    rig: dict
    journal_path: Path
    lines_resumed: int


def run_rig_scan(config: RunConfig, turntable: Turntable, *, resume: bool = False,
                 source: LineSource | None = None, settle_s: float = 0.0,
                 progress: Progress | None = None) -> RigScanResult:
    """Scans on a rig: the turntable turns, the LiDAR takes a line at each stop.

    Args:
      config: the resolved configuration (plant, sensor, geometry, schedule, output).
      turntable: the table; the caller closes it.
      resume: continue the journal beside ``config.output.path``.
      source: the LiDAR; default the simulated one, cast at the table's reported angle.
      settle_s: wait after each move, s.
      progress: called with (lines done, lines total).

    Raises:
      ScanInterruptedError: the rig failed mid-scan (resume later).
      JournalError: see :func:`plantsim.session.run_session`.
    """
    output = check_output_path(config.output.path)  # fail before any move
    timings = {}
    t = time.perf_counter()
    plant = load_configured_plant(config)
    timings["load_mesh"] = time.perf_counter() - t
    t = time.perf_counter()
    scene = build_scene(config.rig, plant, plant_areal_density_kg_m2=config.plant.areal_density_kg_m2)
    timings["build_scene"] = time.perf_counter() - t
    if source is None:
        source = SimulatedLidar(scene, config.lidar, nthread=config.threads)
    journal_path = journal_path_for(output)
    t = time.perf_counter()
    raw, journal = run_session(turntable=turntable, source=source, schedule=config.scan,
                               journal_path=journal_path,
                               identity=scan_identity(config, plant, turntable, source),
                               resume=resume, settle_s=settle_s, progress=progress)
    timings["scan"] = time.perf_counter() - t
    result = finish_scan(config, plant, scene, raw, timings)
    return RigScanResult(result=result, rig={"turntable": turntable.describe(), "lidar": source.describe()},
                         journal_path=journal_path, lines_resumed=journal.lines_resumed)


def rig_sidecar(rig_result: RigScanResult, *, journal_kept: bool) -> dict:
    """The sidecar of ``plantsim scan`` plus the rig and the journal."""
    data = sidecar(rig_result.result)
    raw = rig_result.result.raw
    error = raw.turntable_angle_rad[:, 0] - rig_result.result.config.scan.angles_rad()[: raw.n_lines]
    data["rig"] = {
        **rig_result.rig,
        "angle_error_rad": {"max_abs": float(abs(error).max()) if len(error) else 0.0,
                            "note": "reported minus commanded, per line; points use the reported angle"},
    }
    data["journal"] = {"path": str(rig_result.journal_path), "kept": journal_kept,
                       "lines_resumed": rig_result.lines_resumed}
    return data


def write_rig_result(rig_result: RigScanResult, *, keep_journal: bool = False) -> Path:
    """Writes the cloud and its sidecar atomically, then removes the journal.

    Args:
      keep_journal: keep ``<output>.journal`` (its per-line raw record, misses
        included, is more than the cloud holds). A kept journal of a finished scan
        makes a later run without ``resume`` refuse to start; ``resume`` on it only
        rewrites the output.
    """
    path = Path(rig_result.result.config.output.path)
    write_cloud(path, rig_result.result.cloud, sidecar=rig_sidecar(rig_result, journal_kept=keep_journal))
    if not keep_journal:
        rig_result.journal_path.unlink(missing_ok=True)
    return path
