"""Benchmark of a static 1-degree scan: phases, whole process, and the bare cast.

    python scripts/bench_scan.py ../shared/seed-rig/maize.stl --up y

Prints the median of several runs for each phase; the ratio of plantsim's scan
phase to a bare ``mujoco.batch`` cast of the very same rays measured in the
same run; and the wall time of the whole ``plantsim scan`` process
(interpreter start to file written). Targets (issue 2): the whole process
under 2 s on the 2-core machine; the scan phase within 1.25x of the bare cast.
The original ROS/Gazebo tool took about 40 minutes per scan.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import mujoco.batch
import numpy as np

from plantsim.cloud.export import encode_cloud, write_atomic
from plantsim.plant.mesh import load_plant
from plantsim.cloud.reconstruct import reconstruct
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.raw import BeamGrid
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.scan.schedule import StepScan
from plantsim.scan.pipeline import step_and_shoot
from plantsim.rig.scene import LIDAR_GEOMGROUP, build_scene
from plantsim.sensor.spec import URG_04LX_UG01
from benchkit import median_time  # noqa: E402 (scripts/ is on the path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mesh", type=Path, help="plant mesh, e.g. ../shared/seed-rig/maize.stl")
    parser.add_argument("--up", default="y", choices="xyz")
    parser.add_argument("--units", default="m")
    parser.add_argument("--step-deg", type=float, default=1.0)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    if not args.mesh.is_file():
        sys.exit(f"bench_scan: mesh not found: {args.mesh}")

    lidar, rig, schedule = URG_04LX_UG01, RigGeometry(), StepScan(step_deg=args.step_deg)
    n_rays = schedule.n_lines * lidar.n_beams
    print(f"mesh {args.mesh}, {schedule.n_lines} lines x {lidar.n_beams} beams = {n_rays:,} rays, "
          f"{os.cpu_count()} cores, median of {args.runs} runs; load average {os.getloadavg()[0]:.2f} "
          f"(a shared machine: read the ratios, measured under the same load; scripts/bench_peers.py "
          f"alternates the processes and adds MuJoCo-LiDAR)")

    phases = {}
    phases["load_mesh"], plant = median_time(lambda: load_plant(args.mesh, units=args.units, up=args.up), args.runs)
    phases["build_scene"], scene = median_time(lambda: build_scene(rig, plant), args.runs)
    phases["scan"], raw = median_time(lambda: step_and_shoot(scene, lidar, schedule), args.runs)
    phases["reconstruct"], cloud = median_time(lambda: reconstruct(raw), args.runs)
    phases["encode_las"], data = median_time(lambda: encode_cloud("x.las", cloud), args.runs)
    with tempfile.TemporaryDirectory() as tmp:
        phases["write"], _ = median_time(lambda: write_atomic(Path(tmp) / "x.las", data), args.runs)

    # The bare cast: the same rays, the same batch call, none of plantsim's bookkeeping.
    caster = SimulatedLidar(scene, lidar, BeamGrid.of(lidar).beam_angles_rad()).caster
    origin, dirs = caster.origins_base[0], caster.dirs_base
    angles = schedule.angles_rad()
    nthread = os.cpu_count() or 1

    def bare_with_setup():
        batch = mujoco.batch.Batch(scene.model, nsim=len(angles), nthread=nthread)
        batch.bind("qpos")[:, scene.turntable_qpos_adr] = angles
        return batch.ray(origin, dirs, geomgroup=LIDAR_GEOMGROUP, bodyexclude=scene.lidar_body_id)

    batch = mujoco.batch.Batch(scene.model, nsim=len(angles), nthread=nthread)
    batch.bind("qpos")[:, scene.turntable_qpos_adr] = angles
    bare_cast, (dist, geom) = median_time(
        lambda: batch.ray(origin, dirs, geomgroup=LIDAR_GEOMGROUP, bodyexclude=scene.lidar_body_id), args.runs)
    bare_setup, _ = median_time(bare_with_setup, args.runs)
    same = np.array_equal(np.where(dist < 0, -1, geom), raw.geom_id) and np.allclose(
        np.where(raw.status == 0, dist, np.nan), raw.range_m, rtol=1e-7, atol=0, equal_nan=True)

    print("\nphase            median [s]")
    for name, value in phases.items():
        print(f"  {name:<14} {value:8.4f}")
    print(f"  {'total':<14} {sum(phases.values()):8.4f}")
    print(f"\nbare batch.ray (same rays)        {bare_cast:8.4f} s  ({n_rays / bare_cast / 1e6:.2f} M rays/s)")
    print(f"bare batch.ray incl. Batch setup  {bare_setup:8.4f} s")
    print(f"scan phase / bare cast            {phases['scan'] / bare_cast:8.3f}x  (target <= 1.25x)")
    print(f"scan phase / bare cast incl setup {phases['scan'] / bare_setup:8.3f}x")
    print(f"results identical to the bare cast (ranges to float32): {same}")
    hits = (raw.status == 0).mean()
    print(f"returns: {hits:.1%} of beams, {(raw.hit_class[raw.status == 0] == 1).sum():,} on the plant")

    # The whole process, as a user runs it: --ideal is the perfect-geometry
    # scanner timed above; the default run adds the realistic sensor and servo.
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    interpreter = time.perf_counter() - t
    print(f"\nbare interpreter start {interpreter:.3f} s")
    bare = {}
    for flavour in ("typical", "lean"):
        walls = []
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [sys.executable, str(Path(__file__).with_name("bare_mujoco_scan.py")), str(args.mesh.resolve()),
                   args.up, str(args.step_deg), str(Path(tmp) / "points.npy"), flavour]
            for _ in range(args.runs):
                t = time.perf_counter()
                subprocess.run(cmd, check=True, capture_output=True)
                walls.append(time.perf_counter() - t)
        bare[flavour] = statistics.median(walls)
        print(f"bare MuJoCo process, {flavour} (scripts/bare_mujoco_scan.py: MuJoCo loads the STL, casts the "
              f"same scan, the points saved): median {bare[flavour]:.3f} s")
    bare_process = bare["typical"]
    for label, extra in (("plantsim scan --ideal", ["--ideal"]), ("plantsim scan (realistic default)", [])):
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [sys.executable, "-m", "plantsim", "scan", str(args.mesh), "--up", args.up,
                   "--units", args.units, "--step-deg", str(args.step_deg), "-o",
                   str(Path(tmp) / "scan.las"), *extra]
            walls = []
            for _ in range(args.runs):
                t = time.perf_counter()
                subprocess.run(cmd, check=True, capture_output=True)
                walls.append(time.perf_counter() - t)
        wall = statistics.median(walls)
        print(f"whole `{label}` process: median {wall:.3f} s (min {min(walls):.3f}, max {max(walls):.3f}); "
              f"{wall / bare['typical']:.2f}x the typical bare MuJoCo process{' (target <= 0.8x)' if extra else ''}, "
              f"{wall / bare['lean']:.2f}x the lean one; vs the original tool's ~40 min: {40 * 60 / wall:,.0f}x faster")
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
