"""Runs the servo tests repeatedly while busy loops load every core; prints the figures.

The servo tests talk to an emulator thread through a pty and the real SDK, so they
are the tests most exposed to a machine whose cores are busy (the CI's case). This
starts one ``while 1: pass`` process per core, runs

    python -m pytest -q tests/test_dxl_*.py -p no:cacheprovider

``--runs`` times, stops the loops and prints passes, failures and the run times
(median, and the ratio to one run on the idle machine measured first).

Every failing test of a run is printed with pytest's one-line reason. The servo
tests must pass every run: they use the emulator's bus clock (simulated time moves
with the exchanges, not the wall clock) and a scheduler allowance on the driver's
protocol-derived status timeouts, and a status later still is discarded and retried.

Usage::

    python scripts/servo_tests_under_load.py [--runs 10] [--loops 2] [--pattern 'tests/test_dxl_*.py' ...]
    python scripts/servo_tests_under_load.py --runs 3 --pattern 'tests/test_rig_scan*.py'
    python scripts/servo_tests_under_load.py --runs 5 --pattern 'tests/test_urg_*.py'
"""

from __future__ import annotations

import argparse
import glob
import os
import statistics
import subprocess
import sys
import time


def run_tests(files: list[str]) -> tuple[bool, float, str, list[str]]:
    """Runs pytest once; returns (passed, seconds, summary line, failing tests with their reasons)."""
    start = time.perf_counter()
    # A wide "terminal", so that pytest's summary keeps each failure's reason on its line.
    env = dict(os.environ, COLUMNS="1000")
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-rfE", *files, "-p", "no:cacheprovider"],
                            capture_output=True, text=True, env=env)
    elapsed = time.perf_counter() - start
    lines = result.stdout.splitlines()
    summary = [line for line in lines if " passed" in line or " failed" in line or " error" in line]
    failed = [line[:600] for line in lines if line.startswith(("FAILED", "ERROR"))]
    return result.returncode == 0, elapsed, (summary[-1] if summary else f"pytest exit {result.returncode}"), failed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--loops", type=int, default=os.cpu_count() or 2, help="busy loops (default: one per core)")
    parser.add_argument("--pattern", nargs="+", default=["tests/test_dxl_*.py"], help="test file globs")
    args = parser.parse_args()
    files = sorted({f for pattern in args.pattern for f in glob.glob(pattern)})
    if not files:
        print(f"no test files match {args.pattern}", file=sys.stderr)
        return 2
    print(f"{len(files)} test files: {' '.join(files)}", flush=True)
    ok, idle_s, line, failed = run_tests(files)
    print(f"idle: {'pass' if ok else 'FAIL'} in {idle_s:.1f} s ({line})", flush=True)
    for failure in failed:
        print(f"    {failure}", flush=True)
    loops = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(args.loops)]
    times, passes = [], 0
    try:
        for run in range(1, args.runs + 1):
            ok, elapsed, line, failed = run_tests(files)
            passes += ok
            times.append(elapsed)
            print(f"run {run:2d} with {args.loops} busy loops: {'pass' if ok else 'FAIL'} in {elapsed:.1f} s ({line})",
                  flush=True)
            for failure in failed:
                print(f"    {failure}", flush=True)
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
    median = statistics.median(times)
    print(f"passed {passes} of {args.runs} runs under load; median {median:.1f} s "
          f"({median / idle_s:.1f} x the idle run's {idle_s:.1f} s)")
    return 0 if passes == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
