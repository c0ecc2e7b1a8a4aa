"""Default physics timestep: table-angle error against physics run time.

A continuous 1-rpm spin (10 s of rig time after the ramp) and a 10-degree step
move, without jitter and with jitter (cogging ripple 0.02 N m, torque noise
0.01 N m held 4 ms, backlash 0.2 deg), at several timesteps; error is the
largest |table angle - the 5e-5 s reference| over the run (the table angle the
reconstruction needs), time the median physics wall time of 3 runs.

    PYTHONPATH=. python scripts/timestep_study.py
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np

from plantsim.errors import SimulationError
from plantsim.rig.geometry import RigGeometry
from plantsim.turntable.dynamics import JitterConfig, TurntableDynamics, TurntableSim, build_dynamic_scene

TIMESTEPS = [5e-5, 1e-4, 2.5e-4, 5e-4, 1e-3, 2e-3, 4e-3]
JITTERS = {"none": JitterConfig(),
           "jitter": JitterConfig(ripple_torque_nm=0.02, torque_noise_nm=0.01, torque_noise_period_s=4e-3,
                                  backlash_deg=0.2)}
T_END = 10.5


def run(dt: float, jitter: JitterConfig, motion: str) -> tuple[np.ndarray, np.ndarray]:
    dscene = build_dynamic_scene(RigGeometry(), None, TurntableDynamics(timestep_s=dt, jitter=jitter))
    sim = TurntableSim(dscene, np.random.default_rng(0))
    if motion == "spin":
        sim.command(1e3, profile_velocity_rad_s=2 * math.pi / 60)
    else:
        sim.command(math.radians(10))
    sim.advance(int(round(T_END / dt)))
    tr = sim.trajectory()
    return tr.time_s, tr.table_rad


def main() -> None:
    grid = np.linspace(0.5, T_END - 0.01, 20_000)
    print(f"{'jitter':<7} {'motion':<6} {'timestep_s':>10} {'max_err_urad':>13} {'physics_s':>10} {'x real time':>12}")
    for jname, jitter in JITTERS.items():
        for motion in ("spin", "step"):
            t_ref, a_ref = run(TIMESTEPS[0], jitter, motion)
            ref = np.interp(grid, t_ref, a_ref)
            for dt in TIMESTEPS[1:]:
                times = []
                try:
                    for _ in range(3):
                        t0 = time.perf_counter()
                        t, a = run(dt, jitter, motion)
                        times.append(time.perf_counter() - t0)
                except SimulationError as exc:
                    print(f"{jname:<7} {motion:<6} {dt:>10g} refused: {str(exc)[:90]}")
                    continue
                err = np.abs(np.interp(grid, t, a) - ref).max()
                wall = statistics.median(times)
                print(f"{jname:<7} {motion:<6} {dt:>10g} {err * 1e6:>13.2f} {wall:>10.3f} {T_END / wall:>12.0f}")


if __name__ == "__main__":
    main()
