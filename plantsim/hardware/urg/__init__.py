"""The Hokuyo URG-04LX LiDAR over SCIP 2.0.

* :mod:`~plantsim.hardware.urg.protocol`: encodings, checksums, commands, replies,
  range decoding and the error-code table, as pure functions; a streaming parser.
* :mod:`~plantsim.hardware.urg.driver`: :class:`UrgLidar` over ``pyserial``.
* :mod:`~plantsim.hardware.urg.clock`: :class:`VirtualClock` / :class:`RealTimeClock`
  and the host/sensor :class:`ClockOffset`.
* :mod:`~plantsim.hardware.urg.emulator`: :class:`UrgEmulator`, the sensor on a pty.
* :mod:`~plantsim.hardware.urg.source`: :class:`UrgLineSource`, the sensor as a line
  source of the scan pipeline (``run_scan(config, turntable=..., lidar=...)``).
* :mod:`~plantsim.hardware.urg.pair`: :class:`EmulatorPair`, the emulated rig: the
  servo and the URG emulators sharing one turntable and one clock.

``pyserial`` is imported only when a port is opened; ``import plantsim`` never
imports this package.
"""

from plantsim.hardware.urg import protocol
from plantsim.hardware.urg.clock import ClockOffset, RealTimeClock, VirtualClock, estimate_offset
from plantsim.hardware.urg.driver import UrgInfo, UrgLidar, UrgScan, check_model
from plantsim.hardware.urg.emulator import UrgEmulator, preset_provider, wall_provider
from plantsim.hardware.urg.pair import EmulatorPair, ServoSimClock, TurntableHistory, turntable_provider
from plantsim.hardware.urg.source import UrgLine, UrgLineSource

__all__ = [
    "ClockOffset",
    "EmulatorPair",
    "ServoSimClock",
    "TurntableHistory",
    "RealTimeClock",
    "UrgEmulator",
    "UrgInfo",
    "UrgLidar",
    "UrgLine",
    "UrgLineSource",
    "UrgScan",
    "VirtualClock",
    "check_model",
    "estimate_offset",
    "preset_provider",
    "protocol",
    "turntable_provider",
    "wall_provider",
]
