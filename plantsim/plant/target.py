"""The calibration target: two simple parts a user can build, with an exact distance function.

Set on the turntable disk (turntable frame: origin on the axis at the disk top,
+Z up, +X towards the LiDAR at turntable angle 0):

=========  ==============================================================================
part       what and where (millimetres)
=========  ==============================================================================
block      a rectangular block 190 long (X), 110 wide (Y), 100 tall (Z), standing on the
           disk, its centre on the turntable axis, its long side along X: x -95..95,
           y -55..55, z 0..100 (sawn from timber, or glued from 18 mm MDF sheets); its
           ends stay 5 mm inside the 100 mm disk's rim
post       a cylinder of radius 20, 200 tall, standing on the block's top on its long
           centre line, 40 from the block's centre towards +X: centre (40, 0), z 100..300
           (a 40 mm dowel, glued into a shallow 40 mm hole or onto the top)
=========  ==============================================================================

How to place it: mark the disk's centre (the axis), set the block's centre on it
(a pencil cross on the block's underside helps; a few millimetres off is fine, the
fit estimates where the block stands), long side along the direction that is to be
turntable angle 0, the post on the side towards +X. Matte, light surfaces (paint or
paper) suit a LiDAR best; the sizes must be right to a few tenths of a millimetre
(measure them and pass them as a :class:`CalibrationTarget`).

Why this shape (what each part makes observable, see :mod:`plantsim.cloud.calibration`
and ``docs/calibration.md``): a round part centred on the axis looks the same from
every side, and a scan plane that misses the axis by ``e`` (yaw) changes its range
only by about ``e^2 / 2r``; the block's flat faces change range by ``e tan(psi)``
(psi the face's angle to the beam), first order, and its faces at two distances
from the axis (95 and 55 mm) tell that lateral offset from a turn of the table
(the encoder's zero): the longer the block, the further its end faces from the axis and the
better they pin the zero (190 mm: 0.08 degrees, one sigma, at 0.25-degree steps; a block
past the disk's rim biases the height and tilt, docs/calibration.md). The post off the axis breaks the block's half-turn symmetry
so that the zero is unique, and with its 200 mm of height spanning the LiDAR's
horizon fixes the fan's tilt; the block's top and the disk's top, two horizontal
surfaces at different depths below the LiDAR, fix its height and roll.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class CalibrationTarget:
    """The target's sizes, metres (see the module docstring).

    Attributes:
      block_length_m, block_width_m, block_height_m: the block's size along X, Y, Z.
      post_radius_m, post_height_m: the post's radius and height (it stands on the block).
      post_offset_m: the post's axis from the block's centre along +X.
      sections: facets around the post in the mesh.
    """

    block_length_m: float = 0.190
    block_width_m: float = 0.110
    block_height_m: float = 0.100
    post_radius_m: float = 0.020
    post_height_m: float = 0.200
    post_offset_m: float = 0.040
    sections: int = 256

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name == "sections":
                if isinstance(value, bool) or not isinstance(value, int) or value < 8:
                    raise ValueError(f"sections must be an integer >= 8, got {value!r}")
            elif isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) \
                    or value < 0 or (value == 0 and field.name != "post_offset_m"):
                raise ValueError(f"target {field.name} must be a finite number of metres > 0, got {value!r}")
        if abs(self.post_offset_m) + self.post_radius_m > self.block_length_m / 2 \
                or self.post_radius_m > self.block_width_m / 2:
            raise ValueError(f"the post (radius {self.post_radius_m} m, {self.post_offset_m} m off centre) must "
                             f"stand on the block's top ({self.block_length_m} x {self.block_width_m} m)")

    @property
    def top_m(self) -> float:
        """Height of the post's top above the disk, metres."""
        return self.block_height_m + self.post_height_m

    @property
    def reach_m(self) -> float:
        """The largest distance of any part from the block's centre line, metres."""
        return float(np.hypot(self.block_length_m / 2, self.block_width_m / 2))

    def parts(self) -> dict:
        """Each part as (kind, centre (3,), sizes): "cylinder" (radius, half height); "box" half extents (3,)."""
        return {
            "block": ("box", np.array([0.0, 0.0, self.block_height_m / 2]),
                      np.array([self.block_length_m / 2, self.block_width_m / 2, self.block_height_m / 2])),
            "post": ("cylinder", np.array([self.post_offset_m, 0.0, self.block_height_m + self.post_height_m / 2]),
                     (self.post_radius_m, self.post_height_m / 2)),
        }

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The target as one triangle mesh: vertices (n, 3) float64 metres, turntable frame; faces (m, 3)."""
        import trimesh

        meshes = []
        for kind, centre, size in self.parts().values():
            if kind == "cylinder":
                part = trimesh.creation.cylinder(radius=size[0], height=2 * size[1], sections=self.sections)
            else:
                part = trimesh.creation.box(extents=2 * np.asarray(size))
            part.apply_translation(centre)
            meshes.append(part)
        joined = trimesh.util.concatenate(meshes)
        return np.asarray(joined.vertices, dtype=np.float64), np.asarray(joined.faces, dtype=np.int64)

    def distance(self, points_turntable: np.ndarray, *, disk_radius_m: float | None = None,
                 disk_thickness_m: float = 0.01) -> np.ndarray:
        """Exact signed distance of points to the target's surface (negative inside), metres.

        Args:
          points_turntable: (n, 3) float64, metres, turntable frame.
          disk_radius_m: also the turntable disk (top at z = 0) when given.
        """
        p = np.asarray(points_turntable, dtype=np.float64)
        out = np.full(len(p), np.inf)
        for kind, centre, size in _solids(self, disk_radius_m, disk_thickness_m):
            q = p - centre
            if kind == "cylinder":
                d = np.stack([np.hypot(q[:, 0], q[:, 1]) - size[0], np.abs(q[:, 2]) - size[1]], axis=1)
            else:
                d = np.abs(q) - size
            outside = np.linalg.norm(np.maximum(d, 0.0), axis=1)
            out = np.minimum(out, outside + np.minimum(d.max(axis=1), 0.0))
        return out


CALIBRATION_TARGET = CalibrationTarget()


def target_stl_bytes(target: CalibrationTarget = CALIBRATION_TARGET) -> bytes:
    """The target's mesh as a binary STL (80-byte header, float32 normals and vertices), byte-stable."""
    vertices, faces = target.mesh()
    tri = vertices[faces].astype(np.float32)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    records = np.zeros(len(faces), dtype=[("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
    records["normal"], records["vertices"] = normal, tri
    header = b"plantsim calibration target (see plantsim/plant/target.py), metres, Z up".ljust(80, b" ")
    return header + np.uint32(len(faces)).tobytes() + records.tobytes()


def _ray_cylinder(o: np.ndarray, d: np.ndarray, centre, radius: float, half: float) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays with a capped vertical cylinder: distance (inf: miss) and face (0 side, 1 bottom, 2 top)."""
    q = o - centre
    best = np.full(len(o), np.inf)
    face = np.full(len(o), -1, dtype=np.int64)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (q[:, 0] * d[:, 0] + q[:, 1] * d[:, 1])
    c = q[:, 0] ** 2 + q[:, 1] ** 2 - radius ** 2
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        root = np.sqrt(np.where(disc >= 0, disc, np.nan))
        for t in ((-b - root) / (2 * a), (-b + root) / (2 * a)):
            z = q[:, 2] + t * d[:, 2]
            ok = (t > 0) & (np.abs(z) <= half) & (t < best)
            best, face = np.where(ok, t, best), np.where(ok, 0, face)
        for k, cap in ((1, -half), (2, half)):
            t = (cap - q[:, 2]) / d[:, 2]
            x, y = q[:, 0] + t * d[:, 0], q[:, 1] + t * d[:, 1]
            ok = (t > 0) & (x * x + y * y <= radius ** 2) & (t < best)
            best, face = np.where(ok, t, best), np.where(ok, k, face)
    return best, face


def _ray_box(o: np.ndarray, d: np.ndarray, centre, half) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays with an axis-aligned box (slab method): distance (inf: miss) and face.

    The face is 2 * axis + (1 if the ray enters through the + side): 0..5.
    """
    q = o - centre
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-np.asarray(half) - q) / d
        t2 = (np.asarray(half) - q) / d
    entry = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
    near = entry.max(axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (far >= near) & (near > 0)
    axis = entry.argmax(axis=1)
    plus = t2[np.arange(len(o)), axis] < t1[np.arange(len(o)), axis]
    return np.where(hit, near, np.inf), np.where(hit, 2 * axis + plus, -1)


def _solids(target: CalibrationTarget, disk_radius_m: float | None, disk_thickness_m: float) -> list:
    solids = list(target.parts().values())
    if disk_radius_m is not None:
        solids.append(("cylinder", np.array([0.0, 0.0, -disk_thickness_m / 2]), (disk_radius_m, disk_thickness_m / 2)))
    return solids


def ray_hit(target: CalibrationTarget, origins: np.ndarray, dirs: np.ndarray, *,
            disk_radius_m: float | None = None, disk_thickness_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """The first surface of the target (and the disk) along each ray.

    Args:
      origins, dirs: (n, 3) float64, turntable frame; ``dirs`` unit vectors.
      disk_radius_m: also the turntable disk (top at z = 0) when given.

    Returns:
      distance: (n,) float64 metres along the ray, inf for a miss.
      surface: (n,) int64, which flat face or curved side was hit (8 * part index
        + face, parts in :meth:`CalibrationTarget.parts` order, the disk last), -1
        for a miss. Two rays with the same surface hit one smooth surface.
    """
    origins = np.asarray(origins, dtype=np.float64)
    dirs = np.asarray(dirs, dtype=np.float64)
    best = np.full(len(origins), np.inf)
    surface = np.full(len(origins), -1, dtype=np.int64)
    for index, (kind, centre, size) in enumerate(_solids(target, disk_radius_m, disk_thickness_m)):
        t, face = (_ray_cylinder(origins, dirs, centre, *size) if kind == "cylinder"
                   else _ray_box(origins, dirs, centre, size))
        nearer = t < best
        best, surface = np.where(nearer, t, best), np.where(nearer, 8 * index + face, surface)
    return best, surface


def ray_distance(target: CalibrationTarget, origins: np.ndarray, dirs: np.ndarray, *,
                 disk_radius_m: float | None = None, disk_thickness_m: float = 0.01) -> np.ndarray:
    """Distance along each ray to the first surface of the target (and the disk), inf for a miss.

    Args:
      origins, dirs: (n, 3) float64, turntable frame; ``dirs`` unit vectors.
    """
    return ray_hit(target, origins, dirs, disk_radius_m=disk_radius_m, disk_thickness_m=disk_thickness_m)[0]


def surface_normals(target: CalibrationTarget, points: np.ndarray, surface: np.ndarray, *,
                    disk_radius_m: float | None = None, disk_thickness_m: float = 0.01) -> np.ndarray:
    """Outward unit normals at points on the surfaces :func:`ray_hit` named.

    Args:
      points: (n, 3) float64, metres, turntable frame, on the surfaces.
      surface: (n,) int64 from :func:`ray_hit` (-1: a miss, normal NaN).

    Returns:
      (n, 3) float64 unit vectors.
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.full((len(points), 3), np.nan)
    for index, (kind, centre, _size) in enumerate(_solids(target, disk_radius_m, disk_thickness_m)):
        for face in range(6):
            at = surface == 8 * index + face
            if not at.any():
                continue
            if kind == "box":
                n = np.zeros(3)
                n[face // 2] = 1.0 if face % 2 else -1.0
                normals[at] = n
            elif face == 0:
                radial = points[at, :2] - centre[:2]
                normals[at] = np.column_stack([radial / np.linalg.norm(radial, axis=1, keepdims=True),
                                               np.zeros(int(at.sum()))])
            else:
                normals[at] = [0.0, 0.0, -1.0 if face == 1 else 1.0]
    return normals
