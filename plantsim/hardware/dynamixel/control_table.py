"""Control tables of the XM430-W350 and XL430-W250, as data.

Datasheets (ROBOTIS e-Manual, firmware 4x):

* XM430-W350, model 1020: https://emanual.robotis.com/docs/en/dxl/x/xm430-w350/
* XL430-W250, model 1060: https://emanual.robotis.com/docs/en/dxl/x/xl430-w250/

Each register carries its address and size exactly as in the datasheet's
"Control Table of EEPROM Area" / "Control Table of RAM Area". Ranges are the static
ones; limits that depend on other registers (Goal Position within the position
limits, Goal PWM within PWM Limit, ...) are checked by whoever writes them.
Indirect addresses (168 onwards) are not listed.
"""

from __future__ import annotations

import dataclasses
from typing import Iterator

EEPROM = "EEPROM"
RAM = "RAM"
R = "R"
RW = "RW"

#: Baud Rate register value -> bits per second (e-Manual, "Baud Rate(8)").
BAUD_RATES_BPS = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}

#: Operating Mode register values (e-Manual, "Operating Mode(11)").
OPERATING_MODES = {
    "current": 0,
    "velocity": 1,
    "position": 3,
    "extended_position": 4,
    "current_based_position": 5,
    "pwm": 16,
}

#: Hardware Error Status bits (e-Manual, "Hardware Error Status(70)").
HARDWARE_ERROR_BITS = {
    0: "input voltage error",
    2: "overheating error",
    3: "motor encoder error",
    4: "electrical shock error",
    5: "overload error",
}


@dataclasses.dataclass(frozen=True)
class Register:
    """One control-table item.

    Attributes:
        name: the datasheet's name, e.g. "Goal Position".
        address: byte address.
        size: 1, 2 or 4 bytes, little endian.
        access: "R" or "RW".
        area: "EEPROM" (writable only with torque off) or "RAM".
        default: factory value, or None where the datasheet gives "-".
        minimum, maximum: valid raw range (signed where ``signed``).
        unit: the raw unit, e.g. "0.229 rpm"; "" when dimensionless.
        signed: True for two's-complement registers.
        allowed: when not None, the only values accepted (e.g. Operating Mode).
    """

    name: str
    address: int
    size: int
    access: str
    area: str
    default: int | None
    minimum: int
    maximum: int
    unit: str = ""
    signed: bool = False
    allowed: tuple[int, ...] | None = None

    def __post_init__(self):
        if self.size not in (1, 2, 4):
            raise ValueError(f"size of {self.name!r} must be 1, 2 or 4, got {self.size}")
        if self.access not in (R, RW):
            raise ValueError(f"access of {self.name!r} must be 'R' or 'RW', got {self.access!r}")
        if self.area not in (EEPROM, RAM):
            raise ValueError(f"area of {self.name!r} must be 'EEPROM' or 'RAM', got {self.area!r}")
        if self.minimum > self.maximum:
            raise ValueError(f"range of {self.name!r} is empty: [{self.minimum}, {self.maximum}]")

    @property
    def writable(self) -> bool:
        return self.access == RW

    def accepts(self, value: int) -> bool:
        """True if ``value`` (signed where the register is) is in the static range."""
        if self.allowed is not None:
            return value in self.allowed
        return self.minimum <= value <= self.maximum


@dataclasses.dataclass(frozen=True)
class ControlTable:
    """A model's control table, looked up by register name or address."""

    model_name: str
    model_number: int
    datasheet: str
    registers: tuple[Register, ...]

    def __post_init__(self):
        names = [r.name for r in self.registers]
        if len(set(names)) != len(names):
            raise ValueError(f"register names of {self.model_name} are not unique")
        occupied: dict[int, str] = {}
        for register in self.registers:
            for address in range(register.address, register.address + register.size):
                if address in occupied:
                    raise ValueError(
                        f"{register.name!r} overlaps {occupied[address]!r} at address {address}"
                    )
                occupied[address] = register.name

    def __getitem__(self, name: str) -> Register:
        for register in self.registers:
            if register.name == name:
                return register
        raise KeyError(f"{self.model_name} has no register {name!r}; valid names: {', '.join(self.names)}")

    def __contains__(self, name: str) -> bool:
        return any(r.name == name for r in self.registers)

    def __iter__(self) -> Iterator[Register]:
        return iter(self.registers)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.registers)

    @property
    def size(self) -> int:
        """Number of bytes from address 0 to the end of the last register."""
        return max(r.address + r.size for r in self.registers)

    def at(self, address: int) -> Register | None:
        """The register starting at ``address``, or None."""
        for register in self.registers:
            if register.address == address:
                return register
        return None

    def covering(self, address: int) -> Register | None:
        """The register whose bytes include ``address``, or None (a reserved gap)."""
        for register in self.registers:
            if register.address <= address < register.address + register.size:
                return register
        return None


_U8, _U16, _U32 = (0, 255), (0, 65535), (0, 4294967295)
_S16 = (-32768, 32767)
_S32 = (-2147483648, 2147483647)


def _reg(name, address, size, access, area, default, value_range, unit="", *, signed=False, allowed=None):
    return Register(name, address, size, access, area, default, value_range[0], value_range[1], unit, signed, allowed)


def _x_series(
    *,
    model_number: int,
    current_sensing: bool,
    position_gains: tuple[int, int, int],
    velocity_gains: tuple[int, int],
    velocity_limit: int,
    voltage_limits: tuple[int, int, int],
    temperature_limit: int,
    goal_pwm_default: int,
    modes: tuple[int, ...],
) -> tuple[Register, ...]:
    p, i, d = position_gains
    v_i, v_p = velocity_gains
    v_max, v_min, v_floor = voltage_limits
    registers = [
        # EEPROM area
        _reg("Model Number", 0, 2, R, EEPROM, model_number, _U16),
        _reg("Model Information", 2, 4, R, EEPROM, 0, _U32),
        _reg("Firmware Version", 6, 1, R, EEPROM, 46, _U8),
        _reg("ID", 7, 1, RW, EEPROM, 1, (0, 252)),
        _reg("Baud Rate", 8, 1, RW, EEPROM, 1, (0, 7)),
        _reg("Return Delay Time", 9, 1, RW, EEPROM, 250, (0, 254), "2 us"),
        _reg("Drive Mode", 10, 1, RW, EEPROM, 0, (0, 13)),
        _reg("Operating Mode", 11, 1, RW, EEPROM, 3, (0, 16), allowed=modes),
        _reg("Secondary ID", 12, 1, RW, EEPROM, 255, (0, 255)),
        _reg("Protocol Type", 13, 1, RW, EEPROM, 2, (1, 2), allowed=(1, 2)),
        _reg("Homing Offset", 20, 4, RW, EEPROM, 0, (-1_044_479, 1_044_479), "1 tick", signed=True),
        _reg("Moving Threshold", 24, 4, RW, EEPROM, 10, (0, 1023), "0.229 rpm"),
        _reg("Temperature Limit", 31, 1, RW, EEPROM, temperature_limit, (0, 100), "1 degC"),
        _reg("Max Voltage Limit", 32, 2, RW, EEPROM, v_max, (v_floor, v_max), "0.1 V"),
        _reg("Min Voltage Limit", 34, 2, RW, EEPROM, v_min, (v_floor, v_max), "0.1 V"),
        _reg("PWM Limit", 36, 2, RW, EEPROM, 885, (0, 885), "0.113 %"),
    ]
    if current_sensing:
        registers.append(_reg("Current Limit", 38, 2, RW, EEPROM, 1193, (0, 1193), "2.69 mA"))
    registers += [
        _reg("Velocity Limit", 44, 4, RW, EEPROM, velocity_limit, (0, 1023), "0.229 rpm"),
        _reg("Max Position Limit", 48, 4, RW, EEPROM, 4095, (0, 4095), "1 tick"),
        _reg("Min Position Limit", 52, 4, RW, EEPROM, 0, (0, 4095), "1 tick"),
        _reg("Shutdown", 63, 1, RW, EEPROM, 52, _U8),
        # RAM area
        _reg("Torque Enable", 64, 1, RW, RAM, 0, (0, 1)),
        _reg("LED", 65, 1, RW, RAM, 0, (0, 1)),
        _reg("Status Return Level", 68, 1, RW, RAM, 2, (0, 2)),
        _reg("Registered Instruction", 69, 1, R, RAM, 0, (0, 1)),
        _reg("Hardware Error Status", 70, 1, R, RAM, 0, _U8),
        _reg("Velocity I Gain", 76, 2, RW, RAM, v_i, (0, 16383)),
        _reg("Velocity P Gain", 78, 2, RW, RAM, v_p, (0, 16383)),
        _reg("Position D Gain", 80, 2, RW, RAM, d, (0, 16383)),
        _reg("Position I Gain", 82, 2, RW, RAM, i, (0, 16383)),
        _reg("Position P Gain", 84, 2, RW, RAM, p, (0, 16383)),
        _reg("Feedforward 2nd Gain", 88, 2, RW, RAM, 0, (0, 16383)),
        _reg("Feedforward 1st Gain", 90, 2, RW, RAM, 0, (0, 16383)),
        _reg("Bus Watchdog", 98, 1, RW, RAM, 0, (0, 127), "20 ms"),
        _reg("Goal PWM", 100, 2, RW, RAM, goal_pwm_default, (-885, 885), "0.113 %", signed=True),
    ]
    if current_sensing:
        registers.append(_reg("Goal Current", 102, 2, RW, RAM, 1193, (-1193, 1193), "2.69 mA", signed=True))
    registers += [
        _reg("Goal Velocity", 104, 4, RW, RAM, 0, (-1023, 1023), "0.229 rpm", signed=True),
        _reg("Profile Acceleration", 108, 4, RW, RAM, 0, (0, 32767), "214.577 rpm^2"),
        _reg("Profile Velocity", 112, 4, RW, RAM, 0, (0, 32767), "0.229 rpm"),
        _reg("Goal Position", 116, 4, RW, RAM, None, (-1_048_575, 1_048_575), "1 tick", signed=True),
        _reg("Realtime Tick", 120, 2, R, RAM, None, (0, 32767), "1 ms"),
        _reg("Moving", 122, 1, R, RAM, 0, (0, 1)),
        _reg("Moving Status", 123, 1, R, RAM, 0, _U8),
        _reg("Present PWM", 124, 2, R, RAM, None, _S16, "0.113 %", signed=True),
    ]
    if current_sensing:
        registers.append(_reg("Present Current", 126, 2, R, RAM, None, _S16, "2.69 mA", signed=True))
    else:
        registers.append(_reg("Present Load", 126, 2, R, RAM, None, (-1000, 1000), "0.1 %", signed=True))
    registers += [
        _reg("Present Velocity", 128, 4, R, RAM, None, _S32, "0.229 rpm", signed=True),
        _reg("Present Position", 132, 4, R, RAM, None, _S32, "1 tick", signed=True),
        _reg("Velocity Trajectory", 136, 4, R, RAM, None, _S32, "0.229 rpm", signed=True),
        _reg("Position Trajectory", 140, 4, R, RAM, None, _S32, "1 tick", signed=True),
        _reg("Present Input Voltage", 144, 2, R, RAM, None, _U16, "0.1 V"),
        _reg("Present Temperature", 146, 1, R, RAM, None, _U8, "1 degC"),
    ]
    return tuple(registers)


XM430_W350 = ControlTable(
    model_name="XM430-W350",
    model_number=1020,
    datasheet="https://emanual.robotis.com/docs/en/dxl/x/xm430-w350/",
    registers=_x_series(
        model_number=1020,
        current_sensing=True,
        position_gains=(800, 0, 0),
        velocity_gains=(1920, 100),
        velocity_limit=200,
        voltage_limits=(160, 95, 95),
        temperature_limit=80,
        goal_pwm_default=885,
        modes=(0, 1, 3, 4, 5, 16),
    ),
)

# The XL430-W250 has no current sensing: no Current Limit / Goal Current, and
# Present Load (0.1 %) at 126 instead of Present Current; no current-based modes.
XL430_W250 = ControlTable(
    model_name="XL430-W250",
    model_number=1060,
    datasheet="https://emanual.robotis.com/docs/en/dxl/x/xl430-w250/",
    registers=_x_series(
        model_number=1060,
        current_sensing=False,
        position_gains=(640, 0, 4000),
        velocity_gains=(1000, 100),
        velocity_limit=265,
        voltage_limits=(140, 60, 60),
        temperature_limit=72,
        goal_pwm_default=885,
        modes=(1, 3, 4, 16),
    ),
)

#: Control tables keyed by the CLI's model names.
CONTROL_TABLES = {"xm430-w350": XM430_W350, "xl430-w250": XL430_W250}

#: Control tables keyed by model number, as PING reports it.
CONTROL_TABLES_BY_NUMBER = {table.model_number: table for table in CONTROL_TABLES.values()}


def control_table(model: str) -> ControlTable:
    """Looks up a control table by model name ("xm430-w350", case-insensitive).

    Raises:
        ValueError: for an unknown model, listing the known ones.
    """
    key = model.lower()
    if key not in CONTROL_TABLES:
        raise ValueError(f"model must be one of {sorted(CONTROL_TABLES)}, got {model!r}")
    return CONTROL_TABLES[key]


def hardware_error_names(status: int) -> list[str]:
    """Names of the bits set in a Hardware Error Status value."""
    return [name for bit, name in HARDWARE_ERROR_BITS.items() if status & (1 << bit)]
