"""Point-cloud files: LAS 1.4, PLY, PCD and TXT/XYZ, chosen by extension.

Exporters take a :class:`PointCloud` and return bytes (they never touch the
disk); :func:`write_cloud` is the only writer and writes atomically (a temp
file in the same folder, then ``os.replace``), so a failure leaves no
half-written file. Readers give a :class:`PointCloud` back, for round trips and
for evaluating clouds made elsewhere.

Every format carries the same per-point fields: x, y, z (turntable frame,
metres), classification (what the beam hit; :data:`CLASSIFICATION`), intensity,
beam_index, scan_index, turntable_angle_rad, range_m and time (the beam's time
in seconds; LAS GPS time).
"""

from __future__ import annotations

import io
import json
import os
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

from plantsim.cloud.reconstruct import PointCloud
from plantsim.rig.scene import HitClass

# LAS classification codes (ASPRS LAS 1.4 R15 table 17): the plant is
# "Medium Vegetation" (4); turntable and rig use the user-definable range 64+.
CLASSIFICATION = {HitClass.PLANT: 4, HitClass.TURNTABLE: 64, HitClass.RIG: 65}
_CLASS_OF_CODE = {code: cls for cls, code in CLASSIFICATION.items()}

# LAS coordinate resolution: 0.01 mm, ten times finer than the 0.1 mm asked for.
LAS_SCALE_M = 1e-5

# Name, numpy dtype, PCD type/size letter: the scalar fields after x, y, z.
_FIELDS = (
    ("classification", np.uint8, "U"),
    ("intensity", np.uint16, "U"),
    ("beam_index", np.uint16, "U"),
    ("scan_index", np.uint32, "U"),
    ("turntable_angle_rad", np.float64, "F"),
    ("range_m", np.float64, "F"),
    ("time", np.float64, "F"),
)


def _columns(cloud: PointCloud) -> dict[str, np.ndarray]:
    codes = np.zeros(256, dtype=np.uint8)
    for cls, code in CLASSIFICATION.items():
        codes[int(cls)] = code
    intensity = (np.zeros(len(cloud), np.uint16) if cloud.intensity is None
                 else np.round(np.clip(cloud.intensity, 0.0, 1.0) * 65535).astype(np.uint16))
    return {
        "classification": codes[cloud.hit_class],
        "intensity": intensity,
        "beam_index": cloud.beam_index.astype(np.uint16),
        "scan_index": cloud.scan_index.astype(np.uint32),
        "turntable_angle_rad": cloud.turntable_angle_rad.astype(np.float64),
        "range_m": cloud.range_m.astype(np.float64),
        "time": cloud.time_s.astype(np.float64),
    }


def _cloud_from_columns(xyz: np.ndarray, cols: dict[str, np.ndarray]) -> PointCloud:
    classification = np.asarray(cols["classification"], dtype=np.int64)
    hit_class = np.array([_CLASS_OF_CODE.get(int(c), HitClass.NONE) for c in range(256)],
                         dtype=np.uint8)[classification]
    intensity = np.asarray(cols["intensity"], dtype=np.float64)
    return PointCloud(
        points_turntable=np.ascontiguousarray(xyz, dtype=np.float64),
        hit_class=hit_class,
        beam_index=np.asarray(cols["beam_index"]).astype(np.uint16),
        scan_index=np.asarray(cols["scan_index"]).astype(np.uint32),
        turntable_angle_rad=np.asarray(cols["turntable_angle_rad"], dtype=np.float64),
        range_m=np.asarray(cols["range_m"], dtype=np.float64),
        time_s=np.asarray(cols["time"], dtype=np.float64),
        intensity=(intensity / 65535).astype(np.float32) if intensity.any() else None,
    )


# --- LAS 1.4 (laspy) -------------------------------------------------------

_LAS_EXTRA = (("beam_index", np.uint16, "beam within its scan line"),
              ("scan_index", np.uint32, "scan line (turntable step)"),
              ("turntable_angle_rad", np.float64, "turntable angle, radians"),
              ("range_m", np.float64, "measured range, metres"))


def to_las(cloud: PointCloud) -> bytes:
    """LAS 1.4, point format 6; GPS time is the beam's time (s since the scan's start).

    Raises:
      OverflowError: a coordinate does not fit the 0.01 mm grid (laspy's own check).
    """
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, LAS_SCALE_M)
    xyz = cloud.points_turntable
    header.offsets = np.floor(xyz.min(axis=0)) if len(xyz) else np.zeros(3)
    header.add_extra_dims([laspy.ExtraBytesParams(name=n, type=t, description=d)
                           for n, t, d in _LAS_EXTRA])
    header.generating_software = "plantsim"
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    cols = _columns(cloud)
    las.classification = cols["classification"]
    las.intensity = cols["intensity"]
    las.gps_time = cols["time"]
    for name, _, _ in _LAS_EXTRA:
        las[name] = cols[name]
    buffer = io.BytesIO()
    las.write(buffer)
    return buffer.getvalue()


def from_las(data: bytes) -> PointCloud:
    import laspy

    las = laspy.read(io.BytesIO(data))
    xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)
    names = set(las.point_format.dimension_names)
    n = len(xyz)
    cols = {
        "classification": np.asarray(las.classification),
        "intensity": np.asarray(las.intensity),
        "time": np.asarray(las.gps_time) if "gps_time" in names else np.zeros(n),
    }
    for name, dtype, _ in _LAS_EXTRA:
        cols[name] = np.asarray(las[name]) if name in names else np.zeros(n, dtype)
    return _cloud_from_columns(xyz, cols)


# --- PLY (binary little endian) --------------------------------------------

_PLY_TYPES = {np.uint8: "uchar", np.uint16: "ushort", np.uint32: "uint", np.float64: "double"}


def _structured(cloud: PointCloud, xyz_dtype) -> np.ndarray:
    dtype = [("x", xyz_dtype), ("y", xyz_dtype), ("z", xyz_dtype)] + [
        (name, t) for name, t, _ in _FIELDS]
    rows = np.empty(len(cloud), dtype=np.dtype(dtype).newbyteorder("<"))
    for i, axis in enumerate("xyz"):
        rows[axis] = cloud.points_turntable[:, i]
    for name, values in _columns(cloud).items():
        rows[name] = values
    return rows


def to_ply(cloud: PointCloud) -> bytes:
    """Binary PLY with double-precision coordinates and the scalar fields."""
    props = "".join(f"property {_PLY_TYPES[t]} {name}\n"
                    for name, t in [("x", np.float64), ("y", np.float64), ("z", np.float64)]
                    + [(n, t) for n, t, _ in _FIELDS])
    header = ("ply\nformat binary_little_endian 1.0\ncomment plantsim point cloud, turntable "
              "frame, metres\ncomment classification: 4 plant, 64 turntable, 65 rig\n"
              f"element vertex {len(cloud)}\n{props}end_header\n")
    return header.encode("ascii") + _structured(cloud, np.float64).tobytes()


_PLY_NP = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
           "uint": "<u4", "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1",
           "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4",
           "float32": "<f4", "float64": "<f8"}


def from_ply(data: bytes) -> PointCloud:
    """Reads a binary little-endian PLY point cloud (plantsim's fields, or at least x y z)."""
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError("not a PLY file (no 'ply' magic or 'end_header')")
    lines = data[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise ValueError("only binary_little_endian PLY point clouds are read")
    fields, n, in_vertex = [], 0, False
    for line in lines:
        parts = line.split()
        if parts[:1] == ["element"]:
            in_vertex = parts[1] == "vertex"
            if in_vertex:
                n = int(parts[2])
        elif parts[:1] == ["property"] and in_vertex:
            fields.append((parts[2], _PLY_NP[parts[1]]))
    rows = np.frombuffer(data, dtype=np.dtype(fields), count=n, offset=end + len(b"end_header\n"))
    return _from_rows(rows)


def _from_rows(rows: np.ndarray) -> PointCloud:
    xyz = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float64)
    names = rows.dtype.names
    cols = {name: (rows[name] if name in names else np.zeros(len(rows), t)) for name, t, _ in _FIELDS}
    return _cloud_from_columns(xyz, cols)


# --- PCD v0.7 (binary) -----------------------------------------------------

def to_pcd(cloud: PointCloud) -> bytes:
    """Binary PCD v0.7. Coordinates are float32 (PCL's PointXYZ; 0.06 um at 1 m)."""
    rows = _structured(cloud, np.float32)
    names = rows.dtype.names
    sizes = " ".join(str(rows.dtype[n].itemsize) for n in names)
    types = " ".join("F" if rows.dtype[n].kind == "f" else "U" for n in names)
    header = (f"# .PCD v0.7 - plantsim point cloud, turntable frame, metres\nVERSION 0.7\n"
              f"FIELDS {' '.join(names)}\nSIZE {sizes}\nTYPE {types}\n"
              f"COUNT {' '.join('1' for _ in names)}\nWIDTH {len(rows)}\nHEIGHT 1\n"
              f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(rows)}\nDATA binary\n")
    return header.encode("ascii") + rows.tobytes()


def from_pcd(data: bytes) -> PointCloud:
    """Reads a binary or ASCII PCD v0.7 with at least x y z."""
    header, offset = {}, 0
    while True:
        end = data.index(b"\n", offset)
        line = data[offset:end].decode("ascii", "replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        header[key.upper()] = value.split()
        if key.upper() == "DATA":
            break
    names, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    dtype = np.dtype([(n, f"<{ {'F': 'f', 'U': 'u', 'I': 'i'}[t] }{s}") for n, s, t in zip(names, sizes, types)])
    n = int(header["POINTS"][0])
    if header["DATA"][0] == "binary":
        rows = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
    elif header["DATA"][0] == "ascii":
        table = np.loadtxt(io.BytesIO(data[offset:]), ndmin=2)
        rows = np.empty(len(table), dtype=dtype)
        for i, name in enumerate(names):
            rows[name] = table[:, i]
    else:
        raise ValueError(f"PCD DATA {header['DATA'][0]!r} is not supported (binary or ascii)")
    return _from_rows(rows)


# --- TXT / XYZ (ASCII columns, CloudCompare-style header) ------------------

def to_txt(cloud: PointCloud) -> bytes:
    """ASCII columns: x y z (nanometre resolution) and the scalar fields."""
    cols = _columns(cloud)
    header = "//x y z " + " ".join(cols) + "\n"
    table = np.column_stack([cloud.points_turntable] + [cols[n].astype(np.float64) for n in cols])
    fmt = ["%.9f"] * 3 + ["%d"] * 4 + ["%.12g"] * 3
    buffer = io.BytesIO()
    buffer.write(header.encode("ascii"))
    np.savetxt(buffer, table, fmt=fmt, delimiter=" ")
    return buffer.getvalue()


def from_txt(data: bytes) -> PointCloud:
    first = data.split(b"\n", 1)[0].decode("ascii", "replace")
    names = first.lstrip("/#").split() if first.startswith(("//", "#")) else ["x", "y", "z"]
    table = np.loadtxt(io.BytesIO(data), comments=("//", "#"), ndmin=2)
    rows = np.empty(len(table), dtype=[(n, np.float64) for n in names])
    for i, name in enumerate(names):
        rows[name] = table[:, i]
    return _from_rows(rows)


EXPORTERS: dict[str, Callable[[PointCloud], bytes]] = {
    ".las": to_las, ".ply": to_ply, ".pcd": to_pcd, ".txt": to_txt, ".xyz": to_txt}
READERS: dict[str, Callable[[bytes], PointCloud]] = {
    ".las": from_las, ".ply": from_ply, ".pcd": from_pcd, ".txt": from_txt, ".xyz": from_txt}


def check_output_path(path: str | os.PathLike) -> Path:
    """Validates an output path before any work is done.

    Raises:
      ValueError: unknown extension (lists the valid ones).
      FileNotFoundError: the folder does not exist.
    """
    path = Path(path)
    if path.suffix.lower() not in EXPORTERS:
        raise ValueError(f"unknown point-cloud format {path.suffix or '(none)'!r} for {path}; "
                         f"use one of {', '.join(EXPORTERS)}")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"output folder does not exist: {folder}")
    if path.is_dir():
        raise ValueError(f"output path is a folder: {path}")
    return path


def write_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Writes bytes to ``path`` atomically: all of it, or nothing (the old file stays)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    try:
        with os.fdopen(fd, "wb") as handle:
            # mkstemp makes 0600 files; give the output the usual umask-based mode.
            umask = os.umask(0)
            os.umask(umask)
            os.fchmod(handle.fileno(), 0o666 & ~umask)
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def encode_cloud(path: str | os.PathLike, cloud: PointCloud) -> bytes:
    """The file contents of ``cloud`` in the format ``path``'s extension names."""
    suffix = Path(path).suffix.lower()
    if suffix not in EXPORTERS:
        raise ValueError(f"unknown point-cloud format {suffix!r}; use one of {', '.join(EXPORTERS)}")
    return EXPORTERS[suffix](cloud)


def write_cloud(path: str | os.PathLike, cloud: PointCloud, *, sidecar: dict | None = None) -> None:
    """Writes a cloud (and, if given, its sidecar ``<path>.json``), atomically.

    The cloud is encoded fully in memory before anything touches the disk.
    """
    path = check_output_path(path)
    data = encode_cloud(path, cloud)
    if sidecar is not None:
        text = json.dumps(sidecar, indent=2, sort_keys=False, default=_json_default) + "\n"
        write_atomic(sidecar_path(path), text.encode("utf-8"))
    write_atomic(path, data)


def sidecar_path(path: str | os.PathLike) -> Path:
    path = Path(path)
    return path.with_name(path.name + ".json")


def read_cloud(path: str | os.PathLike) -> PointCloud:
    """Reads a point cloud written by plantsim (or any LAS/PLY/PCD/TXT with x y z)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise ValueError(f"unknown point-cloud format {suffix!r}; use one of {', '.join(READERS)}")
    return READERS[suffix](path.read_bytes())


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
