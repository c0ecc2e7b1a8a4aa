"""The ``plantsim`` command: parse, call, report. No logic of its own."""

from __future__ import annotations

import argparse
import logging
import sys
import time

from plantsim.errors import PlantSimError
from plantsim.sensor.spec import PRESETS

log = logging.getLogger("plantsim")


def _scan_overrides(args: argparse.Namespace) -> dict:
    """Command-line options as a nested dict in the TOML layout (only those given)."""
    pairs = {
        ("plant", "mesh"): args.mesh, ("plant", "units"): args.units, ("plant", "up"): args.up,
        ("plant", "placement"): args.placement,
        ("scan", "step_deg"): args.step_deg, ("scan", "sweep_deg"): args.sweep_deg,
        ("output", "path"): args.output, ("output", "plant_only"): args.plant_only or None,
        ("seed",): args.seed, ("ideal",): args.ideal or None, ("threads",): args.threads,
        ("turntable", "mode"): args.mode, ("turntable", "rpm"): args.rpm,
        ("turntable", "physics"): args.physics,
        ("turntable", "deskew"): False if args.no_deskew else None,
        ("lidar", "preset"): args.lidar, ("sensor_model", "footprint_rings"): args.footprint_rings,
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


def _progress_bar(total_label: str):
    """A tqdm bar on a terminal, nothing otherwise. Returns (callback, close)."""
    if not sys.stderr.isatty():
        return None, lambda: None
    from tqdm import tqdm

    bar = None

    def update(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(total=total, unit="line", desc=total_label, leave=False, file=sys.stderr)
        bar.update(done - bar.n)

    return update, lambda: bar.close() if bar is not None else None


def cmd_scan(args: argparse.Namespace) -> int:
    from plantsim.scan.config import config_from_dict, load_toml, merge
    from plantsim.cloud.export import check_output_path
    from plantsim.scan.pipeline import run_scan, write_result

    t0 = time.perf_counter()
    data, base_dir = {}, None
    if args.config:
        data = load_toml(args.config)
        from pathlib import Path

        base_dir = Path(args.config).resolve().parent
    overrides = _scan_overrides(args)
    # A mesh given on the command line is relative to the working directory.
    config = config_from_dict(merge(data, overrides), base_dir=base_dir if not args.mesh else None)
    check_output_path(config.output.path)  # Fail before any work, not after it.
    progress, close = _progress_bar("scan")
    try:
        result = run_scan(config, progress=progress)
    finally:
        close()
    if args.evaluate:
        from plantsim.scan.pipeline import with_evaluation

        result = with_evaluation(result)
    path = write_result(result)
    plant_points = result.cloud.counts_by_class()["plant"]
    print(f"wrote {len(result.cloud):,} points ({plant_points:,} on the plant) from "
          f"{result.raw.n_lines} lines x {result.raw.n_beams} beams to {path} in "
          f"{time.perf_counter() - t0:.2f} s")
    if result.evaluation is not None:
        print(_evaluation_line(result.evaluation))
    return 0


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
        text += "; trait errors: " + ", ".join(parts)
    return text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="plantsim", description="Simulate a 2D-LiDAR + turntable plant scanner.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True)

    scan = sub.add_parser("scan", help="scan a plant mesh and write a point cloud",
                          description="Scan a plant mesh (STL/OBJ/PLY) on the simulated rig and "
                                      "write a point cloud (.las .ply .pcd .txt .xyz) with a "
                                      "sidecar JSON beside it.")
    scan.add_argument("mesh", nargs="?", help="plant mesh; default: the bundled maize")
    scan.add_argument("-o", "--output", help="output point cloud (default scan.las)")
    scan.add_argument("--config", help="TOML file with any of the options")
    scan.add_argument("--units", choices=["m", "cm", "mm"], help="the mesh file's unit (default m)")
    scan.add_argument("--up", choices=["x", "y", "z"], help="the mesh file's up axis (default z)")
    scan.add_argument("--placement", choices=["base", "bbox", "none"],
                      help="how the plant sits on the disk (default base: base centred on the axis)")
    scan.add_argument("--step-deg", type=float, help="turntable step, degrees (default 1)")
    scan.add_argument("--sweep-deg", type=float, help="total turn, degrees (default 360)")
    scan.add_argument("--seed", type=int, help="seed of all randomness (default 0)")
    scan.add_argument("--ideal", action="store_true",
                      help="perfect geometry: one ray per beam, no noise, no intensity, no dropouts")
    scan.add_argument("--lidar", choices=sorted(PRESETS),
                      help="sensor preset (default urg-04lx-ug01)")
    scan.add_argument("--footprint-rings", type=int,
                      help="rings of sub-rays per beam footprint: 0 one ray, 1 7, 2 19 (default), 3 37")
    scan.add_argument("--plant-only", action="store_true", help="write only points on the plant")
    scan.add_argument("--threads", type=int, help="ray-casting threads (default: all cores)")
    scan.add_argument("--mode", choices=["step", "continuous"],
                      help="step: move, settle, scan a line; continuous: the table turns while the "
                           "LiDAR scans (default step)")
    scan.add_argument("--physics", choices=["auto", "kinematic", "dynamic"],
                      help="turntable physics: auto (default: kinematic step scans, dynamic continuous "
                           "scans), kinematic, or dynamic (the servo in MuJoCo)")
    scan.add_argument("--rpm", type=float, help="continuous mode's turntable speed, rpm (default 1)")
    scan.add_argument("--no-deskew", action="store_true",
                      help="reconstruct with one angle per line, as a naive rig does")
    scan.add_argument("--evaluate", action="store_true",
                      help="measure the scan against its truth: the plant points' distance to the "
                           "placed mesh, Chamfer distance, coverage and, when an exact-traits file "
                           "(<mesh>.traits.json, as for the bundled plants) sits beside the mesh, "
                           "trait errors; written to the sidecar's \"evaluation\" and timings_s")
    scan.set_defaults(func=cmd_scan)

    from plantsim.cli.rig import add_rig_commands
    from plantsim.cli.study import add_study_command

    add_study_command(sub)
    add_rig_commands(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="plantsim: %(levelname)s: %(message)s")
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
