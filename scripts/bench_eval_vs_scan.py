"""Evaluation time against scan time for the bundled maize (issue 12 item 3).

Usage:
    PYTHONPATH=. python scripts/bench_eval_vs_scan.py [--steps 1 0.25] [--runs 3] [--threads N]
                                                      [--grid]

For each turntable step and sensor (ideal, realistic), as ``plantsim scan
--evaluate`` runs them: the scan phases (``run_scan``: load, scene, cast,
reconstruct; the sum of its ``timings_s``) and the evaluation (``evaluate_scan``
with the default options: exact cloud->mesh distance through libigl, coverage,
traits against ``maize.traits.json``), each the median of ``--runs`` runs, scan
and evaluation alternating so both see the same machine load. The evaluation is
split into its metrics (distances and coverage, timed again alone) and what the
rest adds (the traits; with two threads or more they run beside the metrics, so
this is less than their own time). The target is evaluation / scan <= 1. The
machine's load average is printed: on a shared machine, compare ratios only.

``--grid`` also times the hand-written grid kernel (the exact reference) on the
same points and prints the largest difference of the two distances.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from plantsim.evaluation import metrics
from plantsim.evaluation.evaluate import EvaluationOptions, evaluate_scan, evaluation_threads
from plantsim.evaluation.study import SCAN_PHASES
from plantsim.scan.config import config_from_dict
from plantsim.scan.pipeline import run_scan


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=float, nargs="+", default=[1.0, 0.25], help="degrees")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="scan and evaluation threads")
    parser.add_argument("--sensors", nargs="+", default=["ideal", "realistic"],
                        choices=["ideal", "realistic"])
    parser.add_argument("--grid", action="store_true", help="also time the grid reference kernel")
    args = parser.parse_args()

    threads = evaluation_threads(args.threads)
    print(f"bundled maize, {os.cpu_count()} cores, {threads} threads, median of {args.runs} runs, "
          f"load average {os.getloadavg()[0]:.1f} at the start")
    print("scan = run_scan's phases; eval = evaluate_scan; metrics = distances + coverage alone; "
          "+traits = eval - metrics; target eval/scan <= 1")
    print(f"{'step deg':>8} {'sensor':>9} {'plant pts':>9} {'scan s':>7} {'eval s':>7} "
          f"{'metrics s':>9} {'+traits s':>9} {'eval/scan':>9}  target")
    for step in args.steps:
        for sensor in args.sensors:
            config = config_from_dict({"scan": {"step_deg": step}, "sensor": sensor,
                                       **({"threads": args.threads} if args.threads else {})})
            scans, evals, mets = [], [], []
            for _ in range(args.runs):
                result = run_scan(config)
                scans.append(sum(result.timings_s.get(k, 0.0) for k in SCAN_PHASES))
                t_eval, ev = timed(lambda: evaluate_scan(result, options=EvaluationOptions()))
                evals.append(t_eval)
                pts = result.cloud.plant_only().points_turntable
                t_met, _ = timed(lambda: metrics.cloud_mesh_metrics(
                    pts, result.plant.vertices_turntable, result.plant.faces,
                    rng=np.random.default_rng(0), workers=threads))
                mets.append(t_met)
            s, e, m = (statistics.median(x) for x in (scans, evals, mets))
            verdict = "ok" if e <= s else "MISSED"
            load = os.getloadavg()[0]
            print(f"{step:8g} {sensor:>9} {len(pts):9,} {s:7.2f} {e:7.2f} {m:9.2f} "
                  f"{max(e - m, 0.0):9.2f} {e / s:9.2f}  {verdict} (load {load:.1f})", flush=True)
            if args.grid:
                grid_reference(pts, result.plant)


def grid_reference(pts, plant) -> None:
    """libigl against the grid kernel on one cloud: time and largest difference."""
    v, f = plant.vertices_turntable, plant.faces
    t_igl, igl_d = timed(lambda: metrics.MeshProximity(v, f, backend="igl").query(pts).distance)
    t_grid, grid_d = timed(lambda: metrics.MeshProximity(v, f, backend="grid").query(pts).distance)
    print(f"{'':8} distances: libigl {t_igl:.2f} s, grid {t_grid:.2f} s, "
          f"max |d_igl - d_grid| {float(np.abs(igl_d - grid_d).max()):.1e} m")


if __name__ == "__main__":
    main()
