"""An Embree ray-casting backend (``embreex``): the plant's triangles an order of magnitude faster.

Embree traverses the turning mesh geoms (the plant) in float32; every hit's
distance is then recomputed in float64 on the plane of the triangle Embree found
(a plane per triangle, computed once), so that distances and normals are MuJoCo's
to rounding (1e-14 m on the maize). The turning primitive geoms (the
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
        # Each triangle's plane, float64, for the refinement of Embree's float32 hits:
        # unit normal n (right hand over the vertex order, as MuJoCo's) and offset n . v0.
        normal = np.cross(self.triangles[:, 1] - self.triangles[:, 0], self.triangles[:, 2] - self.triangles[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        self._plane_normal = normal
        self._plane_offset = np.einsum("ij,ij->i", normal, self.triangles[:, 0])
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
        found = self._embree.run(origins.astype(np.float32), dirs.astype(np.float32))  # primID, -1: miss
        hit = found >= 0
        tri = found[hit]
        n_hit = self._plane_normal[tri]
        dist = np.full(len(origins), -1.0)
        # Float64 distance to the plane of the triangle Embree found (Embree decided the inside test).
        with np.errstate(divide="ignore", invalid="ignore"):
            dist[hit] = (self._plane_offset[tri] - np.einsum("ij,ij->i", n_hit, origins[hit])) \
                / np.einsum("ij,ij->i", n_hit, dirs[hit])
        if normals:
            normal = np.zeros((len(origins), 3))
            normal[hit] = n_hit
        geom = np.where(hit, self.geom_of_triangle[np.maximum(found, 0)], -1).astype(np.int32)
        mesh_nearer = (dist >= 0) & ((prim.dist_m < 0) | (dist < prim.dist_m))
        out_dist = np.where(mesh_nearer, dist, prim.dist_m)
        out_geom = np.where(mesh_nearer, geom, prim.geom_id)
        out_normal = np.where(mesh_nearer[:, None], normal, prim.normal_base) if normals else None
        return Hits(out_dist, out_geom, out_normal)

