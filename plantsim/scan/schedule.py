"""Scan schedules: which lines a scan takes, and (for a kinematic table) when.

:class:`StepScan` is step-and-shoot: the table turns by ``step_deg``, the LiDAR
takes a line, and so on round ``sweep_deg``. A continuous scan's lines follow
from ``[turntable] rpm`` and the sensor's scan period (see
:mod:`plantsim.turntable.motion`); it uses ``sweep_deg`` alone.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Callable

import numpy as np


log = logging.getLogger(__name__)


Progress = Callable[[int, int], None]

# A bound on lines per scan (0.001 degree steps over a turn), so that a typo cannot
# ask for an endless scan; the plan checks the memory a scan needs as well.
MAX_LINES = 360_000


@dataclasses.dataclass(frozen=True, kw_only=True)
class StepScan:
    """A step-and-shoot schedule (the original tool's mode).

    Attributes:
      step_deg: turntable step between scan lines, degrees (> 0, divides sweep_deg).
      sweep_deg: total turn; lines are taken at 0, step, ..., sweep - step
        (the half-open range: a full 360 does not repeat angle 0).
      step_time_s: time from one line's start to the next (move, settle and
        one scan); must be at least the sensor's scan period.
    """

    step_deg: float = 1.0
    sweep_deg: float = 360.0
    step_time_s: float = 0.5

    def __post_init__(self):
        for field in ("step_deg", "sweep_deg", "step_time_s"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{field} must be a finite number, got {value!r}")
            if value <= 0:
                raise ValueError(f"{field} must be > 0, got {value}")
        if self.sweep_deg > 360:
            raise ValueError(f"sweep_deg must be at most 360 (one turn; more scans every angle again), "
                             f"got {self.sweep_deg:g}")
        n = self.sweep_deg / self.step_deg
        if n > MAX_LINES:
            raise ValueError(f"step_deg = {self.step_deg:g} makes {n:.3g} lines over {self.sweep_deg:g} deg, more "
                             f"than {MAX_LINES:,}; use step_deg >= {self.sweep_deg / MAX_LINES:.3g}")
        if abs(n - round(n)) > 1e-9 * max(1.0, n) or round(n) < 1:
            raise ValueError(
                f"step_deg must divide sweep_deg evenly, got step_deg={self.step_deg} and "
                f"sweep_deg={self.sweep_deg} ({n:.4g} steps); try step_deg="
                f"{self.sweep_deg / max(1, round(n)):.6g}")

    @property
    def n_lines(self) -> int:
        return int(round(self.sweep_deg / self.step_deg))

    def angles_rad(self) -> np.ndarray:
        """Commanded turntable angles. Returns (n_lines,) float64, radians."""
        return np.deg2rad(self.step_deg * np.arange(self.n_lines))












