"""The scan pipeline: one function for every mode, every turntable and every sensor.

A scan is a schedule (:mod:`plantsim.scan.schedule`) x a turntable motion
(kinematic or MuJoCo physics, :mod:`plantsim.turntable.motion`; or a real
turntable driven line by line, :mod:`plantsim.scan.session`) x a line source
(the simulated LiDAR, ideal or realistic: :mod:`plantsim.sensor.lidar`) -> one
raw record (:class:`~plantsim.scan.raw.RawScan`, the content of the scan's ROS 2
bag) -> the reconstruction from what a real rig knows (encoder readings, beam
times, rig geometry: :mod:`plantsim.cloud.reconstruct`) -> the cloud.
:func:`plan_scan` decides the parts once and refuses what they would not use.

:func:`run_scan` writes nothing; :func:`write_result` writes the cloud, its
sidecar (what was actually simulated, part by part) and, when asked, the raw
record as a ROS 2 bag.
"""

from __future__ import annotations

import dataclasses
import math
import logging
import os
import platform
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from plantsim._lazy import LazyGenerator
from plantsim.cloud.reconstruct import PointCloud, reconstruct
from plantsim.plant.mesh import PlantMesh, load_plant
from plantsim.resources import bundled_plant_path
from plantsim.rig.fit import rig_fit_warnings
from plantsim.rig.scene import Scene, build_scene
from plantsim.scan.config import RunConfig
from plantsim.scan.plan import ScanPlan, plan_scan
from plantsim.scan.raw import BeamGrid, RawScan, believed_angles, lidar_pose_of, ns_to_s
from plantsim.sensor.casting import make_backend
from plantsim.scan.schedule import StepScan
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.sensor.model import SensorModel
from plantsim.sensor.spec import LidarSpec
from plantsim.turntable.encoder import EncoderConfig
from plantsim.turntable import motion as motions

if TYPE_CHECKING:  # the evaluation pulls in scipy: imported only when asked for
    from plantsim.evaluation.evaluate import Evaluation, EvaluationOptions
    from plantsim.turntable.table import Turntable

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]


@dataclasses.dataclass(frozen=True, eq=False)
class ScanResult:
    """What a scan produced (before or after writing).

    Attributes:
      config: the configuration.
      plan: the parts that ran.
      plant, scene: the placed plant and the compiled scene.
      raw: the raw record.
      cloud: the reconstructed cloud (plant points only if configured).
      timings_s: wall time of each phase.
      parts: what each part simulated, for the sidecar.
      diagnostics: what the turntable did (dynamic and rig scans).
      evaluation: the scan against its truth, when asked (:func:`with_evaluation`).
      journal_path: the journal of a line-by-line (rig) scan, else None.
      lines_resumed: lines that came from an earlier, interrupted run.
    """

    config: RunConfig
    plan: ScanPlan
    plant: PlantMesh
    scene: Scene
    raw: RawScan
    cloud: PointCloud
    timings_s: dict
    parts: dict
    diagnostics: dict = dataclasses.field(default_factory=dict)
    evaluation: "Evaluation | None" = None
    journal_path: Path | None = None
    lines_resumed: int = 0


def _dist_info_version(module, name: str) -> str | None:
    """The version in ``NAME-VERSION.dist-info`` beside an installed package, or None."""
    try:
        site = Path(module.__file__).resolve().parent.parent
    except (AttributeError, TypeError):
        return None
    found = sorted(site.glob(f"{name}-*.dist-info"))
    return found[0].name[len(name) + 1:-len(".dist-info")] if len(found) == 1 else None


def library_versions() -> dict:
    """Versions of plantsim, Python and the libraries this run loaded (no slow imports).

    A library the run never imported (MuJoCo in a kinematic scan cast with Embree,
    rosbags without ``--raw``) did not shape its output: it is named in
    ``not_loaded`` instead. Versions come from the loaded modules themselves
    (reading package metadata costs ~7 ms a package).
    """
    import sys

    from plantsim import __version__
    from plantsim._lazy import is_loaded

    versions: dict = {"plantsim": __version__, "python": platform.python_version()}
    not_loaded = []
    for name in ("mujoco", "numpy", "scipy", "trimesh", "laspy", "rosbags", "embreex"):
        module = sys.modules.get(name)
        if module is None or not is_loaded(name):
            not_loaded.append(name)
            continue
        # embreex reads its __version__ from package metadata (importing importlib.metadata,
        # ~15 ms); the dist-info folder beside it names the same version.
        version = _dist_info_version(module, name) if name == "embreex" else getattr(module, "__version__", None)
        if version is None:
            from importlib import metadata

            try:
                version = metadata.version(name)
            except metadata.PackageNotFoundError:
                version = "unknown"
        versions[name] = str(version)
    versions["not_loaded"] = not_loaded
    return versions


def load_configured_plant(config: RunConfig) -> PlantMesh:
    options = config.plant
    path = options.mesh if options.mesh else bundled_plant_path(options.bundled)
    T = None if options.T_turntable_mesh is None else np.array(options.T_turntable_mesh)
    placement = options.placement
    if not options.mesh and options.bundled == "calibration-target" and "plant.placement" not in config.explicit \
            and placement == "base" and options.base_point is None:
        # The target stands where it is built (plantsim.plant.target); "base" would centre its
        # footprint (block and dowel together) and move the block off the axis.
        placement = "none"
    return load_plant(path, units=options.units, up=options.up, placement=placement, T_turntable_mesh=T,
                      base_point=options.base_point)


def journal_path_for(output: str | os.PathLike) -> Path:
    """The journal beside an output: ``scan.las`` -> ``scan.las.journal``."""
    output = Path(output)
    return output.with_name(output.name + ".journal")


def _timing(lidar: LidarSpec, grid: BeamGrid) -> motions.LineTiming:
    """The sensor's timing as a motion needs it."""
    return motions.LineTiming(scan_period_s=lidar.scan_period_s,
                              first_beam_s=float(lidar.beam_time_offsets_s()[0]),
                              beam_offsets_s=grid.beam_offsets_s())


def _motion(config: RunConfig, plan: ScanPlan, dscene, grid: BeamGrid,
            rng: np.random.Generator) -> motions.MotionRecord:
    timing = _timing(config.lidar, grid)
    tt = config.turntable
    if plan.motion == "kinematic" and plan.mode == "step":
        if config.scan.step_time_s < config.lidar.scan_period_s:
            raise ValueError(
                f"step_time_s ({config.scan.step_time_s} s) must be at least the sensor's scan period "
                f"({config.lidar.scan_period_s} s): one line must fit in one step")
        return motions.kinematic_step(config.scan.angles_rad(), config.scan.step_time_s, timing,
                                      plan.encoder, rng)
    if plan.motion == "kinematic":
        return motions.kinematic_continuous(tt.rpm, config.scan.sweep_deg, timing, plan.encoder, rng)
    if plan.mode == "step":
        return motions.physics_step(dscene, config.scan.angles_rad(), timing, plan.encoder, rng)
    return motions.physics_continuous(dscene, tt.rpm, config.scan.sweep_deg, timing, plan.encoder, rng)


def _describe_turntable(config: RunConfig, plan: ScanPlan, turntable=None) -> dict:
    if plan.motion == "hardware":
        out = {"motion": "hardware", **turntable.describe(),
               "angle_mode": plan.angle_mode, "encoder": "the table's own (its reported angle)"}
        if plan.mode == "continuous":
            from plantsim.scan.continuous_rig import servo_rpm

            out.update(mode="continuous", rpm_requested=config.turntable.rpm, rpm=servo_rpm(config.turntable.rpm),
                       encoder="the servo's Present Position with its Realtime Tick, put on the host clock")
        return out
    out = {"motion": plan.motion, "mode": plan.mode, "angle_mode": plan.angle_mode,
           "encoder": dataclasses.asdict(plan.encoder)}
    if plan.mode == "continuous":
        out["rpm"] = config.turntable.rpm
    if plan.motion == "kinematic":
        out["model"] = ("a perfect motor: exactly at each commanded angle for the whole line"
                        if plan.mode == "step" else "a perfect motor at constant speed")
    else:
        out["model"] = "the servo in MuJoCo (PID, torque limit, friction, profile)"
        out["dynamics"] = dataclasses.asdict(plan.dynamics)
        out["jitter_active"] = bool(plan.dynamics.jitter.any)
    return out


def run_scan(config: RunConfig, *, plant: PlantMesh | None = None, turntable: "Turntable | None" = None,
             resume: bool = False, settle_s: float = 0.0, progress: Progress | None = None,
             lidar=None) -> ScanResult:
    """Runs the scan a configuration describes (no file is written).

    Args:
      config: the resolved configuration.
      plant: a placed plant (:func:`plantsim.plant.mesh.plant_from_arrays`) instead of the
        one ``config.plant`` names.
      turntable: a table driven line by line (a Dynamixel servo, its emulator, or
        :class:`~plantsim.turntable.table.SimulatedTurntable`); None simulates the
        turntable as ``config.turntable`` says. The caller closes it.
      resume: (with ``turntable``) continue the journal beside the output.
      settle_s: (with ``turntable``) wait after each move, s.
      progress: called with (lines done, lines total).
      lidar: (with ``turntable``) the real LiDAR as the line source
        (:class:`plantsim.hardware.urg.source.UrgLineSource`) instead of the simulated
        one; ``turntable.mode = "continuous"`` then turns the servo while it streams
        (:mod:`plantsim.scan.continuous_rig`).

    Raises:
      ConfigError: a setting the chosen parts would not use (see :func:`plan_scan`).
      SimulationError: the turntable physics cannot run or diverged.
      ScanInterruptedError, JournalError: see :func:`plantsim.scan.session.run_session`.
    """
    _check_types(config, plant, turntable)
    if lidar is not None and turntable is None:
        raise ValueError("a real LiDAR (lidar=...) scans on a real turntable: pass turntable= as well")
    if lidar is not None and lidar.spec.name != config.lidar.name:
        raise ValueError(f"the LiDAR was connected with preset {lidar.spec.name!r} but the configuration's is "
                         f"{config.lidar.name!r}: connect it with preset=config.lidar")
    plan = plan_scan(config, hardware_turntable=turntable is not None, real_lidar=lidar is not None)
    for note in plan.notes:
        log.warning("%s", note)
    timings = {}
    t = time.perf_counter()
    if plant is None:
        plant = load_configured_plant(config)
    timings["load_mesh"] = time.perf_counter() - t
    fit_warnings = rig_fit_warnings(plant, config.rig, config.lidar)
    for warning in fit_warnings:
        log.warning("%s", warning)

    t = time.perf_counter()
    dscene = None
    if plan.motion == "physics":
        from plantsim.turntable.dynamics import build_dynamic_scene

        dscene = build_dynamic_scene(config.rig, plant, plan.dynamics,
                                     plant_areal_density_kg_m2=config.plant.areal_density_kg_m2)
        scene = dscene.scene
    else:
        scene = build_scene(config.rig, plant)  # kinematic: no physics, no plant inertia
    grid = BeamGrid.of(config.lidar)
    source = lidar if lidar is not None else SimulatedLidar(
        scene, config.lidar, grid.beam_angles_rad(), model=None if plan.sensor == "ideal" else config.sensor_model,
        backend=make_backend(scene, config.caster, nthread=config.threads), nthread=config.threads)
    timings["build_scene"] = time.perf_counter() - t

    t = time.perf_counter()
    journal_path, lines_resumed, diagnostics = None, 0, {}
    if turntable is None:
        rng = LazyGenerator(config.seed)  # a perfect sensor and turntable draw nothing
        record = _motion(config, plan, dscene, grid, rng)
        timings["turntable"] = time.perf_counter() - t
        t = time.perf_counter()
        raw = simulate_lines(source, record, grid, plan.angle_mode, rng, progress=progress,
                             encoder_offset_rad=math.radians(config.rig.encoder_offset_deg))
        diagnostics = motions.physics_diagnostics(
            record, raw.time_s, raw.true_turntable_angle_rad, raw.turntable_angle_rad,
            settle_tolerance_rad=plan.dynamics.settle_tolerance_rad if plan.dynamics is not None else None)
        diagnostics["angle_error_plant"] = angle_error_metric(raw)
    else:
        from plantsim.cloud.export import check_output_path
        from plantsim.scan.session import run_session

        output = check_output_path(config.output.path)  # fail before any move
        journal_path = journal_path_for(output)
        if plan.mode == "continuous":
            from plantsim.scan.continuous_rig import run_continuous_session

            raw, journal, timing = run_continuous_session(
                turntable=turntable, source=source, grid=grid, rpm=config.turntable.rpm,
                sweep_deg=config.scan.sweep_deg, journal_path=journal_path,
                identity=scan_identity(config, plant, turntable, source), angle_mode=plan.angle_mode,
                T_base_lidar=scene.T_base_lidar, resume=resume,
                encoder_offset_rad=math.radians(config.rig.encoder_offset_deg), progress=progress)
        else:
            raw, journal = run_session(turntable=turntable, source=source, grid=grid, schedule=config.scan,
                                       seed=config.seed, journal_path=journal_path,
                                       first_beam_s=float(config.lidar.beam_time_offsets_s()[0]),
                                       identity=scan_identity(config, plant, turntable, source),
                                       angle_mode=plan.angle_mode, resume=resume, settle_s=settle_s,
                                       encoder_offset_rad=math.radians(config.rig.encoder_offset_deg),
                                       progress=progress, T_base_lidar=scene.T_base_lidar)
        lines_resumed = journal.lines_resumed
        if plan.mode == "continuous":
            diagnostics = {**timing, "encoder_readings_journaled": int(len(raw.encoder_stamp_ns)),
                           "note": "servo readings (Realtime Tick + Present Position) interpolated to each beam"}
        else:
            error = raw.encoder_angle_rad - raw.commanded_rad
            diagnostics = {"max_reported_minus_commanded_rad": float(np.abs(error).max()) if len(error) else 0.0,
                           "note": "reported minus commanded, per line; points use the reported angle"}
    timings["scan"] = time.perf_counter() - t

    parts = {"plan": {**plan.to_dict(), "rig_fit_warnings": list(fit_warnings)},
             "schedule": _describe_schedule(config, plan, raw),
             "turntable": _describe_turntable(config, plan, turntable), "lidar": source.describe()}
    if lidar is not None:
        parts["real_parts"] = {"turntable": "the servo (its reported angles are the encoder log)",
                               "lidar": f"a real {source.describe()['model']} (ranges, error codes, time stamps)",
                               "simulated": "nothing; the plant mesh and rig geometry only place the "
                                            "sidecar's frames"}
    return finish_scan(config, plan, plant, scene, raw, timings, parts=parts, diagnostics=diagnostics,
                       journal_path=journal_path, lines_resumed=lines_resumed)


def simulate_lines(source: SimulatedLidar, record: motions.MotionRecord, grid: BeamGrid, angle_mode: str,
                   rng: np.random.Generator, *, progress: Progress | None = None,
                   encoder_offset_rad: float = 0.0) -> RawScan:
    """The simulated LiDAR takes every line of a simulated motion, each beam at its own true angle.

    Args:
      encoder_offset_rad: what the simulated encoder reads at turntable angle 0
        (added to its readings and the commanded angles; the reconstruction
        subtracts it again).

    Returns:
      The raw record (ground truth included).
    """
    beam_time_s = ns_to_s(record.line_stamp_ns)[:, None] + grid.beam_offsets_s()[None, :]
    true_rad = record.true_angles(beam_time_s)
    lines = source.cast_lines(true_rad, rng, beam_time_s=beam_time_s, progress=progress)
    shape = lines.range_m.shape
    return RawScan(grid=grid, line_stamp_ns=record.line_stamp_ns, range_m=lines.range_m,
                   status=lines.status, intensity=lines.intensity,
                   encoder_stamp_ns=np.round(record.readings.time_s * 1e9).astype(np.int64),
                   encoder_angle_rad=record.readings.angle_rad + encoder_offset_rad,
                   commanded_rad=record.commanded_rad + encoder_offset_rad, encoder_offset_rad=encoder_offset_rad,
                   angle_mode=angle_mode, lidar_pose=lidar_pose_of(source.scene.T_base_lidar),
                   true_turntable_angle_rad=np.broadcast_to(
                       true_rad if true_rad.ndim == 2 else true_rad[:, None], shape).copy(),
                   hit_class=lines.hit_class, geom_id=lines.geom_id)


def step_and_shoot(scene: Scene, lidar: LidarSpec, schedule: StepScan, *, model: SensorModel | None = None,
                   rng: np.random.Generator | None = None, caster: str = "auto",
                   progress: Progress | None = None) -> RawScan:
    """A step-and-shoot scan of a scene you built: a perfect turntable, the ideal or realistic sensor.

    The same parts as :func:`run_scan` with ``physics = "kinematic"`` (the table
    exactly at each commanded angle, an exact encoder), for scenes made by hand
    (:func:`plantsim.rig.scene.build_scene`, or an MjSpec of analytic shapes).

    Args:
      scene: a compiled scene.
      lidar: the sensor.
      schedule: angles and timing.
      model: the sensor model, or None for the ideal sensor.
      rng: the generator of the sensor model's noise (default: seed 0).
      caster: the ray-casting backend, as ``RunConfig.caster``.
      progress: called with (lines done, lines total).
    """
    if schedule.step_time_s < lidar.scan_period_s:
        raise ValueError(
            f"step_time_s ({schedule.step_time_s} s) must be at least the sensor's scan period "
            f"({lidar.scan_period_s} s): one line must fit in one step")
    rng = np.random.default_rng(0) if rng is None else rng
    grid = BeamGrid.of(lidar)
    source = SimulatedLidar(scene, lidar, grid.beam_angles_rad(), model=model, backend=make_backend(scene, caster))
    record = motions.kinematic_step(schedule.angles_rad(), schedule.step_time_s, _timing(lidar, grid),
                                    EncoderConfig.ideal(),
                                    rng)
    return simulate_lines(source, record, grid, "interpolate", rng, progress=progress)


def angle_error_metric(raw: RawScan) -> dict:
    """How far the plant's points moved because the rig believed other angles than the true ones.

    The reconstruction with the true turntable angles against the one with the
    believed angles, point by point (issue 14: point-to-mesh distance understates
    angle errors, as points slide along leaves). Empty when there is no ground truth.
    """
    if raw.true_turntable_angle_rad is None:
        return {}
    from plantsim.evaluation.angle_error import angle_error_displacement

    # BeamStatus.OK on HitClass.PLANT; the angles of those beams only (most of the grid misses).
    lines, beams = np.nonzero((raw.status == 0) & (raw.hit_class == 1))
    return angle_error_displacement(raw.range_m[lines, beams], raw.beam_angle_rad[beams], raw.T_base_lidar,
                                    raw.true_turntable_angle_rad[lines, beams], believed_angles(raw, lines, beams))


def _check_types(config, plant, turntable) -> None:
    from plantsim.turntable.table import Turntable

    if not isinstance(config, RunConfig):
        raise TypeError(f"config must be a plantsim.RunConfig, got {type(config).__name__}; build one with "
                        "plantsim.RunConfig(...) or plantsim.config_from_dict(toml_data)")
    if plant is not None and not isinstance(plant, PlantMesh):
        raise TypeError(f"plant must be a plantsim.PlantMesh (plantsim.load_plant or plant_from_arrays), got "
                        f"{type(plant).__name__}")
    if turntable is not None and not isinstance(turntable, Turntable):
        raise TypeError(f"turntable must implement plantsim.Turntable (move_to, read_angle_rad, check_angles, "
                        f"describe, identity, close), got {type(turntable).__name__}")


def check_plant_seen(result: ScanResult) -> None:
    """Raises ValueError when no beam hit the plant: the rig cannot see it, so the cloud would say nothing.

    The message gives the beam counts and where to look.
    """
    plant_hits = int((result.raw.hit_class == 1).sum())
    if result.plant.n_faces and plant_hits == 0:
        counts = result.raw.counts()["by_status"]
        lo, hi = result.plant.bounds_turntable()
        raise ValueError(
            f"no beam hit the plant ({result.raw.status.size:,} beams: {counts['ok']:,} on the rig, "
            f"{counts['no_echo']:,} no echo, {counts['too_near']:,} too near); the plant spans z "
            f"{lo[2]:.3g}..{hi[2]:.3g} m and the LiDAR stands {result.config.rig.lidar_distance_m:g} m "
            f"from the axis at {result.config.rig.lidar_height_m:g} m: check [rig] and the plant's units and "
            f"placement (nothing was written)")


def _describe_schedule(config: RunConfig, plan: ScanPlan, raw: RawScan) -> dict:
    out = {"mode": plan.mode, "lines": raw.n_lines, "beams_per_line": raw.n_beams,
           "sweep_deg": config.scan.sweep_deg}
    if plan.mode == "step":
        out["step_deg"] = config.scan.step_deg
        if plan.motion == "kinematic":
            out["step_time_s"] = config.scan.step_time_s
    return out


def finish_scan(config: RunConfig, plan: ScanPlan, plant: PlantMesh, scene: Scene, raw: RawScan,
                timings: dict, **extra) -> ScanResult:
    """Reconstructs a raw scan (plant points only if configured) into a :class:`ScanResult`.

    With ``config.range_filter.enabled`` the ranges are denoised first
    (:func:`plantsim.cloud.denoise.filter_ranges`) and what the filter did goes into
    the parts as ``range_filter``; the result's ``raw`` keeps the sensor's ranges.
    """
    t = time.perf_counter()
    if config.range_filter.enabled:
        from plantsim.cloud.denoise import filter_ranges

        filtered, report = filter_ranges(raw, config.range_filter)
        log.info("range filter: noise %.1f mm, %d of %d returns refitted (median change %.1f mm)",
                 1e3 * report.sigma_m, report.filtered, report.returns, 1e3 * report.median_change_m)
        extra["parts"] = {**extra.get("parts", {}), "range_filter": report.to_dict(config.range_filter)}
        cloud = reconstruct(filtered)
    else:
        cloud = reconstruct(raw)
    if config.output.plant_only:
        cloud = cloud.plant_only()
    timings["reconstruct"] = time.perf_counter() - t
    return ScanResult(config=config, plan=plan, plant=plant, scene=scene, raw=raw, cloud=cloud,
                      timings_s=timings, **extra)


def scan_identity(config: RunConfig, plant: PlantMesh, turntable, source) -> dict:
    """What determines a journaled scan's lines: a journal resumes only under the same identity.

    Every section of the resolved configuration counts (so a section added later
    counts too) except the output options, the thread count, the caster and the
    range filter (which only reconstructs the lines differently); the port is not
    part of it either. The plant is identified by its placed geometry (a hash), not
    its file path, so a relative path from another directory still resumes.
    """
    import hashlib  # here: only a journaled (resumable) scan has an identity; OpenSSL loads in ~4 ms

    digest = hashlib.sha256()
    for array in (plant.vertices_mesh, plant.faces, plant.T_turntable_mesh):
        digest.update(array.tobytes())
    identity = {k: v for k, v in config.to_dict().items() if k not in ("output", "threads", "caster",
                                                                          "range_filter")}
    identity["plant"] = {k: v for k, v in identity["plant"].items() if k != "mesh"}
    identity["plant_geometry_sha256"] = digest.hexdigest()
    identity["rig_turntable"] = turntable.identity()
    identity["line_source"] = (source.identity() if source.kind == "urg" else
                               {"kind": source.kind, "sensor": "ideal" if source.ideal else "realistic"})
    return identity


def with_evaluation(result: ScanResult, *, options: "EvaluationOptions | None" = None,
                    progress=None) -> ScanResult:
    """The result with its own error: plant points against the placed mesh and,
    when an exact-traits file sits beside the mesh, traits against it.

    The evaluation's wall time is added to ``timings_s`` as ``evaluate``; it uses
    the scan's ``config.threads``; ``progress(done, total)`` as ``evaluate_scan``'s.
    """
    from plantsim.evaluation.evaluate import EvaluationOptions, evaluate_scan

    evaluation = evaluate_scan(result, options=options or EvaluationOptions(), progress=progress)
    timings = {**result.timings_s, "evaluate": evaluation.time_s}
    return dataclasses.replace(result, evaluation=evaluation, timings_s=timings)


def simulated_rig_time_s(result: ScanResult) -> float:
    """How long the simulated rig took, seconds: the last line's first beam plus
    one scan period (what a real acquisition would last, not the simulator's time)."""
    raw = result.raw
    if raw.n_lines == 0:
        return 0.0
    first_beam = float(result.config.lidar.beam_time_offsets_s()[0])
    return float(raw.line_time_s[-1]) - first_beam + result.config.lidar.scan_period_s


def sidecar(result: ScanResult) -> dict:
    """The sidecar JSON's content: the configuration and what was actually simulated."""
    out = {
        "plantsim_sidecar": 2,
        "output": result.config.output.path,
        "config": result.config.to_dict(),
        "seed": result.config.seed,
        "simulated": result.parts,
        "versions": library_versions(),
        "frames": {
            "turntable": "origin on the turntable axis at the disk top, +Z up along the axis, "
                         "+X towards the LiDAR at turntable angle 0; metres",
            "T_turntable_mesh": result.plant.T_turntable_mesh.tolist(),
            "T_base_lidar": result.raw.T_base_lidar.tolist(),
        },
        "plant": result.plant.summary(),
        "counts": {**result.raw.counts(), "points_written": len(result.cloud),
                   "points_written_by_class": result.cloud.counts_by_class()},
        "classification_codes": {"plant": 4, "turntable": 64, "rig": 65},
        "timings_s": result.timings_s,
        "simulated_rig_time_s": simulated_rig_time_s(result),
    }
    work = result.parts.get("lidar", {}).get("work")
    if work:
        out["performance"] = performance(result.timings_s, work,
                                         physics_steps=(result.diagnostics or {}).get("physics_steps"))
    if result.diagnostics:
        out["turntable_diagnostics"] = result.diagnostics
    if result.journal_path is not None:
        out["journal"] = {"path": str(result.journal_path), "lines_resumed": result.lines_resumed}
    if result.config.output.raw:
        out["raw"] = {"path": result.config.output.raw, "format": "ROS 2 bag (MCAP storage)"}
    if result.evaluation is not None:
        out["evaluation"] = result.evaluation.to_dict()
    return out


def performance(timings_s: dict, work: dict, *, physics_steps: int | None = None) -> dict:
    """Where a scan's time went: rays cast and rays per second per phase.

    Args:
      timings_s: the run's phase wall times (``ScanResult.timings_s``).
      work: the line source's counts (:meth:`SimulatedLidar.work`).
      physics_steps: MuJoCo steps of the servo physics (``turntable`` phase), if any.

    Returns:
      The line source's phases, plus the scan phase's throughput (beams and all
      rays cast per second of the whole ``scan`` phase, motion excluded), and
      the physics' steps per second when it ran.
    """
    scan_s = timings_s.get("scan", 0.0)
    rays = work["turning_cast"]["rays"]
    out = dict(work)
    if scan_s > 0:
        out["scan_phase"] = {"s": scan_s, "beams_per_s": round(work["beams"] / scan_s),
                             "rays_per_s": round(rays / scan_s)}
    physics_s = timings_s.get("turntable", 0.0)
    if physics_steps and physics_s > 0:
        out["physics"] = {"steps": int(physics_steps), "s": physics_s,
                          "steps_per_s": round(physics_steps / physics_s)}
    return out


def check_outputs(config: RunConfig, *, config_path: str | os.PathLike | None = None,
                  journal_path: str | os.PathLike | None = None) -> Path:
    """Checks, before any work, that a run's outputs can be written and overwrite no input.

    Returns:
      The cloud's path.

    Raises:
      ValueError, FileNotFoundError, FileExistsError: naming the path and the fix.
    """
    from plantsim.cloud.export import check_output_path, sidecar_path
    from plantsim.cloud.outputs import refuse_inputs

    path = check_output_path(config.output.path)
    outputs = {"cloud": path, "sidecar": sidecar_path(path)}
    if config.output.raw:
        from plantsim.cloud.bag import check_bag_path

        outputs["raw record"] = check_bag_path(config.output.raw)
    inputs = {"plant mesh": config.plant.mesh, "configuration file": config_path,
              "scan journal": journal_path if journal_path is not None else journal_path_for(path)}
    refuse_inputs(outputs, inputs)
    if config.output.raw and Path(config.output.raw).resolve() in (path.resolve().parent, *path.resolve().parents):
        raise ValueError(f"the raw record folder {config.output.raw} would hold the cloud {path}; choose "
                         "another --raw folder")
    return path


def write_result(result: ScanResult, path: str | Path | None = None, *, keep_journal: bool = False) -> Path:
    """Writes the cloud, its sidecar and (when configured) the raw record as a ROS 2 bag, as a unit.

    Everything is first written in full beside its target, then all are moved in
    together (:class:`plantsim.cloud.outputs.OutputSet`): a full disk, an error or
    Ctrl-C leaves the earlier outputs as they were. A journal (rig scans) is
    removed only once all are in place, unless ``keep_journal``.
    """
    import json
    from concurrent.futures import ThreadPoolExecutor

    from plantsim.cloud.export import _json_default, encode_cloud, sidecar_path
    from plantsim.cloud.outputs import OutputSet

    config = result.config
    if path is not None:
        config = config.replace(output=dataclasses.replace(config.output, path=str(path)))
    path = check_outputs(config, journal_path=result.journal_path if result.journal_path else None)
    with OutputSet() as outputs:
        if config.output.raw:
            from plantsim.cloud.bag import write_bag

            t = time.perf_counter()
            write_bag(outputs.stage_folder(config.output.raw), result.raw, metadata=bag_metadata(result))
            result.timings_s["write_raw"] = time.perf_counter() - t
        t = time.perf_counter()
        data = encode_cloud(path, result.cloud)
        result.timings_s["encode"] = time.perf_counter() - t
        # The cloud goes to disk (and fsync) beside the making of the sidecar: the one
        # waits on the disk, the other on Python (~5 ms of a 0.35 s scan). Its error, if
        # any, is raised here; the staged files are then discarded as usual.
        with ThreadPoolExecutor(max_workers=1) as pool:
            cloud_staged = pool.submit(outputs.stage_bytes, path, data)
            side = sidecar(result)
            side["output"] = str(path)
            if result.journal_path is not None:
                side["journal"]["kept"] = keep_journal
            text = json.dumps(side, indent=2, default=_json_default) + "\n"
            cloud_staged.result()
        outputs.stage_bytes(sidecar_path(path), text.encode("utf-8"))
        outputs.commit()
    if result.journal_path is not None and not keep_journal:
        result.journal_path.unlink(missing_ok=True)
    return path


def bag_metadata(result: ScanResult) -> dict:
    """What the bag's ``/plantsim/scan_info`` carries besides the raw record itself."""
    return {"config": result.config.to_dict(), "simulated": result.parts, "T_turntable_mesh": result.plant.T_turntable_mesh.tolist(),
            "plant": result.plant.summary(), "versions": library_versions()}

