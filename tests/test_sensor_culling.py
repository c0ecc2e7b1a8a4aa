"""Rays that cannot reach the turning geoms are never cast, and nothing changes for it."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import build_scene
from plantsim.scan.raw import BeamGrid
from plantsim.sensor.casting import rays_may_reach, turning_bounds, turning_geoms
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.sensor.model import SensorModel
from plantsim.sensor.spec import URG_04LX_UG01

ANGLES = BeamGrid.of(URG_04LX_UG01).beam_angles_rad()


def box_scene():
    box = trimesh.creation.box(extents=[0.04, 0.06, 0.2])
    box.apply_translation([0.05, -0.02, 0.1])
    return build_scene(RigGeometry(), plant_from_arrays(np.asarray(box.vertices), np.asarray(box.faces),
                                                         placement="none"))


def test_rays_may_reach_a_cylinder_analytic_cases():
    bounds = (0.2, 0.0, 0.3)
    o = np.array([[1.0, 0, 0.1], [1.0, 0, 0.1], [1.0, 0.25, 0.1], [0.1, 0, -1], [1.0, 0, 0.1],
                  [1.0, 0, 0.5], [1.0, 0, 0.5]])
    d = np.array([[-1.0, 0, 0], [-1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0], [1.0, 0, 0],
                  [-1.0, 0, 0], [-1.0, 0, -1.0]])
    max_dist = np.array([np.inf, 0.5, np.inf, np.inf, np.inf, np.inf, np.inf])
    # enters at 0.8; stopped at 0.5 first; passes beside it; up through it from below; going away;
    # above it; steeply down (z = 0.3 at x = 0.8, z = -0.3 at x = -0.2: misses it)
    np.testing.assert_array_equal(rays_may_reach(o, d, bounds, max_dist),
                                  [True, False, False, True, False, False, False])
    d_down = np.array([[-1.0, 0, -0.3]])  # from (1, 0, 0.5): at x = 0.2 z = 0.26, inside
    assert rays_may_reach(o[:1] + [0, 0, 0.4], d_down, bounds, np.array([np.inf]))[0]


def test_turning_bounds_hold_every_turning_vertex():
    scene = box_scene()
    radius, z_min, z_max = turning_bounds(scene)
    box = trimesh.creation.box(extents=[0.04, 0.06, 0.2])
    box.apply_translation([0.05, -0.02, 0.1])
    v = np.asarray(box.vertices)
    assert radius >= np.hypot(v[:, 0], v[:, 1]).max()
    assert radius < 1.0  # a bound, not everything
    assert z_max > z_min
    assert turning_geoms(scene).any()


@pytest.mark.parametrize("model", [None, SensorModel(footprint_rings=1)], ids=["ideal", "realistic"])
def test_culling_gives_the_hits_of_casting_every_ray(model):
    scene = box_scene()
    source = SimulatedLidar(scene, URG_04LX_UG01, ANGLES, model=model)
    caster = source.caster
    assert 0.0 < caster.reachable_fraction < 0.9  # something is culled, something is cast
    theta = np.radians(np.arange(0, 360, 15.0))
    per_beam = theta[:, None] + np.linspace(0.0, 0.01, len(ANGLES))[None, :]
    culled = [source.cast_lines(theta, np.random.default_rng(3)),
              source.cast_lines(per_beam, np.random.default_rng(4))]
    n_cast, n_culled = caster.n_rays_cast, caster.n_rays_culled
    assert 0 < n_culled < n_cast
    assert source.work()["turning_cast"]["culled"] == n_culled
    caster._may_hit[:-1] = True  # cast every ray
    caster.n_rays_cast = caster.n_rays_culled = 0
    every = [source.cast_lines(theta, np.random.default_rng(3)),
             source.cast_lines(per_beam, np.random.default_rng(4))]
    assert caster.n_rays_cast == n_cast and caster.n_rays_culled == 0
    for a, b in zip(culled, every):
        for field in a._fields:
            x, y = getattr(a, field), getattr(b, field)
            if x is None:
                assert y is None
            else:
                np.testing.assert_array_equal(x, y, err_msg=field)
    assert (culled[0].hit_class == 1).sum() > 50  # the plant was seen


def test_a_thin_disk_is_bounded_by_its_thickness_not_its_diameter():
    scene = box_scene()
    model = scene.model
    disk = model.geom("disk").id
    only_disk = np.arange(model.ngeom) == disk
    radius, z_min, z_max = turning_bounds(scene, geoms=only_disk)
    half_height = float(model.geom_size[disk][1])
    # A cylinder geom on the axis: its bounding sphere's radius (the tighter in XY), and its
    # thickness in Z (its bounding box's, not the sphere's).
    assert float(model.geom_size[disk][0]) < radius <= float(model.geom_rbound[disk]) + 2e-6
    assert z_max - z_min == pytest.approx(2 * half_height, abs=4e-6)
    assert z_max - z_min < 0.5 * radius


@pytest.mark.parametrize("model", [None, SensorModel(footprint_rings=1)], ids=["ideal", "realistic"])
def test_primitive_culling_gives_the_hits_of_casting_every_ray_on_the_disk(model):
    embree = pytest.importorskip("plantsim.sensor.embree")
    if not embree.embree_available():
        pytest.skip("embreex is not installed (pip install 'plantsim[fast]')")
    scene = box_scene()
    scene.model  # compiled: MuJoCo casts the primitives (on a layout, the disk is cast once per ray instead)
    source = SimulatedLidar(scene, URG_04LX_UG01, ANGLES, model=model, backend=embree.EmbreeBackend(scene))
    caster = source.caster
    assert not caster._skip_invariant
    near = caster._may_hit_primitives[:-1]
    assert 0.0 < near.mean() < 0.5  # most rays cannot reach the disk
    theta = np.radians(np.arange(0, 360, 15.0))
    culled = source.cast_lines(theta, np.random.default_rng(3))
    caster._may_hit_primitives = None  # MuJoCo casts every ray against the disk
    every = source.cast_lines(theta, np.random.default_rng(3))
    for field in culled._fields:
        x, y = getattr(culled, field), getattr(every, field)
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=field)
    assert (culled.geom_id == scene.model.geom("disk").id).sum() > 50  # the disk was seen
