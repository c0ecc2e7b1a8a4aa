"""UrgLidar against the emulated URG-04LX: handshake, scans, streams, clock, faults, safety.

Driver and emulator share a VirtualClock, so times are exact and nothing waits on
the machine's load; wall-clock timeouts are generous (5 s) where replies must come,
and short only where a fault guarantees that nothing comes.
"""

import math

import numpy as np
import pytest

from plantsim.errors import (LidarChecksumError, LidarDisconnectedError, LidarModelError, LidarStatusError,
                             LidarTimeoutError)
from plantsim.hardware.safety import SafeStop
from plantsim.hardware.urg import UrgEmulator, UrgLidar, VirtualClock
from plantsim.hardware.urg.clock import ClockOffset, estimate_offset
from plantsim.sensor.spec import URG_04LX_UG01, UTM_30LX, BeamStatus

pytest.importorskip("serial")


def ramp_provider(calls=None):
    """Step k reads 300 + k mm (+ 1 mm per 100 ms of the scan's start time); some error statuses."""

    def provide(t):
        if calls is not None:
            calls.append(t)
        ranges = (300 + np.arange(UrgEmulator.N_STEPS) + round(t * 10)) / 1000.0
        status = np.full(UrgEmulator.N_STEPS, BeamStatus.OK, dtype=np.int8)
        status[200:203] = [BeamStatus.LOW_INTENSITY, BeamStatus.EDGE, BeamStatus.TOO_NEAR]
        ranges[300] = np.nan
        return ranges, status

    return provide


def connect(emulator, clock, **options):
    options.setdefault("timeout_s", 5.0)
    return UrgLidar.connect(emulator.port_path, host_clock=clock.now, sleep=clock.sleep, **options)


@pytest.fixture
def rig():
    clock = VirtualClock(start_s=3.0)
    calls = []
    with UrgEmulator(ramp_provider(calls), clock=clock, timestamp_offset_s=42.0) as emulator:
        yield emulator, clock, calls


def test_handshake_reads_vv_pp_ii(rig):
    emulator, clock, _ = rig
    with connect(emulator, clock) as lidar:
        info = lidar.info
        assert (info.model, info.ares, info.amin, info.amax, info.afrt, info.dmax_mm) == (
            "URG-04LX", 1024, 44, 725, 384, 5600)
        assert info.serial == "H0000001" and info.protocol == "SCIP 2.0"
        assert info.ii["LASR"] == "OFF" and info.scan_period_s == pytest.approx(0.1)


def test_model_mismatch_names_both(rig):
    emulator, clock, _ = rig
    with pytest.raises(LidarModelError, match=r"is a URG-04LX .* but the preset 'utm-30lx'.*ARES=1024 \(expected 1440\)"):
        connect(emulator, clock, preset=UTM_30LX)
    assert emulator.commands[-1].startswith("QT")  # the failed connect still left the laser off


def test_scan_values_angles_and_statuses(rig):
    emulator, clock, calls = rig
    with connect(emulator, clock) as lidar:
        scan = lidar.scan()
    steps = np.arange(44, 727)
    assert scan.first_step == 44 and scan.last_step == 726 and len(scan.ranges_m) == URG_04LX_UG01.n_beams
    np.testing.assert_allclose(scan.angles_rad, URG_04LX_UG01.beam_angles_rad(), atol=1e-12)
    t_scan = calls[-1]
    expected_mm = 300 + steps + round(t_scan * 10)
    ok = scan.status == BeamStatus.OK
    np.testing.assert_array_equal(scan.raw_mm[ok], expected_mm[ok])
    np.testing.assert_allclose(scan.ranges_m[ok], expected_mm[ok] / 1000)
    by_step = dict(zip(steps, scan.status))
    assert (by_step[200], by_step[201], by_step[202], by_step[300]) == (
        BeamStatus.LOW_INTENSITY, BeamStatus.EDGE, BeamStatus.NO_ECHO, BeamStatus.NO_ECHO)
    assert np.isnan(scan.ranges_m[~ok]).all() and scan.n_valid == 683 - 4
    # Timestamps and times: step 0 at t_scan on the shared clock (the host's here).
    assert scan.timestamp_ms == round((t_scan + 42.0) * 1000)
    beam_t = t_scan + steps / 1024 * 0.1
    np.testing.assert_allclose(scan.beam_host_times_s, beam_t, atol=lidar.clock_offset.uncertainty_s + 1e-3)
    assert scan.host_receive_s >= beam_t[-1]


def test_scan_after_a_host_time_is_fresh(rig):
    emulator, clock, _ = rig
    with connect(emulator, clock) as lidar:
        first = lidar.scan()
        settled = clock.now() + 0.35
        later = lidar.scan(after_host_s=settled)
    assert later.beam_host_times_s[0] >= settled - 1e-3
    assert later.sensor_time_s > first.sensor_time_s


def test_stream_scans_every_100_ms(rig):
    emulator, clock, calls = rig
    with connect(emulator, clock) as lidar:
        scans = list(lidar.stream(n_scans=5))
        assert not lidar.laser_is_on
        assert np.diff([s.sensor_time_s for s in scans]) == pytest.approx([0.1] * 4)
        assert all(s.n_valid == 679 for s in scans)
        # Unlimited stream, left early: the driver sends QT.
        for i, _ in enumerate(lidar.stream()):
            if i == 2:
                break
        assert not emulator.streaming and not emulator.laser_on
        assert emulator.commands[-1].startswith("QT")


def test_timestamps_unwrap_across_the_24_bit_wrap():
    clock = VirtualClock()
    wrap_s = (1 << 24) / 1000.0
    with UrgEmulator(clock=clock, timestamp_offset_s=wrap_s - 0.25) as emulator:
        with connect(emulator, clock) as lidar:
            scans = list(lidar.stream(n_scans=6))
    raw = [s.timestamp_ms for s in scans]
    assert any(b < a for a, b in zip(raw, raw[1:])), raw  # the timer did wrap
    assert np.diff([s.sensor_time_s for s in scans]) == pytest.approx([0.1] * 5)
    assert np.diff([s.beam_host_times_s[0] for s in scans]) == pytest.approx([0.1] * 5, abs=1e-9)


@pytest.mark.parametrize("skew_s, latency_s", [(0.0, 0.0), (1234.5678, 0.003), (-2.5, 0.0125)])
def test_clock_offset_with_controlled_skew(skew_s, latency_s):
    clock = VirtualClock(start_s=10.0)
    with UrgEmulator(clock=clock, timestamp_offset_s=skew_s, latency_s=latency_s) as emulator:
        with connect(emulator, clock) as lidar:
            offset = lidar.clock_offset
    assert isinstance(offset, ClockOffset) and offset.n_round_trips == 10
    assert offset.round_trip_s == pytest.approx(2 * latency_s)
    assert offset.uncertainty_s == pytest.approx(latency_s + 0.0005)
    assert abs(offset.offset_s - skew_s) <= offset.uncertainty_s + 1e-9


def test_estimate_offset_takes_the_fastest_round_trip():
    samples = [(0.0, 1_000, 0.010), (1.0, 2_003, 1.002), (2.0, 3_050, 2.100)]
    offset = estimate_offset(samples)
    assert offset.round_trip_s == pytest.approx(0.002)
    assert offset.offset_s == pytest.approx(2.0035 - 1.001)


def test_scip11_and_time_adjust_mode_are_recovered():
    clock = VirtualClock()
    with UrgEmulator(clock=clock, start_in_scip11=True) as emulator:
        with connect(emulator, clock) as lidar:
            assert lidar.scan().n_valid == 682
        assert "SCIP2.0" in emulator.commands
    with UrgEmulator(clock=clock) as emulator:
        emulator.time_adjust = True
        with connect(emulator, clock, sync_clock=False) as lidar:
            assert lidar.info.model == "URG-04LX"
        assert any(c.startswith("TM2") for c in emulator.commands[:3])


def test_status_error_names_the_meaning(rig):
    emulator, clock, _ = rig
    with connect(emulator, clock) as lidar:
        with pytest.raises(LidarStatusError, match=r"status 04 \(end step is out of range\)") as info:
            lidar.scan(start_step=0, end_step=900)
        assert info.value.command == "GD" and info.value.status == "04"


# --- faults ----------------------------------------------------------------------------

def test_occasional_checksum_errors_are_retried(rig):
    emulator, clock, _ = rig
    with connect(emulator, clock) as lidar:
        lidar.laser_on()
        emulator.inject_checksum_errors(100)  # one line in 100: about one GD reply (35 lines) in three is hit
        scans = [lidar.scan() for _ in range(4)]
    assert all(s.n_valid == 679 for s in scans)
    assert sum(c.startswith("GD") for c in emulator.commands) > 4  # some were asked for again


def test_persistent_checksum_errors_raise_naming_the_port(rig):
    emulator, clock, _ = rig
    with connect(emulator, clock) as lidar:
        lidar.laser_on()
        emulator.inject_checksum_errors(1)
        with pytest.raises(LidarChecksumError, match=f"LiDAR on {emulator.port_path} kept sending garbled replies "
                                                     r"to GD.*3 attempts"):
            lidar.scan()
        emulator.clear_faults()


def test_garbled_scans_in_a_stream_are_dropped_then_raise(rig):
    emulator, clock, _ = rig
    with connect(emulator, clock) as lidar:
        emulator.inject_checksum_errors(60)
        scans = list(lidar.stream(n_scans=8))
        assert lidar.dropped_scans > 0 and len(scans) == 8 - lidar.dropped_scans
        emulator.clear_faults()
        with pytest.raises(LidarChecksumError, match="garbled scans in a row"):
            for i, _ in enumerate(lidar.stream()):
                if i == 1:
                    emulator.inject_checksum_errors(1)
        emulator.clear_faults()
    assert not emulator.laser_on


def test_stalled_stream_times_out_and_laser_off_is_not_confirmed(rig):
    emulator, clock, _ = rig
    lidar = connect(emulator, clock, timeout_s=0.3, retries=1)
    got = []
    emulator.inject_stall(after_scans=2)  # two whole scans, half of the third, then silence
    with pytest.raises(LidarTimeoutError, match=f"LiDAR on {emulator.port_path} stopped streaming.*after 2 scans"):
        for scan in lidar.stream():
            got.append(scan)
    assert len(got) == 2
    assert lidar.laser_off() is False  # the stalled sensor cannot confirm
    emulator.clear_faults()
    assert lidar.laser_off() is True
    assert lidar.close() is True


def test_no_reply_is_a_timeout_naming_the_port(rig):
    emulator, clock, _ = rig
    # Connect with the usual timeout (a busy machine may answer the handshake late), then
    # shorten it for the silence this test is about.
    with connect(emulator, clock, retries=1) as lidar:
        lidar.timeout_s = 0.2
        emulator.inject_stall()
        emulator._stalled = True  # silence now, not after a stream
        with pytest.raises(LidarTimeoutError, match=f"no reply from the LiDAR on {emulator.port_path} to VV"):
            lidar._command("VV")
        emulator.clear_faults()
        lidar.timeout_s = 5.0  # for the QT that closes it


def test_unplug_mid_stream_is_a_disconnect(rig):
    emulator, clock, _ = rig
    lidar = connect(emulator, clock, timeout_s=0.5)
    with pytest.raises(LidarDisconnectedError, match=f"LiDAR on {emulator.port_path} vanished"):
        for i, _ in enumerate(lidar.stream()):
            if i == 1:
                emulator.unplug()
    assert lidar.close() is False  # QT cannot be confirmed on a pulled cable


def test_open_missing_port_is_actionable():
    with pytest.raises(LidarDisconnectedError, match="cannot open the LiDAR's port /dev/does-not-exist.*dialout"):
        UrgLidar.connect("/dev/does-not-exist")


# --- safety ---------------------------------------------------------------------------

def test_laser_off_on_exit_even_after_an_error(rig):
    emulator, clock, _ = rig
    with pytest.raises(RuntimeError):
        with connect(emulator, clock) as lidar:
            lidar.laser_on()
            assert emulator.laser_on
            raise RuntimeError("something else failed")
    assert not emulator.laser_on and emulator.commands[-1].startswith("QT")


def test_stop_action_with_safe_stop(rig):
    emulator, clock, _ = rig
    with SafeStop(signals=(), sleep=lambda s: None) as safety:
        lidar = connect(emulator, clock, safety=safety)
        lidar.laser_on()
    assert safety.report.safe and not emulator.laser_on
    assert lidar.close() is True
    n_commands = len(emulator.commands)
    assert lidar.laser_off() is True and len(emulator.commands) == n_commands  # closed: the port stays shut


def test_beam_times_follow_each_scan(rig):
    emulator, clock, calls = rig
    with connect(emulator, clock) as lidar:
        scans = list(lidar.stream(n_scans=3, skip=1))
    starts = calls[-3:]
    assert np.diff(starts) == pytest.approx([0.2, 0.2])
    for scan, t in zip(scans, starts):
        assert scan.beam_host_times_s[0] == pytest.approx(t + 44 / 1024 * 0.1, abs=lidar.clock_offset.uncertainty_s + 1e-3)
        assert math.isclose(scan.beam_host_times_s[-1] - scan.beam_host_times_s[0], 682 / 1024 * 0.1)


def test_preset_provider_beam_times_reach_the_driver_unchanged():
    """A line source given each beam's instant (as the simulated LiDAR seeing the turning
    table would be) comes back through SCIP with those instants as the beams' host times."""
    from plantsim.hardware.urg import preset_provider

    seen = []

    def line(beam_times_s):
        seen.append(beam_times_s)
        return 1.0 + (beam_times_s - beam_times_s[0]) * 10.0, np.zeros(len(beam_times_s), dtype=np.int8)

    clock = VirtualClock(start_s=1.0)
    with UrgEmulator(preset_provider(line), clock=clock, timestamp_offset_s=7.0) as emulator:
        with connect(emulator, clock) as lidar:
            scan = lidar.scan()
    np.testing.assert_allclose(scan.beam_host_times_s, seen[-1], atol=lidar.clock_offset.uncertainty_s + 1e-3)
    np.testing.assert_allclose(scan.ranges_m, np.round(1000 * (1.0 + (seen[-1] - seen[-1][0]) * 10.0)) / 1000)


def test_clock_drift_is_estimated_from_two_syncs():
    clock = VirtualClock(start_s=5.0)
    with UrgEmulator(clock=clock, timestamp_offset_s=20.0, clock_drift_ppm=80.0, latency_s=0.0005) as emulator:
        with connect(emulator, clock) as lidar:
            assert lidar.clock_offset.drift == 0.0
            clock.advance(100.0)
            offset = lidar.sync_clock()
            assert offset.drift == pytest.approx(80e-6, abs=2 * (2 * offset.uncertainty_s) / 100.0)
            clock.advance(200.0)  # long after the sync: the drift keeps the beams on time
            scan = lidar.scan()
    t_step0 = round(scan.sensor_time_s * 1000) / 1000  # invert the emulator's sensor timer exactly
    t_scan = (t_step0 - 20.0) / (1 + 80e-6)
    assert scan.beam_host_times_s[0] == pytest.approx(t_scan + 44 / 1024 * 0.1, abs=2e-3)
