"""``plantsim lidar ...``: the Hokuyo URG LiDAR on its own.

Examples::

    plantsim lidar ping --port /dev/ttyACM0
    plantsim lidar emulator            # prints "lidar: /dev/pts/N"; Ctrl-C to stop
    plantsim lidar ping --port /dev/pts/N
"""

from __future__ import annotations

import argparse
import threading

from plantsim.sensor.spec import PRESETS


def add_urg_commands(subparsers: argparse._SubParsersAction) -> argparse._SubParsersAction:
    """Registers ``lidar ping`` and ``lidar emulator``; returns ``lidar``'s subparsers."""
    lidar = subparsers.add_parser("lidar", help="talk to a Hokuyo URG LiDAR (SCIP 2.0)",
                                  description="The real LiDAR of the rig, a Hokuyo URG-04LX over SCIP 2.0 "
                                              "(docs/urg-lidar.md: wiring, permissions, finding the port).")
    commands = lidar.add_subparsers(dest="lidar_command", required=True)
    ping = commands.add_parser("ping", help="print the LiDAR's model, firmware, serial and a scan's valid beams",
                               description="Connects (switching a SCIP 1.1 sensor to SCIP 2.0), reads VV/PP/II, "
                                           "checks the model against the preset, estimates the clock offset, takes "
                                           "one scan and switches the laser off.")
    ping.add_argument("--port", required=True, help="serial port: /dev/ttyACM0, /dev/serial/by-id/usb-Hokuyo...")
    ping.add_argument("--lidar-preset", default="urg-04lx-ug01", choices=sorted(PRESETS),
                      help="the sensor the rig expects (default urg-04lx-ug01)")
    ping.add_argument("--timeout", type=float, default=1.0, help="reply timeout, s (default 1)")
    ping.set_defaults(func=run_lidar_ping)
    emulator = commands.add_parser("emulator", help="run an emulated URG-04LX on a pseudo-terminal",
                                   description="Starts an emulated URG-04LX on a pty, prints its path and serves "
                                               "until Ctrl-C; it sees a surface at --range-m all round.")
    emulator.add_argument("--range-m", type=float, default=1.0, help="range every beam sees, m (default 1)")
    emulator.add_argument("--speed-factor", type=float, default=1.0,
                          help="emulated seconds per wall-clock second (default 1: real time)")
    emulator.add_argument("--scip11", action="store_true", help="boot in SCIP 1.1, as some firmware does")
    emulator.set_defaults(func=run_lidar_emulator)
    return commands


def run_lidar_ping(args: argparse.Namespace) -> int:
    from plantsim.hardware.urg.driver import UrgLidar
    from plantsim.sensor.spec import lidar_preset

    with UrgLidar.connect(args.port, preset=lidar_preset(args.lidar_preset), timeout_s=args.timeout) as lidar:
        info = lidar.info
        scan = lidar.scan()
        offset = lidar.clock_offset
        print(f"{info.model} on {args.port}: firmware {info.firmware}, serial {info.serial}, {info.protocol}")
        print(f"scan: {scan.n_valid} of {len(scan.ranges_m)} beams with a range (steps {scan.first_step}.."
              f"{scan.last_step}), sensor time {scan.sensor_time_s:.3f} s")
        print(f"clock offset (sensor - host): {offset.offset_s:+.4f} s +- {offset.uncertainty_s * 1000:.1f} ms")
    return 0


def run_lidar_emulator(args: argparse.Namespace) -> int:
    from plantsim.hardware.urg.emulator import RealTimeClock, UrgEmulator, wall_provider

    stop = threading.Event()
    with UrgEmulator(wall_provider(args.range_m), clock=RealTimeClock(args.speed_factor),
                     start_in_scip11=args.scip11) as emulator:
        print(f"lidar: {emulator.port_path}", flush=True)
        try:
            stop.wait()
        except KeyboardInterrupt:
            pass
    return 0
