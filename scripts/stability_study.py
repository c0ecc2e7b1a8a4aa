"""The numerical-stability study of the turntable simulation (issues 4 and 14).

Three parts, one row per case; every row is either ok (with its dynamics
diagnostics) or stopped with the simulator's own cause and fix; any other
exception is a bug, reported as CRASH (exit status 1):

1. the matrix: PID gains 1e-3..1e4 x default, timesteps 1e-5..1e-2 s, load
   inertia 1e-8..1 kg m^2, speeds up to 10 rev/s, integrators Euler,
   implicitfast, RK4;
2. the issue-14 cases (S1-S4, C1, C2, U1, F1) at their extremes;
3. a seeded adversarial random search over every setting (gains, I gain
   register, armature, backlash, ripple, torque noise and its period,
   timestep, integrator, load, speed). Each ok row is re-run at a quarter of
   its timestep: a row whose tracking error or table-vs-shaft changes by more
   than 0.02 rad + 20 % is marked SUSPECT (a silent divergence the guards
   missed).

    PYTHONPATH=. python scripts/stability_study.py [--random 150] [--seed 14] [--csv out.csv]
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import sys
import time

from plantsim.turntable.stability import ISSUE_CASES, random_cases, run_case

GAINS = [1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3, 1e4]
TIMESTEPS = [1e-5, 1e-4, 1e-3, 1e-2]
INERTIAS = [1e-8, 1e-4, 1e-2, 1.0]
SPEEDS = [0.01, 0.1, 0.5, 1.0, 10.0]  # rev/s
INTEGRATORS = ["euler", "implicitfast", "rk4"]


def matrix_cases():
    # Gains x timestep x integrator at the default load and a slow spin ...
    for g, dt, integ in itertools.product(GAINS, TIMESTEPS, INTEGRATORS):
        yield f"gain {g:g} dt {dt:g} {integ}", dict(gain_factor=g, timestep_s=dt, integrator=integ)
    # ... load inertia x timestep x integrator at the default gains ...
    for inertia, dt, integ in itertools.product(INERTIAS, TIMESTEPS, INTEGRATORS):
        yield f"load {inertia:g} dt {dt:g} {integ}", dict(load_inertia_kg_m2=inertia, timestep_s=dt,
                                                          integrator=integ)
    # ... speed x extremes of gain and inertia.
    for speed, g, inertia, integ in itertools.product(SPEEDS, [1e-3, 1.0, 1e4], [1e-8, 1.0], INTEGRATORS):
        yield (f"{speed:g} rev/s gain {g:g} load {inertia:g} {integ}",
               dict(rev_per_s=speed, gain_factor=g, load_inertia_kg_m2=inertia, timestep_s=1e-4, integrator=integ))


def _changed(a: float, b: float) -> bool:
    return abs(a - b) > 0.02 + 0.2 * max(abs(a), abs(b))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--random", type=int, default=150, help="cases of the random search")
    parser.add_argument("--seed", type=int, default=14)
    parser.add_argument("--csv", help="also write the table as CSV")
    args = parser.parse_args(argv)
    groups = [("matrix", list(matrix_cases())), ("issue14", list(ISSUE_CASES.items())),
              ("random", [(f"random {k}", c) for k, c in enumerate(random_cases(args.random, args.seed))])]
    rows, crashes, suspects = [], 0, 0
    t0 = time.perf_counter()
    print(f"{'group':<8} {'case':<44} {'outcome':<8} {'track_rad':>9} {'tbl-shft':>9} {'vel_err':>8}  detail")
    for group, cases in groups:
        for name, case in cases:
            try:
                out = run_case(**case)
                outcome, message = out.outcome, out.message
            except Exception as exc:  # a bug: report it, keep going  # noqa: BLE001
                crashes += 1
                outcome, message, out = "CRASH", f"{type(exc).__name__}: {exc}", None
            diag = out.diagnostics if out is not None else {}
            if group == "random" and outcome == "ok" and case["timestep_s"] / 4 >= 1e-6:
                fine = run_case(**{**case, "timestep_s": case["timestep_s"] / 4, "max_steps": 80_000})
                if fine.outcome != "ok":
                    outcome, message = "SUSPECT", f"at timestep/4: {fine.outcome}: {fine.message}"
                elif (_changed(diag["max_tracking_error_rad"], fine.diagnostics["max_tracking_error_rad"])
                      or _changed(diag["max_table_minus_shaft_rad"], fine.diagnostics["max_table_minus_shaft_rad"])):
                    outcome, message = "SUSPECT", (f"at timestep/4 tracking {fine.diagnostics['max_tracking_error_rad']:.3g}"
                                                   f", table-shaft {fine.diagnostics['max_table_minus_shaft_rad']:.3g}")
                suspects += outcome == "SUSPECT"
            rows.append({"group": group, "case": name, **{k: case.get(k, "") for k in
                         ("gain_factor", "timestep_s", "integrator", "load_inertia_kg_m2", "rev_per_s", "armature",
                          "i_gain_register", "backlash_deg", "ripple_torque_nm", "torque_noise_nm",
                          "torque_noise_period_s")},
                         "outcome": outcome, "diagnostics": json.dumps(diag), "message": message})

            def f(key):
                v = diag.get(key)
                return "-" if v is None else f"{v:.3g}"

            print(f"{group:<8} {name[:44]:<44} {outcome:<8} {f('max_tracking_error_rad'):>9} "
                  f"{f('max_table_minus_shaft_rad'):>9} {f('max_table_velocity_error_rad_s'):>8}  "
                  f"{message.split(';')[0][:110]}")
    counts = {k: sum(r["outcome"] == k for r in rows) for k in ("ok", "refused", "stopped", "error", "SUSPECT", "CRASH")}
    print(f"\n{len(rows)} cases in {time.perf_counter() - t0:.1f} s (random search: {args.random}, seed {args.seed}): "
          + ", ".join(f"{k} {v}" for k, v in counts.items()))
    if args.csv:
        with open(args.csv, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 1 if crashes or suspects else 0


if __name__ == "__main__":
    sys.exit(main())
