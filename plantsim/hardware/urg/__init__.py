"""The Hokuyo URG-04LX LiDAR over SCIP 2.0.

* :mod:`~plantsim.hardware.urg.protocol`: encodings, checksums, commands, replies,
  range decoding and the error-code table, as pure functions; a streaming parser.
* :mod:`~plantsim.hardware.urg.driver`: :class:`UrgLidar` over ``pyserial``.
* :mod:`~plantsim.hardware.urg.emulator`: :class:`UrgEmulator`, the sensor on a pty,
  with :class:`VirtualClock` / :class:`RealTimeClock`.

``pyserial`` is imported only when a port is opened; ``import plantsim`` never
imports this package.
"""

from plantsim.hardware.urg import protocol
from plantsim.hardware.urg.driver import ClockOffset, UrgInfo, UrgLidar, UrgScan, check_model, estimate_offset
from plantsim.hardware.urg.emulator import RealTimeClock, UrgEmulator, VirtualClock, preset_provider, wall_provider

__all__ = [
    "ClockOffset",
    "RealTimeClock",
    "UrgEmulator",
    "UrgInfo",
    "UrgLidar",
    "UrgScan",
    "VirtualClock",
    "check_model",
    "estimate_offset",
    "preset_provider",
    "protocol",
    "wall_provider",
]
