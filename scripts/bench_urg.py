"""Figures for the URG driver and emulator (median of several runs).

    python scripts/bench_urg.py

Prints: the time to parse and decode one 683-beam MD scan (against the sensor's
100 ms period), the streaming rate of emulator + driver on a virtual clock (scans per
wall second, against the real sensor's 10), and the TM round trip and offset
uncertainty over a pty in real time.
"""

from __future__ import annotations

import statistics
import time

from plantsim.hardware.urg import RealTimeClock, UrgEmulator, UrgLidar, VirtualClock
from plantsim.hardware.urg import protocol as p


def parse_time_s(block: bytes, repeats: int = 200) -> float:
    t0 = time.perf_counter()
    for _ in range(repeats):
        reply = p.parse_reply(block)
        p.ranges_from_raw(p.parse_ranges_mm(reply), range_max_mm=5600)
    return (time.perf_counter() - t0) / repeats


def main() -> None:
    runs = 5
    clock = VirtualClock()
    with UrgEmulator(clock=clock) as emulator:
        emulator.laser_on = True
        emulator._laser_on_since_s = 0.0
        block = emulator._scan_reply("MD0044072601000", "99", "MD", 3, 44, 726, 1)[:-2]
    parse = statistics.median(parse_time_s(block) for _ in range(runs))
    print(f"parse + decode one 683-beam scan: {parse * 1e3:.3f} ms = {parse / 0.1:.4f} of the 100 ms scan period")

    rates = []
    for _ in range(runs):
        clock = VirtualClock()
        with UrgEmulator(clock=clock) as emulator, UrgLidar.connect(
                emulator.port_path, host_clock=clock.now, sleep=clock.sleep, timeout_s=5) as lidar:
            t0 = time.perf_counter()
            n = sum(1 for _ in lidar.stream(n_scans=99))
            rates.append(n / (time.perf_counter() - t0))
    rate = statistics.median(rates)
    print(f"emulator + driver streaming on a virtual clock: {rate:.0f} scans/s = {rate / 10:.0f}x the sensor's 10/s")

    offsets = []
    for _ in range(runs):
        with UrgEmulator(clock=RealTimeClock()) as emulator, UrgLidar.connect(emulator.port_path) as lidar:
            offsets.append(lidar.clock_offset)
    rtt = statistics.median(o.round_trip_s for o in offsets)
    unc = statistics.median(o.uncertainty_s for o in offsets)
    print(f"TM1 best round trip over a pty (real time): {rtt * 1e3:.3f} ms; offset uncertainty {unc * 1e3:.3f} ms")


if __name__ == "__main__":
    main()
