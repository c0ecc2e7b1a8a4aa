"""The scene: rig files compile and step without warnings; a static scene has no actuator."""

import mujoco
import numpy as np
import pytest

from plantsim.plant.mesh import plant_from_arrays
from plantsim.resources import data_path
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import LIDAR_GEOMGROUP, HitClass, build_scene


@pytest.mark.parametrize("name", ["mjcf/rig.xml", "mjcf/scene.xml"])
def test_rig_files_compile_and_step_without_warnings(name):
    model = mujoco.MjModel.from_xml_path(str(data_path(name)))
    data = mujoco.MjData(model)
    for _ in range(200):
        mujoco.mj_step(model, data)
    assert [w.number for w in data.warning] == [0] * len(data.warning)
    assert model.nu == 0  # the rig holds no actuator


def test_static_scene_with_plant(box_mesh):
    vertices, faces = box_mesh
    scene = build_scene(RigGeometry(lidar_distance_m=0.4, lidar_height_m=0.2, yaw_deg=5),
                        plant_from_arrays(vertices, faces))
    model = scene.model
    assert model.nu == 0 and model.na == 0 and model.nplugin == 0  # kinematics only
    plant_geom = model.geom("plant")
    assert plant_geom.contype == 0 and plant_geom.conaffinity == 0
    assert scene.geom_class[plant_geom.id] == HitClass.PLANT
    assert scene.geom_class[model.geom("disk").id] == HitClass.TURNTABLE
    assert scene.geom_class[model.geom("bench").id] == HitClass.RIG
    assert scene.geom_class[-1] == HitClass.NONE  # geom id -1 (a miss)
    assert LIDAR_GEOMGROUP[model.geom("lidar_housing").group[0]] == 0  # never cast
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.site("lidar").xpos, [0.4, 0, 0.2], atol=1e-12)
    np.testing.assert_allclose(data.site("lidar").xmat.reshape(3, 3), scene.T_base_lidar[:3, :3],
                               atol=1e-9)
    assert model.body("plant").mass[0] > 0
    for _ in range(100):
        mujoco.mj_step(model, data)
    assert all(w.number == 0 for w in data.warning)
