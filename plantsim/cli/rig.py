"""Command-line commands for the servo rig: ``plantsim emulator`` and ``plantsim rig ...``.

``plantsim.cli`` registers them with :func:`add_rig_commands`; each command sets
``func`` on its namespace, a callable taking the parsed arguments and returning the
exit code; ``python -m plantsim.cli.rig ...`` also runs them alone.

Examples::

    plantsim emulator --model xm430-w350 --id 1 --baud 57600
    plantsim rig ping --port /dev/ttyUSB0 --baud 57600 --id 1
    plantsim rig scan --port /dev/ttyUSB0 --step-deg 10 -o plant.las [--resume]
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading

from plantsim.hardware.dynamixel import control_table as ct

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
    add_rig_scan_command(rig_commands)
    return rig_commands


def add_rig_scan_command(rig_commands: argparse._SubParsersAction) -> None:
    """Registers ``rig scan`` on the ``rig`` command's subparsers."""
    from plantsim.cli.app import add_common_scan_options

    scan = rig_commands.add_parser(
        "scan", help="scan with the turntable servo (the LiDAR is simulated at its reported angle)",
        description="Turns the servo through the schedule and takes one simulated LiDAR line (ideal or "
        "realistic sensor) at each reported angle (hardware in the loop). Each line is journaled to "
        "OUT.journal as it arrives; after a fault or Ctrl-C, run the same command with --resume.")
    _add_connection_arguments(scan)
    add_common_scan_options(scan, preset_flag="--lidar-model")
    scan.add_argument("--resume", action="store_true",
                      help="continue the scan journaled in OUT.journal from its last complete line")
    scan.add_argument("--keep-journal", action="store_true",
                      help="keep OUT.journal after success (default: delete it once the cloud is written)")
    scan.add_argument("--retries", type=int, default=2,
                      help="repeats of a servo read/write whose reply was lost (default: 2)")
    scan.add_argument("--settle-s", type=float, default=0.0, help="wait after each move, s (default: 0)")
    scan.add_argument("--lidar", choices=["sim", "urg"], default="sim",
                      help="sim: simulated LiDAR at the servo's reported angle (default); "
                      "urg: a real Hokuyo (not available yet)")
    scan.set_defaults(func=run_rig_scan)


def run_rig_scan(args: argparse.Namespace) -> int:
    import time

    from plantsim.cli.app import _progress_bar, resolve_config, scan_overrides, summary_line
    from plantsim.errors import HardwareError, ScanInterruptedError, UnsafeStopError
    from plantsim.hardware.dynamixel.turntable import ServoTurntable
    from plantsim.scan.pipeline import check_outputs, check_plant_seen, journal_path_for, run_scan, write_result
    from plantsim.scan.plan import plan_scan

    t0 = time.perf_counter()
    if args.lidar == "urg":
        raise HardwareError("a real URG LiDAR is not available in rig scans yet: plantsim's rig scan "
                            "casts the simulated LiDAR at the servo's reported angle; use --lidar sim")
    config = resolve_config(args, scan_overrides(args))
    output = check_outputs(config, config_path=args.config)  # fail before the servo moves
    plan_scan(config, hardware_turntable=True)  # refuse unused settings before the servo moves
    journal = journal_path_for(output)
    if journal.exists() and not args.resume:
        print(f"plantsim: error: {journal} holds an unfinished scan; run the same command with --resume "
              "to continue it, or delete it to start over", file=sys.stderr)
        return 2
    resume_hint = (f"plantsim: the lines taken are safe in {journal}; to continue, fix the cause and run the "
                   "same command again with --resume")
    progress, close_bar = _progress_bar("rig scan")
    try:
        with rig_safety() as safety:
            try:
                turntable = ServoTurntable.connect(args.port, baud_bps=args.baud_bps, dxl_id=args.dxl_id,
                                                   model=args.model, retries=args.retries, safety=safety,
                                                   driver_options=_driver_options(args))
            except HardwareError as exc:
                print(f"plantsim: error: {exc}", file=sys.stderr)
                return 1
            with turntable:
                result = run_scan(config, turntable=turntable, resume=args.resume, settle_s=args.settle_s,
                                  progress=progress)
    except UnsafeStopError:
        close_bar()  # the DANGER line is printed
        return 1
    except ScanInterruptedError as exc:
        close_bar()
        print(f"plantsim: error: {exc}", file=sys.stderr)
        print(resume_hint, file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP (plantsim.errors.Terminated)
        close_bar()
        print(f"plantsim: {_interrupt_name(exc)}. " + resume_hint.removeprefix("plantsim: "), file=sys.stderr)
        return _interrupt_exit_code(exc)
    finally:
        close_bar()
    check_plant_seen(result)
    path = write_result(result, keep_journal=args.keep_journal)
    print(summary_line(result, path, time.perf_counter() - t0))
    return 0


@contextlib.contextmanager
def rig_safety(stream=None):
    """A :class:`~plantsim.hardware.safety.SafeStop` for a rig command.

    Wrap everything that talks to the hardware: register each device's stop action
    (``ServoTurntable.connect(..., safety=safety)`` does it for the servo; the URG
    LiDAR's ``laser off`` goes the same way). SIGTERM and SIGHUP unwind the block as
    :class:`~plantsim.errors.Terminated` (a ``KeyboardInterrupt``); on leaving it every
    action runs, retried and read back, and when one cannot be confirmed the one-line
    DANGER message is printed to ``stream`` (stderr), whatever the verbosity.
    :class:`~plantsim.errors.UnsafeStopError` then propagates from a block that
    ended normally; catch it and exit non-zero.
    """
    from plantsim.hardware.safety import SafeStop

    safety = SafeStop()
    try:
        with safety:
            yield safety
    finally:
        report = safety.report
        if report is not None and not report.safe:
            print(f"plantsim: {report.warning()}", file=stream or sys.stderr, flush=True)


def _driver_options(args: argparse.Namespace) -> dict:
    timeout_ms = args.status_timeout_ms
    if not (0 < timeout_ms <= 10_000):
        raise ValueError(f"--status-timeout-ms must be in (0, 10000], got {timeout_ms}")
    return {"status_timeout_s": timeout_ms / 1e3}


def _interrupt_name(exc: BaseException) -> str:
    signum = getattr(exc, "signum", None)
    return f"terminated ({signal.Signals(signum).name})" if signum else "interrupted"


def _interrupt_exit_code(exc: BaseException) -> int:
    """128 + the signal's number, as a shell reports a process ended by it (Ctrl-C: 130)."""
    return 128 + getattr(exc, "signum", signal.SIGINT)


def _add_connection_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True, help="serial port, e.g. /dev/ttyUSB0 or an emulator's pty")
    parser.add_argument("--baud", dest="baud_bps", type=int, choices=_BAUDS, default=57_600, metavar="BPS",
                        help="baud rate (default: 57600, the servo's factory setting)")
    parser.add_argument("--id", dest="dxl_id", type=int, default=1, help="servo ID (default: 1)")
    parser.add_argument("--model", choices=sorted(ct.CONTROL_TABLES), default="xm430-w350",
                        help="expected model (default: xm430-w350)")
    parser.add_argument("--status-timeout-ms", type=float, default=34.0, metavar="MS",
                        help="least time to wait for the servo's reply, ms (default: 34, the SDK's; raise it "
                        "for a slow USB adapter or an emulator on a busy machine)")


def run_emulator(args: argparse.Namespace) -> int:
    from plantsim.hardware.dynamixel.emulator import DynamixelEmulator

    ids = args.ids or [1]
    emulator = DynamixelEmulator(ids=ids, model=args.model, baud_bps=args.baud_bps,
                                 speed_factor=args.speed_factor, load_inertia=args.load_inertia)
    # Ctrl-C and SIGTERM stop it, even when a parent started it with SIGINT ignored
    # (a background job of a non-interactive shell).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
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
    from plantsim.validation import require_extra

    require_extra("dynamixel_sdk", "rig", "plantsim rig ping")  # one line, not a traceback
    from plantsim.hardware.dynamixel.driver import DynamixelTurntable
    from plantsim.hardware.dynamixel.turntable import ServoTurntable
    from plantsim.errors import HardwareError

    try:
        with rig_safety(), DynamixelTurntable(model=args.model, **_driver_options(args)) as turntable:
            # Ping leaves the torque as it found it: no stop action to register.
            turntable.connect(args.port, baud_bps=args.baud_bps, dxl_id=args.dxl_id)
            status = ServoTurntable(turntable).status()  # one read: one instant's values
    except HardwareError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(f"plantsim: {_interrupt_name(exc)}", file=sys.stderr)
        return _interrupt_exit_code(exc)
    table = turntable.table
    print(f"model: {table.model_name} ({table.model_number})")
    print(f"firmware: {turntable.firmware_version}")
    print(f"position: {status.position_rad:.4f} rad")
    print(f"velocity: {status.velocity_rad_s:.4f} rad/s")
    print(f"temperature: {status.temperature_c:.0f} degC")
    print(f"input voltage: {status.input_voltage_v:.1f} V")
    print(f"load: {status.load_percent:.1f} %" + (f" ({status.current_a:.3f} A)" if status.current_a is not None else ""))
    print(f"torque: {'on' if status.torque_enabled else 'off'}{', moving' if status.moving else ''}")
    print(f"hardware errors: {', '.join(status.hardware_errors) or 'none'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Runs the rig commands alone (before ``plantsim.cli`` wires them in)."""
    parser = argparse.ArgumentParser(prog="python -m plantsim.cli.rig")
    add_rig_commands(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
