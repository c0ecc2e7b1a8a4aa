"""The calibration target: three simple parts a user can build, with an exact distance function.

Set on the turntable disk, centred on the axis (turntable frame: origin on the
axis at the disk top, +Z up, +X towards the LiDAR at turntable angle 0):

=========  ==============================================================================
part       what and where (millimetres)
=========  ==============================================================================
drum       a cylinder of radius 50, height 150, standing on the disk, its axis on the
           turntable axis (a tin can or a length of 100 mm pipe with a flat cap)
post       a cylinder of radius 20, height 150, standing on the drum's top, on the axis
           (a 40 mm dowel): its top is 300 mm above the disk
fin        a flat plate 40 long, 10 thick, 200 tall, standing on the disk against the
           drum at turntable angle 0: x 50..90, y -5..5, z 0..200 (a strip of plywood)
=========  ==============================================================================

Matte, light surfaces (paint or paper) suit a LiDAR best. What each part makes
observable (see :mod:`plantsim.cloud.calibration`): the drum's range fixes the
LiDAR's distance from the axis and, by where the beams graze it, the plane's
offset from the axis (yaw); the disk top and the drum's and post's tops fix the
height, the tilt and the roll; the fin is the only part that is not round, and
fixes the turntable's zero (the encoder's offset).
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class CalibrationTarget:
    """The target's sizes, metres (see the module docstring)."""

    drum_radius_m: float = 0.050
    drum_height_m: float = 0.150
    post_radius_m: float = 0.020
    post_height_m: float = 0.150
    fin_length_m: float = 0.040
    fin_thickness_m: float = 0.010
    fin_height_m: float = 0.200
    sections: int = 256  # facets around a cylinder in the mesh

    def parts(self) -> dict:
        """Each part as (kind, centre (3,), sizes): "cylinder" radius, half height; "box" half extents."""
        d, p = self.drum_radius_m, self.post_radius_m
        return {
            "drum": ("cylinder", np.array([0.0, 0.0, self.drum_height_m / 2]), (d, self.drum_height_m / 2)),
            "post": ("cylinder", np.array([0.0, 0.0, self.drum_height_m + self.post_height_m / 2]),
                     (p, self.post_height_m / 2)),
            "fin": ("box", np.array([d + self.fin_length_m / 2, 0.0, self.fin_height_m / 2]),
                    np.array([self.fin_length_m / 2, self.fin_thickness_m / 2, self.fin_height_m / 2])),
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
        solids = list(self.parts().values())
        if disk_radius_m is not None:
            solids.append(("cylinder", np.array([0.0, 0.0, -disk_thickness_m / 2]),
                           (disk_radius_m, disk_thickness_m / 2)))
        for kind, centre, size in solids:
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


def _ray_cylinder(o: np.ndarray, d: np.ndarray, centre, radius: float, half: float) -> np.ndarray:
    """First hit distance of rays with a capped vertical cylinder (inf: miss)."""
    q = o - centre
    best = np.full(len(o), np.inf)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (q[:, 0] * d[:, 0] + q[:, 1] * d[:, 1])
    c = q[:, 0] ** 2 + q[:, 1] ** 2 - radius ** 2
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        root = np.sqrt(np.where(disc >= 0, disc, np.nan))
        for t in ((-b - root) / (2 * a), (-b + root) / (2 * a)):
            z = q[:, 2] + t * d[:, 2]
            ok = (t > 0) & (np.abs(z) <= half)
            best = np.where(ok & (t < best), t, best)
        for cap in (-half, half):
            t = (cap - q[:, 2]) / d[:, 2]
            x, y = q[:, 0] + t * d[:, 0], q[:, 1] + t * d[:, 1]
            ok = (t > 0) & (x * x + y * y <= radius ** 2)
            best = np.where(ok & (t < best), t, best)
    return best


def _ray_box(o: np.ndarray, d: np.ndarray, centre, half) -> np.ndarray:
    """First hit distance of rays with an axis-aligned box (inf: miss; slab method)."""
    q = o - centre
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-np.asarray(half) - q) / d
        t2 = (np.asarray(half) - q) / d
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((far >= near) & (near > 0), near, np.inf)


def ray_distance(target: CalibrationTarget, origins: np.ndarray, dirs: np.ndarray, *,
                 disk_radius_m: float | None = None, disk_thickness_m: float = 0.01) -> np.ndarray:
    """Distance along each ray to the first surface of the target (and the disk), inf for a miss.

    Args:
      origins, dirs: (n, 3) float64, turntable frame; ``dirs`` unit vectors.
    """
    best = np.full(len(origins), np.inf)
    solids = list(target.parts().values())
    if disk_radius_m is not None:
        solids.append(("cylinder", np.array([0.0, 0.0, -disk_thickness_m / 2]), (disk_radius_m, disk_thickness_m / 2)))
    for kind, centre, size in solids:
        t = (_ray_cylinder(origins, dirs, centre, *size) if kind == "cylinder"
             else _ray_box(origins, dirs, centre, size))
        best = np.minimum(best, t)
    return best
