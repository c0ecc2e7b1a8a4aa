"""``plantsim study``: error against run time over a grid of settings.

``plantsim.cli`` registers it with :func:`add_study_command`. Examples::

    plantsim study --plant maize --step-deg 4 2 1 0.5 0.25 --ideal-and-realistic \\
        -o docs/error_vs_runtime_maize.csv
    plantsim study --plant maize --plant wheat --step-deg 1 --footprint-rings 0 1 2
    plantsim study --plant maize --range-noise-scale 1 0.5 0.25 0.1   # traits against sensor noise
    plantsim study --plant maize --mode continuous --rpm 0.5 1 2
    plantsim study --plant maize --mode step continuous --step-deg 2 1 --rpm 1 --ideal-and-realistic
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from plantsim.sensor.spec import PRESETS

_DESCRIPTION = """\
Scan one or more plants under every combination of the given settings, measure each
cloud against its mesh (and its traits against the exact traits of the bundled
plants), and write one CSV row per run (settings, wall time, CPU time, simulated rig
time, every metric) and a PNG of error against run time with the Pareto front marked.
Runs go in parallel, one process per core, each casting on one thread.

Settings given with several values are swept; the others keep the defaults of
`plantsim scan` (or of --config). Sensor-only settings (--footprint-rings,
--range-noise-scale) do not apply to ideal runs, which are not repeated for them."""


def _study_overrides(args: argparse.Namespace) -> dict:
    """The fixed (not swept) options, nested as in a TOML file."""
    out: dict = {}
    if args.lidar:
        out["lidar"] = {"preset": args.lidar}
    mode = args.mode[0] if args.mode and len(args.mode) == 1 else None
    turntable = {k: v for k, v in (("mode", mode), ("physics", args.physics)) if v}
    if turntable:
        out["turntable"] = turntable
    plant = {k: v for k, v in (("units", args.units), ("up", args.up)) if v}
    if plant:
        out["plant"] = plant
    if args.ideal:
        out["ideal"] = True
    return out


def cmd_study(args: argparse.Namespace) -> int:
    from plantsim.scan.config import load_toml, merge
    from plantsim.evaluation.evaluate import EvaluationOptions
    from plantsim.cloud.export import write_atomic
    from plantsim.evaluation.study import Sweep, plot_error_vs_time, rows_to_csv, run_study

    from plantsim.validation import require_extra

    # Before any run: a study must not scan for an hour and then fail at the plot.
    require_extra("matplotlib", "plot", "plantsim study's plot")
    base = merge(load_toml(args.config) if args.config else {}, _study_overrides(args))
    grid = [(name, tuple(values)) for name, values in (
        ("mode", args.mode if args.mode and len(args.mode) > 1 else None), ("step_deg", args.step_deg), ("n_beams", args.n_beams),
        ("footprint_rings", args.footprint_rings), ("range_noise_scale", args.range_noise_scale),
        ("timestep_s", args.timestep_s),
        ("rpm", args.rpm), ("seed", args.seed),
        ("ideal", (True, False) if args.ideal_and_realistic else None)) if values]
    sweep = Sweep(plants=tuple(args.plant or ["maize"]), grid=tuple(grid), base=base,
                  evaluation=EvaluationOptions(coverage_distance=args.coverage_mm / 1e3))
    csv_path = Path(args.output)
    png_path = Path(args.png) if args.png else csv_path.with_suffix(".png")
    for path in (csv_path, png_path):
        if not path.parent.is_dir():
            raise FileNotFoundError(f"output folder does not exist: {path.parent}")
    n = len(sweep.runs())
    print(f"study: {n} runs", file=sys.stderr)

    def progress(done: int, total: int, row: dict) -> None:
        what = ", ".join(f"{k} {row[k]}" for k in ("plant", *sweep.setting_names) if row.get(k) is not None)
        figure = (f"error {row['error']}" if row.get("error") else
                  f"{row.get('wall_time_s', float('nan')):.2f} s, Chamfer "
                  f"{row.get('chamfer_m', float('nan')) * 1e3:.3g} mm")
        print(f"[{done}/{total}] {what}: {figure}", file=sys.stderr)

    executor = client = None
    if args.scheduler:
        from plantsim.evaluation.study import dask_executor

        executor, client = dask_executor(args.scheduler)
        print(f"study: on the Dask cluster at {args.scheduler} "
              f"({len(client.scheduler_info().get('workers', {}))} workers)", file=sys.stderr)
    try:
        rows = run_study(sweep, max_workers=args.workers, progress=progress, executor=executor,
                         send_meshes=args.send_meshes, threads_per_run=args.threads_per_run)
    finally:
        if client is not None:
            client.close()
    write_atomic(csv_path, rows_to_csv(rows).encode("utf-8"))
    title = f"{', '.join(Path(p).stem for p in sweep.plants)}: {args.error} against {args.time}"
    write_atomic(png_path, plot_error_vs_time(rows, error=args.error, time=args.time,
                                              setting_names=sweep.setting_names, title=title))
    failed = sum(bool(r.get("error")) for r in rows)
    print(f"wrote {len(rows)} runs to {csv_path} and the plot to {png_path}"
          + (f"; {failed} failed (see the error column)" if failed else ""))
    return 1 if failed else 0


def add_study_command(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Registers ``study`` on the top-level ``subparsers``."""
    study = subparsers.add_parser(
        "study", help="sweep scan settings and plot error against run time",
        description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    study.add_argument("--plant", action="append",
                       help="bundled plant (maize, wheat) or a mesh path; repeat for several "
                            "(default: maize)")
    study.add_argument("-o", "--output", default="study.csv", help="CSV of the runs (default study.csv)")
    study.add_argument("--png", help="the plot (default: the CSV's path with .png)")
    swept = study.add_argument_group("swept settings (one or more values each)")
    swept.add_argument("--step-deg", type=float, nargs="+", help="turntable steps, degrees")
    swept.add_argument("--n-beams", type=int, nargs="+",
                       help="beams per line over the sensor's field of view")
    swept.add_argument("--footprint-rings", type=int, nargs="+",
                       help="footprint sub-ray rings (0: 1 ray, 1: 7, 2: 19); realistic runs only")
    swept.add_argument("--range-noise-scale", type=float, nargs="+",
                       help="the preset's random range noise times each value (0.25: four times quieter); "
                            "realistic runs only")
    swept.add_argument("--timestep-s", type=float, nargs="+",
                       help="servo physics timesteps, s (with --mode continuous or --physics dynamic)")
    swept.add_argument("--rpm", type=float, nargs="+", help="turntable speeds, rpm (with --mode continuous)")
    swept.add_argument("--seed", type=int, nargs="+", help="seeds (repeats of the realistic sensor's noise)")
    sensor = swept.add_mutually_exclusive_group()
    sensor.add_argument("--ideal-and-realistic", action="store_true",
                        help="run every combination with the ideal and with the realistic sensor")
    sensor.add_argument("--ideal", action="store_true", help="ideal sensor only (default: realistic only)")
    fixed = study.add_argument_group("fixed settings")
    fixed.add_argument("--config", help="TOML file with the fixed options (as for plantsim scan)")
    fixed.add_argument("--lidar", choices=sorted(PRESETS), help="sensor preset (default urg-04lx-ug01)")
    fixed.add_argument("--mode", choices=["step", "continuous"], nargs="+",
                       help="turntable mode (default step); both (--mode step continuous) sweeps it: "
                            "--step-deg then applies to the step runs and --rpm to the continuous runs")
    fixed.add_argument("--physics", choices=["auto", "kinematic", "dynamic"], help="turntable physics")
    fixed.add_argument("--units", choices=["m", "cm", "mm"], help="mesh files' unit (default m)")
    fixed.add_argument("--up", choices=["x", "y", "z"], help="mesh files' up axis (default z)")
    measure = study.add_argument_group("measuring and plotting")
    measure.add_argument("--coverage-mm", type=float, default=2.0,
                         help="a mesh point is covered within this distance of the cloud, mm (default 2)")
    measure.add_argument("--error", default="chamfer_m",
                         help="CSV column on the plot's y axis (default chamfer_m; e.g. p95_m, "
                              "height_m_rel_error, leaf_width_m_rel_error)")
    measure.add_argument("--time", default="wall_time_s",
                         help="CSV column on the x axis (default wall_time_s; cpu_time_s, "
                              "simulated_rig_time_s)")
    cluster = study.add_argument_group("where the runs go (default: local processes)")
    cluster.add_argument("--scheduler", metavar="ADDRESS",
                         help="a Dask distributed scheduler, e.g. tcp://10.0.0.5:8786 "
                              "(pip install 'plantsim[cluster]'; see docs/cluster.md)")
    cluster.add_argument("--send-meshes", action="store_true",
                         help="send mesh files with the runs (workers without a shared file system)")
    cluster.add_argument("--threads-per-run", type=int, metavar="N",
                         help="ray-casting threads of each run (default: the worker's cores)")
    measure.add_argument("--workers", type=int,
                         help="parallel runs (default: one per core); 1 runs one after the other")
    study.set_defaults(func=cmd_study)
    return study
