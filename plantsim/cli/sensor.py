"""``plantsim sensor fit``: fit the sensor model to a recording of a flat target.

Example (a plate 0.5 m away for the first 20 min, then 1 m, then 2 m; the
sensor switched on 30 s before the bag started)::

    plantsim sensor fit calib_bag --target 0:1200:0.5 --target 1200:1500:1.0 \\
        --target 1500:1800:2.0 --power-on-s 30 --reflectance 0.9 -o sensor.toml
    plantsim scan --config sensor.toml

The bag is read with :func:`plantsim.cloud.bag.read_raw`; the fit is
:func:`plantsim.sensor.fit.fit_sensor`.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
from pathlib import Path

import numpy as np

from plantsim.sensor.fit import FlatTargetRecording, fit_sensor
from plantsim.sensor.flat_target import FlatTarget
from plantsim.sensor.spec import PRESETS

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class TargetSegment:
    """The plate's pose during a span of the recording (seconds since the bag's start)."""

    start_s: float
    end_s: float
    distance_m: float
    normal_angle_deg: float = 0.0


def parse_target(text: str) -> TargetSegment:
    """``START_S:END_S:DISTANCE_M[:NORMAL_DEG]`` or ``DISTANCE_M`` (the whole recording).

    Raises:
      argparse.ArgumentTypeError: not that form.
    """
    parts = text.split(":")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = None
    if values is None or len(values) not in (1, 3, 4) or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(
            f"--target must be DISTANCE_M or START_S:END_S:DISTANCE_M[:NORMAL_DEG], got {text!r}")
    if len(values) == 1:
        return TargetSegment(-math.inf, math.inf, values[0])
    segment = TargetSegment(*values)
    if segment.end_s <= segment.start_s or segment.distance_m <= 0:
        raise argparse.ArgumentTypeError(
            f"--target {text!r}: END_S must be after START_S and DISTANCE_M > 0")
    return segment


def recording_from_raw(raw, segments: list[TargetSegment], *, power_on_s: float,
                       reflectance: float, half_width_m: float,
                       range_resolution_m: float) -> FlatTargetRecording:
    """A :class:`FlatTargetRecording` from a raw scan and the plate's known poses.

    Lines outside every segment are dropped.

    Args:
      raw: a :class:`plantsim.scan.raw.RawScan` (``range_m`` NaN unless OK,
        ``line_stamp_ns`` since the recording's start, ``grid``).
      segments: where the plate stood when.
      power_on_s: how long the sensor had been on when the recording started, s.
      reflectance: the plate's reflectance.
      half_width_m: half the plate's width, metres.
      range_resolution_m: the sensor's range step.

    Raises:
      ValueError: no line falls in a segment.
    """
    t_s = np.asarray(raw.line_stamp_ns, dtype=np.float64) * 1e-9
    distance = np.full(len(t_s), np.nan)
    normal = np.zeros(len(t_s))
    for seg in segments:
        inside = (t_s >= seg.start_s) & (t_s < seg.end_s)
        distance[inside] = seg.distance_m
        normal[inside] = math.radians(seg.normal_angle_deg)
    use = np.isfinite(distance)
    if not use.any():
        raise ValueError(f"no line of the recording ({t_s.min():.1f}-{t_s.max():.1f} s) falls in a "
                         "--target span: give START_S:END_S in seconds since the bag's first line")
    n = int(use.sum())
    target = FlatTarget.make(n, distance_m=distance[use], normal_angle_rad=normal[use],
                             half_width_m=half_width_m, reflectance=reflectance)
    return FlatTargetRecording(range_m=np.asarray(raw.range_m, dtype=np.float64)[use],
                               beam_angles_rad=raw.grid.beam_angles_rad(),
                               time_since_power_on_s=power_on_s + t_s[use], target=target,
                               range_resolution_m=range_resolution_m)


def cmd_sensor_fit(args: argparse.Namespace) -> int:
    from plantsim.cloud.bag import read_raw

    if args.preset not in PRESETS:
        raise ValueError(f"unknown LiDAR preset {args.preset!r}; valid presets: {', '.join(PRESETS)}")
    raw = read_raw(args.raw)
    if isinstance(raw, tuple):  # read_raw returns (raw, info) today
        raw = raw[0]
    recording = recording_from_raw(raw, args.target, power_on_s=args.power_on_s,
                                   reflectance=args.reflectance, half_width_m=args.half_width_m,
                                   range_resolution_m=PRESETS[args.preset].range_resolution_m)
    fitted = fit_sensor(recording, edge_margin_m=args.edge_margin_m)
    out = Path(args.output)
    out.write_text(fitted.to_toml(args.preset, source=str(args.raw)))
    print(f"fitted {fitted.n_returns:,} returns: noise {fitted.range_sigma_m * 1000:.2f} mm + "
          f"{fitted.range_sigma_rel * 100:.2f} % of white-equivalent range, bias "
          f"{fitted.range_bias_m * 1000:+.2f} mm; wrote {out}")
    return 0


def add_sensor_commands(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Registers ``sensor fit`` on the top-level ``subparsers``."""
    sensor = subparsers.add_parser("sensor", help="fit the sensor model to a real unit")
    commands = sensor.add_subparsers(dest="sensor_command", required=True)
    fit = commands.add_parser(
        "fit", help="fit noise, bias and warm-up drift to a flat-target recording",
        description="Fit the sensor model (noise, bias, warm-up drift) to a ROS 2 bag of the LiDAR "
                    "looking at a flat matte plate at known distances, and write a TOML [lidar] "
                    "section that `plantsim scan --config` reads.",
        epilog="Example: plantsim sensor fit calib --target 0:600:0.5 --target 600:900:1.0 -o sensor.toml")
    fit.add_argument("raw", metavar="RAW", help="the bag folder (sensor_msgs/LaserScan on /scan)")
    fit.add_argument("-o", "--output", required=True, help="the TOML file to write")
    fit.add_argument("--target", type=parse_target, action="append", required=True,
                     metavar="START_S:END_S:DISTANCE_M[:NORMAL_DEG]",
                     help="the plate's perpendicular distance (and the beam angle of its normal, "
                          "default 0) during a span of seconds since the bag's first line; repeat "
                          "for each pose; a bare DISTANCE_M covers the whole recording")
    fit.add_argument("--power-on-s", type=float, default=0.0,
                     help="seconds the sensor had been on at the bag's first line (default 0)")
    fit.add_argument("--reflectance", type=float, default=0.9,
                     help="the plate's reflectance (default 0.9: matte white paper)")
    fit.add_argument("--half-width-m", type=float, default=0.25,
                     help="half the plate's width, metres (default 0.25)")
    fit.add_argument("--edge-margin-m", type=float, default=0.02,
                     help="leave out beams this close to the plate's edges (default 0.02)")
    fit.add_argument("--preset", default="urg-04lx-ug01",
                     help=f"the preset the fit refines ({', '.join(PRESETS)})")
    fit.set_defaults(func=cmd_sensor_fit)
    return fit
