"""The raw record as the field stores it: a ROS 2 bag in MCAP storage, written with ``rosbags``.

No ROS installation is needed. Topics (all stamps: the scan's start plus the
record's nanoseconds):

- ``/scan`` ``sensor_msgs/msg/LaserScan``, one per line, ``frame_id`` "lidar":
  ``header.stamp`` is the line's first beam, ``angle_min``/``angle_max``/
  ``angle_increment``, ``time_increment`` (beam to beam), ``scan_time``,
  ``range_min``/``range_max``, ``ranges`` with REP 117's encoding of misses
  (-inf: nearer than ``range_min``; +inf: no echo within ``range_max``; NaN: an
  invalid measurement such as a weak return or an edge), ``intensities`` (empty
  when not modelled);
- ``/turntable/joint_states`` ``sensor_msgs/msg/JointState``, one per encoder
  reading (joint "turntable", position in radians);
- ``/tf_static`` ``tf2_msgs/msg/TFMessage``: "base" -> "lidar" (the rig geometry);
  ``/tf``: "base" -> "turntable" at each encoder reading, for viewers such as RViz;
- ``/plantsim/scan_info`` ``std_msgs/msg/String``, once: JSON with how to
  reconstruct (``angle_mode``, the commanded angle per line) and the scan's
  configuration and parts;
- ``/plantsim/ground_truth`` ``plantsim_msgs/msg/BeamTruth``, one per line, only
  when simulated: each beam's true turntable angle, status, hit class and geom.

:func:`read_raw` reads such a bag back into the same :class:`RawScan`; a bag
recorded on a real rig (or by another tool) with ``/scan``, the joint states and
the static TF reconstructs the same way (``angle_mode`` "interpolate" unless
``/plantsim/scan_info`` says otherwise).
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from plantsim.scan.raw import BeamGrid, RawScan
from plantsim.sensor.spec import BeamStatus

log = logging.getLogger(__name__)

SCAN_TOPIC = "/scan"
JOINT_TOPIC = "/turntable/joint_states"
INFO_TOPIC = "/plantsim/scan_info"
TRUTH_TOPIC = "/plantsim/ground_truth"
TURNTABLE_JOINT = "turntable"
BASE_FRAME, LIDAR_FRAME, TURNTABLE_FRAME = "base", "lidar", "turntable"

BEAM_TRUTH_MSG = """\
# plantsim's ground truth for one scan line (one entry per beam of the LaserScan of the same stamp).
std_msgs/Header header
float64[] turntable_angle_rad   # the true turntable angle at each beam's instant
uint8[] status                  # plantsim BeamStatus: 0 ok, 1 no echo, 2 too near, 3 low intensity, 4 edge
uint8[] hit_class               # plantsim HitClass of the first surface: 0 none, 1 plant, 2 turntable, 3 rig
int32[] geom_id                 # MuJoCo geom id of that surface, -1 none
"""
BEAM_TRUTH_TYPE = "plantsim_msgs/msg/BeamTruth"


def _typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(BEAM_TRUTH_MSG, BEAM_TRUTH_TYPE))
    return store


def _stamp(store, ns: int):
    Time = store.types["builtin_interfaces/msg/Time"]
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def _header(store, ns: int, frame: str):
    return store.types["std_msgs/msg/Header"](stamp=_stamp(store, ns), frame_id=frame)


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def laser_ranges(raw: RawScan) -> np.ndarray:
    """(n_lines, n_beams) float32 ranges with REP 117's codes for beams without a return."""
    out = raw.range_m.astype(np.float32)
    out[raw.status == BeamStatus.TOO_NEAR] = -np.inf
    out[raw.status == BeamStatus.NO_ECHO] = np.inf
    out[(raw.status == BeamStatus.LOW_INTENSITY) | (raw.status == BeamStatus.EDGE)] = np.nan
    return out


def _transform(store, ns: int, parent: str, child: str, translation, quat_xyzw):
    t = store.types
    return t["geometry_msgs/msg/TransformStamped"](
        header=_header(store, ns, parent), child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=float(translation[0]), y=float(translation[1]),
                                                      z=float(translation[2])),
            rotation=t["geometry_msgs/msg/Quaternion"](x=float(quat_xyzw[0]), y=float(quat_xyzw[1]),
                                                      z=float(quat_xyzw[2]), w=float(quat_xyzw[3]))))


def write_raw(path: str | os.PathLike, raw: RawScan, *, metadata: dict | None = None) -> Path:
    """Writes a raw record as a ROS 2 bag (MCAP storage) in the folder ``path``.

    The bag is built beside ``path`` and moved into place when complete; an
    existing bag folder at ``path`` is replaced, anything else there is refused.

    Args:
      path: the bag folder.
      raw: the raw record.
      metadata: JSON-able facts for ``/plantsim/scan_info`` (configuration, parts).

    Raises:
      FileExistsError: ``path`` exists and is not a bag folder.
      FileNotFoundError: its parent folder does not exist.
    """
    from plantsim.cloud.outputs import OutputSet

    path = check_bag_path(path)
    with OutputSet() as outputs:
        write_bag(outputs.stage_folder(path), raw, metadata=metadata)
        outputs.commit()
    return path


def check_bag_path(path: str | os.PathLike) -> Path:
    """The bag folder ``path``, checked: its parent exists, and it is new or an old bag.

    Raises:
      FileExistsError: ``path`` exists and is not a bag folder.
      FileNotFoundError: its parent folder does not exist.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"output folder does not exist: {path.parent}")
    if path.exists() and not (path / "metadata.yaml").is_file():
        raise FileExistsError(f"{path} exists and is not a ROS 2 bag folder: choose another --raw folder")
    return path


def write_bag(path: Path, raw: RawScan, *, metadata: dict | None = None) -> None:
    """Writes the bag at ``path``, which must not exist (see :func:`write_raw`)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = _typestore()
    t = store.types
    start = int(raw.start_unix_ns)
    grid = raw.grid
    ranges = laser_ranges(raw)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        def conn(topic, msgtype):
            return writer.add_connection(topic, msgtype, typestore=store)

        info_c = conn(INFO_TOPIC, "std_msgs/msg/String")
        static_c = conn("/tf_static", "tf2_msgs/msg/TFMessage")
        scan_c = conn(SCAN_TOPIC, "sensor_msgs/msg/LaserScan")
        joint_c = conn(JOINT_TOPIC, "sensor_msgs/msg/JointState")
        tf_c = conn("/tf", "tf2_msgs/msg/TFMessage")
        truth_c = conn(TRUTH_TOPIC, BEAM_TRUTH_TYPE) if raw.true_turntable_angle_rad is not None else None

        info = {"plantsim_raw": 1, "angle_mode": raw.angle_mode, "start_unix_ns": start,
                "encoder_offset_rad": float(raw.encoder_offset_rad),
                "commanded_rad": [None if not np.isfinite(a) else float(a) for a in raw.commanded_rad],
                **(metadata or {})}
        messages = [(start, info_c, t["std_msgs/msg/String"](data=json.dumps(info)), "std_msgs/msg/String")]
        translation, quat = raw.lidar_pose
        messages.append((start, static_c, t["tf2_msgs/msg/TFMessage"](
            transforms=[_transform(store, start, BASE_FRAME, LIDAR_FRAME, translation, quat)]),
            "tf2_msgs/msg/TFMessage"))
        for ns, angle in zip(raw.encoder_stamp_ns, raw.encoder_angle_rad):
            stamp = start + int(ns)
            messages.append((stamp, joint_c, t["sensor_msgs/msg/JointState"](
                header=_header(store, stamp, BASE_FRAME), name=[TURNTABLE_JOINT],
                position=np.array([angle], dtype=np.float64), velocity=np.zeros(0), effort=np.zeros(0)),
                "sensor_msgs/msg/JointState"))
            half = angle / 2
            messages.append((stamp, tf_c, t["tf2_msgs/msg/TFMessage"](transforms=[_transform(
                store, stamp, BASE_FRAME, TURNTABLE_FRAME, (0.0, 0.0, 0.0),
                (0.0, 0.0, np.sin(half), np.cos(half)))]), "tf2_msgs/msg/TFMessage"))
        no_intensity = np.zeros(0, dtype=np.float32)
        for k in range(raw.n_lines):
            stamp = start + int(raw.line_stamp_ns[k])
            messages.append((stamp, scan_c, t["sensor_msgs/msg/LaserScan"](
                header=_header(store, stamp, LIDAR_FRAME), angle_min=grid.angle_min_rad,
                angle_max=float(np.float32(grid.beam_angles_rad()[-1])),
                angle_increment=grid.angle_increment_rad, time_increment=grid.time_increment_s,
                scan_time=grid.scan_period_s, range_min=grid.range_min_m, range_max=grid.range_max_m,
                ranges=ranges[k], intensities=no_intensity if raw.intensity is None else
                raw.intensity[k].astype(np.float32)), "sensor_msgs/msg/LaserScan"))
            if truth_c is not None:
                messages.append((stamp, truth_c, t[BEAM_TRUTH_TYPE](
                    header=_header(store, stamp, LIDAR_FRAME),
                    turntable_angle_rad=raw.true_turntable_angle_rad[k].astype(np.float64),
                    status=raw.status[k].astype(np.uint8), hit_class=raw.hit_class[k].astype(np.uint8),
                    geom_id=raw.geom_id[k].astype(np.int32)), BEAM_TRUTH_TYPE))
        messages.sort(key=lambda m: m[0])  # log order is time order
        for stamp, connection, msg, msgtype in messages:
            writer.write(connection, stamp, store.serialize_cdr(msg, msgtype))


def read_raw(path: str | os.PathLike) -> tuple[RawScan, dict]:
    """Reads a scan's ROS 2 bag back into a :class:`RawScan`.

    Returns:
      (raw, info): the raw record and ``/plantsim/scan_info`` (empty for a bag
      plantsim did not write).

    Raises:
      FileNotFoundError: no bag at ``path``.
      ValueError: the bag lacks what a reconstruction needs (names it).
    """
    from rosbags.rosbag2 import Reader

    path = Path(path)
    if not (path / "metadata.yaml").is_file():
        raise FileNotFoundError(f"no ROS 2 bag at {path} (no metadata.yaml): give the folder --raw wrote")
    store = _typestore()
    scans, joints, truths, info, pose = [], [], {}, {}, None
    with Reader(path) as reader:
        for connection, _, data in reader.messages():
            topic, msgtype = connection.topic, connection.msgtype
            if topic == SCAN_TOPIC:
                scans.append(store.deserialize_cdr(data, msgtype))
            elif topic == JOINT_TOPIC:
                msg = store.deserialize_cdr(data, msgtype)
                names = list(msg.name)
                i = names.index(TURNTABLE_JOINT) if TURNTABLE_JOINT in names else 0
                joints.append((_stamp_ns(msg.header), float(msg.position[i])))
            elif topic == TRUTH_TOPIC:
                msg = store.deserialize_cdr(data, msgtype)
                truths[_stamp_ns(msg.header)] = msg
            elif topic == INFO_TOPIC:
                info = json.loads(store.deserialize_cdr(data, msgtype).data)
            elif topic == "/tf_static":
                for tf in store.deserialize_cdr(data, msgtype).transforms:
                    if tf.child_frame_id == LIDAR_FRAME:
                        tr, q = tf.transform.translation, tf.transform.rotation
                        pose = (np.array([tr.x, tr.y, tr.z]), np.array([q.x, q.y, q.z, q.w]))
    if not scans:
        raise ValueError(f"{path} has no sensor_msgs/LaserScan on {SCAN_TOPIC}")
    if pose is None:
        raise ValueError(f"{path} has no static transform base -> lidar on /tf_static: the rig geometry "
                         "is needed to reconstruct")
    first = scans[0]
    n_beams = len(first.ranges)
    grid = BeamGrid(angle_min_rad=float(first.angle_min), angle_increment_rad=float(first.angle_increment),
                    time_increment_s=float(first.time_increment), n_beams=n_beams,
                    scan_period_s=float(first.scan_time), range_min_m=float(first.range_min),
                    range_max_m=float(first.range_max))
    stamps_abs = np.array([_stamp_ns(s.header) for s in scans], dtype=np.int64)
    start = int(info.get("start_unix_ns", min([stamps_abs[0]] + [j[0] for j in joints[:1]])))
    ranges = np.stack([np.asarray(s.ranges, dtype=np.float32) for s in scans]).astype(np.float64)
    inside = np.isfinite(ranges) & (ranges >= grid.range_min_m) & (ranges <= grid.range_max_m)
    status = np.full(ranges.shape, BeamStatus.LOW_INTENSITY, dtype=np.uint8)
    status[inside] = BeamStatus.OK
    status[np.isposinf(ranges) | (np.isfinite(ranges) & (ranges > grid.range_max_m))] = BeamStatus.NO_ECHO
    status[np.isneginf(ranges) | (np.isfinite(ranges) & (ranges < grid.range_min_m))] = BeamStatus.TOO_NEAR
    intensity = None
    if all(len(s.intensities) == n_beams for s in scans):
        intensity = np.stack([np.asarray(s.intensities, dtype=np.float32) for s in scans])
    truth = [truths.get(int(ns)) for ns in stamps_abs]
    has_truth = bool(truths) and all(m is not None for m in truth)
    if has_truth:
        status = np.stack([np.asarray(m.status, dtype=np.uint8) for m in truth])
    commanded = info.get("commanded_rad")
    commanded = (np.array([np.nan if a is None else a for a in commanded], dtype=np.float64)
                 if commanded is not None and len(commanded) == len(scans) else np.full(len(scans), np.nan))
    angle_mode = info.get("angle_mode", "interpolate")
    if not joints and angle_mode != "commanded":
        raise ValueError(f"{path} has no turntable readings (sensor_msgs/JointState on {JOINT_TOPIC}): "
                         "the turntable angle of each line is unknown")
    joints.sort()
    raw = RawScan(
        grid=grid, line_stamp_ns=stamps_abs - start, range_m=np.where(status == BeamStatus.OK, ranges, np.nan),
        status=status, intensity=intensity,
        encoder_stamp_ns=np.array([j[0] for j in joints], dtype=np.int64) - start,
        encoder_angle_rad=np.array([j[1] for j in joints], dtype=np.float64), commanded_rad=commanded,
        angle_mode=angle_mode, lidar_pose=pose,
        true_turntable_angle_rad=np.stack([np.asarray(m.turntable_angle_rad, dtype=np.float64) for m in truth])
        if has_truth else None,
        hit_class=np.stack([np.asarray(m.hit_class, dtype=np.uint8) for m in truth]) if has_truth else None,
        geom_id=np.stack([np.asarray(m.geom_id, dtype=np.int32) for m in truth]) if has_truth else None,
        start_unix_ns=start, encoder_offset_rad=float(info.get("encoder_offset_rad", 0.0)))
    return raw, info
