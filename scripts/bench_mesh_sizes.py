"""Where the time of a scan goes as the plant mesh grows (10k to 1M faces).

    python scripts/bench_mesh_sizes.py                      # 10k, 30k, 100k, 300k, 1M faces
    python scripts/bench_mesh_sizes.py --faces 10000 100000 --runs 3

For each size the script makes a procedural plant (curved leaf strips around a
vertical axis, metres, +Z up), writes it as a binary STL in a temporary folder (as
a CAD or photogrammetry export would: every triangle with its own three
vertices), and prints the median time of each phase of an ideal 1-degree step
scan run in this process:

- read: the file to (3 n_faces, 3) vertex rows;
- dedup: vertex de-duplication (``plantsim.plant.mesh.unique_rows``), next to
  ``np.unique(axis=0)`` (what it replaced; the two must give identical output);
- place: the stem-base search of the placement (``find_stem_base``);
- load_plant: read + dedup + checks + placement, as a scan pays it;
- scene: ``build_scene`` for a kinematic scan (token plant inertia), split into the
  MjSpec with the plant mesh and MuJoCo's compile of it, next to the same scene with
  the plant's real shell inertia (what only physics needs);
- caster set-up and the scan itself, with MuJoCo and with Embree;
- reconstruct and encode a PLY;

and then the whole ``plantsim scan MESH --ideal -o x.ply`` process: its own phases
(the sidecar's ``timings_s``, last run), its CPU time (user + system) and its wall
time, with a least-squares fit ``whole = a + b * faces`` over the sizes
(the issue's target: a 1M-face mesh in <= 3 s). Load averages are printed:
the figures mean little on a busy machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from plantsim.cloud.export import encode_cloud
from plantsim.cloud.reconstruct import reconstruct
from plantsim.plant.mesh import _read_arrays, find_stem_base, load_plant, unique_rows
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import build_scene, build_spec
from plantsim.scan.pipeline import step_and_shoot
from plantsim.scan.raw import BeamGrid
from plantsim.scan.schedule import StepScan
from plantsim.sensor.casting import MujocoBackend
from plantsim.sensor.spec import URG_04LX_UG01
from benchkit import child_env, median_time  # noqa: E402 (scripts/ is on the path)

N_LEAVES = 12
ACROSS = 8  # quads across a leaf


def leaf_plant(n_faces: int) -> np.ndarray:
    """A procedural plant of about ``n_faces`` triangles.

    Returns:
      (n_faces', 3, 3) float64 triangle vertices, metres, +Z up, the stem on the Z axis.
    """
    along = max(2, round(n_faces / (2 * ACROSS * N_LEAVES)))
    u = np.linspace(0.0, 1.0, along + 1)[:, None]
    v = np.linspace(-1.0, 1.0, ACROSS + 1)[None, :]
    triangles = []
    for k in range(N_LEAVES):
        phi = 2.399963 * k  # golden angle phyllotaxis
        base_z = 0.02 + 0.25 * k / N_LEAVES
        radial = np.array([np.cos(phi), np.sin(phi), 0.0])
        side = np.array([-np.sin(phi), np.cos(phi), 0.0])
        r = 0.18 * u * (1.0 - 0.2 * k / N_LEAVES)
        z = base_z + 0.15 * u - 0.12 * u * u  # rises, then droops
        half_width = 0.02 * np.sin(np.pi * np.clip(u, 0.02, 0.98)) + 0.001
        twist = 0.6 * u  # the blade rolls along its length
        points = (r[..., None] * radial + (v * half_width * np.cos(twist))[..., None] * side
                  + (z + v * half_width * np.sin(twist))[..., None] * np.array([0.0, 0.0, 1.0]))
        p00, p01 = points[:-1, :-1], points[:-1, 1:]
        p10, p11 = points[1:, :-1], points[1:, 1:]
        triangles.append(np.stack([p00, p10, p11], axis=-2).reshape(-1, 3, 3))
        triangles.append(np.stack([p00, p11, p01], axis=-2).reshape(-1, 3, 3))
    return np.concatenate(triangles)


def write_binary_stl(path: Path, triangles: np.ndarray) -> None:
    record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
    data = np.zeros(len(triangles), dtype=record)
    data["vertices"] = triangles
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    data["normal"] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    with open(path, "wb") as f:
        f.write(b"plantsim bench_mesh_sizes".ljust(80, b" "))
        f.write(np.uint32(len(triangles)).tobytes())
        f.write(data.tobytes())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--faces", type=int, nargs="+", default=[10_000, 30_000, 100_000, 300_000, 1_000_000])
    parser.add_argument("--runs", type=int, default=3, help="runs per phase (median)")
    parser.add_argument("--process-runs", type=int, default=3, help="whole-process runs per size (median)")
    parser.add_argument("--step-deg", type=float, default=1.0)
    args = parser.parse_args()
    try:
        from plantsim.sensor.embree import EmbreeBackend, embree_available
        has_embree = embree_available()
    except ImportError:
        has_embree = False
    lidar, rig, schedule = URG_04LX_UG01, RigGeometry(), StepScan(step_deg=args.step_deg)
    angles = BeamGrid.of(lidar).beam_angles_rad()
    print(f"ideal step scan, {schedule.n_lines} lines x {lidar.n_beams} beams; {os.cpu_count()} cores; "
          f"median of {args.runs} runs per phase; load average {os.getloadavg()[0]:.2f}")

    table = []
    with tempfile.TemporaryDirectory() as tmp:
        for target in args.faces:
            path = Path(tmp) / f"plant_{target}.stl"
            write_binary_stl(path, leaf_plant(target))
            t = {}
            t["read"], (vertices, _) = median_time(lambda: _read_arrays(path), args.runs)
            t["dedup"], (u_new, i_new) = median_time(lambda: unique_rows(vertices), args.runs)
            t["dedup np.unique (old)"], (u_old, i_old) = median_time(
                lambda: np.unique(vertices, axis=0, return_inverse=True), args.runs)
            same = np.array_equal(u_new, u_old) and np.array_equal(i_new, i_old.reshape(-1))
            t["load_plant"], plant = median_time(lambda: load_plant(path), args.runs)
            t["place (stem base)"], _ = median_time(lambda: find_stem_base(plant.vertices_turntable), args.runs)
            t["scene"], scene = median_time(lambda: build_scene(rig, plant), args.runs)
            t["scene: MjSpec"], spec = median_time(
                lambda: build_spec(rig, plant, plant_areal_density_kg_m2=None), args.runs)
            t["scene: MuJoCo compile"], _ = median_time(lambda: build_spec(
                rig, plant, plant_areal_density_kg_m2=None).compile(), args.runs)
            t["scene: MuJoCo compile"] -= t["scene: MjSpec"]
            t["scene with inertia"], _ = median_time(
                lambda: build_scene(rig, plant, plant_areal_density_kg_m2=0.3), args.runs)
            t["caster set-up mujoco"], _ = median_time(lambda: MujocoBackend(scene), args.runs)
            t["scan mujoco"], raw = median_time(lambda: step_and_shoot(scene, lidar, schedule, caster="mujoco"),
                                                args.runs)
            if has_embree:
                t["caster set-up embree"], _ = median_time(lambda: EmbreeBackend(scene), args.runs)
                t["scan embree"], raw_e = median_time(
                    lambda: step_and_shoot(scene, lidar, schedule, caster="embree"), args.runs)
                assert np.array_equal(raw.geom_id, raw_e.geom_id), "Embree and MuJoCo disagree"
            t["reconstruct"], cloud = median_time(lambda: reconstruct(raw), args.runs)
            t["encode ply"], data = median_time(lambda: encode_cloud("x.ply", cloud), args.runs)
            t["write ply"], _ = median_time(lambda: (Path(tmp) / "cloud.ply").write_bytes(data), args.runs)
            del vertices, u_new, i_new, u_old, i_old
            walls, cpus = [], []
            out = Path(tmp) / "x.ply"
            for _ in range(args.process_runs):
                start = time.perf_counter()
                proc = subprocess.Popen([sys.executable, "-m", "plantsim", "scan", str(path), "--up", "z", "--ideal",
                                         "--step-deg", str(args.step_deg), "-o", str(out)],
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=child_env())
                _, status, usage = os.wait4(proc.pid, 0)
                proc.returncode = os.waitstatus_to_exitcode(status)
                if proc.returncode:
                    sys.exit(f"bench_mesh_sizes: plantsim scan {path} failed ({proc.returncode})")
                walls.append(time.perf_counter() - start)
                cpus.append(usage.ru_utime + usage.ru_stime)
            sidecar = json.loads(out.with_name(out.name + ".json").read_text())
            for name, value in sidecar["timings_s"].items():
                t[f"process: {name}"] = value
            t["WHOLE PROCESS (CPU)"] = statistics.median(cpus)
            t["WHOLE PROCESS (wall)"] = statistics.median(walls)
            n_faces = len(plant.faces)
            table.append((n_faces, t))
            print(f"\n{n_faces:,} faces ({len(plant.vertices_turntable):,} vertices), "
                  f"{(raw.hit_class == 1).sum():,} plant hits; dedup identical to np.unique: {same}; "
                  f"load average {os.getloadavg()[0]:.2f}")
            for name, value in t.items():
                print(f"  {name:<24} {value:8.3f} s")
            print(f"  dedup speed-up over np.unique: {t['dedup np.unique (old)'] / t['dedup']:.1f}x; "
                  f"inertia would add {t['scene with inertia'] - t['scene']:+.3f} s")
            path.unlink()

    faces = np.array([n for n, _ in table], dtype=float)
    if len(faces) >= 2:
        print("\nfit over the sizes: phase = a + b * faces")
        for name in table[0][1]:
            y = np.array([t[name] for _, t in table])
            b, a = np.polyfit(faces, y, 1)
            print(f"  {name:<24} a = {a:7.3f} s   b = {b * 1e6:7.3f} us/face   "
                  f"at 1M faces: {a + b * 1e6:6.2f} s")
    print("target: a 1M-face mesh, whole process <= 3 s")


if __name__ == "__main__":
    main()
