"""Point-cloud files: LAS/LAZ 1.4, PLY, PCD, TXT/XYZ/PTS and E57, chosen by extension.

Each writer is checked against the readers people use (tests/test_interop.py):
LAS 1.4 sets the global-encoding WKT bit (PDAL <= 2.7.1 refuses files without it)
and return number / number of returns 1/1 (the spec requires 1..15), with the
scan line as point source id; ``.laz`` is the same, compressed by ``lazrs``
(the ``laz`` extra). PLY has float32 x y z by default (PCL's ``PointXYZ`` reads
doubles as zeros; pass ``xyz_double=True`` for float64), float ``intensity`` and
the other fields named ``scalar_<name>`` so CloudCompare loads them as scalar
fields (Open3D's tensor reader keeps every property). PCD has float32 x y z and
intensity (PCL's ``PointXYZI``) and a uint32 ``label`` holding the class code
(``PointXYZL``). TXT starts with a ``//X Y Z ...`` line that CloudCompare takes
as column names (``Scalar_`` ones as scalar fields, never colours); XYZ is the same
columns without a header (Open3D reads x y z from it); PTS is a point count and
``x y z intensity`` (Open3D and CloudCompare read both). E57 (the ``e57`` extra,
pye57 over libE57Format) has x y z, intensity and the beam/line as E57's row/column
indices.

Exporters take a :class:`PointCloud` and return bytes (they never touch the
disk); :func:`write_cloud` writes a cloud and its sidecar as a unit through
:class:`plantsim.cloud.outputs.OutputSet`, the writer every output goes
through (``plantsim.scan.pipeline.write_result`` adds the raw bag to the same
set), so a failure leaves no half-written file and no new cloud beside an old
sidecar. Readers give a :class:`PointCloud` back, for round trips and
for evaluating clouds made elsewhere; :func:`read_point_field` reads any one per-point
field by name (labels made elsewhere).

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
# Intensity is received power in [0, 1] as float32 (PCL's PointXYZI field).
_FIELDS = (
    ("classification", np.uint8, "U"),
    ("intensity", np.float32, "F"),
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
    intensity = (np.zeros(len(cloud), np.float32) if cloud.intensity is None
                 else np.clip(cloud.intensity, 0.0, 1.0).astype(np.float32))
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
    raw = np.asarray(cols["intensity"])
    # Integer intensity is plantsim 0.2's 0..65535 scale (PLY/PCD uint16 columns).
    intensity = (raw / 65535 if raw.dtype.kind in "ui" else raw).astype(np.float32)
    return PointCloud(
        points_turntable=np.ascontiguousarray(xyz, dtype=np.float64),
        hit_class=hit_class,
        beam_index=np.asarray(cols["beam_index"]).astype(np.uint16),
        scan_index=np.asarray(cols["scan_index"]).astype(np.uint32),
        turntable_angle_rad=np.asarray(cols["turntable_angle_rad"], dtype=np.float64),
        range_m=np.asarray(cols["range_m"], dtype=np.float64),
        time_s=np.asarray(cols["time"], dtype=np.float64),
        intensity=intensity if intensity.any() else None,
    )


# --- LAS 1.4 (laspy) -------------------------------------------------------

_LAS_EXTRA = (("beam_index", np.uint16, "beam within its scan line"),
              ("scan_index", np.uint32, "scan line (turntable step)"),
              ("turntable_angle_rad", np.float64, "turntable angle, radians"),
              ("range_m", np.float64, "measured range, metres"))


def _las_data(cloud: PointCloud):
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    # LAS 1.4 R15 2.4: point formats 6-10 require the WKT bit (bit 4) of the
    # global encoding; PDAL <= 2.7.1 refuses files without it.
    header.global_encoding.wkt = True
    header.scales = np.full(3, LAS_SCALE_M)
    xyz = cloud.points_turntable
    header.offsets = np.floor(xyz.min(axis=0)) if len(xyz) else np.zeros(3)
    header.add_extra_dims([laspy.ExtraBytesParams(name=n, type=t, description=d)
                           for n, t, d in _LAS_EXTRA])
    header.generating_software = "plantsim"
    # The point records are filled as one numpy structured array (laspy's per-dimension
    # setters cost ~50 ms on a 150k-point cloud), with laspy's own rounding and range check.
    records = np.zeros(len(cloud), dtype=header.point_format.dtype())
    for axis, name in enumerate("XYZ"):
        scaled = np.round((xyz[:, axis] - header.offsets[axis]) / header.scales[axis])
        if len(scaled) and (scaled.max() > np.iinfo(np.int32).max or scaled.min() < np.iinfo(np.int32).min):
            raise OverflowError("Values given do not fit after applying offset and scale")
        records[name] = scaled
    cols = _columns(cloud)
    records["classification"] = cols["classification"]
    records["intensity"] = np.round(cols["intensity"].astype(np.float64) * 65535).astype(np.uint16)
    records["gps_time"] = cols["time"]
    # One return per pulse: the simulated and the real URG-04LX report the first echo
    # only (LAS 1.4 R15 table 7 requires 1..15, never 0). Point format 6 packs the
    # return number in bits 0-3 and the number of returns in bits 4-7 of one byte.
    records["bit_fields"] = 1 | (1 << 4)
    # Point source id: the scan line (turntable step) when it fits 16 bits.
    if len(cloud) and int(cloud.scan_index.max()) <= 0xFFFF:
        records["point_source_id"] = cloud.scan_index.astype(np.uint16)
    for name, _, _ in _LAS_EXTRA:
        records[name] = cols[name]
    return laspy.LasData(header, points=laspy.PackedPointRecord(records, header.point_format))


def to_las(cloud: PointCloud) -> bytes:
    """LAS 1.4, point format 6; GPS time is the beam's time (s since the scan's start).

    Intensity is scaled to 0..65535; return number and number of returns are
    1; point source id is the scan line index (when it fits 16 bits). The scan
    angle is left 0: the cloud does not carry the beam's angle in the sensor.

    Raises:
      OverflowError: a coordinate does not fit the 0.01 mm grid (laspy's own check).
    """
    buffer = io.BytesIO()
    _las_data(cloud).write(buffer)
    return buffer.getvalue()


def _laz_backend():
    import laspy

    try:
        import lazrs  # noqa: F401
    except ImportError:
        raise RuntimeError("writing or reading .laz needs lazrs: pip install 'plantsim[laz]'"
                           ) from None
    return laspy.LazBackend.Lazrs


def to_laz(cloud: PointCloud) -> bytes:
    """LAZ: the LAS 1.4 of :func:`to_las`, compressed losslessly by ``lazrs``.

    Raises:
      RuntimeError: lazrs is not installed (names the extra).
    """
    backend = _laz_backend()
    buffer = io.BytesIO()
    _las_data(cloud).write(buffer, do_compress=True, laz_backend=backend)
    return buffer.getvalue()


def from_las(data: bytes) -> PointCloud:
    """Reads LAS or LAZ (any point format with x y z; plantsim's extra bytes if present)."""
    import laspy

    if data[:4] == b"LASF" and len(data) > 104 and data[104] & 0x80:  # compressed bit
        _laz_backend()
    las = laspy.read(io.BytesIO(data))
    xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)
    names = set(las.point_format.dimension_names)
    n = len(xyz)
    cols = {
        "classification": np.asarray(las.classification),
        "intensity": np.asarray(las.intensity, dtype=np.float64) / 65535,
        "time": np.asarray(las.gps_time) if "gps_time" in names else np.zeros(n),
    }
    for name, dtype, _ in _LAS_EXTRA:
        cols[name] = np.asarray(las[name]) if name in names else np.zeros(n, dtype)
    return _cloud_from_columns(xyz, cols)


# --- PLY (binary little endian) --------------------------------------------

_PLY_TYPES = {np.uint8: "uchar", np.int32: "int", np.uint16: "ushort", np.uint32: "uint", np.float32: "float",
              np.float64: "double"}
# CloudCompare loads PLY vertex properties named ``scalar_*`` as scalar fields
# without asking; ``intensity`` it knows by name.
_PLY_PREFIX = "scalar_"


def _structured(cloud: PointCloud, xyz_dtype, rename: dict[str, str] | None = None,
                types: dict[str, type] | None = None) -> np.ndarray:
    rename, types = rename or {}, types or {}
    fields = [(name, types.get(name, t)) for name, t, _ in _FIELDS]
    dtype = [("x", xyz_dtype), ("y", xyz_dtype), ("z", xyz_dtype)] + [
        (rename.get(name, name), t) for name, t in fields]
    rows = np.empty(len(cloud), dtype=np.dtype(dtype).newbyteorder("<"))
    for i, axis in enumerate("xyz"):
        rows[axis] = cloud.points_turntable[:, i]
    for name, values in _columns(cloud).items():
        rows[rename.get(name, name)] = values
    return rows


def to_ply(cloud: PointCloud, *, xyz_double: bool = False) -> bytes:
    """Binary little-endian PLY.

    Args:
      cloud: the points.
      xyz_double: float64 coordinates (default float32: 0.06 um at 1 m, and
        what PCL's ``PointXYZ`` and most viewers read).
    """
    rename = {name: _PLY_PREFIX + name for name, _, _ in _FIELDS if name != "intensity"}
    # Open3D's tensor reader skips ushort/uint properties: the indices are int32.
    rows = _structured(cloud, np.float64 if xyz_double else np.float32, rename,
                       types={"beam_index": np.int32, "scan_index": np.int32})
    props = "".join(f"property {_PLY_TYPES[rows.dtype[n].type]} {n}\n" for n in rows.dtype.names)
    header = ("ply\nformat binary_little_endian 1.0\ncomment plantsim point cloud, turntable "
              "frame, metres\ncomment scalar_classification: 4 plant, 64 turntable, 65 rig\n"
              f"element vertex {len(cloud)}\n{props}end_header\n")
    return header.encode("ascii") + rows.tobytes()


_PLY_NP = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
           "uint": "<u4", "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1",
           "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4",
           "float32": "<f4", "float64": "<f8"}


def from_ply(data: bytes) -> PointCloud:
    """Reads a binary little-endian PLY point cloud (plantsim's fields, or at least x y z)."""
    return _from_rows(_ply_rows(data))


def _ply_rows(data: bytes) -> np.ndarray:
    """A binary little-endian PLY's vertices as a structured array (``scalar_`` prefixes dropped)."""
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
            name = parts[2]
            fields.append((name[len(_PLY_PREFIX):] if name.startswith(_PLY_PREFIX) else name,
                           _PLY_NP[parts[1]]))
    return np.frombuffer(data, dtype=np.dtype(fields), count=n, offset=end + len(b"end_header\n"))


def _from_rows(rows: np.ndarray) -> PointCloud:
    xyz = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float64)
    names = rows.dtype.names
    # "scalar_" names reach a PCD when PCL converts plantsim's PLY (pcl_ply2pcd).
    aliases = {"classification": ("classification", "label", "scalar_classification")}
    cols = {}
    for name, t, _ in _FIELDS:
        found = [a for a in aliases.get(name, (name, _PLY_PREFIX + name)) if a in names]
        cols[name] = rows[found[0]] if found else np.zeros(len(rows), t)
    return _cloud_from_columns(xyz, cols)


# --- PCD v0.7 (binary) -----------------------------------------------------

def to_pcd(cloud: PointCloud) -> bytes:
    """Binary PCD v0.7 for PCL.

    x y z and intensity are float32 (``PointXYZI``); the class code (4 plant,
    64 turntable, 65 rig) is a uint32 ``label`` (``PointXYZL``/``PointXYZRGBL``).
    """
    rows = _structured(cloud, np.float32, rename={"classification": "label"},
                       types={"classification": np.uint32})
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
    return _from_rows(_pcd_rows(data))


def _pcd_rows(data: bytes) -> np.ndarray:
    """A binary or ASCII PCD v0.7's points as a structured array."""
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
    return rows


# --- TXT / XYZ (ASCII columns, CloudCompare-style header) ------------------

def to_txt(cloud: PointCloud) -> bytes:
    """ASCII columns: x y z (nanometre resolution) and the scalar fields.

    The first line, ``//X Y Z Intensity Scalar_classification ...``, names the
    columns for CloudCompare (``SF`` names are scalar fields, never colours);
    Open3D's ``xyz`` reader skips it and reads x y z from every other line.
    """
    cols = _columns(cloud)
    # CloudCompare's ASCII reader takes a column whose name contains "SCALAR" (or
    # "INTENSITY") as a scalar field; others fall to a guess that can read small
    # integer columns as RGB.
    names = ["X", "Y", "Z"] + ["Intensity" if n == "intensity" else f"Scalar_{n}" for n in cols]
    table = np.column_stack([cloud.points_turntable] + [cols[n].astype(np.float64) for n in cols])
    # %.17g: angle, range and time come back bit for bit, as from the binary formats.
    fmt = ["%.9f"] * 3 + ["%d", "%.9g", "%d", "%d"] + ["%.17g"] * 3
    buffer = io.BytesIO()
    buffer.write(("//" + " ".join(names) + "\n").encode("ascii"))
    np.savetxt(buffer, table, fmt=fmt, delimiter=" ")
    return buffer.getvalue()


def to_xyz(cloud: PointCloud) -> bytes:
    """ASCII columns without a header, in the order of :func:`to_txt`'s header.

    Open3D's ``xyz`` reader (which stops at a header line) reads x y z from
    the first three columns.
    """
    text = to_txt(cloud)
    return text[text.index(b"\n") + 1:]


def to_pts(cloud: PointCloud) -> bytes:
    """Leica PTS: a point-count line, then ``x y z intensity`` (Open3D and CloudCompare).

    Only coordinates and intensity travel in this format.
    """
    cols = _columns(cloud)
    buffer = io.BytesIO()
    buffer.write(f"{len(cloud)}\n".encode("ascii"))
    np.savetxt(buffer, np.column_stack([cloud.points_turntable, cols["intensity"]]),
               fmt=["%.9f"] * 3 + ["%.9g"], delimiter=" ")
    return buffer.getvalue()


def from_pts(data: bytes) -> PointCloud:
    return _from_rows(_pts_rows(data))


def _pts_rows(data: bytes) -> np.ndarray:
    """A PTS file's points (count line, then x y z intensity [r g b]) as a structured array."""
    body = data.split(b"\n", 1)[1] if b"\n" in data else b""
    # An empty cloud is the count line alone: no rows to count columns in.
    table = np.loadtxt(io.BytesIO(body), ndmin=2) if body.strip() else np.zeros((0, 4))
    names = ["x", "y", "z", "intensity", "red", "green", "blue"][:table.shape[1]]
    rows = np.empty(len(table), dtype=[(n, np.float64) for n in names])
    for i, name in enumerate(names):
        rows[name] = table[:, i]
    return rows


_TXT_COLUMNS = ["x", "y", "z"] + [name for name, _, _ in _FIELDS]


def from_txt(data: bytes) -> PointCloud:
    """Reads ASCII columns: named by a ``//`` or ``#`` header, else plantsim's order."""
    return _from_rows(_txt_rows(data))


def _txt_rows(data: bytes) -> np.ndarray:
    """ASCII columns as a structured array: named by a ``//`` or ``#`` header (lower case,
    ``Scalar_``/``SF_`` dropped), else plantsim's order, else x y z and ``_col3``, ``_col4``..."""
    first = data.split(b"\n", 1)[0].decode("ascii", "replace")
    header = first.startswith(("//", "#"))
    body = data.split(b"\n", 1)[1] if header and b"\n" in data else (b"" if header else data)
    if header:
        names = [n.split("_", 1)[1] if n.startswith(("Scalar_", "SF_")) else n.lower()
                 for n in first.lstrip("/#").split()]
    # An empty cloud has no rows to count columns in: take the header's (or x y z).
    table = (np.loadtxt(io.BytesIO(body), comments=("//", "#"), ndmin=2) if body.strip()
             else np.zeros((0, len(names) if header else 3)))
    if header:
        intensity_at = names.index("intensity") if "intensity" in names else None
        if intensity_at is not None and len(table):
            values = table[:, intensity_at]
            if values.max() > 1 and (values == np.round(values)).all():
                table[:, intensity_at] = values / 65535  # plantsim 0.2 wrote 0..65535 integers
    elif table.shape[1] == len(_TXT_COLUMNS):
        names = list(_TXT_COLUMNS)
    else:
        names = ["x", "y", "z"]
    names = names[:table.shape[1]] + [f"_col{i}" for i in range(len(names), table.shape[1])]
    rows = np.empty(len(table), dtype=[(n, np.float64) for n in names])
    for i, name in enumerate(names):
        rows[name] = table[:, i]
    return rows


# --- E57 (ASTM E2807, through pye57 / libE57Format) ------------------------

def _pye57():
    try:
        import pye57
    except ImportError:
        raise RuntimeError("writing or reading .e57 needs pye57: pip install 'plantsim[e57]'"
                           ) from None
    return pye57


def to_e57(cloud: PointCloud) -> bytes:
    """E57: one structured scan in the turntable frame (identity pose).

    Fields: ``cartesianX/Y/Z`` (metres; pye57 stores single-precision floats, as
    the PLY default: 0.1 um at 1 m), ``intensity`` (float, [0, 1]),
    ``rowIndex`` = beam within its line and ``columnIndex`` = scan line, E57's
    own grid indices for a line scanner. E57's standard point fields hold no
    class, time, range or turntable angle (pye57 writes no extensions): write
    ``--plant-only`` or a LAS for those.

    Raises:
      RuntimeError: pye57 is not installed (names the extra).
      OverflowError: a beam or line index above 65535 (E57's index fields
        here are 16-bit); never wrapped.
    """
    pye57 = _pye57()
    for name, values in (("beam_index", cloud.beam_index), ("scan_index", cloud.scan_index)):
        if len(values) and int(np.max(values)) > 0xFFFF:
            raise OverflowError(f"{name} reaches {int(np.max(values))}, above the 65535 an E57 "
                                "index holds here; write .las or .ply instead")
    pts = np.ascontiguousarray(cloud.points_turntable, dtype=np.float64)
    data = {
        "cartesianX": pts[:, 0].copy(), "cartesianY": pts[:, 1].copy(), "cartesianZ": pts[:, 2].copy(),
        "intensity": _columns(cloud)["intensity"].astype(np.float64),
        "rowIndex": cloud.beam_index.astype(np.uint16),
        "columnIndex": cloud.scan_index.astype(np.uint16),
    }
    with tempfile.TemporaryDirectory(prefix="plantsim-e57-") as folder:
        path = os.path.join(folder, "cloud.e57")
        e57 = pye57.E57(path, mode="w")
        try:
            # An empty cloud is a file with no scan (pye57 cannot bound an empty one).
            if len(cloud):
                e57.write_scan_raw(data, name="plantsim scan, turntable frame (metres)")
        finally:
            e57.close()
        with open(path, "rb") as handle:
            return handle.read()


def from_e57(data: bytes) -> PointCloud:
    """Reads the first scan of an E57 (none: an empty cloud): x y z, intensity and
    the row/column indices (as beam and line); the class is unknown
    (:attr:`HitClass.NONE`), time, range and angle are zero."""
    pye57 = _pye57()
    with tempfile.TemporaryDirectory(prefix="plantsim-e57-") as folder:
        path = os.path.join(folder, "cloud.e57")
        with open(path, "wb") as handle:
            handle.write(data)
        e57 = pye57.E57(path)
        try:
            scan = (e57.read_scan_raw(0, ignore_unsupported_fields=True) if e57.scan_count else
                    {name: np.zeros(0) for name in ("cartesianX", "cartesianY", "cartesianZ")})
        finally:
            e57.close()
    xyz = np.column_stack([scan["cartesianX"], scan["cartesianY"], scan["cartesianZ"]])
    n = len(xyz)
    cols = {"classification": np.zeros(n, np.uint8),
            "intensity": np.asarray(scan.get("intensity", np.zeros(n)), dtype=np.float32),
            "beam_index": scan.get("rowIndex", np.zeros(n)),
            "scan_index": scan.get("columnIndex", np.zeros(n)),
            "turntable_angle_rad": np.zeros(n), "range_m": np.zeros(n), "time": np.zeros(n)}
    return _cloud_from_columns(xyz, cols)


EXPORTERS: dict[str, Callable[[PointCloud], bytes]] = {
    ".las": to_las, ".laz": to_laz, ".ply": to_ply, ".pcd": to_pcd, ".txt": to_txt,
    ".xyz": to_xyz, ".pts": to_pts, ".e57": to_e57}
READERS: dict[str, Callable[[bytes], PointCloud]] = {
    ".las": from_las, ".laz": from_las, ".ply": from_ply, ".pcd": from_pcd, ".txt": from_txt,
    ".xyz": from_txt, ".pts": from_pts, ".e57": from_e57}
# Formats that carry only x y z and intensity.
LOSSY_FORMATS = frozenset({".pts"})
# Formats that carry x y z, intensity and the beam and line indices (no class, time,
# range or angle).
INDEXED_FORMATS = frozenset({".e57"})
# Formats written through an optional extra: the extra to install.
EXTRA_OF_FORMAT = {".laz": "laz", ".e57": "e57"}


def check_output_path(path: str | os.PathLike) -> Path:
    """Validates an output path before any work is done.

    Raises:
      ValueError: unknown extension (lists the valid ones).
      FileNotFoundError: the folder does not exist.
      RuntimeError: ``.e57`` without pye57 (names the extra).
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
    if path.suffix.lower() == ".e57":
        _pye57()  # a missing extra fails before the scan, not after it
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


def encode_cloud(path: str | os.PathLike, cloud: PointCloud, *, xyz_double: bool = False) -> bytes:
    """The file contents of ``cloud`` in the format ``path``'s extension names.

    Args:
      path: only its extension is used.
      cloud: the points.
      xyz_double: PLY only: float64 coordinates instead of float32.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in EXPORTERS:
        raise ValueError(f"unknown point-cloud format {suffix!r}; use one of {', '.join(EXPORTERS)}")
    if suffix == ".ply" and xyz_double:
        return to_ply(cloud, xyz_double=True)
    return EXPORTERS[suffix](cloud)


def write_cloud(path: str | os.PathLike, cloud: PointCloud, *, sidecar: dict | None = None,
                xyz_double: bool = False) -> None:
    """Writes a cloud (and, if given, its sidecar ``<path>.json``) as a unit.

    The cloud is encoded fully in memory before anything touches the disk; the
    files are then written and swapped in together by
    :class:`plantsim.cloud.outputs.OutputSet` (the one writer: a failure or Ctrl-C
    leaves the earlier files as they were). ``xyz_double`` asks for float64 PLY
    coordinates (default float32).
    """
    from plantsim.cloud.outputs import OutputSet

    path = check_output_path(path)
    data = encode_cloud(path, cloud, xyz_double=xyz_double)
    with OutputSet() as outputs:
        outputs.stage_bytes(path, data)
        if sidecar is not None:
            text = json.dumps(sidecar, indent=2, sort_keys=False, default=_json_default) + "\n"
            outputs.stage_bytes(sidecar_path(path), text.encode("utf-8"))
        outputs.commit()


def sidecar_path(path: str | os.PathLike) -> Path:
    path = Path(path)
    return path.with_name(path.name + ".json")


def read_cloud(path: str | os.PathLike) -> PointCloud:
    """Reads a point cloud written by plantsim (or any LAS/LAZ/PLY/PCD/TXT with x y z)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise ValueError(f"unknown point-cloud format {suffix!r}; use one of {', '.join(READERS)}")
    return READERS[suffix](path.read_bytes())


def read_point_field(path: str | os.PathLike, name: str) -> np.ndarray:
    """One per-point field of a point-cloud file, in the file's point order: a LAS/LAZ
    dimension (standard, as ``classification`` or ``point_source_id``, or extra bytes), a
    PLY vertex property (``scalar_`` prefix optional), a PCD field, or a TXT/XYZ column
    (named by its header, lower case, ``Scalar_``/``SF_`` dropped; a header-less file's
    columns past x y z are ``_col3``, ``_col4``, ...). For per-point labels made elsewhere
    (a hand segmentation in CloudCompare, a labelled dataset such as Pheno4D's
    ``x y z label`` text files).

    Raises:
        ValueError: an unknown format, a format with no such fields (E57, PTS beyond its
            columns), or a field the file does not have (the message lists those it has).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise ValueError(f"unknown point-cloud format {suffix!r}; use one of {', '.join(READERS)}")
    if suffix not in (".las", ".laz", ".ply", ".pcd", ".txt", ".xyz", ".pts"):
        raise ValueError(f"a {suffix} cloud carries no per-point fields beyond its coordinates and "
                         "intensity; write the labels to .las, .ply, .pcd or .txt")
    data = path.read_bytes()
    if suffix in (".las", ".laz"):
        import laspy

        if data[:4] == b"LASF" and len(data) > 104 and data[104] & 0x80:  # compressed bit
            _laz_backend()
        las = laspy.read(io.BytesIO(data))
        names = list(las.point_format.dimension_names)
        if name in names:
            return np.asarray(las[name])
    else:
        rows = {".ply": _ply_rows, ".pcd": _pcd_rows, ".txt": _txt_rows, ".xyz": _txt_rows,
                ".pts": _pts_rows}[suffix](data)
        names = list(rows.dtype.names)
        key = name[len(_PLY_PREFIX):] if suffix == ".ply" and name.startswith(_PLY_PREFIX) else name
        key = key.lower() if suffix in (".txt", ".xyz") and not key.startswith("_col") else key
        if key in names:
            return np.asarray(rows[key])
    raise ValueError(f"{path.name} has no per-point field {name!r}; it has: {', '.join(names)}")


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
