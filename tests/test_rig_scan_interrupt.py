"""Interrupted rig scans: Ctrl-C or SIGTERM at many points, the servo's torque read back off.

Against the servo emulator in this process: the scan pipeline under a SafeStop, and
``plantsim rig scan`` itself, interrupted at packet k of the scan by a real signal
sent to this process; then once more by a signal from outside, to the command in its
own process.
"""

import os
import signal
import subprocess
import sys
import time

import pytest

from plantsim.cli import app as cli
from plantsim.errors import Terminated
from plantsim.hardware.dynamixel.turntable import ServoTurntable
from plantsim.hardware.safety import SafeStop
from plantsim.scan.config import OutputOptions, PlantOptions, RunConfig
from plantsim.scan.journal import read_journal
from plantsim.scan.pipeline import journal_path_for, run_scan
from plantsim.scan.schedule import StepScan
from test_dxl_safety import (FAST, Tripwire, ctrl_c_raises, no_sleep, send_swallowed,  # noqa: F401
                             torque_on_in_emulator)


def config_for(cylinder, out):
    return RunConfig(plant=PlantOptions(mesh=cylinder), scan=StepScan(step_deg=45), sensor="ideal",
                     output=OutputOptions(path=str(out)))


@pytest.mark.parametrize("where", ["after_write", "in_read"])
def test_ctrl_c_at_many_points_of_a_scan_leaves_torque_off(tmp_path, emulator, cylinder, monkeypatch, where):
    fired = 0
    for k in (1, 4, 9, 17, 30, 50, 80):
        config = config_for(cylinder, tmp_path / f"{where}{k}.ply")
        tripwire = Tripwire(monkeypatch, k, where)
        safety = SafeStop(sleep=no_sleep)
        try:
            with safety:
                table = ServoTurntable.connect(emulator.port_path, safety=safety, **FAST)
                tripwire.armed = True
                with table:
                    run_scan(config, turntable=table)
        except KeyboardInterrupt:
            pass
        assert safety.report.safe, safety.report.warning()
        assert not torque_on_in_emulator(emulator), f"torque on after Ctrl-C at scan packet {k} ({where})"
        if tripwire.fired:
            fired += 1
            assert safety.report.reason == "Ctrl-C"
            journal = journal_path_for(config.output.path)
            if journal.exists():  # every journaled line is whole and in order
                lines = read_journal(journal).lines
                assert [line.index for line in lines] == list(range(len(lines)))
    assert fired >= 6


def scan_until_terminated(config, emulator, tripwire):
    """Runs the scan under a SafeStop with ``tripwire`` armed, expecting it to end as
    SIGTERM (``Terminated``); returns the SafeStop."""
    safety = SafeStop(sleep=no_sleep)
    with pytest.raises(Terminated):
        with safety:
            table = ServoTurntable.connect(emulator.port_path, safety=safety, **FAST)
            tripwire.armed = True
            with table:
                run_scan(config, turntable=table)
    return safety


def test_sigterm_mid_scan_then_resume_completes(tmp_path, emulator, cylinder, monkeypatch):
    config = config_for(cylinder, tmp_path / "plant.ply")
    tripwire = Tripwire(monkeypatch, 40, "after_write", fire=lambda: os.kill(os.getpid(), signal.SIGTERM))
    safety = scan_until_terminated(config, emulator, tripwire)
    assert safety.report.reason == "SIGTERM" and safety.report.safe
    assert not torque_on_in_emulator(emulator)
    done = len(read_journal(journal_path_for(config.output.path)).lines)
    assert 0 < done < 8
    tripwire.armed = False
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        result = run_scan(config, turntable=table, resume=True)
    assert result.lines_resumed == done and result.raw.n_lines == 8


@pytest.mark.parametrize("k", [12, 40])
def test_a_sigterm_the_interpreter_swallows_still_stops_the_scan_within_a_line(tmp_path, emulator, cylinder,
                                                                              monkeypatch, k):
    """The CI failure of a `kill` lost in an import lock's callback: the scan ran to its end."""
    config = config_for(cylinder, tmp_path / "plant.ply")
    swallowed = []
    tripwire = Tripwire(monkeypatch, k, "after_write",
                        fire=lambda: swallowed.extend(send_swallowed(signal.SIGTERM, monkeypatch)))
    safety = scan_until_terminated(config, emulator, tripwire)
    assert tripwire.fired and swallowed == [Terminated]
    assert safety.report.reason == "SIGTERM" and safety.report.safe
    assert not torque_on_in_emulator(emulator)
    lines = read_journal(journal_path_for(config.output.path)).lines
    assert 0 < len(lines) < 8 and [line.index for line in lines] == list(range(len(lines)))


def scan_args(emulator, cylinder, out):
    return ["rig", "scan", cylinder, "--port", emulator.port_path, "--step-deg", "45", "-o", str(out),
            "--retries", "2", "--status-timeout-ms", "500"]


@pytest.mark.parametrize("signum, code, words", [(signal.SIGINT, 130, "interrupted"),
                                                  (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_rig_scan_command_stops_the_servo_on_a_signal(tmp_path, emulator, cylinder, monkeypatch, capsys,
                                                      signum, code, words):
    for k in (12, 45):
        out = tmp_path / f"plant{k}.ply"
        tripwire = Tripwire(monkeypatch, k, "after_write", fire=lambda: os.kill(os.getpid(), signum))
        tripwire.armed = True
        assert cli.main(scan_args(emulator, cylinder, out)) == code
        err = capsys.readouterr().err
        assert tripwire.fired
        assert f"plantsim: {words}. the lines taken are safe in" in err and "--resume" in err
        assert "DANGER" not in err
        assert not torque_on_in_emulator(emulator)
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_rig_scan_command_exits_143_on_a_sigterm_the_interpreter_swallowed(tmp_path, emulator, cylinder,
                                                                          monkeypatch, capsys):
    swallowed = []
    tripwire = Tripwire(monkeypatch, 30, "after_write",
                        fire=lambda: swallowed.extend(send_swallowed(signal.SIGTERM, monkeypatch)))
    tripwire.armed = True
    assert cli.main(scan_args(emulator, cylinder, tmp_path / "plant.ply")) == 143
    err = capsys.readouterr().err
    assert swallowed == [Terminated]
    assert "plantsim: terminated (SIGTERM). the lines taken are safe in" in err and "DANGER" not in err
    assert not torque_on_in_emulator(emulator)
    assert len(read_journal(journal_path_for(str(tmp_path / "plant.ply"))).lines) < 8


def test_rig_scan_process_killed_from_outside_leaves_torque_off(tmp_path, emulator, cylinder):
    """SIGTERM from another process (kill PID), while the scan turns the servo."""
    out = tmp_path / "plant.ply"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    process = subprocess.Popen([sys.executable, "-m", "plantsim", *scan_args(emulator, cylinder, out)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        # Wait (generously: the child imports MuJoCo) until the servo is on and turning.
        deadline = time.monotonic() + 120
        while not torque_on_in_emulator(emulator):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the scan never switched the servo on"
            time.sleep(0.01)
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 143, err
    assert "plantsim: terminated (SIGTERM)" in err and "DANGER" not in err
    assert not torque_on_in_emulator(emulator)
