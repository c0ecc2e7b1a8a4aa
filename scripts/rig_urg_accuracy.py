"""How close the emulated rig (servo + URG emulators, one turntable) comes to the simulated LiDAR.

Runs step and continuous rig scans of an off-axis box on ``EmulatorPair`` (ideal sensor) and
compares every return with the simulated LiDAR cast at that beam's true turntable angle (what
``tests/test_rig_urg.py`` asserts). Prints, per mode, the median over runs of: the largest
angle error of a beam (encoder ticks), the largest point error (mm), and the largest ratio of
point error to the stated tolerance 0.5 mm + rho x (1 tick + omega x u_t).

    python scripts/rig_urg_accuracy.py [--runs 3] [--rpm 12] [--speed-factor 2.5]
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import trimesh

from plantsim.cloud.reconstruct import base_to_turntable, points_base_from_ranges
from plantsim.hardware.dynamixel.turntable import ServoTurntable
from plantsim.hardware.urg import EmulatorPair, UrgLidar, UrgLineSource
from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.scene import build_scene
from plantsim.scan.config import OutputOptions, PlantOptions, RunConfig
from plantsim.scan.continuous_rig import servo_rpm
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from plantsim.turntable.options import TurntableOptions
from plantsim.turntable.units import RAD_PER_TICK


def key(range_m):
    return np.where(np.isnan(range_m), -1, np.round(range_m * 1000)).astype(np.int64).tobytes()


def one_run(mode: str, rpm: float, speed_factor: float) -> tuple[float, float, float, float]:
    mesh = trimesh.creation.box(extents=(0.04, 0.04, 0.25))
    mesh.apply_translation((0.06, 0.0, 0.125))
    plant = plant_from_arrays(mesh.vertices, mesh.faces, placement="none")
    out = Path(tempfile.mkdtemp()) / "plant.las"
    turntable = TurntableOptions(mode="continuous", rpm=rpm) if mode == "continuous" else TurntableOptions()
    config = RunConfig(plant=PlantOptions(placement="none"), turntable=turntable,
                       scan=StepScan(step_deg=30) if mode == "step" else StepScan(),
                       output=OutputOptions(path=str(out)))
    t0 = time.perf_counter()
    with EmulatorPair(build_scene(config.rig, plant), config.lidar, speed_factor=speed_factor, record=True) as pair:
        with ServoTurntable.connect(pair.servo_port, retries=5, profile_velocity_rad_s=3.0,
                                    profile_acceleration_rad_s2=20.0,
                                    driver_options={"status_timeout_s": 2.0}) as table, \
                UrgLidar.connect(pair.lidar_port, preset=config.lidar, host_clock=pair.host_clock,
                                 timeout_s=5.0) as lidar:
            result = run_scan(config, plant=plant, turntable=table, lidar=UrgLineSource(lidar, config.lidar))
    wall = time.perf_counter() - t0
    raw, scans = result.raw, pair.scans
    votes = Counter(round((t[0] - raw.line_time_s[i]) * 1000) for i in range(raw.n_lines)
                    for t, _, lines in scans if key(lines.range_m[0]) == key(raw.range_m[i]))
    offset = votes.most_common(1)[0][0] / 1000
    omega = servo_rpm(rpm) * 2 * math.pi / 60 if mode == "continuous" else 0.0
    timing = (result.diagnostics.get("lidar_clock_uncertainty_s", 0) + 0.5e-3
              + result.diagnostics.get("servo_clock_uncertainty_s", 0)) if mode == "continuous" else 0.0
    worst_ticks = worst_mm = worst_ratio = 0.0
    for i in range(raw.n_lines):
        j = int(np.argmin([abs(t[0] - raw.line_time_s[i] - offset) for t, _, _ in scans]))
        _, true, lines = scans[j]
        ok = raw.status[i] == 0
        a = raw.beam_angle_rad[ok]
        rig = base_to_turntable(points_base_from_ranges(raw.range_m[i][ok], a, raw.T_base_lidar),
                                raw.turntable_angle_rad[i][ok])
        ref = base_to_turntable(points_base_from_ranges(lines.range_m[0][ok], a, raw.T_base_lidar), true[ok])
        error = np.linalg.norm(rig - ref, axis=1)
        tolerance = 0.5e-3 + np.linalg.norm(ref[:, :2], axis=1) * (RAD_PER_TICK + omega * timing)
        worst_ticks = max(worst_ticks, float(np.abs(raw.turntable_angle_rad[i][ok] - true[ok]).max() / RAD_PER_TICK))
        worst_mm = max(worst_mm, float(error.max() * 1e3))
        worst_ratio = max(worst_ratio, float((error / tolerance).max()))
    return worst_ticks, worst_mm, worst_ratio, wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--rpm", type=float, default=12.0)
    parser.add_argument("--speed-factor", type=float, default=2.5)
    args = parser.parse_args()
    print(f"emulated pair vs simulated LiDAR at the true angles; {args.runs} runs, median over runs")
    for mode in ("step", "continuous"):
        rows = [one_run(mode, args.rpm, args.speed_factor) for _ in range(args.runs)]
        med = [statistics.median(col) for col in zip(*rows)]
        print(f"{mode:10s}: worst angle error {med[0]:.2f} ticks, worst point error {med[1]:.2f} mm, "
              f"worst error/tolerance {med[2]:.2f}, wall {med[3]:.1f} s per scan")


if __name__ == "__main__":
    main()
