"""Benchmark: a continuous 1-rpm scan (one full turn = 60 s of rig time).

Prints the wall time of each phase (scene, physics + casting, reconstruction),
median of several runs, and how much faster than real time it is.

    PYTHONPATH=. python scripts/bench_continuous.py [mesh] [--up y] [--runs 5] [--rpm 1]
"""

from __future__ import annotations

import argparse
import statistics
import time


from plantsim.plant.mesh import load_plant
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan, simulated_rig_time_s
from plantsim.sensor.spec import PRESETS
from plantsim.turntable.options import TurntableOptions


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default="/work/shared/seed-rig/maize.stl")
    parser.add_argument("--up", default="y")
    parser.add_argument("--units", default="m")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--rpm", type=float, default=1.0)
    parser.add_argument("--ideal", action="store_true",
                        help="the ideal sensor and a perfect servo (no jitter, exact encoder); default realistic")
    args = parser.parse_args(argv)

    lidar = PRESETS["urg-04lx-ug01"]
    plant = load_plant(args.mesh, units=args.units, up=args.up)
    sensor = "ideal" if args.ideal else "realistic"
    config = RunConfig(sensor=sensor, turntable=TurntableOptions(mode="continuous", rpm=args.rpm,
                                                                 physics="dynamic", ideal=args.ideal))
    phases = ("build_scene", "turntable", "scan", "reconstruct")
    times = {k: [] for k in (*phases, "total")}
    for run in range(args.runs):
        t0 = time.perf_counter()
        result = run_scan(config.replace(seed=run), plant=plant)
        times["total"].append(time.perf_counter() - t0)
        for key in phases:
            times[key].append(result.timings_s[key])
    rig_s = simulated_rig_time_s(result)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"mesh {args.mesh}: {plant.n_faces:,} faces; {sensor} sensor, MuJoCo servo physics; "
          f"{result.raw.n_lines} lines x {result.raw.n_beams} beams, {len(result.cloud):,} points, "
          f"{result.diagnostics['physics_steps']:,} physics steps")
    print("median of %d runs: " % args.runs + ", ".join(f"{k} {v:.3f} s" for k, v in med.items()))
    print(f"rig time {rig_s:.1f} s -> {rig_s / med['total']:.1f}x faster than real time (target >= 20x; "
          f"physics alone {rig_s / med['turntable']:.1f}x, casting alone {rig_s / med['scan']:.1f}x)")


if __name__ == "__main__":
    main()
