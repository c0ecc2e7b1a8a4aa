"""The rig commands: the emulator in its own process, pinged through the CLI."""

import argparse
import os
import signal
import subprocess
import sys

import pytest

from plantsim.cli import rig as cli_rig


def parser():
    top = argparse.ArgumentParser(prog="plantsim")
    hook = cli_rig.add_rig_commands(top.add_subparsers(dest="command", required=True))
    return top, hook


def test_commands_are_registered_and_rig_has_a_hook():
    top, hook = parser()
    args = top.parse_args(["emulator", "--id", "1", "--id", "3", "--baud", "1000000"])
    assert args.func is cli_rig.run_emulator and args.ids == [1, 3] and args.baud_bps == 1_000_000
    probe = hook.add_parser("probe")  # the hook still takes further rig commands
    probe.set_defaults(func=lambda a: 0)
    assert top.parse_args(["rig", "probe"]).rig_command == "probe"
    args = top.parse_args(["rig", "scan", "--port", "/dev/ttyUSB0", "--step-deg", "10", "--resume"])
    assert args.func is cli_rig.run_rig_scan and args.resume and args.step_deg == 10
    with pytest.raises(SystemExit):
        top.parse_args(["rig", "ping", "--port", "x", "--baud", "12345"])


def test_emulator_process_and_rig_ping(capsys):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    process = subprocess.Popen(
        [sys.executable, "-m", "plantsim", "emulator", "--id", "4"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        port_path = process.stdout.readline().strip()
        assert port_path.startswith("/dev/")
        top, _ = parser()
        # Another process answers: allow for the scheduler on a busy machine.
        args = top.parse_args(["rig", "ping", "--port", port_path, "--id", "4", "--status-timeout-ms", "500"])
        assert args.func(args) == 0
        out = capsys.readouterr().out
        assert "model: XM430-W350 (1020)" in out and "firmware: 46" in out and "position: 0.0000 rad" in out
        # What a user reads on the rig, in SI units, from one read of the servo at rest.
        assert "velocity: 0.0000 rad/s" in out and "temperature: 30 degC" in out
        assert "input voltage: 12.0 V" in out and "load: 0.0 % (0.000 A)" in out
        assert "torque: off" in out and "hardware errors: none" in out
        args = top.parse_args(["rig", "ping", "--port", port_path, "--id", "5"])
        assert args.func(args) == 1
        assert "error: ping on" in capsys.readouterr().err
    finally:
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=10) == 0


def test_the_scheduler_allowance_reaches_the_driver_and_is_checked():
    from plantsim.cli.rig import _driver_options

    top, _ = parser()
    args = top.parse_args(["rig", "ping", "--port", "/dev/null", "--scheduler-allowance-ms", "2000"])
    assert _driver_options(args) == {"status_timeout_s": 0.034, "scheduler_allowance_s": 2.0}
    args = top.parse_args(["rig", "ping", "--port", "/dev/null", "--scheduler-allowance-ms", "-5"])
    with pytest.raises(ValueError, match=r"--scheduler-allowance-ms must be in \[0, 10000\], got -5"):
        _driver_options(args)
