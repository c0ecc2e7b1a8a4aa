"""Command-line commands for the servo rig: ``plantsim emulator`` and ``plantsim rig ...``.

``plantsim.cli`` registers them with :func:`add_rig_commands`; each command sets
``func`` on its namespace, a callable taking the parsed arguments and returning the
exit code; ``python -m plantsim.cli.rig ...`` also runs them alone.

Examples::

    plantsim emulator --model xm430-w350 --id 1 --baud 57600
    plantsim emulator --lidar [MESH] [--sensor ideal]   # servo and URG sharing one turntable
    plantsim rig ping --port /dev/ttyUSB0 --baud 57600 --id 1
    plantsim rig scan --port /dev/ttyUSB0 --step-deg 10 -o plant.las [--resume]
    plantsim rig scan --port /dev/ttyUSB0 --lidar urg --lidar-port /dev/ttyACM0 [--mode continuous --rpm 2]
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
    emulator.add_argument("--lidar", action="store_true",
                          help="also run an emulated URG-04LX on its own pty that sees the plant on the emulated "
                               "turntable (at the servo's true angle at each beam's instant); prints "
                               "'servo: PATH' and 'lidar: PATH'")
    emulator.add_argument("mesh", nargs="?", help="(--lidar) plant mesh; default: the bundled maize")
    emulator.add_argument("--config", help="(--lidar) TOML with [plant], [rig], [lidar], [sensor_model], seed")
    emulator.add_argument("--units", choices=["m", "cm", "mm"], help="(--lidar) the mesh file's unit (default m)")
    emulator.add_argument("--up", choices=["x", "y", "z"], help="(--lidar) the mesh file's up axis (default z)")
    emulator.add_argument("--placement", choices=["base", "bbox", "none"],
                          help="(--lidar) how the plant sits on the disk (default base)")
    emulator.add_argument("--base-point", type=float, nargs=3, metavar=("X", "Y", "Z"),
                          help="(--lidar) put this point of the mesh on the axis (the file's units and axes)")
    emulator.add_argument("--sensor", choices=["ideal", "realistic"],
                          help="(--lidar) the emulated LiDAR's ranges: ideal (exact first hits) or realistic "
                               "(the sensor model: footprint, noise, dropouts; the default)")
    emulator.add_argument("--seed", type=int, help="(--lidar) seed of the sensor model's noise (default 0)")
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
        "scan", help="scan with the turntable servo and the real URG LiDAR (or a simulated one)",
        description="Turns the servo through the schedule and takes one LiDAR line at each stop: from the "
        "real Hokuyo URG (--lidar urg --lidar-port PORT), or from the simulated LiDAR (ideal or realistic) at "
        "the reported angle (--lidar sim, hardware in the loop). With --lidar urg --mode continuous the servo "
        "turns at --rpm while the URG streams, and each beam's angle is interpolated from the servo's readings. "
        "Each line is journaled to OUT.journal as it arrives; after a fault or Ctrl-C, run the same command with "
        "--resume.")
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
                      "urg: the real Hokuyo URG on --lidar-port")
    scan.add_argument("--lidar-port", help="(--lidar urg) the URG's port: /dev/ttyACM0, "
                      "/dev/serial/by-id/usb-Hokuyo..., or `plantsim emulator --lidar`'s lidar pty")
    scan.add_argument("--lidar-timeout", type=float, default=1.0, metavar="S",
                      help="(--lidar urg) reply timeout of the URG, s (default 1)")
    scan.add_argument("--mode", choices=["step", "continuous"],
                      help="step: move, settle, take a line (default); continuous (--lidar urg): the servo turns "
                      "at --rpm while the LiDAR streams")
    scan.add_argument("--rpm", type=float, help="continuous mode's turntable speed, rpm (default 1; the servo "
                      "turns at the nearest multiple of 0.229 rpm)")
    scan.set_defaults(func=run_rig_scan)


def run_rig_scan(args: argparse.Namespace) -> int:
    import time

    from plantsim.cli.app import _progress_bar, resolve_config, scan_overrides, summary_line
    from plantsim.errors import HardwareError, ScanInterruptedError, UnsafeStopError
    from plantsim.hardware.dynamixel.turntable import ServoTurntable
    from plantsim.scan.pipeline import check_outputs, check_plant_seen, journal_path_for, run_scan, write_result
    from plantsim.scan.plan import plan_scan

    from plantsim.errors import ConfigError

    t0 = time.perf_counter()
    real = args.lidar == "urg"
    if real and not args.lidar_port:
        raise ConfigError("--lidar urg needs --lidar-port PORT: the URG's /dev/ttyACM0 or its "
                          "/dev/serial/by-id/usb-Hokuyo... path (ls -l /dev/serial/by-id)")
    if not real and args.lidar_port:
        raise ConfigError("--lidar-port is the real URG's port: add --lidar urg, or remove --lidar-port")
    config = resolve_config(args, scan_overrides(args))
    if config.turntable.mode == "continuous" and args.settle_s:
        raise ConfigError("--settle-s is the wait after each move of a step scan; a continuous scan does not stop: "
                          "remove it, or use --mode step")
    output = check_outputs(config, config_path=args.config)  # fail before the servo moves
    plan_scan(config, hardware_turntable=True, real_lidar=real)  # refuse unused settings before the servo moves
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
                source = None
                if real:
                    source = _connect_urg(args, config, safety)
                    if source is None:
                        return 1
                try:
                    result = run_scan(config, turntable=turntable, resume=args.resume, settle_s=args.settle_s,
                                      progress=progress, lidar=source)
                finally:
                    if source is not None:
                        source.lidar.close()  # QT: laser off
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
    if not real:  # a real LiDAR does not know what it hit
        check_plant_seen(result)
    path = write_result(result, keep_journal=args.keep_journal)
    if real:
        lidar = result.parts["lidar"]
        resumed = f" ({result.lines_resumed} resumed from the journal)" if result.lines_resumed else ""
        raw = f" and the raw bag to {result.config.output.raw}" if result.config.output.raw else ""
        print(f"wrote {len(result.cloud):,} points from {result.raw.n_lines} lines{resumed} x {result.raw.n_beams} "
              f"beams (real {lidar['model']} serial {lidar['serial']}, servo turntable, {result.plan.mode} mode"
              f"{', ranges filtered' if 'range_filter' in result.parts else ''}) "
              f"to {path}{raw} in {time.perf_counter() - t0:.2f} s")
        return 0
    print(summary_line(result, path, time.perf_counter() - t0))
    return 0


def _connect_urg(args: argparse.Namespace, config, safety):
    """The URG as a line source, its laser registered with ``safety``; None (after one
    line on stderr) when it cannot be reached or is not the configured model."""
    from plantsim.errors import LidarError, LidarModelError
    from plantsim.hardware.urg.driver import UrgLidar, check_model
    from plantsim.hardware.urg.source import UrgLineSource
    from plantsim.sensor.spec import PRESETS

    try:
        lidar = UrgLidar.connect(args.lidar_port, preset=config.lidar, timeout_s=args.lidar_timeout, safety=safety)
    except LidarModelError as exc:
        fits = []
        info = getattr(exc, "info", None)
        for name, spec in sorted(PRESETS.items()):
            try:
                if info is not None and spec.steps_per_rev is not None:
                    check_model(info, spec)
                    fits.append(name)
            except (LidarModelError, ValueError):
                pass
        hint = f"; use --lidar-model {fits[0]}" if fits else "; choose the --lidar-model of this sensor"
        text = str(exc).split("; choose the preset")[0]
        print(f"plantsim: error: {text}{hint}", file=sys.stderr)
        return None
    except LidarError as exc:
        print(f"plantsim: error: {exc}", file=sys.stderr)
        return None
    return UrgLineSource(lidar, config.lidar)


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
    allowance_ms = args.scheduler_allowance_ms
    if not (0 <= allowance_ms <= 10_000):
        raise ValueError(f"--scheduler-allowance-ms must be in [0, 10000], got {allowance_ms}")
    return {"status_timeout_s": timeout_ms / 1e3, "scheduler_allowance_s": allowance_ms / 1e3}


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
    parser.add_argument("--scheduler-allowance-ms", type=float, default=50.0, metavar="MS",
                        help="added to the reply time the protocol allows (bytes at the baud, Return Delay Time, "
                        "USB latency), ms (default: 50; raise it on a host busy with other work)")


def run_emulator(args: argparse.Namespace) -> int:
    from plantsim.hardware.dynamixel.emulator import DynamixelEmulator

    ids = args.ids or [1]
    lidar_only = [f"--{name.replace('_', '-')}" for name in ("config", "units", "up", "placement", "base_point",
                                                             "sensor", "seed")
                  if getattr(args, name, None) is not None] + (["MESH"] if getattr(args, "mesh", None) else [])
    if getattr(args, "lidar", False):
        return _run_emulator_pair(args, ids)
    if lidar_only:
        from plantsim.errors import ConfigError

        raise ConfigError(f"{lidar_only[0]} chooses what the emulated LiDAR sees: add --lidar, or remove it")
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


def _run_emulator_pair(args: argparse.Namespace, ids: list[int]) -> int:
    """``plantsim emulator --lidar``: the servo and the URG sharing one turntable and one clock."""
    import math

    from plantsim.cli.app import resolve_config, scan_overrides
    from plantsim.errors import ConfigError
    from plantsim.hardware.urg.pair import EmulatorPair
    from plantsim.rig.scene import build_scene
    from plantsim.scan.pipeline import load_configured_plant

    if len(ids) != 1:
        raise ConfigError("--lidar emulates one turntable servo: give one --id")
    config = resolve_config(args, scan_overrides(args))
    ideal = config.ideal or config.sensor == "ideal"
    if config.lidar.steps_per_rev != 1024:
        raise ConfigError(f"the emulated LiDAR is a URG-04LX; [lidar] preset {config.lidar.name!r} is not: use "
                          "urg-04lx-ug01")
    plant = load_configured_plant(config)
    scene = build_scene(config.rig, plant)
    pair = EmulatorPair(scene, config.lidar, model=None if ideal else config.sensor_model, seed=config.seed,
                        encoder_offset_rad=math.radians(config.rig.encoder_offset_deg), servo_model=args.model,
                        dxl_id=ids[0], baud_bps=args.baud_bps, speed_factor=args.speed_factor,
                        load_inertia=args.load_inertia)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    with pair:
        print(f"servo: {pair.servo_port}", flush=True)
        print(f"lidar: {pair.lidar_port}", flush=True)
        print(f"{args.model} ID {ids[0]} at {args.baud_bps} bps and a URG-04LX ({'ideal' if ideal else 'realistic'} "
              f"sensor) seeing {config.plant.mesh or config.plant.bundled} on its turntable; "
              "Ctrl-C to stop", file=sys.stderr, flush=True)
        if args.speed_factor > 1:
            print(f"plantsim: note: at --speed-factor {args.speed_factor:g} both devices' clocks run "
                  f"{args.speed_factor:g} x the host's; `plantsim rig scan --mode continuous` times beams on the "
                  "host's clock and refuses them (step scans are fine): use --speed-factor 1 for continuous "
                  "scans", file=sys.stderr, flush=True)
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
