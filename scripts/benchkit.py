"""Helpers the benchmark scripts share (run them as `python scripts/<name>.py`)."""

from __future__ import annotations

import statistics
import time


def median_time(fn, runs):
    """Median wall time of ``runs`` calls of ``fn`` and the last call's result."""
    times, result = [], None
    for _ in range(runs):
        t = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), result
