"""Rays against primitive geoms (box, cylinder, sphere, plane), vectorised, without MuJoCo.

The rig's parts are a handful of primitives; casting them needs no BVH and no
MuJoCo. Each function follows MuJoCo's own ray-primitive rules, so that its hits
are MuJoCo's to rounding (``tests/test_rig_layout.py`` casts the same rays with
``mujoco.mj_ray``, grazing and inside rays included):

- a ray is a point and a direction, the hit distance is in units of the
  direction's length, and only ``x >= 0`` counts (a ray starting inside a solid
  hits its far side);
- a box is tested face by face (axes whose direction component is above 1e-15),
  a hit on a face counts when it lies within the face's rectangle, edges
  included; a cylinder likewise, caps then side; a sphere and the cylinder's
  side solve ``a x^2 + 2 b x + c = 0`` and see no hit when the discriminant is
  below 1e-15;
- boxes and cylinders are skipped unless the ray meets their bounding sphere;
- a plane is hit from its front (+Z) side only, within its size where the size
  is positive.

The normal returned is the surface's outward normal at the hit, base frame.
"""

from __future__ import annotations

import numpy as np

from plantsim.rig.layout import Geom

_MINVAL = 1e-15  # mjMINVAL


def _quad(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The nearest non-negative root of a x^2 + 2 b x + c = 0, else -1 (MuJoCo's ray_quad)."""
    det = b * b - a * c
    ok = det >= _MINVAL
    with np.errstate(invalid="ignore", divide="ignore"):
        root = np.sqrt(np.where(ok, det, 0.0))
        x0 = (-b - root) / a
        x1 = (-b + root) / a
    return np.where(ok & (x0 >= 0), x0, np.where(ok & (x1 >= 0), x1, -1.0))


def _in_bounding_sphere(pos: np.ndarray, radius_sq: float, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    dif = origins - pos
    a = np.einsum("ij,ij->i", dirs, dirs)
    b = np.einsum("ij,ij->i", dirs, dif)
    c = np.einsum("ij,ij->i", dif, dif) - radius_sq
    return _quad(a, b, c) >= 0


def _box(size, lp, lv):
    n = len(lp)
    x = np.full(n, -1.0)
    normal = np.zeros((n, 3))
    others = ((1, 2), (0, 2), (0, 1))
    for i in range(3):
        usable = np.abs(lv[:, i]) > _MINVAL
        for side in (-1.0, 1.0):
            with np.errstate(invalid="ignore", divide="ignore"):
                sol = (side * size[i] - lp[:, i]) / lv[:, i]
            j, k = others[i]
            p0 = lp[:, j] + sol * lv[:, j]
            p1 = lp[:, k] + sol * lv[:, k]
            hit = usable & (sol >= 0) & (np.abs(p0) <= size[j]) & (np.abs(p1) <= size[k])
            better = hit & ((x < 0) | (sol < x))
            x = np.where(better, sol, x)
            normal[better] = 0.0
            normal[better, i] = side
    return x, normal


def _cylinder(size, lp, lv):
    n = len(lp)
    x = np.full(n, -1.0)
    normal = np.zeros((n, 3))
    r, h = size[0], size[1]
    usable = np.abs(lv[:, 2]) > _MINVAL
    for side in (-1.0, 1.0):
        with np.errstate(invalid="ignore", divide="ignore"):
            sol = (side * h - lp[:, 2]) / lv[:, 2]
        p0 = lp[:, 0] + sol * lv[:, 0]
        p1 = lp[:, 1] + sol * lv[:, 1]
        hit = usable & (sol >= 0) & (p0 * p0 + p1 * p1 <= r * r)
        better = hit & ((x < 0) | (sol < x))
        x = np.where(better, sol, x)
        normal[better] = (0.0, 0.0, side)
    a = lv[:, 0] ** 2 + lv[:, 1] ** 2
    b = lv[:, 0] * lp[:, 0] + lv[:, 1] * lp[:, 1]
    c = lp[:, 0] ** 2 + lp[:, 1] ** 2 - r * r
    sol = _quad(a, b, c)
    better = (sol >= 0) & (np.abs(lp[:, 2] + sol * lv[:, 2]) <= h) & ((x < 0) | (sol < x))
    x = np.where(better, sol, x)
    radial = lp[better, :2] + sol[better, None] * lv[better, :2]
    normal[better] = 0.0
    normal[better, :2] = radial / np.linalg.norm(radial, axis=1, keepdims=True)
    return x, normal


def _sphere(size, lp, lv):
    a = np.einsum("ij,ij->i", lv, lv)
    b = np.einsum("ij,ij->i", lv, lp)
    c = np.einsum("ij,ij->i", lp, lp) - size[0] ** 2
    x = _quad(a, b, c)
    hit = x >= 0
    normal = np.zeros((len(lp), 3))
    point = lp[hit] + x[hit, None] * lv[hit]
    normal[hit] = point / np.linalg.norm(point, axis=1, keepdims=True)
    return x, normal


def _plane(size, lp, lv):
    front = lv[:, 2] <= -_MINVAL
    with np.errstate(invalid="ignore", divide="ignore"):
        sol = -lp[:, 2] / lv[:, 2]
    p0 = lp[:, 0] + sol * lv[:, 0]
    p1 = lp[:, 1] + sol * lv[:, 1]
    inside = ((size[0] <= 0) | (np.abs(p0) <= size[0])) & ((size[1] <= 0) | (np.abs(p1) <= size[1]))
    x = np.where(front & (sol >= 0) & inside, sol, -1.0)
    normal = np.zeros((len(lp), 3))
    normal[x >= 0, 2] = 1.0
    return x, normal


_CAST = {"box": _box, "cylinder": _cylinder, "sphere": _sphere, "plane": _plane}


def _bounding_radius_sq(geom: Geom) -> float:
    """The squared radius of the sphere MuJoCo tests a box or cylinder against (inf for a plane)."""
    s = geom.size
    if geom.type == "box":
        return float(s[0] ** 2 + s[1] ** 2 + s[2] ** 2)
    if geom.type == "cylinder":
        return float(s[0] ** 2 + s[1] ** 2)
    if geom.type == "sphere":
        return float(s[0] ** 2)
    return float("inf")


def bounding_radius(geom: Geom) -> float:
    """MuJoCo's geom_rbound for a primitive (inf for a plane)."""
    return float(np.sqrt(_bounding_radius_sq(geom)))


def local_half_extents(geom: Geom) -> np.ndarray:
    """Half sizes of the geom's box in its own frame (inf for a plane)."""
    s = geom.size
    if geom.type == "box":
        return s.copy()
    if geom.type == "cylinder":
        return np.array([s[0], s[0], s[1]])
    if geom.type == "sphere":
        return np.full(3, s[0])
    return np.full(3, np.inf)


def cast_geom(geom: Geom, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hits of (N, 3) rays (base frame) on one primitive geom.

    Returns:
      dist (N,) float64 (-1: miss, units of the direction's length), normal (N, 3)
      float64 outward unit normals, base frame (zero for a miss).
    """
    if geom.type not in _CAST:
        raise ValueError(f"geom {geom.name!r} of type {geom.type!r} is not a primitive this caster handles")
    n = len(origins)
    dist = np.full(n, -1.0)
    normal = np.zeros((n, 3))
    if geom.type in ("box", "cylinder"):
        rows = np.flatnonzero(_in_bounding_sphere(geom.pos_base, _bounding_radius_sq(geom), origins, dirs))
    else:
        rows = np.arange(n)
    if not len(rows):
        return dist, normal
    R = geom.R_base_geom
    lp = (origins[rows] - geom.pos_base) @ R
    lv = dirs[rows] @ R
    with np.errstate(invalid="ignore", divide="ignore"):  # axes a ray runs parallel to give inf/NaN: unused
        x, local_normal = _CAST[geom.type](geom.size, lp, lv)
    dist[rows] = x
    normal[rows] = local_normal @ R.T
    return dist, normal


def cast_geoms(geoms: list[tuple[int, Geom]], origins: np.ndarray, dirs: np.ndarray, *,
               normals: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """First hits of (N, 3) rays on several primitives: (dist, geom id, normal or None).

    ``geoms``: (geom id, geom) pairs; ties go to the lower id, as MuJoCo's loop over geoms does.
    """
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    n = len(origins)
    best = np.full(n, -1.0)
    geom_id = np.full(n, -1, dtype=np.int32)
    normal = np.zeros((n, 3)) if normals else None
    for gid, geom in sorted(geoms, key=lambda item: item[0]):
        d, nrm = cast_geom(geom, origins, dirs)
        better = (d >= 0) & ((best < 0) | (d < best))
        best = np.where(better, d, best)
        geom_id[better] = gid
        if normals:
            normal[better] = nrm[better]
    return best, geom_id, normal
