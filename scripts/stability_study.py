"""The numerical-stability matrix of the turntable simulation (issue 4).

Runs every case (PID gains 1e-3..1e4 x default, timesteps 1e-5..1e-2 s, load
inertia 1e-8..1 kg m^2, speeds up to 10 rev/s, integrators Euler, implicitfast,
RK4) and prints one row per case: it either runs stably (finite, no MuJoCo
warning, bounded tracking error) or stops with an error naming cause and fix.
Any other exception is a bug and is reported as CRASH (exit status 1).

    PYTHONPATH=. python scripts/stability_study.py [--csv out.csv]
"""

from __future__ import annotations

import argparse
import csv
import itertools
import sys
import time

from plantsim.turntable.stability import run_case

GAINS = [1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3, 1e4]
TIMESTEPS = [1e-5, 1e-4, 1e-3, 1e-2]
INERTIAS = [1e-8, 1e-4, 1e-2, 1.0]
SPEEDS = [0.01, 0.1, 0.5, 1.0, 10.0]  # rev/s
INTEGRATORS = ["euler", "implicitfast", "rk4"]


def cases():
    # Gains x timestep x integrator at the default load and a slow spin ...
    for g, dt, integ in itertools.product(GAINS, TIMESTEPS, INTEGRATORS):
        yield dict(gain_factor=g, timestep_s=dt, integrator=integ)
    # ... load inertia x timestep x integrator at the default gains ...
    for inertia, dt, integ in itertools.product(INERTIAS, TIMESTEPS, INTEGRATORS):
        yield dict(load_inertia_kg_m2=inertia, timestep_s=dt, integrator=integ)
    # ... speed x extremes of gain and inertia.
    for speed, g, inertia, integ in itertools.product(SPEEDS, [1e-3, 1.0, 1e4], [1e-8, 1.0], INTEGRATORS):
        yield dict(rev_per_s=speed, gain_factor=g, load_inertia_kg_m2=inertia, timestep_s=1e-4,
                   integrator=integ)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--csv", help="also write the table as CSV")
    args = parser.parse_args(argv)
    rows, crashes = [], 0
    t0 = time.perf_counter()
    header = f"{'gain':>7} {'dt_s':>7} {'integrator':>12} {'inertia':>7} {'rev/s':>6}  outcome  max_err_rad  detail"
    print(header)
    for case in cases():
        try:
            out = run_case(**case)
            outcome, message = out.outcome, out.message
        except Exception as exc:  # a bug: report it, keep going  # noqa: BLE001
            crashes += 1
            outcome, message, out = "CRASH", f"{type(exc).__name__}: {exc}", None
        row = {"gain_factor": case.get("gain_factor", 1.0), "timestep_s": case["timestep_s"],
               "integrator": case["integrator"], "load_inertia_kg_m2": case.get("load_inertia_kg_m2", ""),
               "rev_per_s": case.get("rev_per_s", 0.1), "outcome": outcome,
               "max_tracking_error_rad": "" if out is None else out.max_tracking_error_rad,
               "message": message}
        rows.append(row)
        err = row["max_tracking_error_rad"]
        print(f"{row['gain_factor']:>7.0e} {row['timestep_s']:>7.0e} {row['integrator']:>12} "
              f"{str(row['load_inertia_kg_m2']):>7} {row['rev_per_s']:>6}  {outcome:<8} "
              f"{(f'{err:.3g}' if isinstance(err, float) and err == err else '-'):>11}  "
              f"{message.split(';')[0][:90]}")
    counts = {k: sum(r["outcome"] == k for r in rows) for k in ("ok", "refused", "stopped", "error", "CRASH")}
    print(f"\n{len(rows)} cases in {time.perf_counter() - t0:.1f} s: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    if args.csv:
        with open(args.csv, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 1 if crashes else 0


if __name__ == "__main__":
    sys.exit(main())
