"""The physical rig's turntable: a Dynamixel servo behind the :class:`~plantsim.turntable.table.Turntable` interface."""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from plantsim.errors import HardwareError
from plantsim.turntable import units

log = logging.getLogger(__name__)


class ServoTurntable:
    """The physical rig's turntable: a Dynamixel servo in position mode.

    Use :meth:`connect`, or wrap a connected, configured driver whose torque is on.

    Args:
      driver: a connected :class:`~plantsim.dynamixel.DynamixelTurntable`.
      move_timeout_s: wall-clock limit of one move, s.
      tolerance_rad: accepted final position error of a move, rad (default two
        encoder ticks: the factory P-only gains can stop a tick short against friction).
      stable_interval_s: after a move, the position must read the same tick twice
        this far apart before the angle is reported (the servo clears its Moving
        flag below 1.4 deg/s, while the shaft can still creep the last tick).
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

    @classmethod
    def connect(cls, port: str, *, baud_bps: int = 57_600, dxl_id: int = 1, model: str = "xm430-w350",
                retries: int = 2, profile_velocity_rad_s: float = 0.5,
                profile_acceleration_rad_s2: float = 2.0, **options) -> "ServoTurntable":
        """Connects to the servo, configures a gentle profile and switches torque on.

        The servo's factory gains are kept; only the profile (velocity and
        acceleration caps, so the plant is not shaken) and position mode are set.

        Args:
          port: serial port (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, an emulator's pty).
          baud_bps, dxl_id, model: as the servo is set up (factory: 57600, 1).
          retries: repeats of a read or register write whose status packet was lost.
          profile_velocity_rad_s: the move's velocity cap, rad/s.
          profile_acceleration_rad_s2: the move's acceleration, rad/s^2.
          **options: ``move_timeout_s``, ``tolerance_rad``.

        Raises:
          HardwareError: the servo cannot be reached or refuses the configuration.
        """
        from plantsim.turntable import servo
        from plantsim.hardware.dynamixel.driver import DynamixelTurntable

        base = servo.ServoConfig.xl430_w250 if model == "xl430-w250" else servo.ServoConfig.xm430_w350
        config = base(profile_velocity=profile_velocity_rad_s,
                      profile_acceleration=profile_acceleration_rad_s2)
        driver = DynamixelTurntable(model=model, retries=retries)
        driver.connect(port, baud_bps=baud_bps, dxl_id=dxl_id)
        try:
            driver.configure(config, operating_mode="position")
            driver.torque_on()
            return cls(driver, **options)
        except BaseException:
            driver.close()
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
        deadline = time.monotonic() + self.move_timeout_s
        angle = self.driver.move_to(angle_rad, timeout_s=self.move_timeout_s, tolerance_rad=self.tolerance_rad)
        while True:
            time.sleep(self.stable_interval_s)
            again = self.driver.position()
            if again == angle:
                return angle
            if time.monotonic() > deadline:
                raise HardwareError(
                    f"servo ID {self.driver.dxl_id} on {self.driver.port_name} does not come to rest at "
                    f"{angle_rad:.4f} rad (reads {angle:.4f}, then {again:.4f} rad after "
                    f"{self.stable_interval_s} s) within {self.move_timeout_s} s; check for a loose "
                    "coupling, a swinging load or too low a Position P Gain")
            angle = again

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

    def close(self) -> None:
        """Switches torque off (best effort: the servo may be gone) and releases the port."""
        if self.driver.connected:
            try:
                self.driver.torque_off()
            except HardwareError as exc:
                log.info("torque off on close failed: %s", exc)
        self.driver.close()

    def __enter__(self) -> "ServoTurntable":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
