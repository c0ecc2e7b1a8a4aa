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


def child_env() -> dict:
    """The environment for a benchmarked child process: this one's, with .pyc files written.

    ``PYTHONDONTWRITEBYTECODE`` (set on some CI machines and containers) makes every
    run compile the package's sources again (~60 ms for plantsim), which no user's
    installed package pays; the peers' packages come with their .pyc files. The warm-up
    run then writes them for every contender alike.
    """
    import os

    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env
