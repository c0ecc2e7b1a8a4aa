"""Benchmark: a continuous 1-rpm scan (one full turn = 60 s of rig time).

Prints the wall time of each phase (scene, physics + casting, reconstruction),
median of several runs, and how much faster than real time it is.

    PYTHONPATH=. python scripts/bench_continuous.py [mesh] [--up y] [--runs 5] [--rpm 1]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from plantsim.turntable.options import TurntableOptions
from plantsim.turntable.motion import continuous_scan
from plantsim.turntable.dynamics import build_dynamic_scene
from plantsim.plant.mesh import load_plant
from plantsim.cloud.reconstruct import reconstruct
from plantsim.rig.geometry import RigGeometry
from plantsim.sensor.spec import PRESETS


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default="/work/shared/seed-rig/maize.stl")
    parser.add_argument("--up", default="y")
    parser.add_argument("--units", default="m")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--rpm", type=float, default=1.0)
    parser.add_argument("--ideal", action="store_true", help="no jitter, exact encoder")
    args = parser.parse_args(argv)

    lidar = PRESETS["urg-04lx-ug01"]
    plant = load_plant(args.mesh, units=args.units, up=args.up)
    options = TurntableOptions(mode="continuous", rpm=args.rpm).effective(args.ideal)
    times = {"build_scene": [], "scan": [], "reconstruct": [], "total": []}
    for run in range(args.runs):
        t0 = time.perf_counter()
        ds = build_dynamic_scene(RigGeometry(), plant, options.dynamics)
        t1 = time.perf_counter()
        result = continuous_scan(ds, lidar, 360.0, options, np.random.default_rng(run))
        t2 = time.perf_counter()
        cloud = reconstruct(result.raw)
        t3 = time.perf_counter()
        for key, value in zip(times, (t1 - t0, t2 - t1, t3 - t2, t3 - t0)):
            times[key].append(value)
    rig_s = float(result.trajectory.time_s[-1])
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"mesh {args.mesh}: {plant.n_faces:,} faces; {result.raw.n_lines} lines x {result.raw.n_beams} "
          f"beams, {len(cloud):,} points, {len(result.trajectory.time_s):,} physics steps")
    print("median of %d runs: " % args.runs + ", ".join(f"{k} {v:.3f} s" for k, v in med.items()))
    print(f"rig time {rig_s:.1f} s -> {rig_s / med['total']:.1f}x faster than real time "
          f"(scan alone {rig_s / med['scan']:.1f}x)")


if __name__ == "__main__":
    main()
