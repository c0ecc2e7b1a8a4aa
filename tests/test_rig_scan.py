"""Rig scans: one session for the simulated and the emulated rig, journal and --resume, faults.

The hardware-in-the-loop tests drive the servo emulator through the real
``dynamixel_sdk``; the LiDAR is simulated at the servo's reported angle.
"""

import math

import numpy as np
import pytest
import trimesh

from plantsim.scan.config import OutputOptions, PlantOptions, RunConfig
from plantsim.turntable import units
from plantsim.hardware.dynamixel.emulator import OVERLOAD, DynamixelEmulator
from plantsim.errors import HardwareError, JournalError, ScanInterruptedError
from plantsim.scan.journal import read_journal
from plantsim.cloud.reconstruct import base_to_turntable, points_base_from_ranges
from plantsim.scan.pipeline import journal_path_for, run_scan, step_and_shoot, write_result
from plantsim.scan.raw import BeamGrid
from plantsim.scan.schedule import StepScan
from plantsim.rig.scene import HitClass
from plantsim.sensor.casting import make_backend
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.sensor.spec import BeamStatus
from plantsim.hardware.dynamixel.turntable import ServoTurntable
from plantsim.turntable.table import SimulatedTurntable

QUANTUM_RAD = units.RAD_PER_TICK  # 2 pi / 4096
# The emulator's bus clock: simulated time advances with the exchanges, so the scan
# is the same exchange by exchange however busy the machine. A brisk profile keeps
# the emulated moves short (the CLI's default is gentler). The scheduler allowance
# covers an emulator thread kept waiting; a status later still is retried.
CLOCK = "bus"
ALLOWANCE_S = 2.0  # two busy loops on both cores starved the emulator's thread past 0.5 s
# After each move the shaft must hold its tick for 0.1 s of the servo's clock (what the
# 20 ms default came to when this test ran the emulator on the wall clock at speed 5):
# the integral gain then brings it within a tick of the goal, which the point
# comparisons below count on.
FAST = dict(retries=5, profile_velocity_rad_s=3.0, profile_acceleration_rad_s2=20.0, stable_interval_s=0.1,
            driver_options={"scheduler_allowance_s": ALLOWANCE_S})


def cylinder_config(tmp_path, name="cyl.ply", step_deg=10.0):
    """A 5 cm radius faceted cylinder on the axis, written as a mesh file for the config."""
    mesh = trimesh.creation.cylinder(radius=0.05, height=0.3, sections=512)
    path = tmp_path / "cylinder.stl"
    mesh.export(path)
    return RunConfig(plant=PlantOptions(mesh=str(path)), scan=StepScan(step_deg=step_deg), sensor="ideal",
                     output=OutputOptions(path=str(tmp_path / name)))


def maize_config(tmp_path, name, step_deg=10.0):
    return RunConfig(scan=StepScan(step_deg=step_deg), sensor="ideal", output=OutputOptions(path=str(tmp_path / name)))


def run_rig_scan(config, table, **options):
    """The one scan pipeline with a turntable driven line by line."""
    return run_scan(config, turntable=table, **options)


class Interrupt(Exception):
    pass


def stop_after(k, action=None):
    """A progress callback that acts (default: raises Interrupt) once k lines are done."""

    def progress(done, total):
        if done == k:
            if action is None:
                raise Interrupt
            action()

    return progress


def assert_raw_equal(a, b):
    for name in ("range_m", "status", "hit_class", "geom_id", "time_s", "turntable_angle_rad",
                 "true_turntable_angle_rad", "beam_angle_rad", "T_base_lidar"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def cast_at(scene, lidar, angles_rad, caster="auto"):
    """Ranges and geoms of a kinematic scan at the given angles (the obvious reference).

    ``caster``: the scan's own (its configuration's default), so that the same rays meet
    the same triangles: Embree on the plant's own vertices and MuJoCo on its float32 copy
    of them differ by ~1e-8 m.
    """
    lines = SimulatedLidar(scene, lidar, BeamGrid.of(lidar).beam_angles_rad(),
                           backend=make_backend(scene, caster)).cast_lines(
        np.asarray(angles_rad), np.random.default_rng(0))
    return lines.range_m, lines.status, lines.geom_id


def matched_points(raw_a, raw_b):
    """Turntable-frame points of the beams that return in both scans; their hit classes."""
    both = (raw_a.status == BeamStatus.OK) & (raw_b.status == BeamStatus.OK)
    lines, beams = np.nonzero(both)

    def points(raw):
        base = points_base_from_ranges(raw.range_m[lines, beams], raw.beam_angle_rad[beams], raw.T_base_lidar)
        return base_to_turntable(base, raw.turntable_angle_rad[lines, beams])

    return points(raw_a), points(raw_b), raw_a.hit_class[lines, beams]


# --- the simulated rig through the session -----------------------------------------


def test_simulated_session_is_step_and_shoot_bit_for_bit(tmp_path):
    config = cylinder_config(tmp_path, step_deg=30)
    result = run_rig_scan(config, SimulatedTurntable())
    reference = step_and_shoot(result.scene, config.lidar, config.scan)
    assert_raw_equal(result.raw, reference)


class CountingTurntable(SimulatedTurntable):
    def __init__(self):
        super().__init__()
        self.moves = []

    def move_to(self, angle_rad):
        self.moves.append(angle_rad)
        return super().move_to(angle_rad)


def test_interrupt_and_resume_gives_every_line_once(tmp_path):
    config = cylinder_config(tmp_path, step_deg=30)
    journal = journal_path_for(config.output.path)
    with pytest.raises(Interrupt):
        run_rig_scan(config, SimulatedTurntable(), progress=stop_after(5))
    assert [line.index for line in read_journal(journal).lines] == [0, 1, 2, 3, 4]
    # A crash in the middle of the next write leaves a torn record behind.
    with journal.open("ab") as handle:
        handle.write(b"PSJ1\x40\x00\x00\x00partial")
    with pytest.raises(JournalError, match="pass --resume"):
        run_rig_scan(config, SimulatedTurntable())
    table = CountingTurntable()
    resumed = run_rig_scan(config, table, resume=True)
    assert resumed.lines_resumed == 5 and len(table.moves) == 12 - 5
    assert table.moves[0] == pytest.approx(math.radians(150))
    uninterrupted = run_rig_scan(cylinder_config(tmp_path, "whole.ply", step_deg=30), SimulatedTurntable())
    assert_raw_equal(resumed.raw, uninterrupted.raw)
    assert [line.index for line in read_journal(journal).lines] == list(range(12))
    write_result(resumed)
    assert not journal.exists()


def test_resume_refuses_another_configuration(tmp_path):
    config = cylinder_config(tmp_path, step_deg=30)
    with pytest.raises(Interrupt):
        run_rig_scan(config, SimulatedTurntable(), progress=stop_after(2))
    other = cylinder_config(tmp_path, step_deg=20)
    with pytest.raises(JournalError, match=r"another configuration \(differs in: scan.step_deg\)"):
        run_rig_scan(other, SimulatedTurntable(), resume=True)


class FailingTurntable(SimulatedTurntable):
    def __init__(self, fail_at):
        super().__init__()
        self.fail_at = fail_at

    def move_to(self, angle_rad):
        if angle_rad >= self.fail_at:
            raise HardwareError("servo ID 1 on /dev/ttyUSB0: no status packet; check the cable")
        return super().move_to(angle_rad)


def test_hardware_failure_keeps_the_journal(tmp_path):
    config = cylinder_config(tmp_path, step_deg=30)
    with pytest.raises(ScanInterruptedError, match=r"check the cable \[scan stopped at line 4 of 12 \(90 deg\); "
                       r"the 3 complete lines are safe in .*cyl.ply.journal\]") as caught:
        run_rig_scan(config, FailingTurntable(math.radians(89)))
    assert caught.value.lines_done == 3 and caught.value.n_lines == 12
    assert len(read_journal(journal_path_for(config.output.path)).lines) == 3


def test_session_validates_settle_time(tmp_path):
    config = cylinder_config(tmp_path)
    with pytest.raises(ValueError, match="settle_s must be finite and >= 0, got -1"):
        run_rig_scan(config, SimulatedTurntable(), settle_s=-1)


# --- hardware in the loop: the emulated servo ---------------------------------------


@pytest.fixture
def emulator():
    with DynamixelEmulator(ids=(1,), clock=CLOCK) as emu:
        yield emu


def shaft_recorder(emulator, into):
    """Progress callback recording the emulated shaft's true angle after each line."""

    def progress(done, total):
        with emulator.lock:
            into.append(emulator.servo(1).shaft.position)

    return progress


def check_hil_against_simulated(hil, sim, truth, config):
    """The HIL scan against a simulated one: angles per line, then points. Returns numbers."""
    raw, reference = hil.raw, sim.raw
    commanded = config.scan.angles_rad()
    reported = raw.turntable_angle_rad[:, 0]
    # The servo stops within the move tolerance (2 ticks) of the goal tick, which is
    # within half a tick of the commanded angle; the shaft is within a tick of its report.
    angle_error = reported - commanded
    assert np.abs(angle_error).max() <= 2.5 * QUANTUM_RAD
    shaft_error = np.array(truth[1:]) - reported
    assert np.abs(shaft_error).max() <= QUANTUM_RAD
    # The rays were cast at the reported angle and reconstructed with it: the HIL lines
    # are exactly a kinematic scan at the reported angles.
    range_m, status, geom = cast_at(hil.scene, config.lidar, reported, config.caster)
    np.testing.assert_array_equal(raw.range_m, range_m)
    np.testing.assert_array_equal(raw.geom_id, geom)
    np.testing.assert_array_equal(raw.true_turntable_angle_rad, raw.turntable_angle_rad)
    # Points: turning the table by d theta moves a surface point by rho |d theta|, rho
    # its distance from the axis (in the turntable frame, the fixed rig turns by
    # -d theta just the same). Where the surface is smooth and seen head-on, a beam's
    # point moves by about that much; count how many stay within rho x one tick.
    points_hil, points_sim, hit_class = matched_points(raw, reference)
    distance = np.linalg.norm(points_hil - points_sim, axis=1)
    rho = np.linalg.norm(points_sim[:, :2], axis=1)
    within = distance <= rho * QUANTUM_RAD + 1e-6
    plant = hit_class == HitClass.PLANT
    return {"angle_error_max_ticks": float(np.abs(angle_error).max() / QUANTUM_RAD),
            "shaft_error_max_ticks": float(np.abs(shaft_error).max() / QUANTUM_RAD),
            "points_hil": len(hil.cloud), "points_sim": len(sim.cloud),
            "fraction_within": float(within.mean()), "fraction_plant_within": float(within[plant].mean()),
            "median_distance_m": float(np.median(distance)), "median_bound_m": float(np.median(rho) * QUANTUM_RAD),
            "max_distance_m": float(distance.max())}


def test_hil_scan_of_a_cylinder_matches_the_simulated_scan(tmp_path, emulator):
    config = cylinder_config(tmp_path, "hil.ply", step_deg=30)
    truth = []
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        hil = run_rig_scan(config, table, progress=shaft_recorder(emulator, truth))
    sim = run_rig_scan(cylinder_config(tmp_path, "sim.ply", step_deg=30), SimulatedTurntable())
    numbers = check_hil_against_simulated(hil, sim, truth, config)
    print(numbers)
    # A cylinder on the axis looks the same at every angle: every matched point is the
    # simulated one turned by the angle error, within rho x one tick.
    assert numbers["fraction_within"] == 1.0
    assert numbers["points_hil"] == numbers["points_sim"]


def test_hil_scan_of_the_bundled_maize_matches_the_simulated_scan(tmp_path, emulator):
    config = maize_config(tmp_path, "hil.las")
    truth = []
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        hil = run_rig_scan(config, table, progress=shaft_recorder(emulator, truth))
        path = write_result(hil)
    sim = run_rig_scan(maize_config(tmp_path, "sim.las"), SimulatedTurntable())
    numbers = check_hil_against_simulated(hil, sim, truth, config)
    print(numbers)
    # Leaves seen edge-on or at a silhouette can jump to another surface when the beam
    # moves by a fraction of a tick; nearly all points move less than rho x one tick.
    assert abs(numbers["points_hil"] - numbers["points_sim"]) <= 0.001 * numbers["points_sim"]
    assert numbers["median_distance_m"] <= numbers["median_bound_m"]
    assert numbers["fraction_within"] >= 0.99
    import json

    side = json.loads(path.with_name(path.name + ".json").read_text())
    turntable = side["simulated"]["turntable"]
    assert turntable["motion"] == "hardware" and turntable["port"] == emulator.port_path
    assert turntable["model"] == "XM430-W350" and turntable["firmware"] == 46
    assert side["simulated"]["lidar"]["sensor"] == "ideal"
    assert side["journal"]["kept"] is False and not journal_path_for(path).exists()


def test_lost_reply_mid_scan_is_a_clear_error_then_resume_completes(tmp_path, emulator):
    config = cylinder_config(tmp_path, step_deg=30)
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        with pytest.raises(ScanInterruptedError, match=(
                rf"on {emulator.port_path} ID 1 at 57600 bps failed: \[TxRxResult\] There is no status packet!.*"
                r"Check that the servo is powered.*scan stopped at line 5 of 12.*4 complete lines are safe")):
            # No status will come: no need to allow for the scheduler (each retry waits).
            run_rig_scan(config, table, progress=stop_after(4, lambda: (
                emulator.inject_no_reply(1, count=None), setattr(table.driver, "scheduler_allowance_s", 0.0))))
    emulator.clear_faults()
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        resumed = run_rig_scan(config, table, resume=True)
    assert resumed.lines_resumed == 4
    lines = read_journal(journal_path_for(config.output.path)).lines
    assert [line.index for line in lines] == list(range(12))
    np.testing.assert_array_equal([line.commanded_angle_rad for line in lines], config.scan.angles_rad())
    range_m, _, _ = cast_at(resumed.scene, config.lidar, resumed.raw.turntable_angle_rad[:, 0], config.caster)
    np.testing.assert_array_equal(resumed.raw.range_m, range_m)


def test_unplugged_adapter_mid_scan_then_resume_on_a_new_port(tmp_path):
    config = cylinder_config(tmp_path, step_deg=30)
    with DynamixelEmulator(ids=(1,), clock=CLOCK) as first:
        with ServoTurntable.connect(first.port_path, **FAST) as table:
            with pytest.raises(ScanInterruptedError, match=rf"on {first.port_path} ID 1: the port failed.*"
                               r"connect\(\) again.*the 6 complete lines are safe"):
                run_rig_scan(config, table, progress=stop_after(6, first.disconnect))
    # A replugged adapter (here: a new emulator) has a new port name; the journal still fits.
    with DynamixelEmulator(ids=(1,), clock=CLOCK) as second:
        with ServoTurntable.connect(second.port_path, **FAST) as table:
            resumed = run_rig_scan(config, table, resume=True)
    assert resumed.lines_resumed == 6 and resumed.raw.n_lines == 12
    assert [line.index for line in read_journal(journal_path_for(config.output.path)).lines] == list(range(12))


def test_overload_mid_scan_is_reported_as_the_shutdown(tmp_path, emulator):
    config = cylinder_config(tmp_path, step_deg=30)
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        with pytest.raises(ScanInterruptedError, match=r"reports overload error and has dropped torque.*"
                           r"check the load.*line 3 of 12") as caught:
            run_rig_scan(config, table, progress=stop_after(2, lambda: emulator.inject_hardware_error(1, OVERLOAD)))
    assert caught.value.lines_done == 2


def test_one_lost_reply_is_retried_and_the_scan_completes(tmp_path, emulator):
    config = cylinder_config(tmp_path, step_deg=30)
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        result = run_rig_scan(config, table, progress=stop_after(3, lambda: emulator.inject_no_reply(1, count=1)))
    assert result.raw.n_lines == 12


def test_servo_refuses_angles_beyond_its_position_limits(tmp_path, emulator):
    # The last line of 0.04-degree steps is at 359.96 deg, tick 4096; position mode ends at tick 4095.
    config = RunConfig(scan=StepScan(step_deg=0.04), output=OutputOptions(path=str(tmp_path / "x.ply")))
    with ServoTurntable.connect(emulator.port_path, **FAST) as table:
        with pytest.raises(ValueError, match=r"angles span \[0.00, 359.96\] deg.*limits are \[0.00, 359.91\] deg"):
            run_rig_scan(config, table)
    assert not journal_path_for(config.output.path).exists()
