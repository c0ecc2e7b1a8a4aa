"""An emulated LiDAR slower than its stream, and device clocks faster than the host's.

``plantsim emulator --lidar --speed-factor 20`` used to stall a continuous rig scan:
its LiDAR must cast 200 scans per wall second, and it cast every scan due in one
batch before sending any (each batch's cast time made the next batch larger), so
the host saw no scan for seconds; and even a LiDAR that kept up counts 20 s of its
timer per host second, which a scan timed on the host's clock cannot use. Both on a
clock the test controls (:class:`VirtualClock`): a cast "takes" simulated time by
moving the clock on, and the host's clock is the emulator's divided by 20.
"""

import math

import numpy as np
import pytest

from plantsim.errors import HardwareError
from plantsim.hardware.urg import UrgEmulator, UrgLidar, VirtualClock
from plantsim.hardware.urg.clock import RATE_TOLERANCE, estimate_offset, rate_bounds
from plantsim.hardware.urg.source import UrgLineSource
from plantsim.scan.continuous_rig import check_lidar_clock_rate, run_continuous_session
from plantsim.scan.raw import BeamGrid
from plantsim.sensor.spec import URG_04LX_UG01, BeamStatus

pytest.importorskip("serial")

CAST_S = 0.25  # a cast slower than the 0.1 s scan period: 2.5 scans fall due during each


def flat_provider(clock=None, cast_s=0.0):
    """1 m everywhere; each call moves ``clock`` on by ``cast_s`` (the cast's time)."""

    def provide(t_scan_start_s):
        if clock is not None and cast_s:
            clock.advance(cast_s)
        return np.full(UrgEmulator.N_STEPS, 1.0), np.full(UrgEmulator.N_STEPS, BeamStatus.OK, dtype=np.int8)

    return provide


@pytest.mark.parametrize("rate", [1.0, 1.00005, 2.5, 20.0])
def test_rate_bounds_bracket_the_true_rate_whatever_the_round_trips(rate):
    rng = np.random.default_rng(3)
    samples, t = [], 5.0
    for _ in range(10):
        sent = t
        read = sent + rng.uniform(0, 0.004)  # the sensor reads its timer somewhere inside the round trip
        received = read + rng.uniform(0, 0.004)
        samples.append((sent, math.floor(1000 * (100.0 + rate * read)), received))
        t = received + rng.uniform(0, 0.01)  # a host that sometimes comes back late
    low, high = rate_bounds(samples)
    assert low <= rate <= high
    assert estimate_offset(samples).runs_at_host_rate() == (abs(rate - 1) < RATE_TOLERANCE)


def test_one_round_trip_bounds_nothing():
    assert rate_bounds([(0.0, 5, 0.001)]) == (0.0, math.inf)
    assert estimate_offset([(0.0, 5, 0.001)]).runs_at_host_rate()


def connect(emulator, clock, host_per_emulator_s=1.0):
    """The driver on a host clock that counts ``host_per_emulator_s`` per emulator second."""
    return UrgLidar.connect(emulator.port_path, host_clock=lambda: clock.now() * host_per_emulator_s,
                            sleep=lambda dt: clock.sleep(dt / host_per_emulator_s), timeout_s=5.0)


def test_a_lidar_20_times_faster_than_the_host_is_refused_before_the_scan_starts(tmp_path):
    clock = VirtualClock(start_s=2.0)
    journal = tmp_path / "plant.las.journal"
    # latency_s: each TM round trip takes 4 ms of the emulator's time, so its timer moves during the sync.
    with UrgEmulator(flat_provider(), clock=clock, latency_s=0.002) as emulator, \
            connect(emulator, clock, host_per_emulator_s=1 / 20) as lidar:
        offset = lidar.clock_offset
        assert 15 < offset.rate_low <= 20 <= offset.rate_high
        source = UrgLineSource(lidar, URG_04LX_UG01)
        with pytest.raises(HardwareError, match=r"the LiDAR on /dev/\S+ counts 1\d\.?\d* to \d+\.?\d* s of its "
                           r"time per second of the host's .* an emulator started with --speed-factor\? Restart "
                           r"it with --speed-factor 1 for continuous scans"):
            # Refused before the servo is touched (there is none here) and before a journal is opened.
            run_continuous_session(turntable=None, source=source, grid=BeamGrid.of(URG_04LX_UG01), rpm=1.0,
                                   sweep_deg=360.0, journal_path=journal, identity={}, angle_mode="interpolate",
                                   T_base_lidar=np.eye(4))
        assert not journal.exists()
        assert not emulator.streaming


def test_a_lidar_on_the_hosts_clock_passes_the_check():
    clock = VirtualClock(start_s=2.0)
    with UrgEmulator(flat_provider(), clock=clock, latency_s=0.002, clock_drift_ppm=80.0) as emulator, \
            connect(emulator, clock) as lidar:
        offset = lidar.clock_offset
        assert offset.rate_low <= 1.0 <= offset.rate_high and offset.runs_at_host_rate()
        check_lidar_clock_rate(UrgLineSource(lidar, URG_04LX_UG01))  # no error


def test_a_stream_slower_than_its_period_sends_each_scan_before_casting_the_next():
    clock = VirtualClock(start_s=1.0)
    waiting = []  # at each cast: scans made but not yet handed to the pty
    slow = flat_provider(clock, CAST_S)

    def provide(t_scan_start_s):
        waiting.append(emulator.replies_waiting)
        return slow(t_scan_start_s)

    with UrgEmulator(provide, clock=clock) as emulator, connect(emulator, clock) as lidar:
        stamps = []
        stream = lidar.stream()
        for scan in stream:
            stamps.append(scan.timestamp_ms)
            if len(stamps) == 12:
                break
        stream.close()  # QT: read and answered between two casts, so the laser off is confirmed
        assert not lidar.laser_is_on and not emulator.streaming
    # Every scan of the stream, in order, each stamped with its own 100 ms slot: sent late, not dropped.
    assert np.diff(stamps).tolist() == [100] * 11
    # Each scan went to the pty before the next cast began: casting every scan due in one batch
    # held the batch back (2.5 more scans fall due during each cast, so the batches grew).
    assert len(waiting) >= 12 and not any(waiting), waiting
