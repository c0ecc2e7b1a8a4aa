"""plantsim's whole scan process against its peers', side by side in one process tree.

    pip install -e '.[bench]'          # mujoco-lidar for its peer script
    python scripts/bench_peers.py /work/shared/seed-rig/maize.stl --up y --runs 7

Each contender is a fresh Python process that scans the same mesh at the same
1-degree steps with the URG-04LX's 683-beam fan and writes its points:

- ``plantsim ideal``: ``python -m plantsim scan MESH --sensor ideal --turntable ideal -o x.las``
  (the perfect sensor and turntable; the rig is in the scene and in the cloud);
- ``bare MuJoCo``: scripts/bare_mujoco_scan.py, typical flavour (one ``mj_multiRay``
  a line) and lean flavour (every line in one ``mujoco.batch`` call, no hull);
- ``MuJoCo-LiDAR CPU``: scripts/mujoco_lidar_scan.py (the package's CPU backend,
  used as its README shows), when ``mujoco-lidar`` is installed;
- ``Helios``: when ``pyhelios3d`` is installed (else it says so).

The runs alternate (A B C A B C ...), so a change of load hits every contender
alike; the medians of wall time and of CPU time (user + system of the child) are
printed with the ratios against the targets: plantsim's ideal process <= 0.8x the
typical bare MuJoCo process (issue 9) and <= 0.8x the MuJoCo-LiDAR CPU script
(issue 16). The machine's load average is printed before and after: on a shared
machine read the ratios, which were measured under the same load, not the seconds.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchkit import child_env  # scripts/ is on the path

HERE = Path(__file__).resolve().parent


def run_once(cmd: list[str]) -> tuple[float, float]:
    """Wall and CPU time (user + system) of one child process, seconds."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=child_env())
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    if proc.returncode != 0:
        sys.exit(f"bench_peers: {' '.join(cmd)} failed ({proc.returncode}):\n{err}")
    return wall, usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mesh", type=Path, help="plant mesh, e.g. /work/shared/seed-rig/maize.stl")
    parser.add_argument("--up", default="y", choices="xyz")
    parser.add_argument("--step-deg", type=float, default=1.0)
    parser.add_argument("--runs", type=int, default=7, help="runs of each contender (median)")
    args = parser.parse_args()
    if not args.mesh.is_file():
        sys.exit(f"bench_peers: mesh not found: {args.mesh}")
    mesh, step, py = str(args.mesh.resolve()), str(args.step_deg), sys.executable

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        contenders = {
            "plantsim ideal": [py, "-m", "plantsim", "scan", mesh, "--up", args.up, "--step-deg", step,
                               "--sensor", "ideal", "--turntable", "ideal", "-o", str(out / "plantsim.las")],
            "bare MuJoCo typical": [py, str(HERE / "bare_mujoco_scan.py"), mesh, args.up, step,
                                    str(out / "bare.npy"), "typical"],
            "bare MuJoCo lean": [py, str(HERE / "bare_mujoco_scan.py"), mesh, args.up, step,
                                 str(out / "lean.npy"), "lean"],
        }
        missing = {}
        if importlib.util.find_spec("mujoco_lidar") is not None:
            contenders["MuJoCo-LiDAR CPU"] = [py, str(HERE / "mujoco_lidar_scan.py"), mesh, args.up, step,
                                              str(out / "mujoco_lidar.npy")]
        else:
            missing["MuJoCo-LiDAR CPU"] = "not installed (pip install 'plantsim[bench]')"
        if importlib.util.find_spec("pyhelios") is None:
            missing["Helios LiDAR plugin"] = "not installed (pyhelios3d; needs its native build)"
        else:
            missing["Helios LiDAR plugin"] = "installed, but no peer script for it here yet"

        print(f"mesh {args.mesh}, {360 / args.step_deg:.0f} lines x 683 beams, {os.cpu_count()} cores, "
              f"{args.runs} alternating runs each; load average {os.getloadavg()[0]:.2f}")
        for name, cmd in contenders.items():  # warm the file cache and the .pyc files
            run_once(cmd)
        walls = {name: [] for name in contenders}
        cpus = {name: [] for name in contenders}
        for _ in range(args.runs):
            for name, cmd in contenders.items():
                wall, cpu = run_once(cmd)
                walls[name].append(wall)
                cpus[name].append(cpu)

    wall = {name: statistics.median(v) for name, v in walls.items()}
    cpu = {name: statistics.median(v) for name, v in cpus.items()}
    print(f"\n{'process':<22} {'wall [s]':>9} {'min':>7} {'max':>7} {'CPU [s]':>9}")
    for name in contenders:
        print(f"{name:<22} {wall[name]:9.3f} {min(walls[name]):7.3f} {max(walls[name]):7.3f} {cpu[name]:9.3f}")
    for name, why in missing.items():
        print(f"{name:<22} {why}")

    me = "plantsim ideal"
    print("\nratios (plantsim ideal / peer)      wall     CPU   target")
    for peer, target in (("bare MuJoCo typical", 0.8), ("bare MuJoCo lean", None), ("MuJoCo-LiDAR CPU", 0.8)):
        if peer not in wall:
            continue
        rw, rc = wall[me] / wall[peer], cpu[me] / cpu[peer]
        verdict = "" if target is None else f"<= {target}x: {'met' if rw <= target else 'NOT met'}"
        print(f"  vs {peer:<31} {rw:6.2f}x {rc:6.2f}x   {verdict}")
    print(f"load average after: {os.getloadavg()[0]:.2f} (1 min), {os.getloadavg()[1]:.2f} (5 min)")


if __name__ == "__main__":
    main()
