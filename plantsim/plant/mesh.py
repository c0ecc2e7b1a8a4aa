"""Plant import: read a mesh file, check it, convert units and up axis, and place
it on the turntable.

The result records ``T_turntable_mesh``: the rigid 4x4 transform from the mesh
file's coordinates (scaled to metres) to the turntable frame (origin on the
axis at the disk top, +Z up; see :mod:`plantsim.rig.geometry`).
"""

from __future__ import annotations

import dataclasses
import functools
import io
import logging
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from plantsim.errors import MeshError
from plantsim.transforms import apply_T, make_T, rot_x, rot_y

log = logging.getLogger(__name__)

UNITS_TO_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
MESH_FORMATS = (".stl", ".obj", ".ply")
PLACEMENTS = ("base", "bbox", "none")

# Rotations taking the file's up axis to +Z, right-handed (no mirroring).
_R_UP = {"z": np.eye(3), "y": rot_x(math.pi / 2), "x": rot_y(-math.pi / 2)}

# Plausible plant heights for the size check: a seedling to a tall maize.
_PLAUSIBLE_HEIGHT_M = (0.01, 4.0)


@dataclasses.dataclass(frozen=True, eq=False)
class PlantMesh:
    """A plant mesh placed on the turntable.

    Attributes:
      vertices_mesh: (n, 3) float64, metres, the file's own axes (units applied).
      faces: (m, 3) int32, indices into the vertices; degenerate faces removed.
      T_turntable_mesh: (4, 4) float64, mesh frame (metres) -> turntable frame.
      source: where it came from (a path, or a name for in-memory meshes).
      units: units of the file ("m", "cm", "mm").
      up: the file's up axis ("x", "y", "z").
      n_faces_in_file: faces read before cleaning.
      n_degenerate_dropped: faces dropped for repeated indices or zero area.
      placement: how it was put on the disk, and why there (the stem base found,
        a user's base point, ...); the sidecar's ``plant.placement``.
    """

    vertices_mesh: np.ndarray
    faces: np.ndarray
    T_turntable_mesh: np.ndarray
    source: str = "<memory>"
    units: str = "m"
    up: str = "z"
    n_faces_in_file: int = 0
    n_degenerate_dropped: int = 0
    placement: str = ""

    @functools.cached_property
    def vertices_turntable(self) -> np.ndarray:
        """(n, 3) float64, metres, turntable frame (computed once, read-only).

        Placement checks, the rig-fit warnings, the caster and the sidecar all read it:
        at 1 M faces each computation cost 0.2 s.
        """
        vertices = apply_T(self.T_turntable_mesh, self.vertices_mesh)
        vertices.flags.writeable = False
        return vertices

    @property
    def n_faces(self) -> int:
        return int(len(self.faces))

    def bounds_turntable(self) -> np.ndarray:
        """(2, 3) float64: min and max corner in the turntable frame."""
        v = self.vertices_turntable
        return np.stack([v.min(axis=0), v.max(axis=0)])

    def summary(self) -> dict:
        lo, hi = self.bounds_turntable()
        return {
            "source": self.source,
            "units": self.units,
            "up": self.up,
            "n_vertices": int(len(self.vertices_mesh)),
            "n_faces": self.n_faces,
            "n_faces_in_file": self.n_faces_in_file,
            "n_degenerate_dropped": self.n_degenerate_dropped,
            "bounds_turntable_m": [lo.tolist(), hi.tolist()],
            "T_turntable_mesh": self.T_turntable_mesh.tolist(),
            "placement": self.placement,
        }


_STL_RECORD = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])


def binary_stl_arrays(data: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """Vertices and faces of a binary STL, or None if ``data`` is not one.

    A binary STL is an 80-byte header, a uint32 count and 50 bytes a triangle;
    the exact size identifies it even when the header starts with "solid"
    (as many CAD exporters write).
    """
    if len(data) < 84:
        return None
    n = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
    if len(data) != 84 + 50 * n:
        return None
    records = np.frombuffer(data, dtype=_STL_RECORD, count=n, offset=84)
    vertices = records["vertices"].astype(np.float64).reshape(-1, 3)  # one copy, not two
    return vertices, np.arange(3 * n, dtype=np.int64).reshape(-1, 3)


def _read_arrays(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Reads vertices and faces of an STL/OBJ/PLY file.

    Binary STL is read directly with numpy (importing trimesh costs ~0.6 s, a
    third of a whole scan); everything else goes through trimesh.
    """
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MeshError(f"cannot read mesh file {path}: {exc.strerror or exc}") from exc
    if not data.strip():
        raise MeshError(f"mesh file {path} is empty")
    if path.suffix.lower() == ".stl":
        arrays = binary_stl_arrays(data)
        if arrays is not None:
            return arrays
        looks_ascii = data[:5].lower() == b"solid" and b"facet" in data[:4096].lower()
        if not looks_ascii and len(data) >= 84:
            n = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
            raise MeshError(f"{path} is not a readable STL: not ASCII (no 'solid ... facet'), and as a binary STL "
                            f"its header says {n:,} triangles while the file holds {(len(data) - 84) / 50:,.1f} "
                            f"({len(data):,} bytes): it is truncated or damaged; export it again")
    import trimesh  # Imported here: it is the slowest import on the CLI's path.

    try:
        mesh = trimesh.load(io.BytesIO(data), file_type=path.suffix.lower()[1:], force="mesh",
                            process=False)
    except Exception as exc:  # trimesh raises many types on malformed files.
        raise MeshError(f"cannot parse {path} as {path.suffix.lower()[1:].upper()}: {exc}") from exc
    vertices = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    return vertices, faces


def _ordered_bits(values_f32: np.ndarray) -> np.ndarray:
    """uint32 keys that sort as the float32 values do (-0.0 and +0.0 get one key; no NaN)."""
    bits = (values_f32 + np.float32(0.0)).view(np.uint32)  # -0.0 + 0.0 is +0.0
    return np.where(bits >> np.uint32(31), ~bits, bits | np.uint32(0x80000000))


def unique_rows(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of an (n, 3) array, in lexicographic order, and each row's index among them.

    What ``np.unique(vertices, axis=0, return_inverse=True)`` gives, faster. Rows that
    float32 holds exactly (every STL) are sorted on integer keys that order as the
    floats do: one ``argsort`` of (x, y) packed in 64 bits, then a stable one of (rank
    of (x, y), z) packed likewise, which the first left nearly in order (0.28 s against
    0.71 s for a lexsort, and 3.9 s for ``np.unique``, on the 3 M vertex rows of a 1 M-face
    STL). Other rows take one ``lexsort`` of the three columns. Equal rows that differ
    only in the sign of a zero are one row, as ``np.unique`` has them, represented by
    the first of them in ``vertices``.

    Returns:
      unique (k, 3) float64, inverse (n,) int64 with ``unique[inverse] == vertices``.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if len(vertices) == 0:
        return vertices.reshape(0, 3), np.zeros(0, dtype=np.int64)
    as_f32 = vertices.astype(np.float32)
    if np.array_equal(as_f32, vertices):
        key_x, key_y, key_z = (_ordered_bits(as_f32[:, i]) for i in range(3))
        xy = (key_x.astype(np.uint64) << np.uint64(32)) | key_y
        by_xy = np.argsort(xy)
        xy_sorted = xy[by_xy]
        key = np.empty(len(xy), dtype=np.uint64)  # rank of (x, y), then z: a row's place in full
        key[0] = 0
        np.cumsum(xy_sorted[1:] != xy_sorted[:-1], out=key[1:])
        key <<= np.uint64(32)
        key |= key_z[by_xy]
        refine = np.argsort(key, kind="stable")
        order = by_xy[refine]
        ordered = key[refine]
    else:
        order = np.lexsort((vertices[:, 2], vertices[:, 1], vertices[:, 0]))
        ordered = vertices[order]
    new = np.empty(len(order), dtype=bool)
    new[0] = True
    if ordered.ndim == 1:
        np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    else:
        new[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    first = np.minimum.reduceat(order, np.flatnonzero(new))  # each row's first occurrence
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    return vertices[first], inverse


def clean_arrays(vertices: np.ndarray, faces: np.ndarray, *, source: str = "<memory>"
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """Checks a triangle mesh and drops degenerate faces.

    Vertices that are exact duplicates are merged (STL stores three per face);
    faces with a repeated index or zero area are dropped and counted.

    Args:
      vertices: (n, 3) float, any units.
      faces: (m, 3) int, vertex indices.
      source: name used in error messages.

    Returns:
      vertices (k, 3) float64, faces (p, 3) int32, number of degenerate faces dropped.

    Raises:
      MeshError: no faces, non-finite vertices, out-of-range indices, or
        nothing left after cleaning.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError(f"{source}: expected (n, 3) vertices and (m, 3) triangle faces, got "
                        f"{vertices.shape} and {faces.shape}")
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshError(f"{source}: the mesh has no triangles (is it a mesh file at all?)")
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise MeshError(f"{source}: {int(bad.sum())} of {len(vertices)} vertices are NaN or "
                        f"infinite (first at index {int(np.flatnonzero(bad)[0])}); repair or "
                        f"re-export the mesh")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"{source}: face indices out of range 0..{len(vertices) - 1}")
    unique, inverse = unique_rows(vertices)
    faces = inverse[faces]
    tri = unique[faces]
    doubled_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    extent = float(np.ptp(unique, axis=0).max()) or 1.0
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    # Zero area relative to the mesh's size (float64 cross products of a
    # sliver are ~1e-16 of extent^2 at worst).
    degenerate = repeated | (doubled_area <= 1e-14 * extent * extent)
    n_dropped = int(degenerate.sum())
    faces = faces[~degenerate]
    if len(faces) == 0:
        raise MeshError(f"{source}: all {n_dropped} faces are degenerate (zero area)")
    if n_dropped:
        log.warning("%s: dropped %d degenerate faces of %d", source, n_dropped, n_dropped + len(faces))
    # The vertices still used, in order (what np.unique(faces) gives, without its sort).
    is_used = np.zeros(len(unique), dtype=bool)
    is_used[faces] = True
    remap = np.cumsum(is_used, dtype=np.int64) - 1
    return unique[is_used], remap[faces].astype(np.int32), n_dropped


def _linked_components(points_xy: np.ndarray, link: float) -> np.ndarray:
    """Single-linkage components of a few points (labels, (n,) int64): points within ``link`` join.

    Label propagation on the dense neighbour matrix: cheap for the few hundred grid cells of a
    slice, and without scipy's sparse graphs, whose import alone costs a scan 0.2 s. Many
    points go through ``scipy.sparse.csgraph`` instead.
    """
    n = len(points_xy)
    if n > 3000:
        from scipy import sparse
        from scipy.sparse import csgraph
        from scipy.spatial import cKDTree

        pairs = cKDTree(points_xy).query_pairs(link, output_type="ndarray")
        return csgraph.connected_components(
            sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
            directed=False)[1].astype(np.int64)
    d2 = np.sum((points_xy[:, None, :] - points_xy[None, :, :]) ** 2, axis=-1)
    adjacent = d2 <= link * link
    labels = np.arange(n)
    while True:
        new = np.where(adjacent, labels[None, :], n).min(axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
    _, labels = np.unique(labels, return_inverse=True)
    return labels.reshape(-1).astype(np.int64)


def find_stem_base(vertices_up: np.ndarray, *, max_stem_diameter_m: float = 0.05
                   ) -> tuple[np.ndarray, str]:
    """Where the stem meets the ground: XY of the stem axis, from the base up.

    The mesh's vertices are sliced from the lowest point up in slices of 1 % of the
    height (at least 1 mm), over the lowest 25 %. In each slice the vertices are
    clustered in XY (single linkage at 3 % of the height); a compact cluster
    (extent <= ``max_stem_diameter_m``) that appears at the same place (within its
    own extent) in at least 5 slices is a stem column. The column whose lowest slice
    is lowest wins (the main stem); ties go to the most slices, and the explanation
    lists the others (a wheat's tillers rise from one slice, and the column with the
    most slices is one of them, not necessarily its main culm). A drooping leaf
    crosses few slices at one place, and a pot is wider than a stem, so neither is
    taken for the base. With no column, the XY centre of the lowest 2 % is used and
    the explanation says so.

    Args:
        vertices_up: (n, 3) float64, metres, +Z up.
        max_stem_diameter_m: widest stem accepted, metres.

    Returns:
        ((2,) float64 XY of the stem base, metres; explanation).
    """
    z = vertices_up[:, 2]
    z_min, h = float(z.min()), float(np.ptp(z)) or 1e-3
    dz = max(0.01 * h, 1e-3)
    link = 0.03 * h
    columns: list[list] = []  # [centre_xy, extent, n_slices, first_slice]
    n_slices = int(0.25 * h / dz) + 1
    # The vertices of the sliced band sorted by height once: each slice is then a run,
    # found by bisection, instead of a pass over every vertex (0.23 s at 1 M faces).
    in_band = np.flatnonzero(z < z_min + n_slices * dz)
    by_z = in_band[np.argsort(z[in_band], kind="stable")]
    z_sorted = z[by_z]
    for k in range(n_slices):
        lo, hi = np.searchsorted(z_sorted, [z_min + k * dz, z_min + (k + 1) * dz], side="left")
        sel = vertices_up[by_z[lo:hi], :2]  # z_min + k dz <= z < z_min + (k + 1) dz
        if len(sel) < 3:
            continue
        # Single linkage on the occupied cells of a grid a quarter of the link wide (the
        # slices of a dense mesh hold thousands of vertices within one link of each other,
        # and all their pairs cost seconds); each vertex takes its cell's cluster.
        cell = 0.25 * link
        ij = np.floor(sel / cell).astype(np.int64)
        ij_min = ij.min(axis=0)
        span = int(ij[:, 1].max() - ij_min[1]) + 1
        # One int64 key a cell, ordered as the (i, j) rows: np.unique(axis=0)'s cells, faster.
        keys, inverse = np.unique((ij[:, 0] - ij_min[0]) * span + (ij[:, 1] - ij_min[1]), return_inverse=True)
        cells = np.stack([keys // span + ij_min[0], keys % span + ij_min[1]], axis=1)
        lab = _linked_components((cells + 0.5) * cell, link)[inverse.reshape(-1)]
        for c in range(lab.max() + 1):
            xy = sel[lab == c]
            extent = float(np.ptp(xy, axis=0).max())
            if len(xy) < 3 or extent > max_stem_diameter_m:
                continue
            centre = 0.5 * (xy.min(axis=0) + xy.max(axis=0))
            for col in columns:
                if np.linalg.norm(col[0] - centre) <= max(col[1], extent, 1e-3) and col[4] != k:
                    col[2] += 1
                    col[4] = k
                    break
            else:
                columns.append([centre, extent, 1, k, k])
    stems = [c for c in columns if c[2] >= 5]
    if stems:
        best = min(stems, key=lambda c: (c[3], -c[2]))
        why = (f"stem base at ({best[0][0]:.4f}, {best[0][1]:.4f}) m: a column "
               f"{best[1] * 1e3:.1f} mm wide over {best[2]} slices of {dz * 1e3:.1f} mm")
        tied = [c for c in stems if c[3] == best[3]]
        if len(tied) > 1:
            # Culms of one crown (a wheat's tillers) rise from the same slice: the one with
            # the most slices need not be the main culm. Said, with how to choose another.
            others = ", ".join(f"({c[0][0]:.4f}, {c[0][1]:.4f})" for c in tied if c is not best)
            why += (f"; {len(tied)} columns rise from the lowest slice (culms of one crown?), the others at "
                    f"{others} m: --base-point X Y Z puts another point on the axis")
        return best[0], why
    band = max(0.02 * h, 1e-3)
    foot = vertices_up[z <= z_min + band, :2]
    centre = 0.5 * (foot.min(axis=0) + foot.max(axis=0))
    return centre, ("no stem column found in the lowest 25 % of the plant; centred the lowest "
                    f"2 % ({band * 1e3:.1f} mm) instead")


def placement_transform(vertices_up: np.ndarray, placement: str, *,
                        base_point: np.ndarray | None = None) -> np.ndarray:
    """Translation putting an up-aligned mesh on the disk.

    Args:
      vertices_up: (n, 3) float64, metres, +Z up (file axes rotated).
      placement: "base": the stem base (:func:`find_stem_base`) on the axis and the
        lowest point on the disk top; "bbox": the bounding box's XY centre on the
        axis, lowest point on the disk top; "none": no translation.
      base_point: (3,) float64, metres, up-aligned mesh coordinates: a user's base
        point, put at the turntable origin (overrides ``placement``).

    Returns:
      (3,) float64, metres.
    """
    return _placement_and_note(vertices_up, placement, base_point=base_point)[0]


def _placement_and_note(vertices_up: np.ndarray, placement: str, *,
                        base_point: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """:func:`placement_transform`'s translation, and how and why (a sentence)."""
    if base_point is not None:
        p = np.asarray(base_point, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"base_point must be 3 finite numbers (metres), got {base_point!r}")
        return -p, f"base point ({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m (up-aligned) on the axis at the disk top"
    if placement == "none":
        return np.zeros(3), "none: the file's coordinates (units and up axis applied)"
    z_min = vertices_up[:, 2].min()
    if placement == "base":
        centre_xy, why = find_stem_base(vertices_up)
        log.info("placement base: %s", why)
        note = f"base: {why}"
    else:
        foot = vertices_up[:, :2]
        centre_xy = 0.5 * (foot.min(axis=0) + foot.max(axis=0))
        note = "bbox: the bounding box's XY centre on the axis"
    return -np.array([centre_xy[0], centre_xy[1], z_min]), note + "; the lowest point on the disk top"


def _check_size(height_m: float, units: str, source: str) -> None:
    lo, hi = _PLAUSIBLE_HEIGHT_M
    if lo <= height_m <= hi:
        return
    for other, scale in UNITS_TO_M.items():
        if other != units and lo <= height_m / UNITS_TO_M[units] * scale <= hi:
            hint = f"; did you mean units={other!r}?"
            break
    else:
        hint = ""
    log.warning("%s: the plant is %.4g m tall with units=%r, which looks off for a plant%s",
                source, height_m, units, hint)


def _base_point_up(base_point: Any, units: str, R: np.ndarray, vertices_up: np.ndarray,
                   source: str) -> np.ndarray:
    """A user's base point, given in the mesh file's units and axes, in up-aligned metres;
    refused when it lies off the plant (another unit or axis order, most likely)."""
    p = np.asarray(base_point, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise ValueError(f"base_point must be 3 finite numbers (x, y, z in the mesh file's units and axes), "
                         f"got {base_point!r}")
    point_up = R @ (p * UNITS_TO_M[units])
    lo, hi = vertices_up.min(axis=0), vertices_up.max(axis=0)
    slack = 0.1 * float(np.max(hi - lo))
    outside = float(np.max(np.maximum(lo - slack - point_up, point_up - hi - slack)))
    if outside > 0:
        to_file = R.T / UNITS_TO_M[units]
        lo_f, hi_f = np.sort(np.stack([to_file @ lo, to_file @ hi]), axis=0)
        raise ValueError(
            f"base_point ({', '.join(f'{x:g}' for x in p)}) lies off the plant: the mesh spans "
            f"({', '.join(f'{x:.4g}' for x in lo_f)})..({', '.join(f'{x:.4g}' for x in hi_f)}) {units} in the "
            f"file's axes; give the point in the file's own units ({units}) and axes")
    below = float(point_up[2] - lo[2])
    if below > slack:
        log.warning("%s: base point %.4g m above the plant's lowest point: the plant's lower %.4g m "
                    "lies below the disk top", source, below, below)
    return point_up


def plant_from_arrays(vertices: np.ndarray, faces: np.ndarray, *, units: str = "m",
                      up: str = "z", placement: str = "base",
                      T_turntable_mesh: np.ndarray | None = None, base_point: Any = None,
                      source: str = "<memory>", n_faces_in_file: int | None = None) -> PlantMesh:
    """Builds a :class:`PlantMesh` from arrays (see :func:`load_plant` for the options)."""
    if units not in UNITS_TO_M:
        raise ValueError(f"units must be one of {', '.join(UNITS_TO_M)}, got {units!r}")
    if up not in _R_UP:
        raise ValueError(f"up must be one of x, y, z, got {up!r}")
    if placement not in PLACEMENTS:
        raise ValueError(f"placement must be one of {', '.join(PLACEMENTS)}, got {placement!r}")
    if base_point is not None and (T_turntable_mesh is not None or placement != "base"):
        other = "T_turntable_mesh" if T_turntable_mesh is not None else f"placement {placement!r}"
        raise ValueError(f"base_point and {other} both place the plant: give one")
    n_in = len(faces) if n_faces_in_file is None else n_faces_in_file
    vertices, faces, n_dropped = clean_arrays(vertices, faces, source=source)
    vertices_m = vertices * UNITS_TO_M[units]
    if T_turntable_mesh is None:
        R = _R_UP[up]
        vertices_up = vertices_m @ R.T
        point = None if base_point is None else _base_point_up(base_point, units, R, vertices_up, source)
        if point is not None:
            log.info("placement: the base point given, (%.4g, %.4g, %.4g) m up-aligned, on the axis at the "
                     "disk top", *point)
        t, note = _placement_and_note(vertices_up, placement, base_point=point)
        T = make_T(R, t)
        height = float(np.ptp(vertices_up[:, 2]))
    else:
        T = np.asarray(T_turntable_mesh, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError(f"T_turntable_mesh must be a finite 4x4 matrix, got shape {T.shape}")
        R = T[:3, :3]
        if not (np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(R), 1.0)
                and np.allclose(T[3], [0, 0, 0, 1])):
            raise ValueError("T_turntable_mesh must be rigid: a rotation (orthonormal, det +1) "
                             "and a translation, last row [0, 0, 0, 1]")
        height = float(np.ptp(apply_T(T, vertices_m)[:, 2]))
        note = "T_turntable_mesh given"
    _check_size(height, units, source)
    return PlantMesh(vertices_mesh=vertices_m, faces=faces, T_turntable_mesh=T, source=source,
                     units=units, up=up, n_faces_in_file=int(n_in), n_degenerate_dropped=n_dropped,
                     placement=note)


def load_plant(path: str | os.PathLike, *, units: str = "m", up: str = "z",
               placement: str = "base", T_turntable_mesh: np.ndarray | None = None,
               base_point: Any = None) -> PlantMesh:
    """Reads a plant mesh (STL binary or ASCII, OBJ, PLY) and places it on the turntable.

    Args:
      path: the mesh file.
      units: the file's length unit: "m", "cm" or "mm".
      up: the file's up axis: "x", "y" or "z"; it becomes the turntable's +Z.
      placement: "base" (default: the plant's base centred on the axis, resting
        on the disk top), "bbox" (bounding box centred), or "none" (file
        coordinates, after units and up axis, are turntable coordinates).
      T_turntable_mesh: an explicit (4, 4) rigid placement (mesh metres ->
        turntable); overrides ``up`` and ``placement``.
      base_point: a user's base point, x, y, z in the file's own units and axes
        (as a mesh viewer shows them), put on the axis at the disk top instead of
        the base :func:`find_stem_base` finds (a pot's centre, the main culm of a
        clump of tillers); with ``placement`` "base" only, not with
        ``T_turntable_mesh``. Refused off the plant (10 % of its size beyond its
        bounding box); a point above the plant's lowest sinks the rest below the
        disk top, and a warning says so.

    Returns:
      The placed :class:`PlantMesh`.

    Raises:
      FileNotFoundError: no such file.
      ValueError: an unknown format, unit, axis or placement.
      MeshError: unreadable, empty or garbage content, NaN/inf vertices.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"mesh file not found: {path}")
    if path.is_dir():
        raise MeshError(f"mesh path is a folder, not a file: {path}")
    if path.suffix.lower() not in MESH_FORMATS:
        raise ValueError(f"unsupported mesh format {path.suffix or '(none)'!r} for {path}; "
                         f"use one of {', '.join(MESH_FORMATS)}")
    vertices, faces = _read_arrays(path)
    return plant_from_arrays(vertices, faces, units=units, up=up, placement=placement, base_point=base_point,
                             T_turntable_mesh=T_turntable_mesh, source=str(path))


def shell_inertia(vertices: np.ndarray, faces: np.ndarray, *, areal_density_kg_m2: float
                  ) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, centre of mass and inertia of a thin shell (leaves have no volume).

    Each triangle is a uniform lamina; its second moment about the origin is
    m/12 (a a^T + b b^T + c c^T + s s^T) with s = a + b + c.

    Args:
      vertices: (n, 3) float64, metres, any frame.
      faces: (m, 3) int.
      areal_density_kg_m2: mass per unit area.

    Returns:
      mass (kg), com (3,) metres, inertia (3, 3) kg m^2 about the com, same frame.
    """
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    m_tri = areal_density_kg_m2 * area
    mass = float(m_tri.sum())
    com = (m_tri[:, None] * tri.mean(axis=1)).sum(axis=0) / mass
    t = tri - com
    s = t.sum(axis=1)
    second = (np.einsum("f,fki,fkj->ij", m_tri, t, t) + np.einsum("f,fi,fj->ij", m_tri, s, s)) / 12.0
    inertia = np.trace(second) * np.eye(3) - second
    return mass, com, inertia
