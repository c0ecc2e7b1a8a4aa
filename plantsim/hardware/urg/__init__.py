"""The Hokuyo URG-04LX LiDAR over SCIP 2.0.

* :mod:`~plantsim.hardware.urg.protocol`: encodings, checksums, commands, replies,
  range decoding and the error-code table, as pure functions; a streaming parser.
* :mod:`~plantsim.hardware.urg.driver`: :class:`UrgLidar` over ``pyserial``.
* :mod:`~plantsim.hardware.urg.clock`: :class:`VirtualClock` / :class:`RealTimeClock`
  and the host/sensor :class:`ClockOffset`.
* :mod:`~plantsim.hardware.urg.emulator`: :class:`UrgEmulator`, the sensor on a pty.

``pyserial`` is imported only when a port is opened; ``import plantsim`` never
imports this package.
"""

from plantsim.hardware.urg import protocol
from plantsim.hardware.urg.clock import ClockOffset, RealTimeClock, VirtualClock, estimate_offset
from plantsim.hardware.urg.driver import UrgInfo, UrgLidar, UrgScan, check_model
from plantsim.hardware.urg.emulator import UrgEmulator, preset_provider, wall_provider

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
