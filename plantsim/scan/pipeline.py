"""One scan run, end to end: load, build, scan, reconstruct, encode, write.

The pieces are pure; this module strings them together, times each phase, and
assembles the sidecar. Nothing is written until everything is computed.
"""

from __future__ import annotations

import dataclasses
import logging
import platform
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from plantsim.scan.config import RunConfig
from plantsim.cloud.export import check_output_path, encode_cloud, sidecar_path, write_atomic
from plantsim.plant.mesh import PlantMesh, load_plant
from plantsim.cloud.reconstruct import PointCloud, reconstruct
from plantsim.resources import bundled_plant_path
from plantsim.scan.raw import RawScan
from plantsim.sensor.casting import FootprintCaster, RayCaster, gate_ranges
from plantsim.rig.scene import Scene, build_scene
from plantsim.scan.schedule import StepScan
from plantsim.sensor.model import SensorModel, apply_sensor
from plantsim.sensor.spec import BeamStatus, LidarSpec

if TYPE_CHECKING:  # the evaluation pulls in scipy: imported only when asked for
    from plantsim.evaluation.evaluate import Evaluation, EvaluationOptions

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]


@dataclasses.dataclass(frozen=True, eq=False)
class ScanResult:
    """What a run produced (before or after writing)."""

    config: RunConfig
    plant: PlantMesh
    scene: Scene
    raw: RawScan
    cloud: PointCloud
    timings_s: dict
    evaluation: "Evaluation | None" = None


def library_versions() -> dict:
    """Versions of plantsim and what it runs on (read from metadata: no slow imports)."""
    from importlib import metadata

    from plantsim import __version__

    versions = {"plantsim": __version__, "python": platform.python_version()}
    for name in ("mujoco", "numpy", "scipy", "trimesh", "laspy"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def load_configured_plant(config: RunConfig) -> PlantMesh:
    options = config.plant
    path = options.mesh if options.mesh else bundled_plant_path(options.bundled)
    T = None if options.T_turntable_mesh is None else np.array(options.T_turntable_mesh)
    return load_plant(path, units=options.units, up=options.up, placement=options.placement,
                      T_turntable_mesh=T)


def run_scan(config: RunConfig, *, progress: Progress | None = None) -> ScanResult:
    """Runs the scan a configuration describes (no file is written).

    Args:
      config: the resolved configuration.
      progress: called with (lines done, lines total) while casting.
    """
    timings = {}
    t = time.perf_counter()
    plant = load_configured_plant(config)
    timings["load_mesh"] = time.perf_counter() - t

    # The run's single source of randomness (used by the sensor and motor models).
    rng = np.random.default_rng(config.seed)
    if config.turntable.uses_physics(config.ideal):
        if not config.ideal:
            log.warning("dynamic scans cast one geometric ray per beam at its own instant; the "
                        "sensor model (footprint, noise, intensity, dropouts) is not applied yet")
        scene, raw = _dynamic_scan(config, plant, rng, timings, progress)
    else:
        t = time.perf_counter()
        scene = build_scene(config.rig, plant, plant_areal_density_kg_m2=config.plant.areal_density_kg_m2)
        timings["build_scene"] = time.perf_counter() - t

        t = time.perf_counter()
        if config.ideal:
            caster = RayCaster(scene, config.lidar, nthread=config.threads)
            raw = step_and_shoot(scene, config.lidar, config.scan, caster=caster, progress=progress)
        else:
            caster = FootprintCaster(scene, config.lidar, config.sensor_model, nthread=config.threads)
            raw = realistic_step_and_shoot(scene, config.lidar, config.scan, config.sensor_model,
                                           rng=rng, caster=caster, progress=progress)
        timings["scan"] = time.perf_counter() - t

    return finish_scan(config, plant, scene, raw, timings)


def finish_scan(config: RunConfig, plant: PlantMesh, scene: Scene, raw: RawScan,
                timings: dict) -> ScanResult:
    """Reconstructs a raw scan (plant points only if configured) into a :class:`ScanResult`."""
    t = time.perf_counter()
    cloud = reconstruct(raw)
    if config.output.plant_only:
        cloud = cloud.plant_only()
    timings["reconstruct"] = time.perf_counter() - t
    return ScanResult(config=config, plant=plant, scene=scene, raw=raw, cloud=cloud, timings_s=timings)


def _dynamic_scan(config: RunConfig, plant: PlantMesh, rng: np.random.Generator, timings: dict,
                  progress: Progress | None) -> tuple[Scene, RawScan]:
    """The scan with the servo's physics (issue 4): step or continuous mode."""
    from plantsim.sensor.casting import PoseCaster
    from plantsim.turntable.motion import continuous_scan, dynamic_step_and_shoot
    from plantsim.turntable.dynamics import build_dynamic_scene

    options = config.turntable.effective(config.ideal)
    t = time.perf_counter()
    dscene = build_dynamic_scene(config.rig, plant, options.dynamics,
                                 plant_areal_density_kg_m2=config.plant.areal_density_kg_m2)
    timings["build_scene"] = time.perf_counter() - t
    t = time.perf_counter()
    caster = PoseCaster(dscene.scene, config.lidar, nthread=config.threads)
    if options.mode == "continuous":
        result = continuous_scan(dscene, config.lidar, config.scan.sweep_deg, options, rng,
                                 caster=caster, progress=progress)
    else:
        result = dynamic_step_and_shoot(dscene, config.lidar, config.scan, options, rng,
                                        caster=caster, progress=progress)
    timings["scan"] = time.perf_counter() - t
    return dscene.scene, result.raw


def with_evaluation(result: ScanResult, *, options: "EvaluationOptions | None" = None) -> ScanResult:
    """The result with its own error: plant points against the placed mesh and,
    when an exact-traits file sits beside the mesh, traits against it.

    The evaluation's wall time is added to ``timings_s`` as ``evaluate``.

    Args:
      result: a scan.
      options: how to measure (None: the defaults of
        :class:`plantsim.evaluate.EvaluationOptions`).

    Returns:
      A new ScanResult carrying ``evaluation``.
    """
    from plantsim.evaluation.evaluate import EvaluationOptions, evaluate_scan

    evaluation = evaluate_scan(result, options=options or EvaluationOptions())
    timings = {**result.timings_s, "evaluate": evaluation.time_s}
    return dataclasses.replace(result, evaluation=evaluation, timings_s=timings)


def simulated_rig_time_s(result: ScanResult) -> float:
    """How long the simulated rig took, seconds: the last scan line's time stamp
    plus one scan period (the time a real acquisition would last, not the
    simulator's wall time)."""
    lidar = result.config.lidar
    last_line_t0 = float(result.raw.time_s[-1, 0] - lidar.beam_time_offsets_s()[0])
    return last_line_t0 + lidar.scan_period_s


def sidecar(result: ScanResult) -> dict:
    """The sidecar JSON's content for a result."""
    out = {
        "plantsim_sidecar": 1,
        "output": result.config.output.path,
        "config": result.config.to_dict(),
        "seed": result.config.seed,
        "versions": library_versions(),
        "frames": {
            "turntable": "origin on the turntable axis at the disk top, +Z up along the axis, "
                         "+X towards the LiDAR at turntable angle 0; metres",
            "T_turntable_mesh": result.plant.T_turntable_mesh.tolist(),
            "T_base_lidar": result.scene.T_base_lidar.tolist(),
        },
        "plant": result.plant.summary(),
        "counts": {**result.raw.counts(), "points_written": len(result.cloud),
                   "points_written_by_class": result.cloud.counts_by_class()},
        "classification_codes": {"plant": 4, "turntable": 64, "rig": 65},
        "timings_s": result.timings_s,
        "simulated_rig_time_s": simulated_rig_time_s(result),
    }
    if result.evaluation is not None:
        out["evaluation"] = result.evaluation.to_dict()
    return out


def write_result(result: ScanResult, path: str | Path | None = None) -> Path:
    """Encodes and writes the cloud and its sidecar, atomically."""
    path = check_output_path(path or result.config.output.path)
    t = time.perf_counter()
    data = encode_cloud(path, result.cloud)
    result.timings_s["encode"] = time.perf_counter() - t
    import json

    text = json.dumps(sidecar(result), indent=2) + "\n"
    write_atomic(path, data)
    write_atomic(sidecar_path(path), text.encode("utf-8"))
    return path


def step_and_shoot(scene: Scene, lidar: LidarSpec, schedule: StepScan, *,
                   caster: RayCaster | None = None, progress: Progress | None = None) -> RawScan:
    """An ideal, kinematic step-and-shoot scan (no actuator, no physics).

    The table is exactly at each commanded angle for the whole line.

    Args:
      scene: a compiled scene from :func:`plantsim.scene.build_scene`.
      lidar: the sensor.
      schedule: angles and timing.
      caster: a :class:`RayCaster` to reuse (it must be for this scene and sensor).
      progress: called with (lines done, lines total).

    Returns:
      The :class:`RawScan`.
    """
    if schedule.step_time_s < lidar.scan_period_s:
        raise ValueError(
            f"step_time_s ({schedule.step_time_s} s) must be at least the sensor's scan period "
            f"({lidar.scan_period_s} s): one line must fit in one step")
    caster = caster or RayCaster(scene, lidar)
    dist, geom = caster.cast(schedule.angles_rad(), progress=progress)
    range_m, status = gate_ranges(dist, lidar)
    return kinematic_raw_scan(scene, lidar, schedule, range_m=range_m, status=status, geom_id=geom)


def kinematic_raw_scan(scene: Scene, lidar: LidarSpec, schedule: StepScan, *, range_m: np.ndarray,
                       status: np.ndarray, geom_id: np.ndarray,
                       intensity: np.ndarray | None = None) -> RawScan:
    """The raw record of a kinematic step-and-shoot scan from its per-beam results.

    The table is exactly at each commanded angle for the whole line; line j
    starts at ``j * step_time_s`` and its beams follow the sensor's timing.

    Args:
      range_m, status, geom_id: (n_lines, n_beams) per-beam results.
      intensity: optional (n_lines, n_beams) float.
    """
    angles = schedule.angles_rad()
    line_t0 = schedule.step_time_s * np.arange(schedule.n_lines)
    time_s = line_t0[:, None] + lidar.beam_time_offsets_s()[None, :]
    angle_per_beam = np.broadcast_to(angles[:, None], range_m.shape)
    return RawScan(
        turntable_angle_rad=angle_per_beam,
        true_turntable_angle_rad=angle_per_beam,
        beam_angle_rad=lidar.beam_angles_rad(),
        range_m=range_m,
        status=status,
        hit_class=scene.geom_class[geom_id],
        geom_id=geom_id,
        time_s=time_s,
        T_base_lidar=scene.T_base_lidar,
        intensity=intensity,
    )


def realistic_step_and_shoot(scene: Scene, lidar: LidarSpec, schedule: StepScan,
                             model: SensorModel, *, rng: np.random.Generator,
                             caster: FootprintCaster | None = None,
                             progress: Progress | None = None) -> RawScan:
    """A kinematic step-and-shoot scan through the sensor model.

    Like :func:`plantsim.scan.step_and_shoot` (the table is exactly at each
    commanded angle for the whole line), but each beam is a sampled footprint
    and its return goes through :func:`apply_sensor`.

    Args:
      scene: a compiled scene.
      lidar: the sensor and its noise parameters.
      schedule: angles and timing.
      model: which effects, and the reflectances.
      rng: the run's one generator.
      caster: a :class:`FootprintCaster` to reuse (for this scene, sensor and model).
      progress: called with (lines done, lines total).

    Returns:
      The :class:`RawScan`, with ``intensity`` when the model records it.
    """
    if schedule.step_time_s < lidar.scan_period_s:
        raise ValueError(
            f"step_time_s ({schedule.step_time_s} s) must be at least the sensor's scan period "
            f"({lidar.scan_period_s} s): one line must fit in one step")
    caster = caster or FootprintCaster(scene, lidar, model)
    angles = schedule.angles_rad()
    fp = caster.cast(angles, progress=progress)
    log.debug("footprint: %d of %d beams refined with %d sub-rays", caster.n_refined,
              fp["geom_id"].size, caster.pattern.n_subrays)
    range_m, status, intensity = apply_sensor(fp["range_m"], fp["power"], fp["cos_incidence"],
                                              fp["spread_m"], lidar, model, rng)
    too_near = int((status == BeamStatus.TOO_NEAR).sum())
    if too_near > (status == BeamStatus.OK).sum():
        log.warning("%d beams returned nearer than %s's range_min_m (%g m), more than gave a "
                    "range: move the sensor back ([rig] lidar_distance_m = %g m now)", too_near,
                    lidar.name, lidar.range_min_m, scene.rig.lidar_distance_m)
    return kinematic_raw_scan(scene, lidar, schedule, range_m=range_m, status=status,
                              geom_id=fp["geom_id"], intensity=intensity)
