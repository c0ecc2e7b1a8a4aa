"""Runs the servo tests repeatedly while busy loops load every core; prints the figures.

The servo tests talk to an emulator thread through a pty and the real SDK, so they
are the tests most exposed to a machine whose cores are busy (the CI's case). This
starts one ``while 1: pass`` process per core, runs

    python -m pytest -q tests/test_dxl_*.py -p no:cacheprovider

``--runs`` times, stops the loops and prints passes, failures and the run times
(median, and the ratio to one run on the idle machine measured first).

Usage::

    python scripts/servo_tests_under_load.py [--runs 10] [--loops 2] [--pattern 'tests/test_dxl_*.py']
"""

from __future__ import annotations

import argparse
import glob
import os
import statistics
import subprocess
import sys
import time


def run_tests(files: list[str]) -> tuple[bool, float, str]:
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", *files, "-p", "no:cacheprovider"],
                            capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    summary = [line for line in result.stdout.splitlines() if " passed" in line or " failed" in line]
    failed = [line for line in result.stdout.splitlines() if line.startswith("FAILED")]
    return result.returncode == 0, elapsed, "; ".join(failed + summary[-1:])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--loops", type=int, default=os.cpu_count() or 2, help="busy loops (default: one per core)")
    parser.add_argument("--pattern", default="tests/test_dxl_*.py")
    args = parser.parse_args()
    files = sorted(glob.glob(args.pattern))
    if not files:
        print(f"no test files match {args.pattern}", file=sys.stderr)
        return 2
    ok, idle_s, line = run_tests(files)
    print(f"idle: {'pass' if ok else 'FAIL'} in {idle_s:.1f} s ({line})", flush=True)
    loops = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(args.loops)]
    times, passes = [], 0
    try:
        for run in range(1, args.runs + 1):
            ok, elapsed, line = run_tests(files)
            passes += ok
            times.append(elapsed)
            print(f"run {run:2d} with {args.loops} busy loops: {'pass' if ok else 'FAIL'} in {elapsed:.1f} s ({line})",
                  flush=True)
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
