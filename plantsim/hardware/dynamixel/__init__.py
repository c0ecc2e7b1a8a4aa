"""Dynamixel Protocol 2.0 layer for the turntable servo (XM430-W350, XL430-W250).

* :mod:`~plantsim.turntable.units`: pure register-unit <-> SI conversions.
* :mod:`~plantsim.hardware.dynamixel.control_table`: the control tables, as data.
* :mod:`~plantsim.hardware.dynamixel.protocol`: CRC, stuffing, packets, a streaming parser.
* :mod:`~plantsim.hardware.dynamixel.emulator`: servos on a pty that the real SDK can open.
* :mod:`~plantsim.hardware.dynamixel.driver`: :class:`DynamixelTurntable`, over ``dynamixel_sdk``.

The SDK itself is imported only when a driver connects, so this package (and the
emulator) work without the ``rig`` extra.
"""

from plantsim.hardware.dynamixel import control_table, protocol
from plantsim.turntable import units
from plantsim.hardware.dynamixel.control_table import CONTROL_TABLES, XL430_W250, XM430_W350, ControlTable, Register
from plantsim.hardware.dynamixel.driver import DynamixelTurntable
from plantsim.hardware.dynamixel.emulator import OVERLOAD, DynamixelEmulator

__all__ = [
    "CONTROL_TABLES",
    "OVERLOAD",
    "XL430_W250",
    "XM430_W350",
    "ControlTable",
    "DynamixelEmulator",
    "DynamixelTurntable",
    "Register",
    "control_table",
    "protocol",
    "units",
]
