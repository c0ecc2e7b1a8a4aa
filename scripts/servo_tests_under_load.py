"""Runs the hardware tests N times in a row while busy loops load every core; prints a table.

The hardware tests (the Dynamixel servo's, the URG LiDAR's and the rig scans', which
run both emulators on ptys in threads of the test process) are the tests most exposed
to a machine whose cores are busy, the CI's case. This starts one plain
``while True: pass`` process per core, runs

    python -m pytest -q tests/test_dxl_*.py tests/test_urg_*.py tests/test_rig_scan*.py tests/test_rig_urg.py

``--runs`` times in a row, stops the loops and prints one row per run: pass or FAIL,
the pytest summary, the run's duration and the 1-minute load average at its end; then
every failing test of the run with pytest's one-line reason, and a summary (passes,
median duration, and its ratio to an idle run measured first unless ``--no-idle``).

The tests must pass every run: the emulators run on clocks the tests control (the
servo's bus clock: simulated time moves with the exchanges; the LiDAR's clock follows
the servo's), the driver's status timeouts are derived from the protocol plus a
documented scheduler allowance, and what a real driver retries is retried
(docs/servo-timing.md).

Usage::

    python scripts/servo_tests_under_load.py [--runs 10] [--loops 2] [--no-idle] [--pattern GLOB ...]
    python scripts/servo_tests_under_load.py --runs 3 --pattern 'tests/test_rig_scan*.py'
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import statistics
import subprocess
import sys
import time

HARDWARE_TESTS = ["tests/test_dxl_*.py", "tests/test_urg_*.py", "tests/test_rig_scan*.py", "tests/test_rig_urg.py"]


def run_tests(files: list[str]) -> tuple[bool, float, str, list[str]]:
    """Runs pytest once; returns (passed, seconds, summary line, failing tests with their reasons)."""
    start = time.perf_counter()
    # A wide "terminal", so that pytest's summary keeps each failure's reason on its line.
    env = dict(os.environ, COLUMNS="1000")
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-rfE", *files, "-p", "no:cacheprovider"],
                            capture_output=True, text=True, env=env)
    elapsed = time.perf_counter() - start
    lines = result.stdout.splitlines()
    summary = [line.strip("= ") for line in lines if re.search(r"\d+ (passed|failed|error)", line)]
    failed = [line[:600] for line in lines if line.startswith(("FAILED", "ERROR"))]
    return result.returncode == 0, elapsed, (summary[-1] if summary else f"pytest exit {result.returncode}"), failed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--loops", type=int, default=os.cpu_count() or 2, help="busy loops (default: one per core)")
    parser.add_argument("--pattern", nargs="+", default=HARDWARE_TESTS, help="test file globs")
    parser.add_argument("--no-idle", action="store_true", help="skip the reference run on the unloaded machine")
    args = parser.parse_args()
    files = sorted({f for pattern in args.pattern for f in glob.glob(pattern)})
    if not files:
        print(f"no test files match {args.pattern}", file=sys.stderr)
        return 2
    print(f"{len(files)} test files: {' '.join(files)}", flush=True)
    idle_s = None
    if not args.no_idle:
        ok, idle_s, line, failed = run_tests(files)
        print(f"idle: {'pass' if ok else 'FAIL'} in {idle_s:.1f} s ({line}); load {os.getloadavg()[0]:.2f}",
              flush=True)
        for failure in failed:
            print(f"    {failure}", flush=True)
    loops = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.loops)]
    times, passes, failing = [], 0, {}
    print(f"{'run':>3}  {'result':6}  {'seconds':>7}  {'load1':>5}  pytest", flush=True)
    try:
        for run in range(1, args.runs + 1):
            ok, elapsed, line, failed = run_tests(files)
            passes += ok
            times.append(elapsed)
            print(f"{run:3d}  {'pass' if ok else 'FAIL':6}  {elapsed:7.1f}  {os.getloadavg()[0]:5.2f}  {line}",
                  flush=True)
            for failure in failed:
                print(f"     {failure}", flush=True)
                name = failure.split(" - ")[0].split(" ", 1)[-1]
                failing[name] = failing.get(name, 0) + 1
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
    median = statistics.median(times)
    ratio = f" ({median / idle_s:.1f} x the idle run's {idle_s:.1f} s)" if idle_s else ""
    print(f"passed {passes} of {args.runs} runs with {args.loops} busy loops; median {median:.1f} s{ratio}")
    for name, count in sorted(failing.items(), key=lambda item: -item[1]):
        print(f"    failed in {count} run(s): {name}")
    return 0 if passes == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
