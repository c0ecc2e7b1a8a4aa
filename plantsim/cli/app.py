"""The ``plantsim`` command: parse, call, report. No logic of its own."""

from __future__ import annotations

import argparse
import gc
import logging
import math
import os
import sys
import time

from plantsim.errors import PlantSimError
from plantsim.sensor.spec import PRESETS

log = logging.getLogger("plantsim")


def _opt(args: argparse.Namespace, name: str):
    """An option's value, or None where this command does not have it."""
    return getattr(args, name, None)


def scan_overrides(args: argparse.Namespace) -> dict:
    """Command-line options as a nested dict in the TOML layout (only those given)."""
    pairs = {
        ("plant", "mesh"): _opt(args, "mesh"), ("plant", "units"): _opt(args, "units"), ("plant", "up"): _opt(args, "up"),
        ("plant", "placement"): _opt(args, "placement"), ("plant", "base_point"): _opt(args, "base_point"),
        ("scan", "step_deg"): _opt(args, "step_deg"), ("scan", "sweep_deg"): _opt(args, "sweep_deg"),
        ("output", "path"): _opt(args, "output"), ("output", "plant_only"): _opt(args, "plant_only") or None,
        ("seed",): _opt(args, "seed"), ("ideal",): _opt(args, "ideal") or None, ("threads",): _opt(args, "threads"),
        ("sensor",): _opt(args, "sensor"), ("caster",): _opt(args, "caster"),
        ("turntable", "mode"): _opt(args, "mode"), ("turntable", "rpm"): _opt(args, "rpm"),
        ("turntable", "physics"): _opt(args, "physics"),
        ("turntable", "ideal"): True if _opt(args, "turntable") == "ideal" else None,
        ("output", "raw"): _opt(args, "raw"),
        ("turntable", "deskew"): False if _opt(args, "no_deskew") else None,
        ("lidar", "preset"): _opt(args, "lidar_preset"), ("sensor_model", "footprint_rings"): _opt(args, "footprint_rings"),
        ("range_filter", "enabled"): _opt(args, "range_filter") or None,
    }
    out: dict = {}
    for key, value in pairs.items():
        if value is None:
            continue
        if len(key) == 1:
            out[key[0]] = value
        else:
            out.setdefault(key[0], {})[key[1]] = value
    return out


def _progress_bar(total_label: str, unit: str = "line"):
    """A tqdm bar on a terminal, nothing otherwise. Returns (callback, close)."""
    if not sys.stderr.isatty():
        return None, lambda: None
    from tqdm import tqdm

    bar = None

    def update(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(total=total, unit=unit, desc=total_label, leave=False, file=sys.stderr)
        bar.update(done - bar.n)

    return update, lambda: bar.close() if bar is not None else None


def resolve_config(args: argparse.Namespace, overrides: dict):
    """The RunConfig of a command: its ``--config`` file (TOML, or a scan's sidecar), then the
    command-line options."""
    from plantsim.scan.config import config_from_dict, load_settings, merge

    data, base_dir = {}, None
    if args.config:
        data, base_dir = load_settings(args.config)  # a TOML file's mesh is relative to it; a sidecar's as recorded
    if _opt(args, "turntable") == "dynamic":
        overrides.setdefault("turntable", {})["physics"] = "dynamic"
    # A mesh given on the command line is relative to the working directory.
    return config_from_dict(merge(data, overrides), base_dir=base_dir if not args.mesh else None)


def cmd_scan(args: argparse.Namespace) -> int:
    from plantsim.scan.plan import plan_scan
    from plantsim.scan.pipeline import check_outputs, check_plant_seen, run_scan, write_result

    t0 = time.perf_counter()
    config = resolve_config(args, scan_overrides(args))
    check_outputs(config, config_path=args.config)  # Fail before any work, not after it.
    plan_scan(config)
    plant = None
    if _opt(args, "fit_rig"):
        config, plant, why = fit_rig_to_plant(config)
        print(f"--fit-rig: {why}")
    _import_writer_meanwhile(config.output.path)
    progress, close = _progress_bar("scan")
    try:
        result = run_scan(config, plant=plant, progress=progress)
    finally:
        close()
    check_plant_seen(result)
    if args.evaluate:
        from plantsim.scan.pipeline import with_evaluation

        progress, close = _progress_bar("evaluate", unit="pt")
        try:
            result = with_evaluation(result, progress=progress)
        finally:
            close()
    path = write_result(result)
    print(summary_line(result, path, time.perf_counter() - t0))
    if result.evaluation is not None:
        print(_evaluation_line(result.evaluation))
        # What the trait errors above do not say: a bound, a width the noise reads.
        for note in (result.evaluation.estimate.notes if result.evaluation.estimate is not None else ()):
            print(f"traits note: {note}")
        if not _opt(args, "no_pictures"):
            print(_error_picture_line(result, f"{path}.error.png"))
    return 0


def _import_writer_meanwhile(output_path: str) -> None:
    """Imports laspy on a daemon thread while the scan reads its plant (a LAS or LAZ output only).

    laspy's import (~16 ms) is Python executing module code, and it is needed only
    at the end; the plant's loading is mostly numpy, which lets go of the interpreter
    for its sorts and copies, so the import runs largely on the second core: the ideal
    seed-maize scan process went from 0.343 to 0.333 s (median of 15, alternating).
    The main thread's own ``import laspy`` later waits for it (or repeats its error,
    were it to fail).
    """
    import threading

    if os.path.splitext(output_path)[1].lower() not in (".las", ".laz") or "laspy" in sys.modules:
        return

    def work():
        try:
            import laspy  # noqa: F401
        except Exception:  # the writer's own import says what is wrong, in the main thread
            pass

    threading.Thread(target=work, name="plantsim-import-laspy", daemon=True).start()


def fit_rig_to_plant(config):
    """``--fit-rig``: the configuration with the LiDAR moved to fit the placed plant.

    Returns:
        (RunConfig with the fitted rig, the placed PlantMesh, the sentence saying what was chosen).
    """
    import dataclasses

    from plantsim.rig.fit import fit_rig
    from plantsim.scan.pipeline import load_configured_plant

    plant = load_configured_plant(config)
    rig, why = fit_rig(plant, config.rig, config.lidar)
    return dataclasses.replace(config, rig=rig), plant, why


def _error_picture_line(result, path: str) -> str:
    """Writes the cloud-vs-mesh error picture; one line saying where, or why not."""
    from plantsim.cloud.export import write_atomic
    from plantsim.cloud.render import RenderError, error_picture_of

    if result.evaluation.n_points == 0:
        return "error picture: skipped, no point on the plant"
    try:
        picture = error_picture_of(result.cloud, result.plant, result.config.rig)
        write_atomic(path, picture.png)
    except (RenderError, OSError) as exc:  # a picture never costs the scan
        return f"error picture: skipped ({str(exc).splitlines()[0]}); --no-pictures silences this"
    return f"error picture: {path} (plant points by distance to the mesh, {picture.scale_text()})"


def summary_line(result, path, seconds: float) -> str:
    """One line: what was written, from what, by which parts."""
    counts = result.cloud.counts_by_class()
    rig_points = counts["turntable"] + counts["rig"]
    plan = result.plan
    what = f"{plan.sensor} sensor, {plan.motion} turntable, {plan.mode} mode"
    rf = result.parts.get("range_filter")
    if rf:
        what += f", ranges filtered (noise {1e3 * rf['sigma_m']:.1f} mm)"
    resumed = f" ({result.lines_resumed} resumed from the journal)" if result.lines_resumed else ""
    raw = f" and the raw bag to {result.config.output.raw}" if result.config.output.raw else ""
    return (f"wrote {len(result.cloud):,} points ({counts['plant']:,} on the plant, {rig_points:,} on the rig) "
            f"from {result.raw.n_lines} lines{resumed} x {result.raw.n_beams} beams ({what}) to {path}{raw} "
            f"in {seconds:.2f} s")


def add_common_scan_options(parser: argparse.ArgumentParser, *, preset_flag: str = "--lidar") -> None:
    """Options shared by ``scan`` and ``rig scan``: plant, schedule, sensor, output."""
    parser.add_argument("mesh", nargs="?", help="plant mesh; default: the bundled maize")
    parser.add_argument("-o", "--output", help="output point cloud (default scan.las)")
    parser.add_argument("--config", help="TOML file with any of the options, or a scan's sidecar (.json): "
                        "runs that scan again, with the options given here on top")
    parser.add_argument("--units", choices=["m", "cm", "mm"], help="the mesh file's unit (default m)")
    parser.add_argument("--up", choices=["x", "y", "z"], help="the mesh file's up axis (default z)")
    parser.add_argument("--placement", choices=["base", "bbox", "none"],
                        help="how the plant sits on the disk (default base: base centred on the axis)")
    parser.add_argument("--base-point", type=float, nargs=3, metavar=("X", "Y", "Z"),
                        help="put this point of the mesh on the axis at the disk top instead of the stem base "
                             "found (a pot's centre, a main culm among tillers): the mesh file's own units "
                             "and axes")
    parser.add_argument("--step-deg", type=float, help="turntable step, degrees (default 1)")
    parser.add_argument("--sweep-deg", type=float, help="total turn, degrees (default 360)")
    parser.add_argument("--seed", type=int, help="seed of all randomness (default 0)")
    parser.add_argument("--ideal", action="store_true",
                        help="everything perfect: the ideal sensor (one ray per beam, no noise) and a "
                             "perfect turntable (exact angles, exact encoder)")
    parser.add_argument("--sensor", choices=["ideal", "realistic"],
                        help="the LiDAR alone: ideal (exact first hits) or realistic (footprint, noise, "
                             "intensity, dropouts; the default)")
    parser.add_argument(preset_flag, dest="lidar_preset", choices=sorted(PRESETS),
                        help="sensor preset (default urg-04lx-ug01)")
    parser.add_argument("--footprint-rings", type=int,
                        help="rings of sub-rays per beam footprint: 0 one ray, 1 7, 2 19 (default), 3 37")
    parser.add_argument("--plant-only", action="store_true", help="write only points on the plant")
    parser.add_argument("--range-filter", action="store_true",
                        help="denoise the ranges in the range image before making points (a robust local-plane "
                             "fit over 7 x 7 beams; [range_filter] in the config sets the window); the raw "
                             "record keeps the sensor's ranges")
    parser.add_argument("--threads", type=int, help="ray-casting threads (default: all cores)")
    parser.add_argument("--caster", choices=["mujoco", "embree", "auto"],
                        help="ray caster: auto (default: Embree when installed, else MuJoCo), embree, or mujoco "
                             "(the reference: the same hits, slower)")
    parser.add_argument("--raw", metavar="DIR",
                        help="also write the raw record (every beam, encoder readings, rig geometry, "
                             "ground truth) as a ROS 2 bag (MCAP) in DIR")
    parser.add_argument("--no-deskew", action="store_true",
                        help="reconstruct with one angle per line (the commanded angle in step mode, the "
                             "reading at the line's start in continuous mode), as a naive rig does")


def _evaluation_line(evaluation) -> str:
    """One line of the evaluation for the terminal (the sidecar has it all)."""
    m = evaluation.metrics
    if m is None:
        return "evaluation: no point on the plant"
    text = (f"evaluation: cloud->mesh median {m.median * 1e3:.3g} mm, p95 {m.p95 * 1e3:.3g} mm; "
            f"Chamfer {m.chamfer * 1e3:.3g} mm; coverage {m.coverage:.1%} within "
            f"{m.coverage_distance * 1e3:g} mm")
    if evaluation.traits is not None:
        parts = [f"{e.trait.removesuffix('_m')} {e.relative_error:.1%}" for e in evaluation.traits.errors
                 if e.trait in ("height_m", "stem_diameter_m", "mean_stem_distance_m", "leaf_width_m")]
        # Several stems: each one's height error (the stem height compared above is the
        # tallest's, and a tiller read far off hides behind it).
        own = [e.relative_error for e in evaluation.traits.errors
               if e.trait.startswith("stem[") and e.trait.endswith("].height_m") and math.isfinite(e.relative_error)]
        if len(own) > 1:
            parts.append(f"stem heights {min(own):.1%}-{max(own):.1%}")
        alone = getattr(evaluation, "labelled_leaves", None)
        area = next((e for e in evaluation.traits.errors if e.trait == "leaf_area_m2"), None)
        if alone is not None and area is not None and math.isfinite(alone.leaf_area_m2) and area.reference:
            # The leaf area's error were the leaves cut out perfectly: the scan's own limit.
            parts.append(f"leaf area {area.relative_error:.1%} (its {alone.leaf_count} labelled leaves measured "
                         f"alone {abs(alone.leaf_area_m2 - area.reference) / area.reference:.1%})")
        matched = getattr(evaluation, "leaf_match", None)
        if matched is not None:
            # A count can be right with leaves split and others merged.
            parts.append(f"leaves matched {matched.true_positives} of {matched.found} found to "
                         f"{matched.seen} labelled (PQ {matched.panoptic_quality:.2f})")
        text += "; trait errors: " + ", ".join(parts)
    return text


def cmd_reconstruct(args: argparse.Namespace) -> int:
    from plantsim.cloud.bag import read_raw
    from plantsim.cloud.export import check_output_path, write_cloud
    from plantsim.cloud.reconstruct import reconstruct

    path = check_output_path(args.output)
    raw, metadata = read_raw(args.raw)
    if args.angle_mode:
        raw = raw.replace(angle_mode=args.angle_mode)
    if args.rig:
        import math

        from plantsim.scan.config import config_from_dict, load_toml
        from plantsim.scan.raw import lidar_pose_of

        rig = config_from_dict({"rig": load_toml(args.rig).get("rig", {})}).rig
        raw = raw.replace(lidar_pose=lidar_pose_of(rig.T_base_lidar()),
                          encoder_offset_rad=math.radians(rig.encoder_offset_deg))
    filter_report = None
    if args.range_filter:
        from plantsim.cloud.denoise import filter_ranges
        from plantsim.scan.config import RangeFilter

        settings = RangeFilter(enabled=True)
        raw, report = filter_ranges(raw, settings)
        filter_report = report.to_dict(settings)
        print(f"range filter: noise {1e3 * report.sigma_m:.1f} mm, {report.filtered:,} of {report.returns:,} "
              f"returns refitted (median change {1e3 * report.median_change_m:.1f} mm)")
    cloud = reconstruct(raw)
    if args.plant_only:
        if raw.true_turntable_angle_rad is None:
            raise ValueError(f"--plant-only needs the ground truth of what each beam hit, and {args.raw} has "
                             "none (a real scan): drop --plant-only")
        cloud = cloud.plant_only()
    sidecar = {"plantsim_sidecar": 2, "output": str(path), "reconstructed_from": str(args.raw),
               "angle_mode": raw.angle_mode, "scan_info": metadata,
               "frames": {"T_base_lidar": raw.T_base_lidar.tolist()},
               "counts": {**raw.counts(), "points_written": len(cloud)}}
    if filter_report is not None:
        sidecar["range_filter"] = filter_report
    write_cloud(path, cloud, sidecar=sidecar)
    print(f"wrote {len(cloud):,} points from {raw.n_lines} lines x {raw.n_beams} beams ({raw.angle_mode} "
          f"angles) to {path}")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from plantsim.cloud.bag import read_raw
    from plantsim.cloud.calibration import PARAMETERS, calibrate, rig_toml
    from plantsim.cloud.export import write_atomic
    from plantsim.rig.geometry import RigGeometry
    from plantsim.scan.config import config_from_dict, load_toml

    out = Path(args.output)
    if not out.parent.is_dir():
        raise FileNotFoundError(f"output folder does not exist: {out.parent}")
    raw, info = read_raw(args.raw)
    if args.start:
        start = config_from_dict({"rig": load_toml(args.start).get("rig", {})}).rig
    elif "rig" in info.get("config", {}):
        start = config_from_dict({"rig": info["config"]["rig"]}).rig
    else:
        start = RigGeometry()
    result = calibrate(raw, nominal=start, range_offset_m=None if args.range_offset_mm is None
                       else float(args.range_offset_mm) * 1e-3)
    write_atomic(out, rig_toml(result, source=str(args.raw)).encode("utf-8"))
    for name in PARAMETERS:
        unit, factor = ("mm", 1e3) if name.endswith("_m") else ("deg", 1.0)
        print(f"{name:20s} {getattr(result.rig, name) * factor:10.4f} {unit:3s} +- "
              f"{result.std[name] * factor:.3g}  {'observable' if result.observable[name] else 'NOT observable'}"
              f"  (start {getattr(start, name) * factor:.4g})")
    print(f"{result.n_kept:,} of {result.n_points:,} returns on the target, RMS {result.rms_m * 1e3:.2f} mm; "
          f"wrote {out}")
    return 0


def build_parser(*, only_scan: bool = False) -> argparse.ArgumentParser:
    """The ``plantsim`` parser; ``only_scan`` leaves out every command but ``scan`` (their modules
    load the hardware drivers and the sensor fit, which a scan never uses)."""
    parser = argparse.ArgumentParser(
        prog="plantsim", description="Simulate a 2D-LiDAR + turntable plant scanner.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    parser.add_argument("--version", action="version", version=f"plantsim {__import__('plantsim').__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    scan = sub.add_parser("scan", help="scan a plant mesh and write a point cloud",
                          description="Scan a plant mesh (STL/OBJ/PLY) on the simulated rig and "
                                      "write a point cloud (.las .ply .pcd .txt .xyz) with a "
                                      "sidecar JSON beside it.")
    add_common_scan_options(scan)
    scan.add_argument("--mode", choices=["step", "continuous"],
                      help="step: move, settle, scan a line; continuous: the table turns while the "
                           "LiDAR scans (default step)")
    scan.add_argument("--turntable", choices=["ideal", "dynamic"],
                      help="the turntable alone: ideal (a perfect motor and encoder) or dynamic (the "
                           "servo in MuJoCo with its jitter and encoder); default: kinematic step scans, "
                           "dynamic continuous scans, dynamic whenever servo or jitter settings are given")
    scan.add_argument("--physics", choices=["auto", "kinematic", "dynamic"],
                      help="turntable physics (TOML [turntable] physics): auto, kinematic or dynamic")
    scan.add_argument("--rpm", type=float, help="continuous mode's turntable speed, rpm (default 1)")
    scan.add_argument("--evaluate", action="store_true",
                      help="measure the scan against its truth: the plant points' distance to the "
                           "placed mesh, Chamfer distance, coverage and, when an exact-traits file "
                           "(<mesh>.traits.json, as for the bundled plants) sits beside the mesh or the mesh "
                           "names its stem/leaf parts (OBJ o/g names, GLB nodes, PLY face label), "
                           "trait errors; written to the sidecar's \"evaluation\" and timings_s, "
                           "with a picture of the error in OUT.error.png (when EGL or OSMesa is present)")
    scan.add_argument("--fit-rig", action="store_true",
                      help="set the LiDAR's distance from the axis and its height from the placed plant's "
                           "extent (swept radius, height) so it sees the whole plant, and say what was chosen")
    scan.add_argument("--no-pictures", action="store_true",
                      help="with --evaluate: do not draw OUT.error.png")
    scan.set_defaults(func=cmd_scan)
    if only_scan:
        return parser

    reconstruct = sub.add_parser(
        "reconstruct", help="rebuild a point cloud from a raw scan (ROS 2 bag)",
        description="Rebuild the point cloud of a raw record written with --raw (or recorded on a rig with "
                    "the same conventions: sensor_msgs/LaserScan on /scan, the turntable's "
                    "sensor_msgs/JointState on /turntable/joint_states, TF base -> lidar), from what a real "
                    "rig knows: ranges, beam times, encoder readings and the rig geometry.")
    reconstruct.add_argument("raw", metavar="DIR", help="the bag folder")
    reconstruct.add_argument("-o", "--output", required=True, help="output point cloud (.las .ply .pcd .txt .xyz)")
    reconstruct.add_argument("--plant-only", action="store_true",
                             help="only points the ground truth says hit the plant (simulated bags)")
    reconstruct.add_argument("--range-filter", action="store_true",
                             help="denoise the ranges in the range image first (plantsim.cloud.denoise, 7 x 7 "
                                  "beams, the noise measured on the scan)")
    reconstruct.add_argument("--angle-mode", choices=["interpolate", "line", "commanded"],
                             help="override the bag's rule for the turntable angle of each beam")
    reconstruct.add_argument("--rig", metavar="TOML",
                             help="a [rig] section (e.g. from plantsim calibrate) whose geometry and encoder offset "
                                  "replace the bag's")
    reconstruct.set_defaults(func=cmd_reconstruct)

    calibrate = sub.add_parser(
        "calibrate", help="fit the rig geometry to a raw scan of the calibration target",
        description="Estimate the rig geometry (LiDAR distance from the axis, height above the disk, tilt, yaw, "
                    "roll, and the encoder's offset) from a raw scan (--raw, or a rig's bag) of the calibration "
                    "target (plantsim/plant/target.py says how to build it; simulate it with [plant] bundled = "
                    "\"calibration-target\"), and write a [rig] section for plantsim scan --config or "
                    "plantsim reconstruct --rig.")
    calibrate.add_argument("raw", metavar="DIR", help="the bag folder")
    calibrate.add_argument("-o", "--output", required=True, help="the [rig] TOML to write")
    calibrate.add_argument("--start", metavar="TOML",
                           help="a configuration whose [rig] is the starting guess (default: the bag's own "
                                "configuration, else plantsim's default rig)")
    calibrate.add_argument("--range-offset-mm", type=float, default=0.0, nargs="?", const=None,
                           help="the LiDAR's known range offset (plantsim sensor fit's range_bias_m, in mm; "
                                "default 0); give the flag without a value to fit it too (distance far less sure)")
    calibrate.set_defaults(func=cmd_calibrate)

    from plantsim.cli.rig import add_rig_commands
    from plantsim.cli.study import add_study_command

    add_study_command(sub)
    __import__("plantsim.cli.sensor", fromlist=["add_sensor_commands"]).add_sensor_commands(sub)
    add_rig_commands(sub)
    __import__("plantsim.cli.render", fromlist=["add_render_command"]).add_render_command(sub)
    __import__("plantsim.cli.urg", fromlist=["add_urg_commands"]).add_urg_commands(sub)
    __import__("plantsim.cli.traits", fromlist=["add_traits_command"]).add_traits_command(sub)
    __import__("plantsim.cli.plant", fromlist=["add_plant_commands"]).add_plant_commands(sub)
    return parser


def _lean_scan_process(*, draws: bool = False) -> None:
    """Keeps a scan's process from loading what a scan never uses (the command line only).

    On import MuJoCo probes for an OpenGL library for ``mujoco.Renderer`` (with GLFW by
    starting a second Python process, ~40 ms) and laspy imports ``requests`` (~70 ms) to
    read COPC files over HTTP. A scan neither draws nor downloads: unless it will draw
    (``draws``: an evaluated scan's error picture), ``MUJOCO_GL=disable`` is set for this
    process (a user's own setting is left alone), so that if the scan loads MuJoCo at all
    (physics, the MuJoCo caster; a kinematic scan cast with Embree never does) it skips
    the probe; and ``requests`` is marked absent, which laspy handles as an optional
    dependency. Called before anything imports either.
    """
    if not draws and "mujoco" not in sys.modules and "MUJOCO_GL" not in os.environ:
        os.environ["MUJOCO_GL"] = "disable"
    sys.modules.setdefault("requests", None)
    _reuse_freed_memory()


def _reuse_freed_memory() -> None:
    """Lets glibc's malloc keep freed memory for reuse in this (short-lived) process.

    A scan makes and drops arrays of a few megabytes again and again. By default glibc
    maps each of the first ones fresh and hands freed heap back to the kernel, so the
    next array of that size faults its pages in again. Serving blocks below 32 MiB
    (glibc's own ceiling for its adaptive threshold) from the heap and never trimming
    it cut the page faults of a scan of the bundled maize from 27.8k to 21.0k and its
    peak memory from 108 to 96 MB, and ~7 ms of its 0.37 s. Not glibc (macOS, musl):
    nothing is changed.
    """
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc <malloc.h>
    mallopt(M_MMAP_THRESHOLD, 32 << 20)
    mallopt(M_TRIM_THRESHOLD, 1 << 30)


def exit_without_teardown(code: int) -> None:
    """Ends a finished scan's process without dismantling the interpreter (:func:`plantsim.cli.run`).

    The outputs are written, fsynced and moved in by now. What Python would still do is
    run the exit handlers (done here: logging is flushed, the caster's worker threads
    joined, ``weakref.finalize`` callbacks run) and then free every module and object
    one by one, ~10 ms of a 0.37 s scan of the bundled maize for nothing: the kernel
    takes the memory back at once.
    """
    import atexit

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more can be said
            pass
    os._exit(code)


def main(argv: list[str] | None = None) -> int:
    """Runs a command line (``argv``, default the process's own: ``plantsim ...``)."""
    own_process = argv is None
    argv = sys.argv[1:] if own_process else list(argv)
    from plantsim.cli import command_of

    scan_only = command_of(argv) == "scan"
    parser = build_parser(only_scan=scan_only)
    args = parser.parse_args(argv)
    if scan_only and own_process:  # a caller's process (tests, scripts) is left as it is
        _lean_scan_process(draws=bool(_opt(args, "evaluate")))
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="plantsim: %(levelname)s: %(message)s")
    if own_process:
        # What is loaded by now (numpy, the command line) lives as long as the process:
        # moved out of the cyclic collector's way, the collections that the scan's many
        # small objects (the mesh handed to Embree as Python numbers) trigger no longer
        # walk it again and again (~20 ms of a 0.4 s scan). New objects are collected as usual.
        gc.freeze()
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("plantsim: interrupted; nothing was written", file=sys.stderr)
        return 130
    except (PlantSimError, ValueError, FileNotFoundError, OverflowError) as exc:
        print(f"plantsim: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"plantsim: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "),
              file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
