"""The turntable as a scan session sees it: move to an angle, say where it is.

:class:`Turntable` is the narrow interface; :class:`SimulatedTurntable` is the
kinematic table of a simulated scan (exactly at every commanded angle), and
:class:`plantsim.hardware.dynamixel.turntable.ServoTurntable` is the physical
rig's Dynamixel servo (or the emulator on a pty, which the driver cannot tell
apart from a servo). A scan drives such a table line by line
(:mod:`plantsim.scan.session`).

Angles are the turntable frame's (counter-clockwise from above about +Z, see
:mod:`plantsim.rig.geometry`); on the servo, raw position 0 is angle 0, so the plant's
0-degree face is wherever the servo's zero is (set Homing Offset to move it).
"""

from __future__ import annotations

import logging
import math
from typing import Protocol, runtime_checkable

import numpy as np


log = logging.getLogger(__name__)


@runtime_checkable
class Turntable(Protocol):
    """What a scan session needs from a turntable.

    Attributes:
      kinematic: True when the table is simulated and exactly at every commanded
        angle; a session then time-stamps lines by the schedule instead of the clock.
    """

    kinematic: bool

    def check_angles(self, angles_rad: np.ndarray) -> None:
        """Raises ValueError, before any move, if the table cannot reach these angles."""

    def move_to(self, angle_rad: float) -> float:
        """Turns to ``angle_rad`` and waits until the table is at rest there.

        Returns:
          The angle the table reports afterwards, rad (the scan uses this one).

        Raises:
          HardwareError: the table failed or stopped answering.
        """

    def read_angle_rad(self) -> float:
        """The angle the table reports now, rad."""

    def describe(self) -> dict:
        """JSON-able facts for the sidecar (kind, model, port, ...)."""

    def identity(self) -> dict:
        """The facts that must match for a journal to be resumed on this table.

        The transport (port path, baud) is not part of it: a replugged adapter or a
        restarted emulator gets a new port name.
        """

    def close(self) -> None:
        """Releases the table."""


class SimulatedTurntable:
    """A kinematic turntable: it is exactly where it was told to go."""

    kinematic = True

    def __init__(self, angle_rad: float = 0.0):
        self._angle_rad = float(angle_rad)

    def check_angles(self, angles_rad: np.ndarray) -> None:
        if not np.isfinite(np.asarray(angles_rad, dtype=np.float64)).all():
            raise ValueError("angles_rad must be finite")

    def move_to(self, angle_rad: float) -> float:
        if not math.isfinite(angle_rad):
            raise ValueError(f"angle_rad must be finite, got {angle_rad!r}")
        self._angle_rad = float(angle_rad)
        return self._angle_rad

    def read_angle_rad(self) -> float:
        return self._angle_rad

    def describe(self) -> dict:
        return {"kind": "simulated", "model": "kinematic (exactly at each commanded angle)"}

    def identity(self) -> dict:
        return {"kind": "simulated"}

    def close(self) -> None:
        pass


