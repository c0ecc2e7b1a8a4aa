"""The 'top seen too steeply' warning looks at the top's own radius, not the plant's widest reach."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.fit import MAX_ELEVATION_DEG, rig_fit_warnings
from plantsim.rig.geometry import RigGeometry
from plantsim.sensor.spec import URG_04LX_UG01


def _plant(*boxes):
    """Boxes given as (centre xyz, extents xyz), metres, turntable frame."""
    meshes = []
    for centre, extents in boxes:
        box = trimesh.creation.box(extents=extents)
        box.apply_translation(centre)
        meshes.append(box)
    mesh = trimesh.util.concatenate(meshes)
    return plant_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces), placement="none")


RIG = RigGeometry(lidar_distance_m=0.35, lidar_height_m=0.15)


def _steep(warnings):
    return [w for w in warnings if "above the horizontal" in w]


def test_a_wide_low_leaf_does_not_make_a_narrow_top_steep():
    # a 6 mm stem 0.45 m tall on the axis, and a leaf reaching 0.25 m out near the ground
    plant = _plant(((0, 0, 0.225), (0.006, 0.006, 0.45)), ((0.15, 0, 0.05), (0.2, 0.02, 0.002)))
    # the top at its own radius (3 mm): atan((0.45 - 0.15) / (0.35 - 0.003)) = 40.9 deg
    assert math.degrees(math.atan2(0.30, 0.347)) < MAX_ELEVATION_DEG
    assert _steep(rig_fit_warnings(plant, RIG, URG_04LX_UG01)) == []


def test_a_wide_top_seen_steeply_is_warned_with_its_angle():
    # the same stem with a leaf reaching 0.25 m out at the very top
    plant = _plant(((0, 0, 0.225), (0.006, 0.006, 0.45)), ((0.15, 0, 0.449), (0.2, 0.02, 0.002)))
    expected = math.degrees(math.atan2(0.45 - 0.15, 0.35 - math.hypot(0.25, 0.01)))  # 71.6 deg
    (warning,) = _steep(rig_fit_warnings(plant, RIG, URG_04LX_UG01))
    assert f"seen {expected:.0f} deg above" in warning
