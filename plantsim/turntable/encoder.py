"""The turntable's encoder as the host sees it: sampled, late, quantised, imperfect.

A reading taken at host time ``t`` (the time stamp the host records) holds the
shaft angle of ``t - latency_s``, plus a constant offset, a once-per-turn
eccentricity error, white noise, and is then rounded to whole ticks, as the
servo's Present Position register is. Readings come at ``read_rate_hz``.

The reconstruction knows only the readings and their time stamps; it
interpolates them linearly to each beam's time (:func:`angles_at`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


@dataclasses.dataclass(frozen=True, kw_only=True)
class EncoderConfig:
    """The turntable encoder and how the host reads it.

    Attributes:
      ticks_per_rev: resolution (the XM430's AS5045 gives 4096); None = exact.
      noise_rad: standard deviation of white noise per reading, radians.
      offset_rad: constant error (the zero is not where the host thinks), radians.
      eccentricity_rad: amplitude of the once-per-turn error, radians
        (error = ``eccentricity_rad * sin(theta + eccentricity_phase_rad)``).
      eccentricity_phase_rad: its phase, radians.
      drift_rad_per_s: the offset's slow drift (e.g. thermal), radians per
        second of scan time.
      latency_s: age of a reading when the host stamps it, s.
      read_rate_hz: readings per second.
    """

    ticks_per_rev: int | None = 4096
    noise_rad: float = 0.0
    offset_rad: float = 0.0
    eccentricity_rad: float = 0.0
    eccentricity_phase_rad: float = 0.0
    drift_rad_per_s: float = 0.0
    latency_s: float = 0.0
    read_rate_hz: float = 100.0

    def __post_init__(self):
        t = self.ticks_per_rev
        if t is not None and (isinstance(t, bool) or not isinstance(t, int) or t < 2):
            raise ValueError(f"encoder ticks_per_rev must be an integer >= 2 or None (exact), got {t!r}")
        for name in ("noise_rad", "offset_rad", "eccentricity_rad", "eccentricity_phase_rad",
                     "drift_rad_per_s", "latency_s", "read_rate_hz"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"encoder {name} must be a finite number, got {value!r}")
        for name in ("noise_rad", "eccentricity_rad", "latency_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"encoder {name} must be >= 0, got {getattr(self, name)}")
        if self.read_rate_hz <= 0:
            raise ValueError(f"encoder read_rate_hz must be > 0, got {self.read_rate_hz}")

    @classmethod
    def ideal(cls, *, read_rate_hz: float = 100.0) -> "EncoderConfig":
        """An exact encoder (no quantisation, noise, offset, eccentricity or latency)."""
        return cls(ticks_per_rev=None, read_rate_hz=read_rate_hz)

    def replace(self, **changes) -> "EncoderConfig":
        return dataclasses.replace(self, **changes)


def measure(angle_true_rad: np.ndarray, config: EncoderConfig, rng: np.random.Generator, *,
            time_s: np.ndarray | None = None) -> np.ndarray:
    """What the encoder reports for true shaft angles (no sampling or latency).

    Args:
      angle_true_rad: (n,) float64, unwrapped shaft angle, radians.
      config: the encoder.
      rng: source of the noise (drawn only when ``noise_rad`` > 0).
      time_s: (n,) float64, when each was measured (for the drift; None = 0).

    Returns:
      (n,) float64, radians; whole ticks when ``ticks_per_rev`` is set.
    """
    theta = np.asarray(angle_true_rad, dtype=np.float64)
    reading = theta + config.offset_rad
    if config.drift_rad_per_s and time_s is not None:
        reading = reading + config.drift_rad_per_s * np.asarray(time_s, dtype=np.float64)
    if config.eccentricity_rad:
        reading = reading + config.eccentricity_rad * np.sin(theta + config.eccentricity_phase_rad)
    if config.noise_rad:
        reading = reading + rng.normal(0.0, config.noise_rad, theta.shape)
    if config.ticks_per_rev is not None:
        tick = 2 * math.pi / config.ticks_per_rev
        reading = np.round(reading / tick) * tick
    return reading


@dataclasses.dataclass(frozen=True, eq=False)
class EncoderReadings:
    """The host's log of encoder readings.

    Attributes:
      time_s: (n,) float64, host time stamps, s, increasing.
      angle_rad: (n,) float64, the readings, radians (unwrapped).
    """

    time_s: np.ndarray
    angle_rad: np.ndarray

    def angles_at(self, t_s: np.ndarray) -> np.ndarray:
        """Readings interpolated linearly to given times (held beyond the ends)."""
        return np.interp(t_s, self.time_s, self.angle_rad)


def read(time_s: np.ndarray, shaft_rad: np.ndarray, config: EncoderConfig, rng: np.random.Generator, *,
         t_end_s: float | None = None) -> EncoderReadings:
    """Samples the encoder over a recorded shaft trajectory.

    Args:
      time_s: (n,) float64, physics times, s, increasing from 0.
      shaft_rad: (n,) float64, true shaft angle at those times.
      config: the encoder.
      rng: the run's random generator.
      t_end_s: last host time to read at (default the trajectory's end).

    Returns:
      :class:`EncoderReadings` at ``0, 1/rate, 2/rate, ...``; a reading whose
      measurement would predate the trajectory holds its first angle.
    """
    t_end = float(time_s[-1]) if t_end_s is None else float(t_end_s)
    n = int(math.floor(t_end * config.read_rate_hz + 1e-9)) + 1
    t_read = np.arange(n) / config.read_rate_hz
    t_then = t_read - config.latency_s
    shaft_then = np.interp(t_then, time_s, shaft_rad)
    return EncoderReadings(time_s=t_read, angle_rad=measure(shaft_then, config, rng, time_s=t_then))
