"""The physical rig's turntable: a Dynamixel servo behind the :class:`~plantsim.turntable.table.Turntable` interface."""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np

from plantsim.errors import HardwareError
from plantsim.hardware.dynamixel import control_table as ct
from plantsim.turntable import units

log = logging.getLogger(__name__)

# Realtime Tick wraps at 32768 ms (e-Manual, "Realtime Tick(120)").
_TICK_PERIOD_MS = 32768
# Host pause between two reads while a finished move settles, s (not a measure of
# time: the servo's clock is).
_REST_POLL_S = 0.002
# The span status() reads in one exchange: Torque Enable (64) .. Present Temperature (146).
_STATUS_REGISTERS = ("Torque Enable", "Hardware Error Status", "Moving", "Present Velocity",
                     "Present Position", "Present Input Voltage", "Present Temperature")

_TORQUE_ADVICE = ("switch off the servo's 12 V supply now: the turntable may still be powered and "
                  "can hold or move the plant")


@dataclasses.dataclass(frozen=True)
class ServoStatus:
    """What the servo reports, in SI units (one :meth:`ServoTurntable.status` call).

    Attributes:
        position_rad: present position, rad (raw 0 = 0 rad).
        velocity_rad_s: present velocity, rad/s.
        temperature_c: internal temperature, degC.
        input_voltage_v: supply voltage at the servo, V.
        current_a: motor current, A (None on the XL430, which has no current sensor).
        load_percent: load, % of the maximum (XL430: Present Load; XM430: present
            current over the Current Limit), signed with the direction of torque.
        hardware_errors: names of the Hardware Error Status bits set (empty when fine).
        torque_enabled: True when the motor is powered.
        moving: the servo's Moving flag.
    """

    position_rad: float
    velocity_rad_s: float
    temperature_c: float
    input_voltage_v: float
    current_a: float | None
    load_percent: float
    hardware_errors: tuple[str, ...]
    torque_enabled: bool
    moving: bool


class ServoTurntable:
    """The physical rig's turntable: a Dynamixel servo in position mode.

    Use :meth:`connect`, or wrap a connected, configured driver whose torque is on.

    Args:
      driver: a connected :class:`~plantsim.hardware.dynamixel.DynamixelTurntable`.
      move_timeout_s: limit of one move on the servo's own clock (Realtime Tick), s.
      tolerance_rad: accepted final position error of a move, rad (default two
        encoder ticks: the factory P-only gains can stop a tick short against friction).
      stable_interval_s: after a move, the position must read the same tick twice
        this far apart on the servo's clock before the angle is reported (the servo
        clears its Moving flag below 1.4 deg/s, while the shaft can still creep the
        last tick).
    """

    kinematic = False

    def __init__(self, driver, *, move_timeout_s: float = 30.0,
                 tolerance_rad: float = 2 * units.RAD_PER_TICK, stable_interval_s: float = 0.02):
        for name, value in (("move_timeout_s", move_timeout_s), ("tolerance_rad", tolerance_rad),
                            ("stable_interval_s", stable_interval_s)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        self.driver = driver
        self.move_timeout_s = move_timeout_s
        self.tolerance_rad = tolerance_rad
        self.stable_interval_s = stable_interval_s
        self._closed_safe = False  # close() confirmed the torque off
        self._current_limit: int | None = None  # Current Limit register, read once by status()

    @classmethod
    def connect(cls, port: str, *, baud_bps: int = 57_600, dxl_id: int = 1, model: str = "xm430-w350",
                retries: int = 2, profile_velocity_rad_s: float = 0.5,
                profile_acceleration_rad_s2: float = 2.0, safety=None, driver_options: dict | None = None,
                **options) -> "ServoTurntable":
        """Connects to the servo, configures a gentle profile and switches torque on.

        The servo's factory gains are kept; only the profile (velocity and
        acceleration caps, so the plant is not shaken) and position mode are set.

        Args:
          port: serial port (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, an emulator's pty).
          baud_bps, dxl_id, model: as the servo is set up (factory: 57600, 1).
          retries: repeats of a read or register write whose status packet was lost.
          profile_velocity_rad_s: the move's velocity cap, rad/s.
          profile_acceleration_rad_s2: the move's acceleration, rad/s^2.
          safety: a :class:`~plantsim.hardware.safety.SafeStop` to register the servo's
            stop action with, as soon as the port is open (before torque comes on).
          driver_options: more keyword arguments of
            :class:`~plantsim.hardware.dynamixel.driver.DynamixelTurntable`
            (``status_timeout_s``, ``allow_reboot``).
          **options: ``move_timeout_s``, ``tolerance_rad``.

        Raises:
          HardwareError: the servo cannot be reached or refuses the configuration.
        """
        from plantsim.turntable import servo
        from plantsim.hardware.dynamixel.driver import DynamixelTurntable

        driver_options = dict(driver_options or {})
        base = servo.ServoConfig.xl430_w250 if model == "xl430-w250" else servo.ServoConfig.xm430_w350
        config = base(profile_velocity=profile_velocity_rad_s,
                      profile_acceleration=profile_acceleration_rad_s2)
        driver = DynamixelTurntable(model=model, retries=retries, **driver_options)
        table = cls(driver, **options)  # validates the options before the port is opened
        driver.connect(port, baud_bps=baud_bps, dxl_id=dxl_id)
        if safety is not None:
            # Registered before torque can come on: a Ctrl-C from here on is covered.
            safety.register(table.stop_action())
        try:
            driver.configure(config, operating_mode="position")
            driver.torque_on()
            return table
        except BaseException:
            table.close()  # torque off (read back), port released
            raise

    def check_angles(self, angles_rad: np.ndarray) -> None:
        angles_rad = np.asarray(angles_rad, dtype=np.float64)
        ticks = units.rad_to_ticks(angles_rad)
        low = self.driver.read_register("Min Position Limit")
        high = self.driver.read_register("Max Position Limit")
        if len(ticks) and (ticks.min() < low or ticks.max() > high):
            raise ValueError(
                f"the scan's angles span [{math.degrees(angles_rad.min()):.2f}, "
                f"{math.degrees(angles_rad.max()):.2f}] deg, but the servo's position limits are "
                f"[{math.degrees(units.ticks_to_rad(low)):.2f}, {math.degrees(units.ticks_to_rad(high)):.2f}] "
                "deg; use sweep_deg <= 360 (one turn in position mode)")

    def move_to(self, angle_rad: float) -> float:
        angle = self.driver.move_to(angle_rad, timeout_s=self.move_timeout_s, tolerance_rad=self.tolerance_rad)
        # Judged on the servo's clock (Realtime Tick, read with the position in one
        # exchange), not the host's: a host kept waiting by its scheduler must not
        # take two reads a scheduler-delay apart for two reads stable_interval_s apart.
        first = self._tick_and_position()
        start_ms, since_ms = first[0], 0
        reference_ms, reference_ticks = first
        while True:
            time.sleep(_REST_POLL_S)
            tick_ms, ticks = self._tick_and_position()
            since_ms = (tick_ms - start_ms) % _TICK_PERIOD_MS
            if ticks != reference_ticks:
                reference_ms, reference_ticks = tick_ms, ticks
            elif (tick_ms - reference_ms) % _TICK_PERIOD_MS >= 1e3 * self.stable_interval_s:
                return units.ticks_to_rad(ticks)
            if since_ms > 1e3 * self.move_timeout_s:
                raise HardwareError(
                    f"servo ID {self.driver.dxl_id} on {self.driver.port_name} does not come to rest at "
                    f"{angle_rad:.4f} rad (reached {angle:.4f}, now {units.ticks_to_rad(ticks):.4f} rad; not "
                    f"the same tick for {self.stable_interval_s} s) within {self.move_timeout_s} s; check for a "
                    "loose coupling, a swinging load or too low a Position P Gain")

    def _tick_and_position(self) -> tuple[int, int]:
        values = self.driver.read_registers("Realtime Tick", "Present Position")
        return values["Realtime Tick"], values["Present Position"]

    def read_angle_rad(self) -> float:
        return self.driver.position()

    def describe(self) -> dict:
        d = self.driver
        return {"kind": "dynamixel", "model": d.table.model_name, "model_number": d.table.model_number,
                "firmware": d.firmware_version, "port": d.port_name, "baud_bps": d.baud_bps,
                "id": d.dxl_id, "tolerance_rad": self.tolerance_rad,
                "encoder_rad_per_tick": units.RAD_PER_TICK}

    def identity(self) -> dict:
        return {"kind": "dynamixel", "model": self.driver.table.model_name, "id": self.driver.dxl_id}

    # --- what a user reads on the rig -------------------------------------------------

    def velocity_rad_s(self) -> float:
        """Present velocity, rad/s."""
        return self.driver.velocity()

    def temperature_c(self) -> float:
        """Internal temperature, degC (the servo shuts down at its Temperature Limit, 80 degC)."""
        return self.driver.temperature()

    def input_voltage_v(self) -> float:
        """Supply voltage at the servo, V."""
        return 0.1 * self.driver.read_register("Present Input Voltage")

    def current_a(self) -> float | None:
        """Motor current, A; None on a model without a current sensor (XL430)."""
        if "Present Current" not in self.driver.table:
            return None
        return self.driver.current()

    def load_percent(self) -> float:
        """Load, % of the maximum, signed (XL430: Present Load; XM430: current / Current Limit)."""
        table = self.driver.table
        if "Present Load" in table:
            return 0.1 * self.driver.read_register("Present Load")
        limit = self.driver.read_register("Current Limit")
        return 100.0 * self.driver.read_register("Present Current") / limit if limit else math.nan

    def hardware_errors(self) -> tuple[str, ...]:
        """Names of the Hardware Error Status bits set (overload, overheating, ...); empty when fine."""
        return tuple(ct.hardware_error_names(self.driver.hardware_error_status()))

    def torque_enabled(self) -> bool:
        """True when the servo's motor is powered (Torque Enable read back)."""
        return self.driver.torque_enabled()

    def status(self) -> ServoStatus:
        """Everything above in one record, read in one exchange (one instant's values).

        One READ spans Torque Enable (64) .. Present Temperature (146), 83 bytes: the
        X series has no bulk read of scattered registers from one servo that the
        emulator and every firmware answer (FAST_BULK_READ needs firmware 46+ and
        still takes one span per ID). The XM430's Current Limit (EEPROM, for
        ``load_percent``) is read once and kept; :meth:`invalidate` forgets it.
        """
        table = self.driver.table
        names = _STATUS_REGISTERS + (("Present Current",) if "Present Current" in table else ("Present Load",))
        raw = self.driver.read_registers(*names)
        if "Present Current" in raw:
            if self._current_limit is None:
                self._current_limit = self.driver.read_register("Current Limit")
            current_a = units.current_units_to_a(raw["Present Current"])
            load_percent = (100.0 * raw["Present Current"] / self._current_limit if self._current_limit
                            else math.nan)
        else:
            current_a, load_percent = None, 0.1 * raw["Present Load"]
        return ServoStatus(
            position_rad=units.ticks_to_rad(raw["Present Position"]),
            velocity_rad_s=units.velocity_units_to_rad_s(raw["Present Velocity"]),
            temperature_c=float(raw["Present Temperature"]),
            input_voltage_v=0.1 * raw["Present Input Voltage"],
            current_a=current_a, load_percent=load_percent,
            hardware_errors=tuple(ct.hardware_error_names(raw["Hardware Error Status"])),
            torque_enabled=raw["Torque Enable"] == 1, moving=raw["Moving"] == 1)

    def invalidate(self) -> None:
        """Forgets the cached Current Limit (call after writing it through the driver)."""
        self._current_limit = None

    # --- safety -----------------------------------------------------------------------

    def stop_action(self):
        """The servo's :class:`~plantsim.hardware.safety.StopAction` for a :class:`~plantsim.hardware.safety.SafeStop`.

        Stop: torque off, after freeing a port an interrupted call left busy (and
        reconnecting after a lost link). Verify: Torque Enable read back as 0.
        """
        from plantsim.hardware.safety import StopAction

        def stop() -> None:
            if not self._closed_safe:
                self.driver.emergency_stop()

        def verify() -> bool:
            return self._closed_safe or not self.driver.torque_enabled()

        return StopAction("servo torque", stop, verify, advice=_TORQUE_ADVICE)

    def close(self) -> bool:
        """Switches torque off, reads it back (3 tries) and releases the port.

        Returns:
            True when Torque Enable read back 0. False (logged as an error) when it
            could not be confirmed: use a :class:`~plantsim.hardware.safety.SafeStop`
            to tell the user.
        """
        confirmed = False
        self._closed_safe = False
        if self.driver.connected:
            for attempt in range(1, 4):
                try:
                    self.driver.emergency_stop()
                    if not self.driver.torque_enabled():
                        confirmed = True
                        break
                except HardwareError as exc:
                    log.warning("torque off on close, attempt %d of 3: %s", attempt, exc)
            if not confirmed:
                log.error("servo ID %s on %s: torque NOT confirmed off; %s", self.driver.dxl_id,
                          self.driver.port_name, _TORQUE_ADVICE)
        self.driver.close()
        self._closed_safe = confirmed
        return confirmed

    def __enter__(self) -> "ServoTurntable":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
