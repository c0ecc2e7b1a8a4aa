"""Ray casting for the simulated LiDAR: one interface for every scan.

Only the turntable's body and what it carries (the disk, the plant) turn. So a
ray cast at turntable angle theta is the same ray turned by ``Rz(-theta)`` into
the turntable frame and cast against the turning geoms with the hinge at 0;
everything else (bench, servo housing, post, any static world geom) never
moves, so each ray of the sensor is cast against it once, up front. The nearer of the two hits is the beam's first hit.
This one rule serves a step scan (one angle per line), a continuous scan (one
angle per beam) and every footprint sub-ray alike.

A :class:`Caster` holds the sensor's rays (the "ray table", base frame, fixed by
the rig geometry and the sensor) and casts any selection of them at any
turntable angles. The casting itself is a backend: :class:`MujocoBackend`
(``mujoco.batch``, the reference) or, when installed, Embree
(:mod:`plantsim.sensor.embree`). MuJoCo is imported only by the backend that
uses it: a kinematic scan cast with Embree never loads it.
"""

from __future__ import annotations

import copy
import logging
import os
import time
from typing import Callable, NamedTuple, Protocol

import numpy as np

from plantsim.rig.layout import N_GROUPS
from plantsim.rig.scene import Scene
from plantsim.sensor.spec import BeamStatus, LidarSpec

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]

# MuJoCo's mesh BVH can cull a ray that lies exactly in a plane holding mesh
# vertices (../shared/notes/mujoco-raycasting.md): a scan plane through the
# turntable axis is that case at every angle where the plant has a vertex row.
# Moving every origin this far off the scan plane, along its normal, removes
# it; the reconstruction error it adds is at most this distance.
AXIS_TRAP_OFFSET_M = 1e-9


def _groups(*groups: int) -> np.ndarray:
    return np.array([1 if g in groups else 0 for g in range(N_GROUPS)], dtype=np.uint8)


CAST_GEOMGROUP = _groups(0, 1, 2)  # rig, turntable, plant; group 3 (the sensor's housing) is never cast
_HIDDEN_GROUP = 5  # where a backend's private model copy parks the geoms one cast must not see


def turning_geoms(scene: Scene) -> np.ndarray:
    """(ngeom,) bool: the geoms that turn with the table (on the turntable body or its descendants)."""
    if scene.layout is not None:
        return scene.layout.turning
    model = scene.model
    table = model.body("turntable").id
    turning_body = np.zeros(model.nbody, dtype=bool)
    for body in range(model.nbody):
        b = body
        while b > 0 and b != table:
            b = model.body_parentid[b]
        turning_body[body] = b == table
    return turning_body[model.geom_bodyid]


def gate_ranges(dist_m: np.ndarray, lidar: LidarSpec) -> tuple[np.ndarray, np.ndarray]:
    """Applies the sensor's range limits to first-hit distances.

    Args:
      dist_m: (...) float64 metres, first-hit distance, -1 for a miss.
      lidar: the sensor.

    Returns:
      range_m (...) float64 with NaN where there is no return, status (...) uint8.
    """
    status = np.full(dist_m.shape, BeamStatus.OK, dtype=np.uint8)
    status[(dist_m < 0) | (dist_m > lidar.range_max_m)] = BeamStatus.NO_ECHO
    status[(dist_m >= 0) & (dist_m < lidar.range_min_m)] = BeamStatus.TOO_NEAR
    range_m = np.where(status == BeamStatus.OK, dist_m, np.nan)
    return range_m, status


class Hits(NamedTuple):
    """First hits of rays.

    dist_m (...) float64 (-1: miss); geom_id (...) int32 (-1: miss); normal_base
    (..., 3) float64 unit surface normals in the base frame (zero for a miss), or None.
    """

    dist_m: np.ndarray
    geom_id: np.ndarray
    normal_base: np.ndarray | None


class Backend(Protocol):
    """What a ray-casting backend does (MuJoCo's is the reference).

    A backend that casts the turning primitives apart from the turning meshes may
    also have ``primitive_bounds`` (a :func:`turning_bounds` cylinder holding those
    primitives) and accept ``cast_turning(..., reach_primitives=mask)``: the
    :class:`Caster` then passes which rays may reach that cylinder (known per ray
    of its table, since the cylinder is about the axis), and the backend casts
    the primitives for those alone. A backend whose ``cast_invariant`` gives the
    hits of the turning geoms that are solids of revolution about the axis (the
    same at every angle; ``invariant_geoms`` says which) has them cast once per ray
    of the table; it then takes ``cast_turning(..., skip_invariant=True)`` and its
    ``variant_primitive_bounds`` holds the other turning primitives.
    """

    name: str

    def cast_turning(self, origins: np.ndarray, dirs: np.ndarray, *, normals: bool = False) -> Hits:
        """Casts (N, 3) rays, turntable frame, against the turning geoms with the hinge at 0."""

    def cast_fixed(self, origins: np.ndarray, dirs: np.ndarray, *, normals: bool = False) -> Hits:
        """Casts (N, 3) rays, base frame, against the fixed rig."""


class MujocoBackend:
    """``mujoco.batch`` on copies of the scene with the hinge at 0; releases the GIL.

    The rays of a call are spread over ``nsim`` simulations so that the batch's
    ``nthread`` threads share them.
    """

    name = "mujoco"

    def __init__(self, scene: Scene, *, nthread: int | None = None, rays_per_sim: int = 8192):
        import mujoco.batch

        self.scene = scene
        self.nthread = nthread or max(1, os.cpu_count() or 1)
        self.nsim = 2 * self.nthread
        self.rays_per_sim = rays_per_sim
        turning = turning_geoms(scene)
        self._batches = {}
        for name, hide in (("turning", ~turning), ("fixed", turning)):
            model = copy.deepcopy(scene.model)
            model.geom_group[hide] = _HIDDEN_GROUP
            self.replace_model(name, model)
        stat = scene.model.stat
        # Padding rays: from far above the scene going up; they miss every bounding box.
        self._pad_origin = np.asarray(stat.center) + (0.0, 0.0, 10.0 * max(stat.extent, 1.0))

    def replace_model(self, which: str, model: mujoco.MjModel) -> None:
        """Casts ``which`` ("turning" or "fixed") rays against this model copy (geoms to skip in group 5)."""
        import mujoco.batch

        self._batches[which] = mujoco.batch.Batch(model, nsim=self.nsim, nthread=self.nthread)

    def _cast(self, which, origins, dirs, normals) -> Hits:
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        n = len(origins)
        dist = np.empty(n)
        geom = np.empty(n, dtype=np.int32)
        normal = np.empty((n, 3)) if normals else None
        per_call = self.nsim * self.rays_per_sim
        for lo in range(0, n, per_call):
            hi = min(lo + per_call, n)
            count = hi - lo
            nsim = min(self.nsim, count)
            per = -(-count // nsim)
            pnt = np.empty((nsim * per, 3))
            vec = np.empty((nsim * per, 3))
            pnt[:count], vec[:count] = origins[lo:hi], dirs[lo:hi]
            pnt[count:], vec[count:] = self._pad_origin, (0.0, 0.0, 1.0)
            out = self._batches[which].ray(pnt.reshape(nsim, per, 3), vec.reshape(nsim, per, 3),
                                  geomgroup=CAST_GEOMGROUP, flg_static=True,
                                  bodyexclude=self.scene.lidar_body_id, ids=np.arange(nsim),
                                  normal=normals)
            dist[lo:hi] = out[0].reshape(-1)[:count]
            geom[lo:hi] = out[1].reshape(-1)[:count]
            if normals:
                normal[lo:hi] = out[2].reshape(-1, 3)[:count]
        return Hits(dist, geom, normal)

    def cast_turning(self, origins, dirs, *, normals=False) -> Hits:
        return self._cast("turning", origins, dirs, normals)

    def cast_fixed(self, origins, dirs, *, normals=False) -> Hits:
        return self._cast("fixed", origins, dirs, normals)


BACKENDS = ("mujoco", "embree", "auto")


def make_backend(scene: Scene, name: str = "mujoco", *, nthread: int | None = None) -> Backend:
    """A backend by name: "mujoco", "embree" (needs ``embreex``), or "auto" (Embree if installed).

    Raises:
      ValueError: an unknown name, or "embree" without ``embreex`` installed.
    """
    if name not in BACKENDS:
        raise ValueError(f"ray caster must be one of {', '.join(BACKENDS)}, got {name!r}")
    if name in ("embree", "auto"):
        try:
            from plantsim.sensor.embree import EmbreeBackend, embree_available
        except ImportError:
            available = False
        else:
            available = embree_available()
        if available:
            return EmbreeBackend(scene, nthread=nthread)
        if name == "embree":
            raise ValueError("caster = \"embree\" needs the embreex package: pip install "
                             "'plantsim[fast]', or use caster = \"mujoco\"")
    return MujocoBackend(scene, nthread=nthread)


def take_rows(table: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``table[index]`` for a (n, ...) table and an int index of any shape (the same values).

    ``np.take`` along axis 0 gathers rows of a small last axis (points, normals) about
    3x faster than fancy indexing.
    """
    return np.take(table, index, axis=0)


def put_rows(table: np.ndarray, index: np.ndarray, rows: np.ndarray) -> None:
    """``table[index] = rows`` for a C-contiguous (n, 3) float64 table (the same values).

    The rows are scattered as 24-byte records, about twice as fast as fancy assignment.
    """
    rows = np.ascontiguousarray(rows, dtype=np.float64)
    if table.dtype != np.float64 or table.ndim != 2 or table.shape[1] != 3 or not table.flags.c_contiguous:
        table[index] = rows
        return
    record = np.dtype((np.void, 24))
    table.view(record).reshape(-1)[index] = rows.reshape(-1, 3).view(record).reshape(-1)


def rotate_z(vectors: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rotates (..., 3) vectors about +Z by (...) angles (right hand)."""
    return _turn(vectors, np.cos(angle_rad), np.sin(angle_rad))


def _turn(vectors: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Rotates (..., 3) vectors about +Z given the angles' cosines and sines (broadcast)."""
    out = np.empty(vectors.shape)
    x, y = vectors[..., 0], vectors[..., 1]
    out[..., 0] = c * x - s * y
    out[..., 1] = s * x + c * y
    out[..., 2] = vectors[..., 2]
    return out


def turning_bounds(scene: Scene, *, margin_m: float = 1e-6, geoms: np.ndarray | None = None
                   ) -> tuple[float, float, float]:
    """A cylinder about the turntable axis holding every turning geom at every angle.

    The table turns about the base frame's Z axis (the hinge at 0 puts the
    turntable frame on the base frame), so a cylinder about that axis holds the
    turning geoms at every angle if it holds them at one: a ray that misses it
    misses them at any turntable angle. Mesh geoms are bounded by their
    vertices, other geoms by the tighter of two coaxial cylinders that both hold
    them (their intersection holds them too): the one about their bounding sphere
    (``geom_rbound``) and the one about the corners of their bounding box
    (``geom_aabb``), so a thin disk gets its thickness, not its diameter, in Z.

    Args:
      scene: the compiled scene.
      margin_m: added to the radius and both ends.
      geoms: (ngeom,) bool, the turning geoms to bound (default: all of them).

    Returns:
      (radius_m, z_min_m, z_max_m), base frame; (0, 0, -1) (an empty cylinder)
      when nothing that a ray may hit turns.
    """
    if scene.layout is not None:
        return _axis_cylinder(_layout_parts(scene, geoms), margin_m)
    import mujoco

    model = scene.model
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    cast = np.isin(model.geom_group, np.nonzero(CAST_GEOMGROUP)[0])
    chosen = turning_geoms(scene) if geoms is None else (np.asarray(geoms, dtype=bool) & turning_geoms(scene))
    parts = []
    for g in np.nonzero(chosen & cast)[0]:
        pos, rot = data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3)
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and model.geom_dataid[g] >= 0:
            mesh = model.geom_dataid[g]
            v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            parts.append(("vertices", model.mesh_vert[v0:v0 + nv].astype(np.float64) @ rot.T + pos))
        else:
            box = model.geom_aabb[g]
            parts.append(("primitive", pos, float(model.geom_rbound[g]), box[:3], box[3:], rot))
    return _axis_cylinder(parts, margin_m)


def _layout_parts(scene: Scene, geoms: np.ndarray | None) -> list:
    """The parts of :func:`_axis_cylinder` from the scene's layout (no MuJoCo).

    The plant is given by its own float64 vertices (MuJoCo's model holds them as
    float32; the same relative pad covers both).
    """
    from plantsim.sensor.primitives import bounding_radius, local_half_extents

    layout = scene.layout
    cast = np.isin(layout.group, np.nonzero(CAST_GEOMGROUP)[0])
    chosen = layout.turning if geoms is None else (np.asarray(geoms, dtype=bool) & layout.turning)
    parts = []
    for g in np.nonzero(chosen & cast)[0]:
        geom = layout.geoms[g]
        if geom.type == "mesh":
            parts.append(("vertices", scene.plant.vertices_turntable if scene.plant is not None
                          and geom.name == "plant" else None))
        else:
            parts.append(("primitive", geom.pos_base, bounding_radius(geom), np.zeros(3), local_half_extents(geom),
                          geom.R_base_geom))
    return parts


_CORNER_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def _axis_cylinder(parts: list, margin_m: float) -> tuple[float, float, float]:
    """The cylinder about the Z axis holding every part (see :func:`turning_bounds`).

    Args:
      parts: ``("vertices", (n, 3) base frame or None for unknown)`` or
        ``("primitive", pos (3,), bounding radius, box centre (3,) and half sizes (3,)
        in the geom's frame, R (3, 3) the geom's axes)``.
    """
    radius, z_min, z_max = 0.0, np.inf, -np.inf
    for part in parts:
        if part[0] == "vertices":
            v = part[1]
            if v is None:
                return np.inf, -np.inf, np.inf
            # float32 vertices: pad by their rounding as well.
            pad = 1e-6 * float(np.abs(v).max(initial=0.0))
            radius = max(radius, float(np.hypot(v[:, 0], v[:, 1]).max(initial=0.0)) + pad)
            z_min, z_max = min(z_min, float(v[:, 2].min()) - pad), max(z_max, float(v[:, 2].max()) + pad)
            continue
        _, pos, rb, centre, half, rot = part
        if not (rb > 0 and np.isfinite(rb)):  # a plane or an unbounded geom: no cylinder holds it
            return np.inf, -np.inf, np.inf
        r, lo, hi = float(np.hypot(pos[0], pos[1])) + rb, pos[2] - rb, pos[2] + rb
        if np.all(np.isfinite(centre)) and np.all(np.isfinite(half)):
            corners = (centre + half * _CORNER_SIGNS) @ rot.T + pos
            pad = 1e-9 * (1.0 + float(np.abs(corners).max()))
            r = min(r, float(np.hypot(corners[:, 0], corners[:, 1]).max()) + pad)
            lo, hi = max(lo, float(corners[:, 2].min()) - pad), min(hi, float(corners[:, 2].max()) + pad)
        radius = max(radius, r)
        z_min, z_max = min(z_min, lo), max(z_max, hi)
    if z_max < z_min:
        return 0.0, 0.0, -1.0
    return radius + margin_m, z_min - margin_m, z_max + margin_m


def rays_may_reach(origins: np.ndarray, dirs: np.ndarray, bounds: tuple[float, float, float],
                   max_dist_m: np.ndarray) -> np.ndarray:
    """Whether each ray enters a Z-axis cylinder before ``max_dist_m`` (conservative).

    Args:
      origins, dirs: (N, 3) float64, base frame (dirs need not be unit).
      bounds: (radius_m, z_min_m, z_max_m) from :func:`turning_bounds`.
      max_dist_m: (N,) float64, the ray's length to consider (inf: unbounded).

    Returns:
      (N,) bool: False only where the ray's segment [0, max_dist_m] surely misses the cylinder.
    """
    radius, z_min, z_max = bounds
    if not np.isfinite(radius):
        return np.ones(len(origins), dtype=bool)
    ox, oy, oz = origins[:, 0], origins[:, 1], origins[:, 2]
    dx, dy, dz = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        # |o_xy + t d_xy|^2 <= R^2: a t^2 + 2 b t + c <= 0.
        a = dx * dx + dy * dy
        b = ox * dx + oy * dy
        c = ox * ox + oy * oy - radius * radius
        disc = b * b - a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        t0 = np.where(a > 0, (-b - root) / a, np.where(c <= 0, -np.inf, np.inf))
        t1 = np.where(a > 0, (-b + root) / a, np.where(c <= 0, np.inf, -np.inf))
        t0 = np.where((a > 0) & (disc < 0), np.inf, t0)
        # z_min <= o_z + t d_z <= z_max.
        za, zb = (z_min - oz) / dz, (z_max - oz) / dz
        inside_z = (oz >= z_min) & (oz <= z_max)
        s0 = np.where(dz != 0, np.minimum(za, zb), np.where(inside_z, -np.inf, np.inf))
        s1 = np.where(dz != 0, np.maximum(za, zb), np.where(inside_z, np.inf, -np.inf))
    enter = np.maximum(np.maximum(t0, s0), 0.0)
    leave = np.minimum(t1, s1)
    # A relative slack on the entry so rounding can only keep a ray, never drop one.
    return (enter <= leave) & (enter <= max_dist_m * (1 + 1e-9) + 1e-9)


class Caster:
    """Casts a sensor's rays at given turntable angles.

    Args:
      scene: the compiled scan scene.
      origins_base: (n_rays, 3) float64, metres, base frame: the ray table.
      dirs_base: (n_rays, 3) float64 unit vectors, base frame.
      backend: a :class:`Backend` (default: MuJoCo's).
      nthread: threads of the default backend.

    Attributes:
      pad_id: a ray id that casts nothing (a miss), for padding ragged selections.
      n_rays_cast: turning rays cast so far (padding excluded), including those
        resolved by the bounding cylinder alone (``n_rays_culled``).
      n_rays_culled: rays of ``n_rays_cast`` that could not reach the turning geoms
        (they miss the cylinder about the axis that holds them, or hit the rig, or a
        turning solid of revolution cast once, first) and so never reached the backend.
      n_rays_fixed: rays cast once against the fixed rig (the whole ray table).
      cast_fixed_s, cast_turning_s: wall time inside the backend, s.
    """

    def __init__(self, scene: Scene, origins_base: np.ndarray, dirs_base: np.ndarray, *,
                 backend: Backend | None = None, nthread: int | None = None):
        self.scene = scene
        self.backend = backend or MujocoBackend(scene, nthread=nthread)
        n = len(origins_base)
        self.pad_id = n
        # The ray table with the padding ray appended (row n), cast from contiguous float64 rows.
        self._origins = np.zeros((n + 1, 3))
        self._dirs = np.zeros((n + 1, 3))
        self._origins[:n] = np.asarray(origins_base, dtype=np.float64).reshape(n, 3)
        self._dirs[:n] = np.asarray(dirs_base, dtype=np.float64).reshape(n, 3)
        self._dirs[n] = (0.0, 0.0, 1.0)
        self.origins_base = self._origins[:n]
        self.dirs_base = self._dirs[:n]
        t = time.perf_counter()
        fixed = self.backend.cast_fixed(self.origins_base, self.dirs_base, normals=True)
        self.cast_fixed_s = time.perf_counter() - t
        self.n_rays_fixed = n
        self.cast_turning_s = 0.0
        # Turning geoms that are solids of revolution about the axis (the disk) give the same
        # hit at every angle: a backend that casts them apart casts each ray once here, and
        # their hits join the rig's (a ray stopped by the disk is then never cast again).
        invariant = getattr(self.backend, "cast_invariant", None)
        inv = invariant(self.origins_base, self.dirs_base, normals=True) if invariant is not None else None
        self._skip_invariant = inv is not None
        turning_mask = None
        if inv is not None:
            nearer = (inv.dist_m >= 0) & ((fixed.dist_m < 0) | (inv.dist_m < fixed.dist_m))
            fixed = Hits(np.where(nearer, inv.dist_m, fixed.dist_m), np.where(nearer, inv.geom_id, fixed.geom_id),
                         np.where(nearer[:, None], inv.normal_base, fixed.normal_base))
            turning_mask = ~self.backend.invariant_geoms
        self._fixed_dist = np.append(fixed.dist_m, -1.0)
        self._fixed_geom = np.append(fixed.geom_id, -1).astype(np.int32)
        self._fixed_normal = np.vstack([fixed.normal_base, np.zeros((1, 3))])
        # Rays that cannot reach the turning geoms at any angle (they miss the cylinder about
        # the axis that holds them, or the rig stops them first) are never cast: their hit
        # is the rig's, exactly as if they had been cast and missed.
        reach = rays_may_reach(self.origins_base, self.dirs_base, turning_bounds(scene, geoms=turning_mask),
                               np.where(fixed.dist_m >= 0, fixed.dist_m, np.inf))
        self._may_hit = np.append(reach, False)
        # A backend that casts the turning primitives apart from the meshes (Embree) casts
        # them only for the rays that may reach them (a bounding cylinder, rotation-invariant).
        self._may_hit_primitives = None
        bounds = getattr(self.backend, "variant_primitive_bounds" if self._skip_invariant else "primitive_bounds",
                         None)
        if bounds is not None:
            near = rays_may_reach(self.origins_base, self.dirs_base, bounds,
                                  np.where(fixed.dist_m >= 0, fixed.dist_m, np.inf))
            self._may_hit_primitives = np.append(near, False)
        self.n_rays_cast = 0
        self.n_rays_culled = 0
        self._pool = None  # made on the first parallel cast

    def _tally(self, n_selected: int, n_chosen: int, backend_s: float) -> None:
        self.n_rays_cast += n_selected
        self.n_rays_culled += n_selected - n_chosen
        self.cast_turning_s += backend_s

    def _chunk_pool(self):
        """Threads that cast whole chunks side by side, for a backend that says its
        ``cast_turning`` may run on several threads at once (``concurrent_calls``) and
        takes ``split=False`` (cast on the calling thread); None otherwise."""
        nthread = int(getattr(self.backend, "nthread", 1) or 1)
        if not getattr(self.backend, "concurrent_calls", False) or nthread < 2:
            return None
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(nthread, thread_name_prefix="plantsim-cast")
        return self._pool

    @property
    def reachable_fraction(self) -> float:
        """The share of the ray table that may hit a turning geom (the rest is never cast)."""
        return float(self._may_hit[:-1].mean()) if self.pad_id else 0.0

    def cast(self, ray_ids: np.ndarray, table_rad: np.ndarray, *, normals: bool = False,
             chunk_lines: int = 64, progress: Progress | None = None) -> Hits:
        """First hits of the selected rays, each at its own turntable angle.

        Args:
          ray_ids: (n_lines, k) int, indices into the ray table (``pad_id``: none).
          table_rad: (n_lines,) or (n_lines, k) float64, the true turntable angle
            per line or per ray, radians.
          normals: also return surface normals (base frame).
          chunk_lines: lines per backend call (progress granularity).
          progress: called with (lines done, lines total).

        Returns:
          :class:`Hits` of shape (n_lines, k).
        """
        ids = np.asarray(ray_ids)
        n_lines, k = ids.shape
        theta = np.asarray(table_rad, dtype=np.float64)
        per_line = theta.ndim == 1  # one angle a line: one cos/sin a line, broadcast over its rays
        # The rig's hits first; the turning geoms' hits replace them where nearer.
        dist = self._fixed_dist[ids]
        geom = self._fixed_geom[ids]
        normal = take_rows(self._fixed_normal, ids) if normals else None
        flat_dist, flat_geom = dist.reshape(-1), geom.reshape(-1)
        flat_normal = normal.reshape(-1, 3) if normals else None

        def cast_chunk(lo: int, hi: int, split: bool) -> tuple[int, int, float, float]:
            """Lines lo..hi into the flat arrays (disjoint rows a chunk); returns
            (rays selected, rays cast, backend s, chunk s)."""
            t_chunk = time.perf_counter()
            sel = ids[lo:hi].reshape(-1)
            at = np.flatnonzero(self._may_hit[sel])  # flat positions in this chunk that are cast
            chosen = sel[at]
            if per_line:  # one cosine and sine a line, spread over its rays
                line = at // k
                c, s = np.cos(theta[lo:hi])[line], np.sin(theta[lo:hi])[line]
            else:
                th = theta[lo:hi].reshape(-1)[at]
                c, s = np.cos(th), np.sin(th)
            o = _turn(take_rows(self._origins, chosen), c, -s)
            d = _turn(take_rows(self._dirs, chosen), c, -s)
            options = {} if split else {"split": False}
            if self._skip_invariant:
                options["skip_invariant"] = True
            if self._may_hit_primitives is not None:
                options["reach_primitives"] = self._may_hit_primitives[chosen]
            t = time.perf_counter()
            hits = self.backend.cast_turning(o, d, normals=normals, **options)
            backend_s = time.perf_counter() - t
            dt = hits.dist_m
            df = self._fixed_dist[chosen]
            nearer = np.flatnonzero((dt >= 0) & ((df < 0) | (dt <= df)))
            where = lo * k + at[nearer]
            flat_dist[where] = dt[nearer]
            flat_geom[where] = hits.geom_id[nearer]
            if normals:
                # Back from the turntable frame to the base frame.
                put_rows(flat_normal, where, _turn(take_rows(hits.normal_base, nearer), c[nearer], s[nearer]))
            n_selected = sel.size - int(np.count_nonzero(sel == self.pad_id))
            return n_selected, len(chosen), backend_s, time.perf_counter() - t_chunk

        chunks = [(lo, min(lo + chunk_lines, n_lines)) for lo in range(0, n_lines, chunk_lines)]
        pool = self._chunk_pool() if len(chunks) > 1 else None
        if pool is None:
            for lo, hi in chunks:
                n_selected, n_chosen, backend_s, _ = cast_chunk(lo, hi, True)
                self._tally(n_selected, n_chosen, backend_s)
                if progress is not None:
                    progress(hi, n_lines)
        else:
            # Whole chunks side by side, each casting on its own thread: the turning of the
            # rays and the merging (numpy, which releases the GIL) overlap Embree's traversal
            # instead of waiting for it. The backend's share of the section's wall time is
            # counted as its cast time (the chunks' own times overlap).
            t = time.perf_counter()
            futures = [pool.submit(cast_chunk, lo, hi, False) for lo, hi in chunks]
            backend_total = chunk_total = 0.0
            try:
                for (_, hi), future in zip(chunks, futures):
                    n_selected, n_chosen, backend_s, chunk_s = future.result()
                    self._tally(n_selected, n_chosen, 0.0)
                    backend_total, chunk_total = backend_total + backend_s, chunk_total + chunk_s
                    if progress is not None:
                        progress(hi, n_lines)
            finally:
                for future in futures:
                    future.cancel()
            if chunk_total > 0:
                self.cast_turning_s += (time.perf_counter() - t) * backend_total / chunk_total
        return Hits(dist, geom, normal)
