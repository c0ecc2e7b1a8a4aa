"""The MuJoCo scene of a scan: the rig file, the user's rig geometry, the plant.

A scene holds only what its scan needs. A static scan's scene has the hinge but
no actuator and runs kinematics only; dynamic scans add their actuator and
jitter sources on top of this (see the ``dynamic`` hooks).

A kinematic scan's scene compiles MuJoCo's model only when something asks for
it (:attr:`Scene.model`): its geoms are known without MuJoCo
(:mod:`plantsim.rig.layout`), and the Embree caster casts the plant and the rig's
primitives from them, so such a scan never imports MuJoCo.
"""

from __future__ import annotations

import enum
import logging
from typing import TYPE_CHECKING, Callable

import numpy as np

from plantsim.errors import SceneError
from plantsim.plant.mesh import PlantMesh, shell_inertia
from plantsim.resources import data_path
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.layout import N_GROUPS, LayoutError, RigLayout, rig_layout, rig_placement

if TYPE_CHECKING:
    import mujoco

log = logging.getLogger(__name__)


class HitClass(enum.IntEnum):
    """What a beam hit; set by the geom group of the surface (mjcf/rig.xml)."""

    NONE = 0
    PLANT = 1
    TURNTABLE = 2
    RIG = 3


# Geom group -> what a hit on it is. Group 3 (the sensor's own body) is never cast.
GROUP_CLASS = {0: HitClass.RIG, 1: HitClass.TURNTABLE, 2: HitClass.PLANT}
LIDAR_GEOMGROUP = np.array([1 if g in GROUP_CLASS else 0 for g in range(N_GROUPS)], dtype=np.uint8)


class Scene:
    """A scan scene: the rig, the plant, and MuJoCo's model of them (compiled when first asked for).

    Attributes:
      model: the compiled MuJoCo model (world frame = base frame); a scene built
        with a layout compiles it on first access.
      layout: the scene's geoms without MuJoCo (:mod:`plantsim.rig.layout`), or
        None for a scene compiled from a spec of its own.
      rig: the rig geometry it was built with.
      plant: the plant on the turntable, or None for an empty rig.
      geom_class: (ngeom + 1,) uint8 HitClass per geom id; the last entry is
        NONE, so ``geom_class[geomid]`` maps MuJoCo's -1 (miss) to NONE.
      lidar_body_id: body whose geoms the LiDAR's rays ignore (its housing).
      turntable_qpos_adr: index of the turntable hinge angle in qpos.
      T_base_lidar: (4, 4) float64, the LiDAR pose in the base (world) frame.
    """

    def __init__(self, *, rig: RigGeometry, plant: PlantMesh | None, geom_class: np.ndarray,
                 lidar_body_id: int, turntable_qpos_adr: int, T_base_lidar: np.ndarray,
                 model: "mujoco.MjModel | None" = None, layout: RigLayout | None = None,
                 compile_model: "Callable[[], mujoco.MjModel] | None" = None):
        if model is None and compile_model is None:
            raise ValueError("a Scene needs a model or a way to compile one")
        self.rig = rig
        self.plant = plant
        self.geom_class = geom_class
        self.lidar_body_id = lidar_body_id
        self.turntable_qpos_adr = turntable_qpos_adr
        self.T_base_lidar = T_base_lidar
        self.layout = layout
        self._model = model
        self._compile_model = compile_model

    @property
    def model_compiled(self) -> bool:
        """Whether MuJoCo's model exists yet (a lazy scene compiles it on first access)."""
        return self._model is not None

    @property
    def model(self) -> "mujoco.MjModel":
        if self._model is None:
            model = self._compile_model()
            # The layout named the geoms the casters used: MuJoCo's model must agree.
            classes = np.array([GROUP_CLASS.get(int(g), HitClass.NONE) for g in model.geom_group]
                               + [HitClass.NONE], dtype=np.uint8)
            if not np.array_equal(classes, self.geom_class) or model.body("lidar").id != self.lidar_body_id:
                raise SceneError("MuJoCo's compiled scene disagrees with plantsim's reading of the rig file "
                                 "(plantsim.rig.layout): please report this")
            self._model = model
        return self._model


def _set_rig_geometry(spec: "mujoco.MjSpec", rig: RigGeometry, T_base_lidar: np.ndarray) -> None:
    import mujoco

    placement = rig_placement(rig, T_base_lidar)
    for name, values in placement["geoms"].items():
        geom = spec.geom(name)
        old = np.array(geom.size, dtype=np.float64)
        geom.size = np.where(np.isnan(values["size"]), old, values["size"])
        geom.pos = values["pos"]
    lidar = spec.body("lidar")
    lidar.pos = placement["lidar_body"]["pos"]
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, placement["lidar_body"]["R"].ravel())
    lidar.quat = quat


def _add_plant(spec: "mujoco.MjSpec", plant: PlantMesh, areal_density_kg_m2: float | None) -> None:
    import mujoco

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
               plant_areal_density_kg_m2: float | None = 0.3) -> "mujoco.MjSpec":
    """The scene as an editable MjSpec (before compilation).

    Args:
      rig: rig geometry.
      plant: the plant to put on the turntable, or None.
      plant_areal_density_kg_m2: mass per leaf area for the plant's explicit
        inertial (a fresh maize leaf is ~0.2-0.3 kg/m^2); None for a scene that
        runs no physics (a token inertial).
    """
    import mujoco

    spec = mujoco.MjSpec.from_file(str(data_path("mjcf/scene.xml")))
    _set_rig_geometry(spec, rig, rig.T_base_lidar())
    if plant is not None:
        _add_plant(spec, plant, plant_areal_density_kg_m2)
    return spec


def _compile_checked(spec: "mujoco.MjSpec") -> "mujoco.MjModel":
    """Compiles a spec and checks the model for MuJoCo warnings."""
    import mujoco

    try:
        model = spec.compile()
    except Exception as exc:  # MuJoCo raises ValueError with its compiler message.
        raise SceneError(f"MuJoCo could not compile the scene: {exc}") from exc
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    warnings = [mujoco.mjtWarning(i).name for i, w in enumerate(data.warning) if w.number]
    if warnings:
        raise SceneError(f"MuJoCo warned while checking the scene: {', '.join(warnings)}")
    return model


def compile_scene(spec: "mujoco.MjSpec", rig: RigGeometry, plant: PlantMesh | None) -> Scene:
    """Compiles a spec from :func:`build_spec` and checks it for MuJoCo warnings."""
    model = _compile_checked(spec)
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
    computes the real one). Such a scene compiles MuJoCo's model only when first
    asked for (:attr:`Scene.model`), unless the rig file holds MJCF that
    :mod:`plantsim.rig.layout` does not read.
    """
    if plant_areal_density_kg_m2 is None:
        try:
            layout = rig_layout(rig, with_plant=plant is not None)
        except LayoutError as exc:
            log.info("MuJoCo compiles the scene now: %s", exc)
        else:
            geom_class = np.array([GROUP_CLASS.get(g.group, HitClass.NONE) for g in layout.geoms]
                                  + [HitClass.NONE], dtype=np.uint8)
            return Scene(rig=rig, plant=plant, geom_class=geom_class, lidar_body_id=layout.body_id("lidar"),
                         turntable_qpos_adr=0, T_base_lidar=rig.T_base_lidar(), layout=layout,
                         compile_model=lambda: _compile_checked(build_spec(rig, plant,
                                                                           plant_areal_density_kg_m2=None)))
    spec = build_spec(rig, plant, plant_areal_density_kg_m2=plant_areal_density_kg_m2)
    return compile_scene(spec, rig, plant)
