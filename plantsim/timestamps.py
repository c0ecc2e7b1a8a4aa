"""Time stamps as a ROS 2 bag stores them: whole nanoseconds, and the one conversion to seconds."""

from __future__ import annotations

import numpy as np


def ns_to_s(ns: np.ndarray) -> np.ndarray:
    """Integer nanoseconds to float64 seconds (the one conversion used everywhere)."""
    return np.asarray(ns, dtype=np.int64) / 1e9


def s_to_ns(seconds: np.ndarray) -> np.ndarray:
    """Float seconds to integer nanoseconds (rounded)."""
    return np.round(np.asarray(seconds, dtype=np.float64) * 1e9).astype(np.int64)
