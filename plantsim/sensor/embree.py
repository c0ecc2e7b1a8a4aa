"""An Embree ray-casting backend (``embreex``): the plant's triangles an order of magnitude faster.

Embree traverses the turning mesh geoms (the plant) in float32; every hit's
distance is then recomputed in float64 on the plane of the triangle Embree found
(a plane per triangle, computed once). MuJoCo is the reference: the tests cast
the same rays with both and compare hit for hit.

Two ways to get the scene, one result:

- A scene with a layout (:mod:`plantsim.rig.layout`; every scene
  :func:`plantsim.rig.scene.build_scene` makes for a kinematic scan): the
  plant's triangles come from the plant itself, float64, and the rig's
  primitives (bench, housing, post, disk) are cast analytically by
  :mod:`plantsim.sensor.primitives`, following MuJoCo's rules. MuJoCo is neither
  imported nor compiled. MuJoCo's model stores mesh vertices as float32, so
  distances on the plant differ from MuJoCo's by that rounding (a few 1e-8 m
  at 0.5 m); the planes here are the mesh's exact ones.
- Any other scene (a dynamic scan's, or one compiled from a spec of its own):
  the triangles come from MuJoCo's compiled model (its float32 vertices, placed
  by the geom poses), so that distances and normals are MuJoCo's to rounding
  (within 2e-14 m over 245,880 beams on the bundled maize), and MuJoCo casts the
  primitives: on the same rig rebuilt without the plant when that has exactly the
  scene's other geoms, else on copies of the scene's model with the meshes hidden.

Threads: Embree's traversal releases the GIL, so the rays of a call are split
into ``nthread`` contiguous blocks cast on a thread pool (each ray's hit does not
depend on the split: the same hits on any number of threads), while MuJoCo casts
the turning primitives in the calling thread at the same time.

Precision: Embree decides hit or miss and which triangle in float32 (relative
precision ~1.2e-7, i.e. ~1e-7 m over the 0.8 m scene). Only a ray grazing a
triangle's edge or a silhouette within about that distance may pick a
neighbouring triangle (the same geom, a distance differing by the neighbour's
slope times ~1e-7 m) or flip between hit and miss; none did on the maize or on
the tests' analytic shapes. ``scripts/bench_casters.py`` counts such rays and
prints rays/s of both backends.
"""

from __future__ import annotations

import copy
import gc
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from plantsim.errors import PlantSimError
from plantsim.rig.scene import Scene, build_scene
from plantsim.sensor.casting import (_HIDDEN_GROUP, CAST_GEOMGROUP, Hits, MujocoBackend, put_rows, take_rows,
                                     turning_bounds, turning_geoms)
from plantsim.sensor.primitives import cast_geoms


def embree_available() -> bool:
    """Whether ``embreex`` can be imported."""
    try:
        import embreex.rtcore_scene  # noqa: F401
    except ImportError:
        return False
    return True


def embreex_mesh_input(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Arguments for ``embreex``'s ``TriangleMesh`` that it copies ~10x faster than float/int arrays.

    embreex copies its input into Embree's buffers element by element through Python
    indexing: ``vertices[i, k]`` and ``faces[i][k]``. On numeric arrays each access
    makes a numpy scalar, and each ``faces[i]`` a row view (6.8 s for a 1 M-face mesh on
    a loaded machine). Handed an object array of Python floats (the float32 values,
    exactly) and a 1-D object array of index tuples, the same loop reads existing
    Python objects: 0.64 s, conversion included. Embree receives the same float32
    vertices and the same indices (a test compares hits with the plain form).

    Args:
      vertices: (n, 3) float, metres; rounded to float32 as Embree stores them.
      faces: (m, 3) int vertex indices.
    """
    as_f32 = np.asarray(vertices, dtype=np.float32)
    face_rows = np.empty(len(faces), dtype=object)
    face_rows[:] = list(zip(*np.asarray(faces, dtype=np.int64).T.tolist()))
    return {"vertices": as_f32.astype(np.float64).astype(object), "indices": face_rows}


class EmbreeBackend:
    """Casts the turning mesh geoms with Embree, everything else with MuJoCo (see the module docstring)."""

    name = "embree"
    # Fewer rays than this a thread are cast on one thread (a pool hand-off costs ~50 us).
    MIN_RAYS_PER_THREAD = 4096

    def __init__(self, scene: Scene, *, nthread: int | None = None):
        self.nthread = nthread or max(1, os.cpu_count() or 1)
        self._pool = None  # made on first use: a backend that never casts in parallel starts no threads
        self._embree = None
        self._mujoco = None
        if scene.layout is not None and not scene.model_compiled:
            self._init_from_layout(scene)
        else:
            self._init_from_model(scene)
        # Each triangle's plane, float64, for the refinement of Embree's float32 hits:
        # unit normal n (right hand over the vertex order, as MuJoCo's) and offset n . v0.
        normal = np.cross(self.triangles[:, 1] - self.triangles[:, 0], self.triangles[:, 2] - self.triangles[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        self._plane_normal = normal
        self._plane_offset = np.einsum("ij,ij->i", normal, self.triangles[:, 0])

    def _build_embree(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.triangles = vertices[faces]
        self._embree = rtcore_scene.EmbreeScene()
        # The hand-off makes ~3 Python objects a face (none in a cycle); with the cyclic
        # collector paused it is not walked every 700 of them (~4 ms of 0.35 s at 70k faces).
        collecting = gc.isenabled()
        gc.disable()
        try:
            TriangleMesh(scene=self._embree, **embreex_mesh_input(vertices, faces))
        finally:
            if collecting:
                gc.enable()

    def _init_from_layout(self, scene: Scene) -> None:
        """The plant's own triangles for Embree, the rig's primitives analytic: no MuJoCo."""
        layout = scene.layout
        cast = CAST_GEOMGROUP[np.clip(layout.group, 0, len(CAST_GEOMGROUP) - 1)].astype(bool)
        excluded = np.array([g.body == layout.bodies[scene.lidar_body_id] for g in layout.geoms])
        usable = cast & ~excluded
        is_mesh = np.array([g.type == "mesh" for g in layout.geoms])
        self.detail = ("Embree on the plant's own float64 triangles (float32 traversal, float64 distance); "
                       "the rig's primitives analytic (plantsim.sensor.primitives); no MuJoCo model used to cast")
        self._fixed_prims = [(i, g) for i, g in enumerate(layout.geoms)
                             if usable[i] and not g.turning and not is_mesh[i]]
        self._turning_prims = [(i, g) for i, g in enumerate(layout.geoms)
                               if usable[i] and g.turning and not is_mesh[i]]
        self.invariant_geoms = np.zeros(len(layout.geoms), dtype=bool)
        for i, g in self._turning_prims:
            self.invariant_geoms[i] = is_solid_of_revolution(g)
        self._variant_prims = [(i, g) for i, g in self._turning_prims if not self.invariant_geoms[i]]
        self._invariant_prims = [(i, g) for i, g in self._turning_prims if self.invariant_geoms[i]]
        self._geom_ids = None
        mesh_geoms = np.flatnonzero(usable & is_mesh & layout.turning)
        self.primitive_bounds = turning_bounds(scene, geoms=~is_mesh)
        self.variant_primitive_bounds = turning_bounds(scene, geoms=~is_mesh & ~self.invariant_geoms)
        if len(mesh_geoms) and scene.plant is not None and scene.plant.n_faces:
            self.geom_of_triangle = np.full(scene.plant.n_faces, mesh_geoms[0], dtype=np.int32)
            self._build_embree(scene.plant.vertices_turntable, scene.plant.faces)
        else:
            self.geom_of_triangle = np.zeros(0, np.int32)
            self.triangles = np.zeros((0, 3, 3))

    def _init_from_model(self, scene: Scene) -> None:
        """Triangles from MuJoCo's compiled model; MuJoCo casts the primitives."""
        import mujoco

        self.detail = "Embree on MuJoCo's mesh vertices (float64 distance); MuJoCo on the primitives"
        self._fixed_prims = self._turning_prims = self._variant_prims = self._invariant_prims = None
        self.invariant_geoms = None
        model = scene.model
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)  # the hinge at 0: the turntable frame is the base frame
        turning = turning_geoms(scene)
        is_mesh = model.geom_type == mujoco.mjtGeom.mjGEOM_MESH
        cast_group = np.isin(model.geom_group, (0, 1, 2))
        mesh_geoms = np.nonzero(turning & is_mesh & cast_group)[0]
        vertices, faces, geom_of = [], [], []
        n_vertices = 0
        for g in mesh_geoms:
            mesh = model.geom_dataid[g]
            v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            f0, nf = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
            # MuJoCo stores a mesh re-centred (and re-oriented) in its geom frame: geom_xpos/xmat undo that.
            vertices.append(model.mesh_vert[v0:v0 + nv].astype(np.float64) @ data.geom_xmat[g].reshape(3, 3).T
                            + data.geom_xpos[g])
            faces.append(model.mesh_face[f0:f0 + nf].astype(np.int64) + n_vertices)
            geom_of.append(np.full(nf, g, dtype=np.int32))
            n_vertices += nv
        self.geom_of_triangle = np.concatenate(geom_of) if geom_of else np.zeros(0, np.int32)
        # The cylinder about the axis that holds the turning geoms MuJoCo casts (the disk): a
        # caster that knows which of its rays cannot reach it passes ``reach_primitives``.
        self.primitive_bounds = turning_bounds(scene, geoms=~np.isin(np.arange(model.ngeom), mesh_geoms))
        if len(self.geom_of_triangle):
            self._build_embree(np.concatenate(vertices), np.concatenate(faces))
        else:
            self.triangles = np.zeros((0, 3, 3))
        nthread = self.nthread
        # MuJoCo for the turning primitives and the fixed rig: on the same rig rebuilt without
        # the plant when that gives the very same geoms (copying and batching a model that
        # carries a big mesh costs ~1 us per face, three times over), else on copies of the
        # scene's model with the meshes hidden.
        lite = _without_meshes(scene, mesh_geoms)
        if lite is not None:
            lite_scene, self._geom_ids = lite
            self._mujoco = MujocoBackend(lite_scene, nthread=nthread)
        else:
            self._geom_ids = None
            self._mujoco = MujocoBackend(scene, nthread=nthread)
            primitives_only = copy.deepcopy(model)
            primitives_only.geom_group[~turning | is_mesh] = _HIDDEN_GROUP
            self._mujoco.replace_model("turning", primitives_only)

    def _full_ids(self, hits: Hits) -> Hits:
        if self._geom_ids is None:
            return hits
        geom = np.where(hits.geom_id >= 0, self._geom_ids[np.maximum(hits.geom_id, 0)], -1).astype(np.int32)
        return Hits(hits.dist_m, geom, hits.normal_base)

    def cast_fixed(self, origins, dirs, *, normals=False) -> Hits:
        if self._fixed_prims is not None:
            return Hits(*cast_geoms(self._fixed_prims, origins, dirs, normals=normals))
        return self._full_ids(self._mujoco.cast_fixed(origins, dirs, normals=normals))

    def _run_embree(self, origins32: np.ndarray, dirs32: np.ndarray, split: bool = True):
        """Starts Embree on (N, 3) float32 rays; returns a function giving the (N,) primIDs (-1: miss).

        ``split``: spread the rays over this backend's threads (else cast on the calling one).
        """
        n = len(origins32)
        blocks = min(self.nthread, n // self.MIN_RAYS_PER_THREAD) if split else 1
        if blocks < 2:
            found = self._embree.run(origins32, dirs32)
            return lambda: found
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.nthread, thread_name_prefix="plantsim-embree")
        edges = np.linspace(0, n, blocks + 1).astype(int)
        futures = [self._pool.submit(self._embree.run, origins32[lo:hi], dirs32[lo:hi])
                   for lo, hi in zip(edges[:-1], edges[1:])]
        return lambda: np.concatenate([f.result() for f in futures])

    def cast_invariant(self, origins, dirs, *, normals=False) -> Hits | None:
        """Casts (N, 3) rays, base frame, against the turning geoms that are solids of
        revolution about the turntable axis (the disk: :attr:`invariant_geoms`).

        Their hits do not depend on the table's angle, so a caster casts each ray of
        its table once, merges the hits with the fixed rig's, and passes
        ``cast_turning(..., skip_invariant=True)``. None when this backend casts no
        such geoms apart (MuJoCo casts the primitives).
        """
        if self._invariant_prims is None:
            return None
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        return Hits(*cast_geoms(self._invariant_prims, origins, dirs, normals=normals))

    def _cast_primitives(self, origins, dirs, normals, reach, skip_invariant=False) -> Hits:
        n = len(origins)
        if self._turning_prims is not None:
            prims = self._variant_prims if skip_invariant else self._turning_prims
            if not prims:
                return Hits(np.full(n, -1.0), np.full(n, -1, dtype=np.int32), np.zeros((n, 3)) if normals else None)
            cast = lambda o, d: Hits(*cast_geoms(prims, o, d, normals=normals))  # noqa: E731
        else:
            cast = lambda o, d: self._full_ids(self._mujoco.cast_turning(o, d, normals=normals))  # noqa: E731
        if reach is None:
            return cast(origins, dirs)
        sub = np.flatnonzero(reach)
        dist, geom = np.full(n, -1.0), np.full(n, -1, dtype=np.int32)
        normal = np.zeros((n, 3)) if normals else None
        if len(sub):
            hits = cast(take_rows(origins, sub), take_rows(dirs, sub))
            dist[sub], geom[sub] = hits.dist_m, hits.geom_id
            if normals:
                put_rows(normal, sub, hits.normal_base)
        return Hits(dist, geom, normal)

    @property
    def concurrent_calls(self) -> bool:
        """Whether :meth:`cast_turning` may run on several threads at once: yes when the
        turning primitives are cast analytically (numpy and Embree, no shared MuJoCo data)."""
        return self._turning_prims is not None

    def cast_turning(self, origins, dirs, *, normals=False, reach_primitives=None, split=True,
                     skip_invariant=False) -> Hits:
        """Casts (N, 3) rays, turntable frame, against the turning geoms with the hinge at 0.

        ``reach_primitives``: (N,) bool, False where the ray surely misses the cylinder
        :attr:`primitive_bounds` (:attr:`variant_primitive_bounds` with ``skip_invariant``)
        (MuJoCo then casts only the others); None: cast all.
        ``skip_invariant``: leave out the geoms :meth:`cast_invariant` casts (the caller
        has their hits); only when that returns hits.
        ``split``: spread Embree's rays over the backend's threads (False: cast on the
        calling thread, for a caller that already casts chunks side by side).
        """
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        if skip_invariant and self._invariant_prims is None:
            raise ValueError("skip_invariant: this backend casts no invariant geoms apart (cast_invariant gives None)")
        if self._embree is None or not len(origins):
            return self._cast_primitives(origins, dirs, normals, reach_primitives, skip_invariant)
        embree_result = self._run_embree(origins.astype(np.float32), dirs.astype(np.float32), split)
        # MuJoCo on the turning primitives while Embree's threads traverse the mesh.
        prim = self._cast_primitives(origins, dirs, normals, reach_primitives, skip_invariant)
        found = embree_result()  # primID, -1: miss
        at = np.flatnonzero(found >= 0)
        tri = found[at]
        n_hit = take_rows(self._plane_normal, tri)
        o, d = take_rows(origins, at), take_rows(dirs, at)
        # Float64 distance to the plane of the triangle Embree found (Embree decided the inside test).
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = (self._plane_offset[tri] - (n_hit[:, 0] * o[:, 0] + n_hit[:, 1] * o[:, 1] + n_hit[:, 2] * o[:, 2])) \
                / (n_hit[:, 0] * d[:, 0] + n_hit[:, 1] * d[:, 1] + n_hit[:, 2] * d[:, 2])
        # The mesh's hit replaces the primitives' where it is nearer (only hits are touched).
        prim_d = prim.dist_m[at]
        nearer = np.flatnonzero((dist >= 0) & ((prim_d < 0) | (dist < prim_d)))
        where = at[nearer]
        out_dist, out_geom = prim.dist_m, prim.geom_id
        out_dist[where] = dist[nearer]
        out_geom[where] = self.geom_of_triangle[tri[nearer]]
        out_normal = None
        if normals:
            out_normal = prim.normal_base
            put_rows(out_normal, where, take_rows(n_hit, nearer))
        return Hits(out_dist, out_geom, out_normal)



def is_solid_of_revolution(geom) -> bool:
    """Whether a primitive is a solid of revolution about the turntable axis (base Z).

    Such a geom (a sphere centred on the axis, a cylinder whose own axis is the
    turntable's, like the disk) is the same surface at every table angle: a ray's
    hit on it does not depend on the angle. Exact tests (a placement off the axis
    by any amount, or tilted, is not one): nothing approximate is folded.
    """
    on_axis = geom.pos_base[0] == 0.0 and geom.pos_base[1] == 0.0
    if geom.type == "sphere":
        return bool(on_axis)
    if geom.type == "cylinder":
        axis = geom.R_base_geom[:, 2]
        return bool(on_axis and axis[0] == 0.0 and axis[1] == 0.0 and abs(axis[2]) == 1.0)
    return False


def _without_meshes(scene: Scene, mesh_geoms: np.ndarray) -> tuple[Scene, np.ndarray] | None:
    """The scene's rig rebuilt without a plant, if its geoms are exactly the scene's other geoms.

    Returns:
      (the rebuilt scene, (ngeom_lite,) int32 the scene's geom id of each of its geoms),
      or None when the scene is not the plain rig plus turning meshes (then the caller
      works on copies of the scene's own model).
    """
    import mujoco

    full = scene.model
    try:
        lite = build_scene(scene.rig)
    except PlantSimError:
        return None
    small = lite.model
    kept = np.setdiff1d(np.arange(full.ngeom), mesh_geoms)
    if small.ngeom != len(kept):
        return None
    names_full = [full.geom(int(g)).name for g in kept]
    names_small = [small.geom(g).name for g in range(small.ngeom)]
    if "" in names_small or sorted(names_small) != sorted(names_full) or len(set(names_small)) != len(names_small):
        return None
    ids = np.array([full.geom(name).id for name in names_small], dtype=np.int32)
    data_full, data_small = mujoco.MjData(full), mujoco.MjData(small)
    mujoco.mj_kinematics(full, data_full)
    mujoco.mj_kinematics(small, data_small)
    same = (np.array_equal(full.geom_type[ids], small.geom_type)
            and np.array_equal(full.geom_size[ids], small.geom_size)
            and np.array_equal(full.geom_group[ids], small.geom_group)
            and np.array_equal(data_full.geom_xpos[ids], data_small.geom_xpos)
            and np.array_equal(data_full.geom_xmat[ids], data_small.geom_xmat)
            and np.array_equal(turning_geoms(scene)[ids], turning_geoms(lite))
            and full.body(scene.lidar_body_id).name == small.body(lite.lidar_body_id).name)
    return (lite, ids) if same else None
