"""``plantsim lidar ping`` against the emulated URG-04LX."""

import pytest

from plantsim.cli.app import main
from plantsim.hardware.urg import UrgEmulator, VirtualClock

pytest.importorskip("serial")


def test_lidar_ping_prints_model_firmware_serial_and_valid_beams(capsys):
    with UrgEmulator(clock=VirtualClock(), serial="H1234567") as emulator:
        assert main(["lidar", "ping", "--port", emulator.port_path, "--timeout", "5"]) == 0
        assert not emulator.laser_on
    out = capsys.readouterr().out
    assert f"URG-04LX on {emulator.port_path}: firmware 3.3.00" in out and "serial H1234567" in out
    assert "scan: 682 of 683 beams with a range" in out


def test_lidar_ping_wrong_preset_is_an_error(capsys):
    with UrgEmulator(clock=VirtualClock()) as emulator:
        assert main(["lidar", "ping", "--port", emulator.port_path, "--lidar-preset", "utm-30lx"]) == 2
    assert "but the preset 'utm-30lx' expects otherwise" in capsys.readouterr().err
