"""Point-cloud files: LAS 1.4 / LAZ, PLY, PCD and TXT/XYZ, chosen by extension.

Exporters take a :class:`PointCloud` and return bytes (they never touch the
disk); :func:`write_cloud` is the only writer and writes atomically (a temp
file in the same folder, then ``os.replace``), so a failure leaves no
half-written file. Readers give a :class:`PointCloud` back, for round trips and
for evaluating clouds made elsewhere.

Every format carries the same per-point fields: x, y, z (turntable frame,
metres), classification (what the beam hit; :data:`CLASSIFICATION`), intensity,
beam_index, scan_index, turntable_angle_rad, range_m and time (the beam's time
in seconds; LAS GPS time). Each format names and types them the way the tools
that read it expect (checked against Open3D, PCL and CloudCompare's readers):

- LAS/LAZ: point format 6, intensity uint16 (0..65535 for 0..1), the rest as
  extra bytes; one return per pulse (return number = number of returns = 1),
  the WKT global-encoding bit set (LAS 1.4 R15 requires it for formats 6-10).
- PLY: x y z float32 (``precision="double"`` for float64), ``intensity``
  float32, the other fields prefixed ``scalar_`` (CloudCompare loads every
  ``scalar_*`` property as a scalar field without asking, and strips the
  prefix) in types Open3D's tensor reader keeps (uint8, uint16, int32, float64).
- PCD: x y z float32 (PCL's ``PointXYZ``), ``intensity`` float32
  (``PointXYZI``), the class code as uint32 ``label`` (``PointXYZL``).
- TXT: a ``//`` header line CloudCompare reads (``intensity`` and ``scalar_*``
  columns become scalar fields). XYZ: the same columns with no header line, so
  Open3D (which reads the first three columns) accepts it.
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
# LAS 1.4 R15 table 16: point formats 6-10 store the scan angle as int16 in 0.006 degree steps.
LAS_SCAN_ANGLE_STEP_DEG = 0.006

PRECISIONS = ("single", "double")

# The scalar fields after x, y, z, in file order: plantsim's name and the numpy
# dtype a lossless column needs. Formats rename or retype them below.
_FIELDS = (
    ("intensity", np.float32),
    ("classification", np.uint8),
    ("beam_index", np.uint16),
    ("scan_index", np.uint32),
    ("turntable_angle_rad", np.float64),
    ("range_m", np.float64),
    ("time", np.float64),
)
_FIELD_NAMES = tuple(name for name, _ in _FIELDS)


def _columns(cloud: PointCloud) -> dict[str, np.ndarray]:
    """plantsim's per-point fields as columns (``_FIELDS`` order and dtypes)."""
    codes = np.zeros(256, dtype=np.uint8)
    for cls, code in CLASSIFICATION.items():
        codes[int(cls)] = code
    n = len(cloud)
    intensity = (np.zeros(n, np.float32) if cloud.intensity is None
                 else np.clip(np.asarray(cloud.intensity, dtype=np.float32), 0.0, 1.0))
    return {
        "intensity": intensity,
        "classification": codes[cloud.hit_class],
        "beam_index": cloud.beam_index.astype(np.uint16),
        "scan_index": cloud.scan_index.astype(np.uint32),
        "turntable_angle_rad": cloud.turntable_angle_rad.astype(np.float64),
        "range_m": cloud.range_m.astype(np.float64),
        "time": cloud.time_s.astype(np.float64),
    }


# Names other tools (and plantsim's older files) use for plantsim's fields.
_ALIASES = {"label": "classification", "gps_time": "time", "scalar_intensity": "intensity"}


def _canonical(name: str) -> str:
    name = _ALIASES.get(name, name)
    if name.startswith("scalar_") and name[len("scalar_"):] in _FIELD_NAMES:
        return name[len("scalar_"):]
    return name


def _cloud_from_columns(xyz: np.ndarray, cols: dict[str, np.ndarray]) -> PointCloud:
    """A cloud from x y z and whatever of plantsim's fields a file had (by canonical name).

    Intensity stored as floats is taken as is (0..1); stored as integers (LAS,
    plantsim's files before 0.3) it is scaled from 0..65535. All-zero intensity
    means "not modelled" (None).
    """
    n = len(xyz)
    cols = {_canonical(k): v for k, v in cols.items()}
    get = lambda name, dtype: (np.asarray(cols[name]) if name in cols  # noqa: E731
                               else np.zeros(n, dtype))
    classification = get("classification", np.uint8).astype(np.int64)
    hit_class = np.array([_CLASS_OF_CODE.get(c, HitClass.NONE) for c in range(256)],
                         dtype=np.uint8)[np.clip(classification, 0, 255)]
    raw = get("intensity", np.float32)
    intensity = (raw.astype(np.float64) / 65535 if raw.dtype.kind in "ui"
                 else raw.astype(np.float64))
    return PointCloud(
        points_turntable=np.ascontiguousarray(xyz, dtype=np.float64),
        hit_class=hit_class,
        beam_index=get("beam_index", np.uint16).astype(np.uint16),
        scan_index=get("scan_index", np.uint32).astype(np.uint32),
        turntable_angle_rad=get("turntable_angle_rad", np.float64).astype(np.float64),
        range_m=get("range_m", np.float64).astype(np.float64),
        time_s=get("time", np.float64).astype(np.float64),
        intensity=intensity.astype(np.float32) if intensity.any() else None,
    )


def _check_precision(precision: str) -> np.dtype:
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return np.dtype(np.float32 if precision == "single" else np.float64)


def _rows(cloud: PointCloud, layout: tuple[tuple[str, str, np.dtype], ...],
          xyz_dtype: np.dtype) -> np.ndarray:
    """A little-endian structured array: x y z, then ``layout``'s (file name, plantsim name, dtype)."""
    dtype = np.dtype([(a, xyz_dtype) for a in "xyz"] + [(f, t) for f, _, t in layout])
    rows = np.empty(len(cloud), dtype=dtype.newbyteorder("<"))
    for i, axis in enumerate("xyz"):
        rows[axis] = cloud.points_turntable[:, i]
    cols = _columns(cloud)
    for file_name, name, t in layout:
        values = cols[name]
        if np.dtype(t).kind in "ui" and len(values) and values.max() > np.iinfo(t).max:
            raise OverflowError(f"{name} reaches {values.max()}, more than the file's "
                                f"{np.dtype(t).name} column {file_name!r} holds")
        rows[file_name] = values
    return rows


def _xyz_from_rows(rows: np.ndarray) -> np.ndarray:
    names = rows.dtype.names
    missing = [a for a in "xyz" if a not in names]
    if missing:
        raise ValueError(f"the file has no {', '.join(missing)} field; found {', '.join(names)}")
    return np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float64)


def _from_rows(rows: np.ndarray) -> PointCloud:
    return _cloud_from_columns(_xyz_from_rows(rows),
                               {n: rows[n] for n in rows.dtype.names if n not in "xyz"})


# --- LAS 1.4 / LAZ (laspy; LAZ through lazrs) ---------------------------------

_LAS_EXTRA = (("beam_index", np.uint16, "beam within its scan line"),
              ("scan_index", np.uint32, "scan line (turntable step)"),
              ("turntable_angle_rad", np.float64, "turntable angle, radians"),
              ("range_m", np.float64, "measured range, metres"))


def to_las(cloud: PointCloud, *, beam_angle_rad: np.ndarray | None = None,
           compress: bool = False) -> bytes:
    """LAS 1.4, point format 6 (or LAZ when ``compress``); GPS time is the beam's time.

    Per point: return number = number of returns = 1 (the sensor reports one
    echo per beam); scan angle = the beam's angle in the LiDAR's scan plane
    (0.006 degree steps) when ``beam_angle_rad`` is given, else 0; point source
    ID 0 (one scanner, one file; the scan line is the ``scan_index`` extra
    dimension, which holds all 32 bits). The WKT global-encoding bit is set, as
    LAS 1.4 R15 requires for point formats 6-10 (no CRS: the turntable frame is local).

    Args:
      cloud: the points.
      beam_angle_rad: (n,) float64 radians, lidar frame, one per point (e.g.
        ``spec.beam_angles_rad()[cloud.beam_index]``), or None.
      compress: write LAZ (laspy's lazrs backend) instead of LAS.

    Raises:
      OverflowError: a coordinate does not fit the 0.01 mm grid (laspy's own check).
      ValueError: ``beam_angle_rad`` has the wrong shape or leaves -196.6..196.6 degrees.
    """
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.global_encoding.wkt = True
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
    las.intensity = np.round(cols["intensity"].astype(np.float64) * 65535).astype(np.uint16)
    las.gps_time = cols["time"]
    las.return_number = np.ones(len(cloud), np.uint8)
    las.number_of_returns = np.ones(len(cloud), np.uint8)
    if beam_angle_rad is not None:
        las.scan_angle = _las_scan_angle(beam_angle_rad, len(cloud))
    for name, _, _ in _LAS_EXTRA:
        las[name] = cols[name]
    buffer = io.BytesIO()
    if compress:
        las.write(buffer, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    else:
        las.write(buffer, do_compress=False)
    return buffer.getvalue()


def _las_scan_angle(beam_angle_rad: np.ndarray, n: int) -> np.ndarray:
    angle = np.asarray(beam_angle_rad, dtype=np.float64)
    if angle.shape != (n,):
        raise ValueError(f"beam_angle_rad must have shape ({n},), one per point, got {angle.shape}")
    steps = np.round(np.rad2deg(angle) / LAS_SCAN_ANGLE_STEP_DEG)
    limit = np.iinfo(np.int16).max
    if n and np.abs(steps).max() > limit:
        raise ValueError(f"beam_angle_rad must lie within +-{limit * LAS_SCAN_ANGLE_STEP_DEG:.1f} "
                         f"degrees (LAS scan angle), got {np.rad2deg(np.abs(angle).max()):.1f}")
    return steps.astype(np.int16)


def to_laz(cloud: PointCloud, *, beam_angle_rad: np.ndarray | None = None) -> bytes:
    """LAZ: :func:`to_las` compressed with lazrs (lossless, about a third of the size)."""
    return to_las(cloud, beam_angle_rad=beam_angle_rad, compress=True)


def from_las(data: bytes) -> PointCloud:
    """Reads LAS or LAZ (laspy; LAZ needs lazrs)."""
    import laspy

    las = laspy.read(io.BytesIO(data))
    xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)
    names = set(las.point_format.dimension_names)
    cols = {"classification": np.asarray(las.classification),
            "intensity": np.asarray(las.intensity)}
    if "gps_time" in names:
        cols["time"] = np.asarray(las.gps_time)
    for name, _, _ in _LAS_EXTRA:
        if name in names:
            cols[name] = np.asarray(las[name])
    return _cloud_from_columns(xyz, cols)


# --- PLY (binary little endian) --------------------------------------------

# Sized PLY type names: Open3D's tensor reader keeps uint16 but skips "ushort",
# "short", "char" and any uint32, so scan_index is int32 (2**31 scan lines is plenty).
_PLY_TYPE = {"u1": "uint8", "<u2": "uint16", "<i4": "int32", "<f4": "float32", "<f8": "float64"}
_PLY_LAYOUT = (
    ("intensity", "intensity", np.dtype("<f4")),
    ("scalar_classification", "classification", np.dtype("u1")),
    ("scalar_beam_index", "beam_index", np.dtype("<u2")),
    ("scalar_scan_index", "scan_index", np.dtype("<i4")),
    ("scalar_turntable_angle_rad", "turntable_angle_rad", np.dtype("<f8")),
    ("scalar_range_m", "range_m", np.dtype("<f8")),
    ("scalar_time", "time", np.dtype("<f8")),
)


def to_ply(cloud: PointCloud, *, precision: str = "single") -> bytes:
    """Binary little-endian PLY.

    Args:
      cloud: the points.
      precision: "single" (float32 x y z, 0.06 um steps at 1 m; what PCL's
        ``PointXYZ`` and most viewers expect) or "double" (float64).

    Raises:
      ValueError: unknown ``precision``.
      OverflowError: a scan_index beyond int32.
    """
    rows = _rows(cloud, _PLY_LAYOUT, _check_precision(precision))
    props = "".join(f"property {_PLY_TYPE[rows.dtype[n].str.replace('|', '')]} {n}\n"
                    for n in rows.dtype.names)
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
            if parts[1] == "list":
                raise ValueError(f"vertex list property {parts[-1]!r} is not supported")
            fields.append((parts[2], _PLY_NP[parts[1]]))
    rows = np.frombuffer(data, dtype=np.dtype(fields), count=n, offset=end + len(b"end_header\n"))
    return _from_rows(rows)


# --- PCD v0.7 (binary) -----------------------------------------------------

_PCD_LAYOUT = (
    ("intensity", "intensity", np.dtype("<f4")),
    ("label", "classification", np.dtype("<u4")),
    ("beam_index", "beam_index", np.dtype("<u2")),
    ("scan_index", "scan_index", np.dtype("<u4")),
    ("turntable_angle_rad", "turntable_angle_rad", np.dtype("<f8")),
    ("range_m", "range_m", np.dtype("<f8")),
    ("time", "time", np.dtype("<f8")),
)


def to_pcd(cloud: PointCloud, *, precision: str = "single") -> bytes:
    """Binary PCD v0.7: PCL's typed loaders (PointXYZ, PointXYZI, PointXYZL) read it.

    Args:
      cloud: the points.
      precision: "single" (float32 x y z, as PCL's point types hold them) or
        "double" (float64; only PCL's untyped ``PCLPointCloud2`` keeps them).
    """
    rows = _rows(cloud, _PCD_LAYOUT, _check_precision(precision))
    names = rows.dtype.names
    sizes = " ".join(str(rows.dtype[n].itemsize) for n in names)
    types = " ".join({"f": "F", "u": "U", "i": "I"}[rows.dtype[n].kind] for n in names)
    header = (f"# .PCD v0.7 - plantsim point cloud, turntable frame, metres; "
              f"label: 4 plant, 64 turntable, 65 rig\nVERSION 0.7\n"
              f"FIELDS {' '.join(names)}\nSIZE {sizes}\nTYPE {types}\n"
              f"COUNT {' '.join('1' for _ in names)}\nWIDTH {len(rows)}\nHEIGHT 1\n"
              f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(rows)}\nDATA binary\n")
    return header.encode("ascii") + rows.tobytes()


def from_pcd(data: bytes) -> PointCloud:
    """Reads a binary or ASCII PCD v0.7 with at least x y z."""
    header, offset = {}, 0
    while True:
        end = data.find(b"\n", offset)
        if end < 0:
            raise ValueError("not a PCD file (no DATA line in the header)")
        line = data[offset:end].decode("ascii", "replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        header[key.upper()] = value.split()
        if key.upper() == "DATA":
            break
    names, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = header.get("COUNT", ["1"] * len(names))
    if any(c != "1" for c in counts):
        raise ValueError(f"PCD fields with COUNT > 1 are not supported (COUNT {' '.join(counts)})")
    dtype = np.dtype([(n, f"<{ {'F': 'f', 'U': 'u', 'I': 'i'}[t] }{s}")
                      for n, s, t in zip(names, sizes, types)])
    n = int(header["POINTS"][0])
    if header["DATA"][0] == "binary":
        rows = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
    elif header["DATA"][0] == "ascii":
        table = np.loadtxt(io.BytesIO(data[offset:]), ndmin=2, dtype=np.float64)
        rows = np.empty(len(table), dtype=dtype)
        for i, name in enumerate(names):
            rows[name] = table[:, i]
    else:
        raise ValueError(f"PCD DATA {header['DATA'][0]!r} is not supported (binary or ascii)")
    return _from_rows(rows)


# --- TXT (CloudCompare header) / XYZ (no header; Open3D) ------------------

# Column names CloudCompare's ASCII reader maps by itself: x y z as coordinates,
# "intensity" and anything containing "scalar" as scalar fields. Without them it
# guesses small integer columns to be RGB.
_TXT_NAMES = ("x", "y", "z") + tuple(
    n if n == "intensity" else f"scalar_{n}" for n in _FIELD_NAMES)
_TXT_FORMATS = {"intensity": "%.9g", "classification": "%d", "beam_index": "%d",
                "scan_index": "%d", "turntable_angle_rad": "%.17g", "range_m": "%.17g",
                "time": "%.17g"}


def _table_text(cloud: PointCloud) -> bytes:
    cols = _columns(cloud)
    # Integers go through int64 so "%d" never sees a float; floats keep full precision.
    table = [cloud.points_turntable[:, i] for i in range(3)] + [cols[n] for n in _FIELD_NAMES]
    fmt = ["%.9f"] * 3 + [_TXT_FORMATS[n] for n in _FIELD_NAMES]
    line = " ".join(fmt) + "\n"
    buffer = io.StringIO()
    for row in zip(*(c.tolist() for c in table)):
        buffer.write(line % row)
    return buffer.getvalue().encode("ascii")


def to_txt(cloud: PointCloud) -> bytes:
    """ASCII columns with a CloudCompare header: x y z (1 nm steps) and every scalar field."""
    return ("//" + " ".join(_TXT_NAMES) + "\n").encode("ascii") + _table_text(cloud)


def to_xyz(cloud: PointCloud) -> bytes:
    """ASCII columns, no header: x y z then the fields in :func:`to_txt`'s order.

    Open3D reads the first three columns; plantsim reads all of them back.
    """
    return _table_text(cloud)


def from_txt(data: bytes) -> PointCloud:
    """Reads ASCII columns: a ``//`` or ``#`` header names them; without one, ten
    columns are plantsim's (:func:`to_xyz`), otherwise the first three are x y z."""
    first = data.split(b"\n", 1)[0].decode("ascii", "replace").strip()
    header = first.startswith(("//", "#"))
    body = data.split(b"\n", 1)[1] if header else data
    table = (np.loadtxt(io.BytesIO(body), comments=("//", "#"), ndmin=2, dtype=np.float64)
             if body.strip() else np.zeros((0, 0)))
    if header:
        names = [n.lower() for n in first.lstrip("/#").split()]
    elif table.shape[1] == len(_TXT_NAMES):
        names = list(_TXT_NAMES)
    else:
        names = ["x", "y", "z"]
    if table.size and table.shape[1] < len(names):
        raise ValueError(f"the header names {len(names)} columns but rows have {table.shape[1]}")
    rows = {name: table[:, i] for i, name in enumerate(names)} if table.size else {
        name: np.zeros(0) for name in names}
    missing = [a for a in "xyz" if a not in rows]
    if missing:
        raise ValueError(f"no {', '.join(missing)} column; the header names {', '.join(names)}")
    xyz = np.stack([rows["x"], rows["y"], rows["z"]], axis=1)
    cols = {}
    for name, values in rows.items():
        canonical = _canonical(name)
        if canonical in ("x", "y", "z"):
            continue
        if canonical == "intensity":
            # Text has no types: plantsim's files before 0.3 wrote 0..65535 integers.
            legacy = values.size and values.max() > 1 and (values == np.round(values)).all()
            values = (values / 65535 if legacy else values).astype(np.float32)
        cols[canonical] = values
    return _cloud_from_columns(xyz, cols)


EXPORTERS: dict[str, Callable[..., bytes]] = {
    ".las": to_las, ".laz": to_laz, ".ply": to_ply, ".pcd": to_pcd, ".txt": to_txt,
    ".xyz": to_xyz}
READERS: dict[str, Callable[[bytes], PointCloud]] = {
    ".las": from_las, ".laz": from_las, ".ply": from_ply, ".pcd": from_pcd, ".txt": from_txt,
    ".xyz": from_txt}
# Which keyword options each format takes (see encode_cloud).
_OPTIONS = {".las": ("beam_angle_rad",), ".laz": ("beam_angle_rad",),
            ".ply": ("precision",), ".pcd": ("precision",)}


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


def encode_cloud(path: str | os.PathLike, cloud: PointCloud, *, precision: str = "single",
                 beam_angle_rad: np.ndarray | None = None) -> bytes:
    """The file contents of ``cloud`` in the format ``path``'s extension names (pure).

    Args:
      path: only its extension is used (``EXPORTERS`` lists them).
      cloud: the points.
      precision: "single" or "double" x y z in PLY and PCD; LAS/LAZ (0.01 mm
        grid) and TXT/XYZ (1 nm steps) do not depend on it.
      beam_angle_rad: (n,) radians, lidar frame, per point: the LAS/LAZ scan
        angle (ignored by the other formats, which have no such field).

    Raises:
      ValueError: unknown extension or precision.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in EXPORTERS:
        raise ValueError(f"unknown point-cloud format {suffix!r}; use one of {', '.join(EXPORTERS)}")
    _check_precision(precision)
    given = {"precision": precision, "beam_angle_rad": beam_angle_rad}
    return EXPORTERS[suffix](cloud, **{k: given[k] for k in _OPTIONS.get(suffix, ())})


def write_cloud(path: str | os.PathLike, cloud: PointCloud, *, sidecar: dict | None = None,
                precision: str = "single", beam_angle_rad: np.ndarray | None = None) -> None:
    """Writes a cloud (and, if given, its sidecar ``<path>.json``), atomically.

    The cloud is encoded fully in memory before anything touches the disk.
    ``precision`` and ``beam_angle_rad`` are :func:`encode_cloud`'s.
    """
    path = check_output_path(path)
    data = encode_cloud(path, cloud, precision=precision, beam_angle_rad=beam_angle_rad)
    if sidecar is not None:
        text = json.dumps(sidecar, indent=2, sort_keys=False, default=_json_default) + "\n"
        write_atomic(sidecar_path(path), text.encode("utf-8"))
    write_atomic(path, data)


def sidecar_path(path: str | os.PathLike) -> Path:
    path = Path(path)
    return path.with_name(path.name + ".json")


def read_cloud(path: str | os.PathLike) -> PointCloud:
    """Reads a point cloud written by plantsim (or any LAS/LAZ/PLY/PCD/TXT/XYZ with x y z)."""
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
