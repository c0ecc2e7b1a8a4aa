"""Command-line commands for the servo rig: ``plantsim emulator`` and ``plantsim rig ...``.

``plantsim.cli`` registers them with :func:`add_rig_commands`; each command sets
``func`` on its namespace, a callable taking the parsed arguments and returning the
exit code. Until that is wired, ``python -m plantsim.cli_rig ...`` runs them alone.

Examples::

    plantsim emulator --model xm430-w350 --id 1 --baud 57600
    plantsim rig ping --port /dev/ttyUSB0 --baud 57600 --id 1
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading

from plantsim.dynamixel import control_table as ct

_BAUDS = sorted(b for b in ct.BAUD_RATES_BPS.values() if b != 4_500_000)


def add_rig_commands(subparsers: argparse._SubParsersAction) -> argparse._SubParsersAction:
    """Registers ``emulator`` and ``rig ping`` on the top-level ``subparsers``.

    Returns:
        The ``rig`` command's own subparsers, the hook for further rig commands:
        ``rig_commands.add_parser("scan", ...)`` with ``set_defaults(func=...)``.
    """
    emulator = subparsers.add_parser(
        "emulator",
        help="run an emulated Dynamixel servo on a pseudo-terminal",
        description="Starts emulated Protocol 2.0 servos on a pty and prints its path; "
        "open that path with the Dynamixel SDK or `plantsim rig`. Runs until Ctrl-C.",
    )
    emulator.add_argument("--model", choices=sorted(ct.CONTROL_TABLES), default="xm430-w350")
    emulator.add_argument("--id", dest="ids", type=int, action="append",
                          help="servo ID, repeat for several servos on the bus (default: 1)")
    emulator.add_argument("--baud", dest="baud_bps", type=int, choices=_BAUDS, default=57_600, metavar="BPS",
                          help="initial Baud Rate register (default: 57600)")
    emulator.add_argument("--speed-factor", type=float, default=1.0,
                          help="simulated seconds per wall second (default: 1)")
    emulator.add_argument("--load-inertia", type=float, default=0.0,
                          help="inertia carried by the shaft, kg m^2 (default: 0)")
    emulator.set_defaults(func=run_emulator)

    rig = subparsers.add_parser("rig", help="talk to the real turntable servo")
    rig_commands = rig.add_subparsers(dest="rig_command", metavar="COMMAND", required=True)
    ping = rig_commands.add_parser("ping", help="ping the servo; print model, firmware, position")
    _add_connection_arguments(ping)
    ping.set_defaults(func=run_rig_ping)
    return rig_commands


def _add_connection_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True, help="serial port, e.g. /dev/ttyUSB0 or an emulator's pty")
    parser.add_argument("--baud", dest="baud_bps", type=int, choices=_BAUDS, default=57_600, metavar="BPS",
                        help="baud rate (default: 57600, the servo's factory setting)")
    parser.add_argument("--id", dest="dxl_id", type=int, default=1, help="servo ID (default: 1)")
    parser.add_argument("--model", choices=sorted(ct.CONTROL_TABLES), default="xm430-w350",
                        help="expected model (default: xm430-w350)")


def run_emulator(args: argparse.Namespace) -> int:
    from plantsim.dynamixel.emulator import DynamixelEmulator

    ids = args.ids or [1]
    emulator = DynamixelEmulator(ids=ids, model=args.model, baud_bps=args.baud_bps,
                                 speed_factor=args.speed_factor, load_inertia=args.load_inertia)
    with emulator:
        print(emulator.port_path, flush=True)
        print(f"{args.model} ID {', '.join(map(str, ids))} at {args.baud_bps} bps; Ctrl-C to stop",
              file=sys.stderr, flush=True)
        try:
            threading.Event().wait()
        except KeyboardInterrupt:
            pass
    return 0


def run_rig_ping(args: argparse.Namespace) -> int:
    from plantsim.dynamixel.driver import DynamixelTurntable
    from plantsim.errors import HardwareError

    try:
        with DynamixelTurntable(model=args.model) as turntable:
            turntable.connect(args.port, baud_bps=args.baud_bps, dxl_id=args.dxl_id)
            position = turntable.position()
            status = turntable.hardware_error_status()
    except HardwareError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    table = turntable.table
    print(f"model: {table.model_name} ({table.model_number})")
    print(f"firmware: {turntable.firmware_version}")
    print(f"position: {position:.4f} rad")
    if status:
        print(f"hardware error: {', '.join(ct.hardware_error_names(status))}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Runs the rig commands alone (before ``plantsim.cli`` wires them in)."""
    parser = argparse.ArgumentParser(prog="python -m plantsim.cli_rig")
    add_rig_commands(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
