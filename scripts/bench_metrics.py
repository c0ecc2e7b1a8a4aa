"""Time exact point-to-mesh distance for millions of points against ~100k triangles.

Usage:
    PYTHONPATH=. python scripts/bench_metrics.py [--points 1000000 3000000] [--repeats 3]
        [--subdivisions 6] [--noise 0.002] [--mesh PATH.stl]

The mesh is a trimesh icosphere (subdivisions 6: 81,920 triangles; radius 0.3 m) unless
``--mesh`` names a mesh file; points are uniform surface samples pushed off by Gaussian
noise of ``--noise`` metres (near-surface, like a scan). Prints the median of
``--repeats`` runs and points per second; the index build is timed separately.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
import trimesh

from plantsim.evaluation import metrics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, nargs="+", default=[1_000_000, 3_000_000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--subdivisions", type=int, default=6)
    parser.add_argument("--noise", type=float, default=0.002, help="metres")
    parser.add_argument("--mesh", default=None, help="a mesh file instead of the icosphere")
    args = parser.parse_args()

    if args.mesh:
        mesh = trimesh.load_mesh(args.mesh)
        label = args.mesh
    else:
        mesh = trimesh.creation.icosphere(subdivisions=args.subdivisions, radius=0.3)
        label = f"icosphere(subdivisions={args.subdivisions}, radius=0.3 m)"
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"mesh: {label}: {len(faces):,} triangles; cores: {cores}")

    t0 = time.perf_counter()
    prox = metrics.MeshProximity(vertices, faces)
    print(f"index build: {time.perf_counter() - t0:.3f} s")

    rng = np.random.default_rng(0)
    for n in args.points:
        samples, _ = metrics.sample_surface(vertices, faces, n, rng=rng)
        points = samples + rng.normal(scale=args.noise, size=samples.shape)
        times, cpu = [], []
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            result = prox.query(points)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        med = statistics.median(times)
        # CPU seconds (all threads) show the work done when the machine is shared.
        print(
            f"{n:>10,} points: wall median {med:.3f} s over {args.repeats} runs "
            f"(min {min(times):.3f}, max {max(times):.3f}) -> {n / med:,.0f} points/s; "
            f"CPU median {statistics.median(cpu):.3f} s; "
            f"median distance {np.median(result.distance) * 1e3:.3f} mm; "
            f"load average {os.getloadavg()[0]:.1f}"
        )


if __name__ == "__main__":
    main()
