"""Benchmark: a continuous 1-rpm scan (one full turn = 60 s of rig time).

Prints the wall time of each phase (scene, physics + casting, reconstruction),
median of several runs, and how much faster than real time it is; then the
physics alone (the servo turning the table with the plant on it for the same
rig time), stepped in chunks inside MuJoCo (``TurntableSim``, mujoco.rollout)
against the former one ``mj_step`` call per step from Python, measured in the
same run.

    PYTHONPATH=. python scripts/bench_continuous.py [mesh] [--up y] [--runs 5] [--rpm 1]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import mujoco
import numpy as np


from plantsim.plant.mesh import load_plant
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan, sidecar, simulated_rig_time_s
from plantsim.sensor.spec import PRESETS
from plantsim.turntable.dynamics import TurntableSim, build_dynamic_scene, torque_gains
from plantsim.turntable.options import TurntableOptions


TARGET_X = 40.0  # issue #16: a continuous 1-rpm realistic scan at least 40x faster than real time


def per_step_reference(dscene, rpm: float, n: int) -> np.ndarray:
    """The former loop: one mj_step call per physics step, the profile fed per step."""
    sim = TurntableSim(dscene, np.random.default_rng(0))
    profile = sim.command(1e3, profile_velocity_rad_s=rpm * 2 * math.pi / 60)
    m, d = dscene.scene.model, mujoco.MjData(dscene.scene.model)
    g = torque_gains(dscene.dynamics.servo)
    ca, qa, va = dscene.servo_ctrl_adr, dscene.servo_qpos_adr, dscene.servo_dof_adr
    table_qa = int(m.jnt_qposadr[m.joint("turntable").id])
    rec = np.empty((n, 5))
    chunk = 200
    for start in range(0, n, chunk):
        k = min(chunk, n - start)
        t = (start + np.arange(k)) * sim.dt
        p_ref, v_ref, a_ref = profile.sample(t)
        ctrl = np.stack([p_ref, v_ref, g["kff_vel"] * v_ref + g["kff_acc"] * a_ref], axis=1)
        for i in range(k):
            d.ctrl[ca:ca + 3] = ctrl[i]
            mujoco.mj_step(m, d)
            rec[start + i, 1] = d.qpos[table_qa]
            rec[start + i, 2] = d.qpos[qa]
            rec[start + i, 3] = d.qvel[va]
    return rec


def chunked(dscene, rpm: float, n: int) -> np.ndarray:
    sim = TurntableSim(dscene, np.random.default_rng(0))
    sim.command(1e3, profile_velocity_rad_s=rpm * 2 * math.pi / 60)
    sim.advance(n)
    return sim.trajectory().table_rad


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default="/work/shared/seed-rig/maize.stl")
    parser.add_argument("--up", default="y")
    parser.add_argument("--units", default="m")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--rpm", type=float, default=1.0)
    parser.add_argument("--ideal", action="store_true",
                        help="the ideal sensor and a perfect servo (no jitter, exact encoder); default realistic")
    parser.add_argument("--threads", type=int, default=None, help="ray-casting threads (default: every core)")
    args = parser.parse_args(argv)

    lidar = PRESETS["urg-04lx-ug01"]
    plant = load_plant(args.mesh, units=args.units, up=args.up)
    sensor = "ideal" if args.ideal else "realistic"
    config = RunConfig(sensor=sensor, turntable=TurntableOptions(mode="continuous", rpm=args.rpm,
                                                                 physics="dynamic", ideal=args.ideal),
                       threads=args.threads)
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
          f"{result.diagnostics['physics_steps']:,} physics steps; {args.threads or os.cpu_count()} casting "
          f"threads, caster {result.parts['lidar']['ray_caster']}")
    perf = sidecar(result)["performance"]
    print("last run's sidecar performance: " + "; ".join(
        f"{k} {v['s']:.3f} s" + (f" ({v['rays']:,} rays)" if "rays" in v else "")
        for k, v in perf.items() if isinstance(v, dict) and "s" in v))
    print("median of %d runs: " % args.runs + ", ".join(f"{k} {v:.3f} s" for k, v in med.items()))
    speed = rig_s / med["total"]
    print(f"rig time {rig_s:.1f} s -> {speed:.1f}x faster than real time (target >= {TARGET_X:.0f}x: "
          f"{'met' if speed >= TARGET_X else 'NOT met'}; physics alone {rig_s / med['turntable']:.1f}x, "
          f"casting alone {rig_s / med['scan']:.1f}x)")
    print("load average (1, 5, 15 min): " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))

    # Physics alone, the same rig time, without jitter (the deterministic servo), both ways.
    dyn = config.turntable.dynamics.replace(jitter=config.turntable.dynamics.jitter.__class__())
    dscene = build_dynamic_scene(config.rig, plant, dyn)
    n = result.diagnostics["physics_steps"]
    ways = {"per-step (before)": per_step_reference, "chunked (now)": chunked}
    physics = {k: [] for k in ways}
    for run in range(args.runs):
        for name, fn in ways.items():  # alternate, so load changes hit both
            t0 = time.perf_counter()
            fn(dscene, args.rpm, n)
            physics[name].append(time.perf_counter() - t0)
    pmed = {k: statistics.median(v) for k, v in physics.items()}
    print(f"physics alone, {n:,} steps ({n * dyn.timestep_s:.1f} s rig time), median of {args.runs}: "
          + ", ".join(f"{k} {v:.3f} s ({n * dyn.timestep_s / v:.0f}x real time)" for k, v in pmed.items())
          + f"; chunked is {pmed['per-step (before)'] / pmed['chunked (now)']:.2f}x faster")
    print("load average (1, 5, 15 min): " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
