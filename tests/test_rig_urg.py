"""Rig scans with the URG LiDAR, hardware in the loop: both emulators in one process on ptys.

The servo emulator (``DynamixelEmulator``) and the URG emulator share one turntable and
one clock (:class:`plantsim.hardware.urg.pair.EmulatorPair`): the LiDAR's timer and the
servo's Realtime Tick count the servo emulator's simulated time, and the host clock the
drivers use is that time too (``host_clock=pair.host_clock``). Nothing is timed on the
wall clock: the emulator records where the table truly was at every beam's instant,
and the rig knows only what the devices report (the sensor's timestamps, the servo's
tick and position), so the checks below hold however late the machine runs the threads.

The reference: the simulated LiDAR of the same configuration (scene, preset, ideal
sensor) cast at each beam's true turntable angle, reconstructed with those angles.
The pair's cloud must match it beam by beam within

    |p_rig - p_ref| <= 0.5 mm + rho * (1 tick + omega * u_t)

* 0.5 mm: the URG sends whole millimetres (the reference is not rounded);
* rho: the point's distance from the turntable axis, the lever arm of an angle error
  (at most the beam's range plus the LiDAR's distance from the axis);
* 1 tick (2 pi / 4096 rad): the servo's reading is its shaft angle rounded to a tick
  (half a tick), and a table at rest may still creep by half a tick after the move's
  stable check (step) or the readings are interpolated linearly between two ticks
  (continuous);
* omega * u_t (continuous only): the turn during the beam-time error, u_t = the TM
  offset's uncertainty + the half millisecond of the sensor's whole-ms stamp + the
  servo tick clock's uncertainty (which includes its half millisecond).
"""

import json
import math
import signal
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest
import trimesh

from plantsim.cloud.reconstruct import base_to_turntable, points_base_from_ranges
from plantsim.errors import ScanInterruptedError, Terminated
from plantsim.hardware.dynamixel.turntable import ServoTurntable
from plantsim.hardware.safety import SafeStop
from plantsim.hardware.urg.driver import UrgLidar
from plantsim.hardware.urg.pair import EmulatorPair
from plantsim.hardware.urg.source import UrgLineSource
from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.scene import HitClass, build_scene
from plantsim.scan.config import OutputOptions, PlantOptions, RunConfig
from plantsim.scan.continuous_rig import continuous_line_count, servo_rpm
from plantsim.scan.journal import read_journal
from plantsim.scan.pipeline import journal_path_for, run_scan, write_result
from plantsim.scan.schedule import StepScan
from plantsim.sensor.spec import BeamStatus
from plantsim.turntable.options import TurntableOptions
from plantsim.turntable.units import RAD_PER_TICK
from test_dxl_safety import send_swallowed

SPEED_FACTOR = 2.5
# A long status timeout costs nothing while replies come, and keeps a reply that a loaded machine
# delays from being lost (and then taken for the answer to the next request).
FAST = dict(retries=5, profile_velocity_rad_s=3.0, profile_acceleration_rad_s2=20.0,
            driver_options={"status_timeout_s": 2.0})
RPM = 12.0


def box_plant():
    """A 4 x 4 x 25 cm box 6 cm off the axis: every turn of the table shows in the ranges."""
    mesh = trimesh.creation.box(extents=(0.04, 0.04, 0.25))
    mesh.apply_translation((0.06, 0.0, 0.125))
    return plant_from_arrays(mesh.vertices, mesh.faces, placement="none")


def config_for(tmp_path, mode="step", **scan):
    turntable = TurntableOptions(mode="continuous", rpm=RPM) if mode == "continuous" else TurntableOptions()
    return RunConfig(plant=PlantOptions(placement="none"), turntable=turntable,
                     scan=StepScan(**scan) if scan else StepScan(),
                     output=OutputOptions(path=str(tmp_path / "plant.las")))


@pytest.fixture()
def plant():
    return box_plant()


def start_pair(config, plant):
    return EmulatorPair(build_scene(config.rig, plant), config.lidar, speed_factor=SPEED_FACTOR, record=True).start()


def connect(pair, config, safety=None):
    table = ServoTurntable.connect(pair.servo_port, **FAST)
    # A generous reply timeout: on a loaded machine the emulators' threads can wait long for a core.
    lidar = UrgLidar.connect(pair.lidar_port, preset=config.lidar, host_clock=pair.host_clock, timeout_s=5.0)
    return table, lidar


def range_key(range_m):
    return np.where(np.isnan(range_m), -1, np.round(range_m * 1000)).astype(np.int64).tobytes()


def truth_of_lines(raw, scans, *, resumed_at=None):
    """The emulator's record of each journaled line: (beam times, true angles, simulated lines).

    Lines are matched by time: the raw stamps are the host clock minus the scan's zero,
    the record's are the emulator's time, so one offset per run (found from the lines
    whose millimetre ranges equal a recorded scan's) links them; a resumed scan's
    second run (lines from ``resumed_at`` on) has its own zero.
    """
    runs = [range(raw.n_lines)] if resumed_at is None else [range(resumed_at), range(resumed_at, raw.n_lines)]
    out = []
    for run in runs:
        votes = Counter()
        for i in run:
            for times, _, lines in scans:
                if range_key(lines.range_m[0]) == range_key(raw.range_m[i]):
                    votes[round((times[0] - raw.line_time_s[i]) * 1000)] += 1
        offset_s = votes.most_common(1)[0][0] / 1000
        for i in run:
            j = int(np.argmin([abs(times[0] - raw.line_time_s[i] - offset_s) for times, _, _ in scans]))
            times, true, lines = scans[j]
            assert abs(times[0] - raw.line_time_s[i] - offset_s) < 0.01, f"line {i} has no emulated scan"
            # The rig journaled exactly what the emulated sensor sent: the simulated ranges in whole mm.
            assert range_key(lines.range_m[0]) == range_key(raw.range_m[i]), f"line {i}"
            np.testing.assert_array_equal(lines.status[0], raw.status[i])
            out.append((times, true, lines))
    return out


def assert_matches_simulation(raw, scans, *, omega_rad_s=0.0, timing_s=0.0, resumed_at=None):
    """Every return of the rig's cloud against the simulated LiDAR at the true angles (see the module)."""
    n_points = 0
    worst = 0.0
    for i, (times, true, lines) in enumerate(truth_of_lines(raw, scans, resumed_at=resumed_at)):
        ok = raw.status[i] == BeamStatus.OK
        angles = raw.beam_angle_rad[ok]
        rig = base_to_turntable(points_base_from_ranges(raw.range_m[i][ok], angles, raw.T_base_lidar),
                                raw.turntable_angle_rad[i][ok])
        ref = base_to_turntable(points_base_from_ranges(lines.range_m[0][ok], angles, raw.T_base_lidar), true[ok])
        rho = np.linalg.norm(ref[:, :2], axis=1)
        tolerance = 0.5e-3 + 1e-6 + rho * (RAD_PER_TICK + omega_rad_s * timing_s)
        error = np.linalg.norm(rig - ref, axis=1)
        assert (error <= tolerance).all(), (i, float((error - tolerance).max()))
        n_points += int(ok.sum())
        worst = max(worst, float((error / tolerance).max()) if len(error) else 0.0)
    assert n_points > 100 * raw.n_lines
    return worst


def test_step_scan_with_the_emulated_urg_matches_the_simulated_scan(tmp_path, plant):
    config = config_for(tmp_path, step_deg=45)
    pair = start_pair(config, plant)
    try:
        table, lidar = connect(pair, config)
        with table, lidar:
            result = run_scan(config, plant=plant, turntable=table, lidar=UrgLineSource(lidar, config.lidar))
    finally:
        pair.stop()
    raw = result.raw
    assert raw.n_lines == 8 and raw.angle_mode == "line" and raw.intensity is None
    assert raw.true_turntable_angle_rad is None and (raw.hit_class == HitClass.NONE).all()
    assert_matches_simulation(raw, pair.scans)
    # Each line was measured with the table at rest at its stop: the true angle is one value per line.
    for times, true, _ in truth_of_lines(raw, pair.scans):
        assert np.ptp(true) < 0.5 * RAD_PER_TICK
    lidar_part = result.parts["lidar"]
    assert lidar_part["kind"] == "urg" and lidar_part["real"] and lidar_part["serial"] == "H0000001"
    assert lidar_part["firmware"].startswith("3.3.00") and "real_parts" in result.parts
    assert result.plan.sensor == "urg"


def continuous_tolerance(result):
    timing = result.diagnostics
    omega = servo_rpm(RPM) * 2 * math.pi / 60
    return omega, timing["lidar_clock_uncertainty_s"] + 0.5e-3 + timing["servo_clock_uncertainty_s"]


def assert_covers_the_sweep(raw, sweep_deg=360.0):
    """Lines in turning order, about one line period apart (a line the host could not place while
    the machine was starved may be missing: two periods at most), over the whole sweep."""
    per_line = servo_rpm(RPM) * 6.0 * raw.grid.scan_period_s
    starts = np.degrees(raw.encoder_offset_rad + raw.turntable_angle_rad[:, 0])
    gaps = np.diff(starts)
    bad = np.flatnonzero((gaps <= 0.4 * per_line) | (gaps >= 2.6 * per_line))
    assert not len(bad), ([(int(i), round(float(gaps[i] / per_line), 2)) for i in bad], len(starts),
                          np.round(gaps / per_line, 2).tolist())
    assert starts[-1] - starts[0] >= sweep_deg - 1.6 * per_line


def test_continuous_scan_with_the_emulated_pair_matches_the_simulated_scan(tmp_path, plant):
    config = config_for(tmp_path, "continuous")
    pair = start_pair(config, plant)
    try:
        table, lidar = connect(pair, config)
        with table, lidar:
            result = run_scan(config, plant=plant, turntable=table, lidar=UrgLineSource(lidar, config.lidar))
            # A normal end holds the table and gives back position mode, torque on.
            assert table.driver.read_register("Operating Mode") == 3 and table.torque_enabled()
        assert pair.servo.servo(1).get("Torque Enable") == 0  # closing the table switched it off
    finally:
        pair.stop()
    raw = result.raw
    n_lines = continuous_line_count(360.0, RPM, 0.1)
    assert raw.n_lines == n_lines and raw.angle_mode == "interpolate"
    assert np.isnan(raw.commanded_rad).all() and (np.diff(raw.encoder_stamp_ns) > 0).all()
    # The encoder log is the servo's own readings (Realtime Tick + position), not one per line.
    assert len(raw.encoder_stamp_ns) >= 10 and not np.isin(raw.line_stamp_ns, raw.encoder_stamp_ns).all()
    assert_covers_the_sweep(raw)
    omega, timing_s = continuous_tolerance(result)
    assert_matches_simulation(raw, pair.scans, omega_rad_s=omega, timing_s=timing_s)
    # The beams of one line were measured while the table turned: each line's true angles span a turn.
    _, true, _ = truth_of_lines(raw, pair.scans)[n_lines // 2]
    assert np.ptp(true) > 0.5 * omega * 0.1 * 682 / 1024


def test_unplugged_lidar_mid_scan_keeps_the_journal_and_resume_completes_it(tmp_path, plant):
    config = config_for(tmp_path, "continuous")
    journal = journal_path_for(config.output.path)
    pair = start_pair(config, plant)
    try:
        table, lidar = connect(pair, config)
        with table, lidar:
            def unplug_at_20(done, total):
                if done == 20:
                    pair.lidar.unplug()

            with pytest.raises(ScanInterruptedError, match=r"continuous scan stopped after line 2\d of "
                               r"\d+; the 2\d complete lines are safe in .*plant\.las\.journal"):
                run_scan(config, plant=plant, turntable=table, lidar=UrgLineSource(lidar, config.lidar),
                         progress=unplug_at_20)
            # The fault switched the servo's torque off at once.
            assert pair.servo.servo(1).get("Torque Enable") == 0
        kept = read_journal(journal)
        assert 20 <= len(kept.lines) <= 21 and len(kept.encoder["angle_rad"]) > 20
        pair.replug()
        table, lidar = connect(pair, config)
        with table, lidar:
            result = run_scan(config, plant=plant, turntable=table, lidar=UrgLineSource(lidar, config.lidar),
                              resume=True)
    finally:
        pair.stop()
    raw = result.raw
    assert raw.n_lines == continuous_line_count(360.0, RPM, 0.1) and result.lines_resumed == len(kept.lines)
    assert_covers_the_sweep(raw)
    omega, timing_s = continuous_tolerance(result)
    # Both runs' lines against the truth; the first run's clocks were as good as the second's (same emulators).
    assert_matches_simulation(raw, pair.scans, omega_rad_s=omega, timing_s=2 * timing_s,
                              resumed_at=result.lines_resumed)
    write_result(result)
    assert not journal.exists()


def test_settings_a_real_lidar_does_not_use_are_refused(tmp_path, plant):
    from plantsim.errors import ConfigError
    from plantsim.scan.plan import plan_scan
    from plantsim.sensor.model import SensorModel

    base = config_for(tmp_path)
    cases = [
        (base.replace(sensor="ideal"), r"--sensor ideal chooses the simulated LiDAR's model; .*remove --sensor"),
        (base.replace(ideal=True), r"--ideal describes simulated parts"),
        (base.replace(sensor_model=SensorModel(dropouts=False)), r"sensor_model is set|describes the simulated "
                                                                   r"sensor model"),
        (base.replace(output=OutputOptions(path=base.output.path, plant_only=True)), r"--plant-only needs"),
        (config_for(tmp_path, "continuous", step_deg=5), r"--step-deg applies to step scans"),
        (base.replace(turntable=TurntableOptions(rpm=3.0)), r"--rpm applies to continuous scans"),
    ]
    for config, message in cases:
        with pytest.raises(ConfigError, match=message):
            plan_scan(config, hardware_turntable=True, real_lidar=True)
    plan = plan_scan(config_for(tmp_path, "continuous"), hardware_turntable=True, real_lidar=True)
    assert (plan.mode, plan.sensor, plan.angle_mode) == ("continuous", "urg", "interpolate")


def test_cli_emulator_pair_and_rig_scan_end_to_end(tmp_path, capsys):
    """``plantsim emulator --lidar`` in its own process, ``plantsim rig scan --lidar urg`` against it."""
    from plantsim import cli

    mesh = trimesh.creation.box(extents=(0.04, 0.04, 0.25))
    mesh.apply_translation((0.06, 0.0, 0.125))
    mesh_path = tmp_path / "box.stl"
    mesh.export(mesh_path)
    emulator = subprocess.Popen([sys.executable, "-m", "plantsim", "emulator", "--lidar", str(mesh_path),
                                 "--placement", "none", "--sensor", "ideal"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        servo_line, lidar_line = emulator.stdout.readline(), emulator.stdout.readline()
        assert servo_line.startswith("servo: /dev/pts/") and lidar_line.startswith("lidar: /dev/pts/"), \
            emulator.stderr.read() if emulator.poll() is not None else servo_line
        servo, lidar = servo_line.split()[1], lidar_line.split()[1]
        out = tmp_path / "plant.las"
        common = ["rig", "scan", str(mesh_path), "--placement", "none", "--port", servo, "--status-timeout-ms",
                  "500", "--lidar-timeout", "15", "-o", str(out)]
        assert cli.main(common + ["--lidar", "urg"]) == 2
        assert "--lidar urg needs --lidar-port PORT" in capsys.readouterr().err
        assert cli.main(common + ["--lidar", "urg", "--lidar-port", lidar, "--sensor", "realistic"]) == 2
        assert "remove --sensor" in capsys.readouterr().err
        assert cli.main(common + ["--lidar", "urg", "--lidar-port", lidar, "--lidar-model", "utm-30lx"]) == 1
        assert "use --lidar-model urg-04lx-ug01" in capsys.readouterr().err
        code = cli.main(common + ["--lidar", "urg", "--lidar-port", lidar, "--mode", "continuous", "--rpm", "20",
                                  "--sweep-deg", "60", "--raw", str(tmp_path / "raw")])
        captured = capsys.readouterr()
        assert code == 0, captured.err
        assert "lines x 683 beams (real URG-04LX serial H0000001, servo turntable, continuous mode)" in captured.out
    finally:
        emulator.terminate()
        emulator.wait(timeout=10)
    side = json.loads((tmp_path / "plant.las.json").read_text())
    lidar_part = side["simulated"]["lidar"]
    assert lidar_part["kind"] == "urg" and lidar_part["real"] is True
    assert (lidar_part["model"], lidar_part["serial"]) == ("URG-04LX", "H0000001")
    assert side["simulated"]["turntable"]["mode"] == "continuous"
    assert side["counts"]["points_written"] > 1000
    assert not journal_path_for(out).exists()


def test_garbled_streamed_scans_are_dropped_and_the_scan_still_matches(tmp_path, plant):
    config = config_for(tmp_path, "continuous")
    pair = start_pair(config, plant)
    try:
        table, lidar = connect(pair, config)
        with table, lidar:
            def garble_from_5(done, total):
                if done == 5:
                    pair.lidar.inject_checksum_errors(150)  # one data line in 150: about one scan in five

            result = run_scan(config, plant=plant, turntable=table, lidar=UrgLineSource(lidar, config.lidar),
                              progress=garble_from_5)
    finally:
        pair.stop()
    assert result.diagnostics["lidar_scans_dropped"] > 0
    assert result.parts["lidar"]["dropped_scans"] == result.diagnostics["lidar_scans_dropped"]
    assert result.raw.n_lines == continuous_line_count(360.0, RPM, 0.1)
    omega, timing_s = continuous_tolerance(result)
    assert_matches_simulation(result.raw, pair.scans, omega_rad_s=omega, timing_s=timing_s)


def test_stalled_stream_interrupts_the_scan_with_the_servo_stopped(tmp_path, plant):
    config = config_for(tmp_path, "continuous")
    pair = start_pair(config, plant)
    try:
        table = ServoTurntable.connect(pair.servo_port, **FAST)
        lidar = UrgLidar.connect(pair.lidar_port, preset=config.lidar, host_clock=pair.host_clock, timeout_s=2.0)
        with table, lidar:
            def stall_at_8(done, total):
                if done == 8:
                    pair.lidar.inject_stall(after_scans=0)

            with pytest.raises(ScanInterruptedError, match=r"stopped streaming: no scan for .* \[continuous scan "
                                                           r"stopped after line \d+ of \d+"):
                run_scan(config, plant=plant, turntable=table, lidar=UrgLineSource(lidar, config.lidar),
                         progress=stall_at_8)
            assert pair.servo.servo(1).get("Torque Enable") == 0
    finally:
        pair.stop()
    assert len(read_journal(journal_path_for(config.output.path)).lines) >= 8


def test_a_swallowed_sigterm_stops_a_continuous_scan_within_a_line_with_the_servo_off(tmp_path, plant, monkeypatch):
    config = config_for(tmp_path, "continuous")
    pair = start_pair(config, plant)
    swallowed = []
    try:
        safety = SafeStop(sleep=lambda s: None)
        with pytest.raises(Terminated):
            with safety:
                table = ServoTurntable.connect(pair.servo_port, safety=safety, **FAST)
                lidar = UrgLidar.connect(pair.lidar_port, preset=config.lidar, host_clock=pair.host_clock,
                                         timeout_s=5.0, safety=safety)
                with table, lidar:
                    def kill_at_10(done, total):
                        if done == 10:
                            swallowed.extend(send_swallowed(signal.SIGTERM, monkeypatch))

                    run_scan(config, plant=plant, turntable=table, lidar=UrgLineSource(lidar, config.lidar),
                             progress=kill_at_10)
        assert swallowed == [Terminated]  # the interpreter went on; the loop's check stopped the scan
        assert safety.report.reason == "SIGTERM" and safety.report.safe, safety.report.summary()
        assert pair.servo.servo(1).get("Torque Enable") == 0
    finally:
        pair.stop()
    assert 10 <= len(read_journal(journal_path_for(config.output.path)).lines) <= 11
