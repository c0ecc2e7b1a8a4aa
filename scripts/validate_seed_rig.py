"""Validate plantsim against the original ROS/Gazebo rig and its outputs.

    python scripts/validate_seed_rig.py ../shared/seed-rig

Rebuilds the original rig's geometry (../shared/seed-rig/README.md: LiDAR
0.3575 m from the axis and 0.105 m above the disk top, 726 beams over +-130
degrees, 0.08-4 m), scans maize.stl and wheat.stl at 1 degree, and prints, for
our cloud and for the original tool's output, the median, 95th and 99th
percentile and maximum exact distance from each point to the mesh.

The seed-rig files carry no licence: this script reads them where they are and
copies nothing.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from plantsim.plant.mesh import load_plant
from plantsim.evaluation.metrics import point_to_mesh_distance
from plantsim.cloud.reconstruct import reconstruct
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.schedule import StepScan
from plantsim.scan.pipeline import step_and_shoot
from plantsim.rig.scene import build_scene
from plantsim.sensor.spec import LidarSpec
from plantsim.transforms import make_T, rot_x, rot_z

# The original rig, in plantsim's terms (seed-rig README, "Geometry of the original world").
SEED_RIG = RigGeometry(lidar_distance_m=0.3575, lidar_height_m=0.105, disk_radius_m=0.0804)
SEED_LIDAR = LidarSpec(name="gazebo-seed-rig", n_beams=726, angle_min_deg=-130.0,
                       angle_increment_deg=260.0 / 725, range_min_m=0.08, range_max_m=4.0,
                       scan_period_s=1 / 30)
# Mesh (metres, Y up) -> turntable: move the axis/disk-top point to the origin,
# roll +90 deg about X (mesh +Y up), then turn -90 deg about Z so that the
# LiDAR, at mesh +Z from the axis, lies on +X as plantsim's frame has it.
T_TURNTABLE_SEEDMESH = (make_T(rot_z(-math.pi / 2)) @ make_T(rot_x(math.pi / 2))
                        @ make_T(t=[0.0599, -0.1961, -0.2816]))
# The original output's frame: z is world height (disk top at 0.1183 m), the
# profile at angle 0 lies in its x-z plane with the LiDAR towards +x.
SEED_OUTPUT_DISK_TOP_Z = 0.1183


def stats_mm(distance_m: np.ndarray) -> str:
    q = np.percentile(distance_m, [50, 95, 99]) * 1e3
    return (f"median {q[0]:.3g} mm, p95 {q[1]:.3g} mm, p99 {q[2]:.3g} mm, "
            f"max {distance_m.max() * 1e3:.3g} mm  ({len(distance_m):,} points)")


def original_points_turntable(path: Path) -> tuple[np.ndarray, int]:
    table = np.loadtxt(path, delimiter="\t", ndmin=2)
    valid = np.isfinite(table).all(axis=1)
    points = table[valid].copy()
    points[:, 2] -= SEED_OUTPUT_DISK_TOP_Z
    return points, int((~valid).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("seed_rig", type=Path, help="path to ../shared/seed-rig")
    parser.add_argument("--step-deg", type=float, default=1.0)
    args = parser.parse_args()
    if not (args.seed_rig / "maize.stl").is_file():
        sys.exit(f"validate_seed_rig: no maize.stl in {args.seed_rig}")

    for name in ("maize", "wheat"):
        print(f"== {name} ==")
        t = time.perf_counter()
        plant = load_plant(args.seed_rig / f"{name}.stl", T_turntable_mesh=T_TURNTABLE_SEEDMESH)
        raw = step_and_shoot(build_scene(SEED_RIG, plant), SEED_LIDAR, StepScan(step_deg=args.step_deg))
        cloud = reconstruct(raw)
        elapsed = time.perf_counter() - t
        vertices, faces = plant.vertices_turntable, plant.faces
        # Points on the mesh's geom (plant and the mesh's own disk; our disk and rig excluded).
        ours = cloud.plant_only().points_turntable
        print(f"plantsim ({elapsed:.2f} s, {raw.n_lines} x {raw.n_beams} rays): "
              f"{stats_mm(point_to_mesh_distance(ours, vertices, faces).distance)}")
        lo, hi = ours.min(axis=0), ours.max(axis=0)
        print(f"  our cloud spans z {lo[2]:.3f}..{hi[2]:.3f} m (mesh top {vertices[:, 2].max():.3f} m)")
        output = args.seed_rig / f"{name}_scan_1deg.txt"
        if not output.is_file():
            print(f"  (no {output.name}: skipping the original tool's output)")
            continue
        theirs, n_nan = original_points_turntable(output)
        d = point_to_mesh_distance(theirs, vertices, faces).distance
        print(f"original tool, as written: {stats_mm(d)}; {n_nan:,} NaN rows")
        mirrored = theirs * [1.0, -1.0, 1.0]
        print(f"original tool, mirror undone (y -> -y): "
              f"{stats_mm(point_to_mesh_distance(mirrored, vertices, faces).distance)}")
        print(f"  its cloud spans z {theirs[:, 2].min():.3f}..{theirs[:, 2].max():.3f} m "
              f"(range gate cut the top)")


if __name__ == "__main__":
    main()
