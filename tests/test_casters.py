"""The ray-casting backends agree hit for hit: MuJoCo (the reference) and Embree."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from plantsim.plant.mesh import load_plant, plant_from_arrays
from plantsim.resources import bundled_plant_path
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import build_scene
from plantsim.scan.raw import BeamGrid
from plantsim.sensor import casting
from plantsim.sensor.casting import MujocoBackend, make_backend
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.sensor.model import SensorModel
from plantsim.sensor.spec import URG_04LX_UG01

embree = pytest.importorskip("plantsim.sensor.embree")
if not embree.embree_available():
    pytest.skip("embreex is not installed (pip install 'plantsim[fast]')", allow_module_level=True)

ANGLES = BeamGrid.of(URG_04LX_UG01).beam_angles_rad()


def both(scene, model=None, angles_deg=np.arange(0, 360, 7.0), *, embree_from="model"):
    """The same lines cast by MuJoCo and by Embree.

    ``embree_from``: "model" gives Embree a scene whose MuJoCo model is compiled (the
    triangles are MuJoCo's float32 vertices, MuJoCo casts the primitives); "layout" gives it
    a fresh, uncompiled copy of the scene (the plant's own float64 triangles, the rig's
    primitives analytic, no MuJoCo).
    """
    out = {}
    for name in ("mujoco", "embree"):
        use = scene
        if name == "embree" and embree_from == "layout":
            use = build_scene(scene.rig, scene.plant)
            assert not use.model_compiled
        else:
            use.model  # compiled
        source = SimulatedLidar(use, URG_04LX_UG01, ANGLES, model=model, backend=make_backend(use, name))
        assert source.caster.backend.name == name
        if name == "embree":
            assert ("no MuJoCo model used to cast" in source.describe()["ray_caster_detail"]) == (embree_from == "layout")
            assert use.model_compiled == (embree_from == "model")
        out[name] = source.cast_lines(np.radians(angles_deg), np.random.default_rng(0))
    return out["mujoco"], out["embree"]


def _same_ranges(a, b, embree_from):
    if embree_from == "model":
        np.testing.assert_array_equal(a.range_m, b.range_m)  # float64 refinement, then the same float32 rounding
    else:
        # The plant's own vertices against MuJoCo's float32 copies of them: a few 1e-8 m at 0.5 m.
        np.testing.assert_array_equal(np.isnan(a.range_m), np.isnan(b.range_m))
        ok = ~np.isnan(a.range_m)
        np.testing.assert_allclose(b.range_m[ok], a.range_m[ok], rtol=0, atol=2e-7)


def shapes():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    sphere.apply_translation([0.03, -0.02, 0.12])
    box = trimesh.creation.box(extents=[0.02, 0.05, 0.08])
    box.apply_transform(trimesh.transformations.rotation_matrix(0.4, [0, 0, 1]))
    box.apply_translation([-0.04, 0.03, 0.05])
    cylinder = trimesh.creation.cylinder(radius=0.01, height=0.3, sections=32)
    cylinder.apply_translation([0.0, 0.0, 0.15])  # on the axis: the axis-trap case
    return trimesh.util.concatenate([sphere, box, cylinder])


@pytest.mark.parametrize("embree_from", ["model", "layout"])
@pytest.mark.parametrize("which", ["shapes", "maize"])
def test_ideal_lines_are_the_same_hit_for_hit(which, embree_from):
    if which == "shapes":
        mesh = shapes()
        plant = plant_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces), placement="none")
    else:
        plant = load_plant(bundled_plant_path("maize"))
    a, b = both(build_scene(RigGeometry(), plant), embree_from=embree_from)
    np.testing.assert_array_equal(a.geom_id, b.geom_id)
    np.testing.assert_array_equal(a.status, b.status)
    _same_ranges(a, b, embree_from)
    assert (a.hit_class == 1).sum() > 500


@pytest.mark.parametrize("embree_from", ["model", "layout"])
def test_realistic_lines_agree_beam_for_beam(embree_from):
    a, b = both(build_scene(RigGeometry(), load_plant(bundled_plant_path("maize"))), model=SensorModel(),
                angles_deg=np.arange(0, 360, 15.0), embree_from=embree_from)
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_array_equal(a.geom_id, b.geom_id)
    ok = a.status == 0
    # The same footprints and noise draws; only a 1 mm quantisation step can flip on a rounding.
    assert np.abs(a.range_m[ok] - b.range_m[ok]).max() <= 0.001 + 1e-9
    np.testing.assert_allclose(a.intensity[ok], b.intensity[ok], atol=1e-3)


@pytest.mark.parametrize("embree_from", ["model", "layout"])
def test_a_scene_without_a_turning_mesh_falls_to_mujoco_alone(embree_from):
    scene = build_scene(RigGeometry())  # no plant: the disk is a primitive
    a, b = both(scene, embree_from=embree_from)
    np.testing.assert_array_equal(a.range_m, b.range_m)
    np.testing.assert_array_equal(a.geom_id, b.geom_id)


def test_asking_for_embree_without_it_says_how_to_install(monkeypatch):
    monkeypatch.setattr(embree, "embree_available", lambda: False)
    scene = build_scene(RigGeometry())
    with pytest.raises(ValueError, match=r"caster = \"embree\" needs the embreex package"):
        make_backend(scene, "embree")
    assert isinstance(make_backend(scene, "auto"), MujocoBackend)
    assert casting.BACKENDS == ("mujoco", "embree", "auto")


def random_rays(n, seed=0):
    """Rays from a sphere of 0.5 m about the plant, aimed at random points of its bounding box."""
    rng = np.random.default_rng(seed)
    start = rng.normal(size=(n, 3))
    start = 0.5 * start / np.linalg.norm(start, axis=1, keepdims=True) + (0.0, 0.0, 0.15)
    target = rng.uniform((-0.2, -0.2, -0.05), (0.2, 0.2, 0.35), size=(n, 3))
    dirs = target - start
    return start, dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


@pytest.mark.parametrize("path", ["rig-rebuilt", "model-copies", "layout"])
def test_backend_calls_agree_with_mujoco_with_normals(path, monkeypatch):
    if path == "model-copies":  # the path for scenes that are not the plain rig plus a plant
        monkeypatch.setattr(embree, "_without_meshes", lambda scene, mesh_geoms: None)
    mesh = shapes()
    plant = plant_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces), placement="none")
    scene = build_scene(RigGeometry(), plant)
    if path == "layout":  # no MuJoCo behind Embree: the plant's own triangles, analytic primitives
        fast = embree.EmbreeBackend(scene)
        assert not scene.model_compiled
        reference = MujocoBackend(build_scene(RigGeometry(), plant))
    else:
        reference, fast = MujocoBackend(scene), embree.EmbreeBackend(scene)
        assert (fast._geom_ids is not None) == (path == "rig-rebuilt")
    # MuJoCo's float32 copy of the vertices against the plant's own: ~3e-8 m at 0.3 m, times the
    # slope of an oblique hit (1.2e-7 m on 2 rays of 3482 here).
    atol = 5e-7 if path == "layout" else 1e-12
    origins, dirs = random_rays(20_000)
    for cast in ("cast_turning", "cast_fixed"):
        a = getattr(reference, cast)(origins, dirs, normals=True)
        b = getattr(fast, cast)(origins, dirs, normals=True)
        np.testing.assert_array_equal(a.geom_id, b.geom_id)
        np.testing.assert_array_equal(a.dist_m < 0, b.dist_m < 0)
        hit = a.dist_m >= 0
        assert hit.sum() > 2000
        # Float64 refinement: far inside float32's 1.2e-7 x the 0.8 m scene.
        np.testing.assert_allclose(b.dist_m[hit], a.dist_m[hit], rtol=0, atol=atol)
        cos = np.einsum("ij,ij->i", a.normal_base[hit], b.normal_base[hit])
        np.testing.assert_allclose(cos, 1.0, atol=1e-9 if path != "layout" else 1e-6)
    turning = fast.cast_turning(origins, dirs)
    assert np.isin(turning.geom_id[turning.geom_id >= 0], [scene.model.geom("disk").id,
                                                          scene.model.geom("plant").id]).all()
    assert turning.normal_base is None


def test_embree_threads_give_the_hits_of_one_thread():
    """Rays split over threads (blocks of MIN_RAYS_PER_THREAD or more) hit exactly as on one thread."""
    plant = load_plant(bundled_plant_path("maize"))
    scene = build_scene(RigGeometry(), plant)
    one, four = embree.EmbreeBackend(scene, nthread=1), embree.EmbreeBackend(scene, nthread=4)
    rng = np.random.default_rng(5)
    n = 5 * embree.EmbreeBackend.MIN_RAYS_PER_THREAD + 17  # four blocks of unequal ends
    origins = np.column_stack([np.full(n, 0.35), rng.uniform(-0.05, 0.05, n), rng.uniform(0.0, 0.5, n)])
    dirs = np.column_stack([-np.ones(n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    a = one.cast_turning(origins, dirs, normals=True)
    b = four.cast_turning(origins, dirs, normals=True)
    assert four._pool is not None and one._pool is None  # the split did happen
    assert (a.geom_id >= 0).sum() > n // 10
    np.testing.assert_array_equal(a.dist_m, b.dist_m)
    np.testing.assert_array_equal(a.geom_id, b.geom_id)
    np.testing.assert_array_equal(a.normal_base, b.normal_base)


@pytest.mark.parametrize("normals", [False, True])
def test_chunks_cast_side_by_side_give_the_hits_and_counts_of_one_thread(normals):
    """A Caster on a backend that allows concurrent calls casts whole chunks on several
    threads: every hit, normal and counter is what one thread gives."""
    plant = load_plant(bundled_plant_path("maize"))
    scene = build_scene(RigGeometry(), plant)  # never compiled: primitives analytic
    sources = {n: SimulatedLidar(scene, URG_04LX_UG01, ANGLES, backend=embree.EmbreeBackend(scene, nthread=n))
               for n in (1, 3)}
    assert sources[3].caster.backend.concurrent_calls and sources[3].caster._chunk_pool() is not None
    assert sources[1].caster._chunk_pool() is None
    ids = np.broadcast_to(np.arange(len(ANGLES)), (37, len(ANGLES)))
    theta = np.radians(np.arange(37) * 9.7)
    got = {n: s.caster.cast(ids, theta, normals=normals, chunk_lines=5) for n, s in sources.items()}
    seen = []
    sources[3].caster.cast(ids, theta, chunk_lines=5, progress=lambda done, total: seen.append((done, total)))
    assert seen == [(min(hi, 37), 37) for hi in range(5, 41, 5)]
    assert (got[1].geom_id >= 0).sum() > 1000
    np.testing.assert_array_equal(got[1].dist_m, got[3].dist_m)
    np.testing.assert_array_equal(got[1].geom_id, got[3].geom_id)
    if normals:
        np.testing.assert_array_equal(got[1].normal_base, got[3].normal_base)
    one, many = sources[1].caster, sources[3].caster  # many cast the lines twice
    assert one.n_rays_cast == 37 * len(ANGLES) and one.n_rays_culled > 0
    assert (many.n_rays_cast, many.n_rays_culled) == (2 * one.n_rays_cast, 2 * one.n_rays_culled)
    assert many.cast_turning_s > 0


def test_row_gather_and_scatter_are_fancy_indexing():
    rng = np.random.default_rng(2)
    table = rng.normal(size=(50, 3))
    index = rng.integers(0, 50, size=(4, 7))
    np.testing.assert_array_equal(casting.take_rows(table, index), table[index])
    got, want = np.zeros((60, 3)), np.zeros((60, 3))
    where = rng.choice(60, size=20, replace=False)
    rows = rng.normal(size=(20, 3))
    casting.put_rows(got, where, rows)
    want[where] = rows
    np.testing.assert_array_equal(got, want)
    strided = np.zeros((60, 6))[:, ::2]  # not contiguous: plain fancy assignment
    casting.put_rows(strided, where, rows)
    np.testing.assert_array_equal(strided, want)


def test_embree_mesh_input_builds_the_scene_of_plain_arrays():
    """The object-array input (fast to copy) gives Embree the very mesh the numeric arrays give."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    mesh = shapes()
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    plain, fast = rtcore_scene.EmbreeScene(), rtcore_scene.EmbreeScene()
    TriangleMesh(scene=plain, vertices=vertices.astype(np.float32), indices=faces.astype(np.int32))
    TriangleMesh(scene=fast, **embree.embreex_mesh_input(vertices, faces))
    origins, dirs = random_rays(20_000)
    o, d = origins.astype(np.float32), dirs.astype(np.float32)
    want = plain.run(o, d)
    assert (want >= 0).sum() > 1000
    np.testing.assert_array_equal(fast.run(o, d), want)
    np.testing.assert_array_equal(fast.run(o, d, output=1)["tfar"], plain.run(o, d, output=1)["tfar"])


def test_building_the_embree_scene_leaves_the_cyclic_collector_as_it_found_it():
    import gc

    scene = build_scene(RigGeometry(), plant_from_arrays(np.asarray(shapes().vertices), np.asarray(shapes().faces)))
    was = gc.isenabled()
    try:
        for enabled in (True, False):
            gc.enable() if enabled else gc.disable()
            embree.EmbreeBackend(scene, nthread=1)
            assert gc.isenabled() is enabled
    finally:
        gc.enable() if was else gc.disable()


def _geom(type_, pos=(0.0, 0.0, -0.005), R=np.eye(3)):
    from plantsim.rig.layout import Geom

    return Geom(name="g", type=type_, size=np.array([0.1, 0.005, 0.0]), pos_base=np.array(pos, dtype=float),
                R_base_geom=np.asarray(R, dtype=float), group=1, body="turntable", turning=True)


def test_only_exact_solids_of_revolution_about_the_axis_are_invariant():
    flip = np.diag([1.0, -1.0, -1.0])  # the cylinder upside down: still about the axis
    about_z = trimesh.transformations.rotation_matrix(0.3, [0, 0, 1])[:3, :3]
    tilted = trimesh.transformations.rotation_matrix(1e-9, [1, 0, 0])[:3, :3]
    assert embree.is_solid_of_revolution(_geom("cylinder"))
    assert embree.is_solid_of_revolution(_geom("cylinder", R=flip))
    assert embree.is_solid_of_revolution(_geom("cylinder", R=about_z))
    assert embree.is_solid_of_revolution(_geom("sphere", pos=(0.0, 0.0, 0.2), R=tilted))
    assert not embree.is_solid_of_revolution(_geom("cylinder", R=tilted))
    assert not embree.is_solid_of_revolution(_geom("cylinder", pos=(1e-12, 0.0, 0.0)))
    assert not embree.is_solid_of_revolution(_geom("sphere", pos=(0.0, 1e-12, 0.0)))
    assert not embree.is_solid_of_revolution(_geom("box"))


def test_the_disk_cast_once_gives_the_hits_of_the_disk_cast_at_every_angle():
    """The disk's hits, cast once in the base frame and merged as the caster merges the rig's,
    are those of casting every turning geom with the rays turned to each angle."""
    plant = load_plant(bundled_plant_path("maize"))
    backend = embree.EmbreeBackend(build_scene(RigGeometry(), plant), nthread=1)  # layout: disk analytic
    disk = [g.name for g in build_scene(RigGeometry()).layout.geoms].index("disk")
    assert backend.invariant_geoms.sum() == 1 and backend.invariant_geoms[disk]
    rng = np.random.default_rng(11)
    n = 4000
    origins_base = np.column_stack([np.full(n, 0.35), rng.uniform(-0.12, 0.12, n), rng.uniform(-0.02, 0.3, n)])
    dirs_base = np.column_stack([-np.ones(n), rng.uniform(-0.4, 0.4, n), rng.uniform(-1.2, 0.2, n)])
    dirs_base /= np.linalg.norm(dirs_base, axis=1, keepdims=True)
    inv = backend.cast_invariant(origins_base, dirs_base, normals=True)
    assert (inv.geom_id == disk).sum() > n // 10
    for theta in np.radians([0.0, 37.0, 181.5, 300.0]):
        c, s = np.cos(theta), np.sin(theta)
        R = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # base -> turntable at angle theta
        o, d = origins_base @ R.T, dirs_base @ R.T
        want = backend.cast_turning(o, d, normals=True)
        rest = backend.cast_turning(o, d, normals=True, skip_invariant=True)
        assert not (rest.geom_id == disk).any()
        nearer = (inv.dist_m >= 0) & ((rest.dist_m < 0) | (inv.dist_m < rest.dist_m))
        got_geom = np.where(nearer, inv.geom_id, rest.geom_id)
        got_dist = np.where(nearer, inv.dist_m, rest.dist_m)
        np.testing.assert_array_equal(got_geom, want.geom_id)
        np.testing.assert_allclose(got_dist, want.dist_m, rtol=0, atol=1e-12)
        on_disk = want.geom_id == disk
        np.testing.assert_allclose(inv.normal_base[on_disk], want.normal_base[on_disk] @ R, atol=1e-12)


def test_skipping_the_invariant_geoms_is_refused_where_mujoco_casts_them():
    scene = build_scene(RigGeometry(), load_plant(bundled_plant_path("maize")))
    scene.model  # compiled: MuJoCo casts the primitives
    backend = embree.EmbreeBackend(scene, nthread=1)
    assert backend.cast_invariant(np.zeros((1, 3)), np.array([[1.0, 0, 0]])) is None
    with pytest.raises(ValueError, match="skip_invariant"):
        backend.cast_turning(np.zeros((1, 3)), np.array([[1.0, 0, 0]]), skip_invariant=True)
