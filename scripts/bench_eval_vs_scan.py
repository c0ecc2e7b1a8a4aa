"""Evaluation time against scan time for the bundled maize (issue 12 item 3).

Usage:
    PYTHONPATH=. python scripts/bench_eval_vs_scan.py [--steps 1 0.25] [--runs 3]

For each turntable step: the scan phase (step-and-shoot cast + reconstruction,
ideal sensor) and the evaluation of its plant points (``evaluate_cloud``: exact
cloud->mesh distance, coverage, traits), with the libigl backend and with the
hand-written grid kernel (the reference). Prints medians of ``--runs`` runs and
the ratio evaluation / scan (target: <= 1 with libigl).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

from plantsim.cloud.reconstruct import reconstruct
from plantsim.evaluation import metrics
from plantsim.evaluation.evaluate import EvaluationOptions, evaluate_cloud
from plantsim.plant.mesh import load_plant
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import build_scene
from plantsim.scan.pipeline import step_and_shoot
from plantsim.scan.schedule import StepScan
from plantsim.sensor.spec import URG_04LX_UG01

MAIZE = Path(__file__).resolve().parents[1] / "assets" / "maize.stl"


def median_time(fn, runs):
    times, result = [], None
    for _ in range(runs):
        t = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=float, nargs="+", default=[1.0, 0.25], help="degrees")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--no-realistic", action="store_true",
                        help="skip the realistic-sensor runs (run_one, as plantsim study)")
    args = parser.parse_args()

    plant = load_plant(MAIZE)
    scene = build_scene(RigGeometry(), plant)
    print(f"bundled maize ({len(plant.faces):,} triangles), {os.cpu_count()} cores, "
          f"median of {args.runs} runs")
    print("eval = evaluate_cloud (metrics + traits); metrics = cloud_mesh_metrics alone")
    print(f"{'step deg':>8} {'points':>8} {'scan s':>8} {'eval igl s':>11} {'eval grid s':>12} "
          f"{'metrics igl s':>14} {'metrics grid s':>15} {'eval igl/scan':>14} "
          f"{'metrics igl/scan':>17} {'max |d_igl - d_grid| m':>23}")
    original = metrics.MeshProximity.__init__
    for step in args.steps:
        schedule = StepScan(step_deg=step)

        def scan():
            return reconstruct(step_and_shoot(scene, URG_04LX_UG01, schedule))

        t_scan, cloud = median_time(scan, args.runs)
        pts = cloud.plant_only().points_turntable
        times, dists, mtimes = {}, {}, {}
        for backend in ("igl", "grid"):
            def init(self, *a, _backend=backend, **k):
                original(self, *a, **{**k, "backend": _backend})

            metrics.MeshProximity.__init__ = init
            try:
                times[backend], _ = median_time(
                    lambda: evaluate_cloud(pts, plant, options=EvaluationOptions()), args.runs)
                mtimes[backend], _ = median_time(lambda: metrics.cloud_mesh_metrics(
                    pts, plant.vertices_turntable, plant.faces, rng=0), args.runs)
                dists[backend] = metrics.MeshProximity(plant.vertices_turntable,
                                                       plant.faces).query(pts).distance
            finally:
                metrics.MeshProximity.__init__ = original
        diff = float(abs(dists["igl"] - dists["grid"]).max())
        print(f"{step:8g} {len(pts):8,} {t_scan:8.3f} {times['igl']:11.3f} {times['grid']:12.3f} "
              f"{mtimes['igl']:14.3f} {mtimes['grid']:15.3f} {times['igl'] / t_scan:14.2f} "
              f"{mtimes['igl'] / t_scan:17.2f} {diff:23.2e}")
    if not args.no_realistic:
        realistic(args.steps, args.runs)


def realistic(steps, runs) -> None:
    """As plantsim study runs them: a realistic scan (its phases) and --evaluate's evaluation."""
    from plantsim.evaluation.study import Sweep, run_one

    print("\nrealistic sensor, as plantsim study / scan --evaluate run them (libigl backend)")
    print(f"{'step deg':>8} {'scan phases s':>14} {'evaluation s':>13} {'eval/scan':>10}")
    for step in steps:
        sweep = Sweep(plants=("maize",), grid=(("step_deg", (step,)),))
        run = sweep.runs()[0]
        rows = [run_one(run, sweep.config_data(run), sweep.evaluation) for _ in range(runs)]
        if rows[0].get("error"):
            print(f"{step:8g} failed: {rows[0]['error']}")
            continue
        scan_s = statistics.median(r["wall_time_s"] for r in rows)
        eval_s = statistics.median(r["evaluate_time_s"] for r in rows)
        print(f"{step:8g} {scan_s:14.3f} {eval_s:13.3f} {eval_s / scan_s:10.2f}")


if __name__ == "__main__":
    main()
