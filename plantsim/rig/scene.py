"""The MuJoCo scene of a scan: the rig file, the user's rig geometry, the plant.

A scene holds only what its scan needs. A static scan's scene has the hinge but
no actuator and runs kinematics only; dynamic scans add their actuator and
jitter sources on top of this (see the ``dynamic`` hooks).
"""

from __future__ import annotations

import dataclasses
import enum
import logging

import mujoco
import numpy as np

from plantsim.errors import SceneError
from plantsim.plant.mesh import PlantMesh, shell_inertia
from plantsim.resources import data_path
from plantsim.rig.geometry import RigGeometry

log = logging.getLogger(__name__)


class HitClass(enum.IntEnum):
    """What a beam hit; set by the geom group of the surface (mjcf/rig.xml)."""

    NONE = 0
    PLANT = 1
    TURNTABLE = 2
    RIG = 3


# Geom group -> what a hit on it is. Group 3 (the sensor's own body) is never cast.
GROUP_CLASS = {0: HitClass.RIG, 1: HitClass.TURNTABLE, 2: HitClass.PLANT}
LIDAR_GEOMGROUP = np.array([1 if g in GROUP_CLASS else 0 for g in range(mujoco.mjNGROUP)],
                           dtype=np.uint8)

# Post behind the sensor, from the bench top up to the sensor's underside.
_POST_BEHIND_M = 0.04
_POST_RADIUS_M = 0.01
_SENSOR_HALF_HEIGHT_M = 0.025
_BENCH_HALF_THICKNESS_M = 0.01


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """A compiled scan scene.

    Attributes:
      model: the compiled MuJoCo model (world frame = base frame).
      rig: the rig geometry it was built with.
      plant: the plant on the turntable, or None for an empty rig.
      geom_class: (ngeom + 1,) uint8 HitClass per geom id; the last entry is
        NONE, so ``geom_class[geomid]`` maps MuJoCo's -1 (miss) to NONE.
      lidar_body_id: body whose geoms the LiDAR's rays ignore (its housing).
      turntable_qpos_adr: index of the turntable hinge angle in qpos.
      T_base_lidar: (4, 4) float64, the LiDAR pose in the base (world) frame.
    """

    model: mujoco.MjModel
    rig: RigGeometry
    plant: PlantMesh | None
    geom_class: np.ndarray
    lidar_body_id: int
    turntable_qpos_adr: int
    T_base_lidar: np.ndarray


def _set_rig_geometry(spec: mujoco.MjSpec, rig: RigGeometry, T_base_lidar: np.ndarray) -> None:
    disk = spec.geom("disk")
    disk.size = [rig.disk_radius_m, rig.disk_thickness_m / 2, 0]
    disk.pos = [0, 0, -rig.disk_thickness_m / 2]
    pedestal = spec.geom("pedestal")
    pedestal.size = [pedestal.size[0], rig.pedestal_height_m / 2, 0]
    pedestal.pos = [0, 0, -rig.disk_thickness_m - rig.pedestal_height_m / 2]
    bench_top_z = -rig.disk_thickness_m - rig.pedestal_height_m
    bench = spec.geom("bench")
    x_lo, x_hi = -rig.disk_radius_m - 0.2, rig.lidar_distance_m + 0.15
    bench.size = [(x_hi - x_lo) / 2, max(0.3, rig.disk_radius_m + 0.1), _BENCH_HALF_THICKNESS_M]
    bench.pos = [(x_hi + x_lo) / 2, 0, bench_top_z - _BENCH_HALF_THICKNESS_M]

    lidar = spec.body("lidar")
    lidar.pos = T_base_lidar[:3, 3]
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, T_base_lidar[:3, :3].ravel())
    lidar.quat = quat

    yaw = np.deg2rad(rig.yaw_deg)
    post_xy = T_base_lidar[:2, 3] + _POST_BEHIND_M * np.array([np.cos(yaw), np.sin(yaw)])
    post_top_z = rig.lidar_height_m - _SENSOR_HALF_HEIGHT_M
    post = spec.geom("lidar_post")
    half = max((post_top_z - bench_top_z) / 2, 1e-3)
    post.size = [_POST_RADIUS_M, half, 0]
    post.pos = [post_xy[0], post_xy[1], bench_top_z + half]


def _add_plant(spec: mujoco.MjSpec, plant: PlantMesh, areal_density_kg_m2: float | None) -> None:
    vertices_turntable = plant.vertices_turntable
    if len(vertices_turntable) < 4:
        # MuJoCo wants at least 4 vertices in a mesh; a lone triangle gets an unused
        # copy of its centroid, which no face references and no ray can hit.
        vertices_turntable = np.vstack([vertices_turntable, vertices_turntable.mean(axis=0)])
    # Python lists cross into MuJoCo's vectors faster than numpy arrays (element by element
    # either way: 0.24 s against 0.30 s at 1 M faces); the values are the same.
    mesh = spec.add_mesh(name="plant", uservert=vertices_turntable.ravel().tolist(),
                         userface=plant.faces.ravel().tolist())
    # Thin open leaves have no volume: MuJoCo must not try a volumetric inertia.
    mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
    if areal_density_kg_m2 is None:
        # No physics will run: a token inertial (MuJoCo needs a valid body), not the
        # plant's real one, which costs a pass over every triangle.
        mass, com, inertia = 1e-3, vertices_turntable.mean(axis=0), 1e-9 * np.eye(3)
    else:
        mass, com, inertia = shell_inertia(vertices_turntable, plant.faces,
                                           areal_density_kg_m2=areal_density_kg_m2)
    # A line-like mesh has a vanishing principal moment; keep it positive.
    floor = max(1e-12, 1e-9 * float(np.trace(inertia)))
    inertia = inertia + floor * np.eye(3)
    body = spec.body("turntable").add_body(
        name="plant", explicitinertial=True, mass=max(mass, 1e-9), ipos=com,
        fullinertia=[inertia[0, 0], inertia[1, 1], inertia[2, 2],
                     inertia[0, 1], inertia[0, 2], inertia[1, 2]])
    body.add_geom(spec.find_default("plant"), name="plant", type=mujoco.mjtGeom.mjGEOM_MESH,
                  meshname="plant")


def build_spec(rig: RigGeometry, plant: PlantMesh | None = None, *,
               plant_areal_density_kg_m2: float | None = 0.3) -> mujoco.MjSpec:
    """The scene as an editable MjSpec (before compilation).

    Args:
      rig: rig geometry.
      plant: the plant to put on the turntable, or None.
      plant_areal_density_kg_m2: mass per leaf area for the plant's explicit
        inertial (a fresh maize leaf is ~0.2-0.3 kg/m^2); None for a scene that
        runs no physics (a token inertial).
    """
    spec = mujoco.MjSpec.from_file(str(data_path("mjcf/scene.xml")))
    _set_rig_geometry(spec, rig, rig.T_base_lidar())
    if plant is not None:
        _add_plant(spec, plant, plant_areal_density_kg_m2)
    return spec


def compile_scene(spec: mujoco.MjSpec, rig: RigGeometry, plant: PlantMesh | None) -> Scene:
    """Compiles a spec from :func:`build_spec` and checks it for MuJoCo warnings."""
    try:
        model = spec.compile()
    except Exception as exc:  # MuJoCo raises ValueError with its compiler message.
        raise SceneError(f"MuJoCo could not compile the scene: {exc}") from exc
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    warnings = [mujoco.mjtWarning(i).name for i, w in enumerate(data.warning) if w.number]
    if warnings:
        raise SceneError(f"MuJoCo warned while checking the scene: {', '.join(warnings)}")
    geom_class = np.array([GROUP_CLASS.get(int(g), HitClass.NONE) for g in model.geom_group]
                          + [HitClass.NONE], dtype=np.uint8)
    return Scene(model=model, rig=rig, plant=plant, geom_class=geom_class,
                 lidar_body_id=model.body("lidar").id,
                 turntable_qpos_adr=int(model.jnt_qposadr[model.joint("turntable").id]),
                 T_base_lidar=rig.T_base_lidar())


def build_scene(rig: RigGeometry, plant: PlantMesh | None = None, *,
                plant_areal_density_kg_m2: float | None = None) -> Scene:
    """Builds and compiles the static scan scene (no actuator, kinematics only).

    The plant gets a token inertial unless ``plant_areal_density_kg_m2`` is given:
    a kinematic scan never uses it (:func:`plantsim.turntable.dynamics.build_dynamic_scene`
    computes the real one).
    """
    spec = build_spec(rig, plant, plant_areal_density_kg_m2=plant_areal_density_kg_m2)
    return compile_scene(spec, rig, plant)
