"""Clocks for the URG: the emulator's (virtual or real time) and the host/sensor offset.

* :class:`VirtualClock`: simulated seconds that move only when told; the emulator and
  a test's driver share one, so tests never wait on wall time.
* :class:`RealTimeClock`: wall time, optionally faster.
* :class:`ClockOffset` and :func:`estimate_offset`: the sensor's timer against the
  host's clock from TM1 round trips (minimum-delay filter), with the drift.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time

import numpy as np


class VirtualClock:
    """Simulated seconds that move only when told: ``advance``, ``advance_to``, ``sleep``.

    Thread-safe. Shared by the emulator (which advances it while it waits for a scan
    or a reply) and by a test's driver (``host_clock=clock.now, sleep=clock.sleep``).
    """

    is_virtual = True

    def __init__(self, start_s: float = 0.0):
        self._now = float(start_s)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._now

    def advance_to(self, t_s: float) -> None:
        """Moves to ``t_s`` (never backwards)."""
        with self._lock:
            self._now = max(self._now, float(t_s))

    def advance(self, dt_s: float) -> None:
        if not dt_s >= 0:
            raise ValueError(f"dt_s must be >= 0, got {dt_s!r}")
        with self._lock:
            self._now += float(dt_s)

    def sleep(self, dt_s: float) -> None:
        """A driver's pause: the clock moves on at once."""
        self.advance(max(0.0, dt_s))


class RealTimeClock:
    """Wall time (``time.perf_counter``) since creation, times ``speed_factor``."""

    is_virtual = False

    def __init__(self, speed_factor: float = 1.0):
        if not (math.isfinite(speed_factor) and speed_factor > 0):
            raise ValueError(f"speed_factor must be finite and > 0, got {speed_factor!r}")
        self.speed_factor = float(speed_factor)
        self._t0 = time.perf_counter()

    def now(self) -> float:
        return (time.perf_counter() - self._t0) * self.speed_factor

    def advance_to(self, t_s: float) -> None:
        delay = (t_s - self.now()) / self.speed_factor
        if delay > 0:
            time.sleep(delay)

    def sleep(self, dt_s: float) -> None:
        if dt_s > 0:
            time.sleep(dt_s / self.speed_factor)



#: How far a device clock's rate may be from the host's before a scan timed on the host
#: clock refuses it: crystals differ by ppm; 1 % is far above that and far below an
#: emulator run faster than real time (``--speed-factor``).
RATE_TOLERANCE = 0.01


@dataclasses.dataclass(frozen=True)
class ClockOffset:
    """The sensor's clock against the host's: ``sensor_s = host_s + offset_s``.

    Attributes:
        offset_s: sensor time minus host time, s (sensor time unwrapped from the
            24-bit ms timer, in s).
        uncertainty_s: half the best round trip plus half a timer tick, s: the
            offset is within +-uncertainty_s whatever the split of the delay.
        round_trip_s: the best (least) round trip, s.
        host_time_s: host time of that round trip's middle, s.
        n_round_trips: round trips tried.
        drift: how fast the offset grows, s per host s (the sensor crystal's rate
            error; 1e-4 is 100 ppm), from this and an earlier estimate; 0: unknown.
            ``offset(t) = offset_s + drift * (t - host_time_s)``.
        rate_low, rate_high: bounds on the sensor clock's rate, sensor s per host s,
            from the first and last round trips (bounds, not estimates: each reading
            lies within its own round trip, give or take the timer's 1 ms). A sensor
            runs at 1 within ppm; an emulator started with ``--speed-factor 20``
            runs at 20. (0, inf) from a single round trip.
    """

    offset_s: float
    uncertainty_s: float
    round_trip_s: float
    host_time_s: float
    n_round_trips: int
    drift: float = 0.0
    rate_low: float = 0.0
    rate_high: float = math.inf

    def runs_at_host_rate(self, tolerance: float = RATE_TOLERANCE) -> bool:
        """Whether the bounds allow the sensor's clock to run at the host's rate (within ``tolerance``)."""
        return self.rate_low <= 1.0 + tolerance and self.rate_high >= 1.0 - tolerance

    def host_from_sensor(self, sensor_s):
        """Host time of a sensor time (s, unwrapped), the drift taken into account."""
        sensor_s = np.asarray(sensor_s, dtype=np.float64)
        return (sensor_s - self.offset_s + self.drift * self.host_time_s) / (1.0 + self.drift)


def estimate_offset(samples: list[tuple[float, int, float]]) -> ClockOffset:
    """The offset from TM1 round trips ``(host_sent_s, sensor_ms, host_received_s)``.

    The sensor read its timer somewhere inside each round trip; the shortest round
    trip brackets it tightest, so its midpoint is taken (the minimum-delay filter of
    NTP and of Cristian's algorithm). ``sensor_ms`` is unwrapped ms; the timer
    counts whole ms, so the reading's own middle is ``sensor_ms + 0.5``.
    """
    if not samples:
        raise ValueError("samples must hold at least one round trip")
    sent, sensor_ms, received = min(samples, key=lambda s: s[2] - s[0])
    round_trip = received - sent
    if round_trip < 0:
        raise ValueError(f"a round trip ended before it began ({sent} -> {received}): is the host clock monotonic?")
    middle = 0.5 * (sent + received)
    rate_low, rate_high = rate_bounds(samples)
    return ClockOffset(offset_s=(sensor_ms + 0.5) / 1000.0 - middle, uncertainty_s=0.5 * round_trip + 0.0005,
                       round_trip_s=round_trip, host_time_s=middle, n_round_trips=len(samples),
                       rate_low=rate_low, rate_high=rate_high)


def rate_bounds(samples: list[tuple[float, int, float]], *, resolution_ms: float = 1.0) -> tuple[float, float]:
    """Bounds on a device clock's rate against the host's, from round trips in time order.

    Each reading ``(host_sent_s, device_ms, host_received_s)`` was taken inside its
    round trip, and the device's timer counts whole ``resolution_ms``, so between the
    first and the last reading the device counted its span within
    ``[sent_last - received_first, received_last - sent_first]`` of host time:

        rate_low  = (device span - resolution) / (received_last - sent_first)
        rate_high = (device span + resolution) / (sent_last - received_first)

    However late a busy host reads, these bound the rate (a late read widens the
    host interval, never moves it off). Returns (0, inf) for fewer than two samples
    or intervals that bound nothing.
    """
    if len(samples) < 2:
        return 0.0, math.inf
    (sent0, device0, received0), (sent1, device1, received1) = samples[0], samples[-1]
    span_s = (device1 - device0) / 1000.0
    res_s = resolution_ms / 1000.0
    outer, inner = received1 - sent0, sent1 - received0
    low = max(0.0, (span_s - res_s) / outer) if outer > 0 else 0.0
    high = (span_s + res_s) / inner if inner > 0 else math.inf
    return low, high
