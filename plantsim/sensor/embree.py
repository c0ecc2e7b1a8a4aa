"""An Embree ray-casting backend (``embreex``): the plant's triangles an order of magnitude faster.

Embree traverses the turning mesh geoms (the plant) in float32; every hit is then
recomputed in float64 on the triangle Embree found (Moller-Trumbore), so that
distances and normals are MuJoCo's to rounding. The turning primitive geoms (the
disk) and the fixed rig stay with MuJoCo, which is exact on primitives and cheap
there. MuJoCo is the reference: the tests cast the same rays with both and
compare hit for hit.

Only where float32 cannot tell (a ray grazing a triangle's edge within about
1e-7 of its size) may the two pick different triangles or disagree about a hit;
``scripts/bench_casters.py`` counts such rays.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from plantsim.rig.scene import Scene
from plantsim.sensor.casting import _HIDDEN_GROUP, Hits, MujocoBackend, turning_geoms


def embree_available() -> bool:
    """Whether ``embreex`` can be imported."""
    try:
        import embreex.rtcore_scene  # noqa: F401
    except ImportError:
        return False
    return True


class EmbreeBackend:
    """Casts the turning mesh geoms with Embree, everything else with MuJoCo (see the module docstring)."""

    name = "embree"

    def __init__(self, scene: Scene, *, nthread: int | None = None):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        model = scene.model
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)  # the hinge at 0: the turntable frame is the base frame
        turning = turning_geoms(scene)
        is_mesh = model.geom_type == mujoco.mjtGeom.mjGEOM_MESH
        cast_group = np.isin(model.geom_group, (0, 1, 2))
        triangles, geom_of = [], []
        for g in np.nonzero(turning & is_mesh & cast_group)[0]:
            mesh = model.geom_dataid[g]
            v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            f0, nf = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
            vertices = model.mesh_vert[v0:v0 + nv].astype(np.float64) @ data.geom_xmat[g].reshape(3, 3).T \
                + data.geom_xpos[g]
            triangles.append(vertices[model.mesh_face[f0:f0 + nf]])
            geom_of.append(np.full(nf, g, dtype=np.int32))
        self.triangles = np.concatenate(triangles) if triangles else np.zeros((0, 3, 3))
        self.geom_of_triangle = np.concatenate(geom_of) if geom_of else np.zeros(0, np.int32)
        self._embree = None
        if len(self.triangles):
            self._embree = rtcore_scene.EmbreeScene()
            TriangleMesh(scene=self._embree, vertices=self.triangles.astype(np.float32))
        # MuJoCo for the turning primitives (with the mesh geoms hidden) and for the fixed rig.
        self._mujoco = MujocoBackend(scene, nthread=nthread)
        primitives_only = copy.deepcopy(model)
        primitives_only.geom_group[~turning | is_mesh] = _HIDDEN_GROUP
        self._mujoco.replace_model("turning", primitives_only)

    def cast_fixed(self, origins, dirs, *, normals=False) -> Hits:
        return self._mujoco.cast_fixed(origins, dirs, normals=normals)

    def cast_turning(self, origins, dirs, *, normals=False) -> Hits:
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        prim = self._mujoco.cast_turning(origins, dirs, normals=normals)
        if self._embree is None or not len(origins):
            return prim
        found = self._embree.run(origins.astype(np.float32), dirs.astype(np.float32), output=1)["primID"]
        hit = found >= 0
        dist = np.full(len(origins), -1.0)
        normal = np.zeros((len(origins), 3))
        if hit.any():
            tri = self.triangles[found[hit]]
            t, n = _refine(origins[hit], dirs[hit], tri)
            dist[hit] = t
            normal[hit] = n
        geom = np.where(hit, self.geom_of_triangle[np.maximum(found, 0)], -1).astype(np.int32)
        mesh_nearer = (dist >= 0) & ((prim.dist_m < 0) | (dist < prim.dist_m))
        out_dist = np.where(mesh_nearer, dist, prim.dist_m)
        out_geom = np.where(mesh_nearer, geom, prim.geom_id)
        out_normal = np.where(mesh_nearer[:, None], normal, prim.normal_base) if normals else None
        return Hits(out_dist, out_geom, out_normal)


def _refine(origins: np.ndarray, dirs: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Float64 ray-triangle distance (Moller-Trumbore, without the inside test: Embree decided it) and
    the unit face normal."""
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    p = np.cross(dirs, e2)
    det = np.einsum("ij,ij->i", e1, p)
    s = origins - tri[:, 0]
    q = np.cross(s, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", e2, q) / det
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return t, n
